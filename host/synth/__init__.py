"""Synthetic indoor scenes with full ground truth (evaluation only: the pipeline never imports this package).

- `stats`: VSI-Bench (ARKitScenes) statistics the scenes are drawn from (`vsibench_stats.json`);
- `scene`: `SceneConfig`, `generate_scene` (room, furniture from textured primitives, placement);
- `trajectory`: `camera_track` (handheld walk-through);
- `render`: `Renderer` (CPU rasteriser: RGB, depth, instance masks, coverage);
- `generate`: `write_scene` (7-Scenes-style folder + mp4 + scene.json + questions.jsonl), `load_scene`;
- `questions`: `generate_questions` (answers from `evaluation.box_truth`), `ground_truth_map`;
- `oracle`: `OracleDetector` (detections from instance masks with controlled misses and score noise);
- `cli`: `mosaic synth`.
"""
