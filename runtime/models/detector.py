"""Object detector adapters: image + object names -> `perception.Detections`.

Closed-set detectors (SSD MobileNet on COCO here) map the question's names onto their label list through
`SYNONYMS` (sofa -> couch, table -> dining table, tv -> tv/tvmonitor, plant -> potted plant ...). A name that
maps to no label is returned in `Detections.undetectable` -- never silently treated as "not present".
Open-vocabulary detectors (OWLv2, `owlv2.py`) take the names directly and cache a text embedding per name.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..types import Detections
from . import ImageLRU, RoleModel, preprocess_image
from ..infra.bundle import load_bundle

# question name -> candidate labels (the first one present in the model's label list is used; several may be).
SYNONYMS: dict[str, list[str]] = {
    "sofa": ["couch", "sofa"],
    "couch": ["couch", "sofa"],
    "table": ["dining table", "diningtable"],
    "dining table": ["dining table", "diningtable"],
    "desk": ["dining table", "diningtable"],
    "tv": ["tv", "tvmonitor"],
    "television": ["tv", "tvmonitor"],
    "monitor": ["tv", "tvmonitor"],
    "tv monitor": ["tv", "tvmonitor"],
    "screen": ["tv", "tvmonitor"],
    "plant": ["potted plant", "pottedplant"],
    "potted plant": ["potted plant", "pottedplant"],
    "fridge": ["refrigerator"],
    "refrigerator": ["refrigerator"],
    "stool": ["chair"],
    "chair": ["chair"],
    "bed": ["bed"],
    "toilet": ["toilet"],
    "sink": ["sink"],
    "laptop": ["laptop"],
    "computer": ["laptop", "tv", "tvmonitor"],
    "microwave": ["microwave"],
    "oven": ["oven"],
    "stove": ["oven"],
    "toaster": ["toaster"],
    "book": ["book"],
    "clock": ["clock"],
    "vase": ["vase"],
    "cup": ["cup"],
    "mug": ["cup"],
    "bottle": ["bottle"],
    "bowl": ["bowl"],
    "keyboard": ["keyboard"],
    "mouse": ["mouse"],
    "phone": ["cell phone"],
    "cell phone": ["cell phone"],
    "backpack": ["backpack"],
    "bag": ["handbag", "backpack", "suitcase"],
    "suitcase": ["suitcase"],
    "umbrella": ["umbrella"],
    "bench": ["bench"],
    "person": ["person"],
    "car": ["car"],
    "bicycle": ["bicycle"],
    "teddy bear": ["teddy bear"],
}


def normalize_name(name: str) -> str:
    return " ".join(name.lower().replace("_", " ").replace("-", " ").split())


def closed_labels(bundle: Any) -> list[str] | None:
    """The label list of the bundle's closed-set detector; None without a detector or with an open-vocabulary
    one. bundle: a bundle folder or a loaded `Bundle`."""
    b = load_bundle(bundle) if isinstance(bundle, (str, os.PathLike)) else bundle
    return (b.spec("detector", verify=False).semantics.get("labels") or None) if b.has_role("detector") else None


def one_name_per_label(mapping: dict[str, list[int]], labels: Sequence[str], preferred: Sequence[str]) -> set[str]:
    """Names that reach the same detector labels are aliases of one detection (desk / table -> "dining table",
    monitor / tv -> "tv"): keep one per label set — a `preferred` name, else the one that is the label itself,
    else the label's head noun ("table" for "dining table", not the alphabetically first alias "desk"), else the
    alphabetically first — so a map of every category names each detection once."""
    groups: dict[tuple[int, ...], list[str]] = {}
    for n, ids in mapping.items():
        groups.setdefault(tuple(sorted(ids)), []).append(n)
    keep = set()
    for ids, names in groups.items():
        exact = [n for n in names if any(normalize_name(labels[i]) == normalize_name(n) for i in ids)]
        head = [n for n in names if any(normalize_name(labels[i]).split(" ")[-1] == normalize_name(n) for i in ids)]
        pref = [n for n in names if n in preferred]
        keep.add(sorted(pref or exact or head or names)[0])
    return keep


def map_names(names: Sequence[str], labels: Sequence[str]) -> tuple[dict[str, list[int]], list[str]]:
    """Question names -> label ids of a closed label list, and the names that cannot be detected.

    Exact label matches (after normalising case, '_' and '-') and singular forms ('chairs' -> chair) count;
    otherwise `SYNONYMS` is consulted. Returns ({name: [label ids]}, undetectable names).
    """
    index: dict[str, list[int]] = {}
    for i, lab in enumerate(labels):
        index.setdefault(normalize_name(lab), []).append(i)
    mapping: dict[str, list[int]] = {}
    missing: list[str] = []
    for name in names:
        n = normalize_name(name)
        cands = [n, n[:-1] if n.endswith("s") else n] + SYNONYMS.get(n, []) + SYNONYMS.get(n[:-1], [])
        ids = sorted({i for c in cands for i in index.get(normalize_name(c), []) if normalize_name(c) != "n/a"})
        if ids:
            mapping[name] = ids
        else:
            missing.append(name)
    return mapping, missing


@dataclass
class DetectorConf:
    """score_threshold: a detection the key-frame search counts and a single view may stand on alone;
    candidate_threshold: key-frame perception keeps detections down to this score for the map to verify across
    views (`map.verify`; None = score_threshold: no candidates below it); nms_iou: per-class NMS where the graph
    has none (YOLOX); max_detections per frame."""

    score_threshold: float = 0.5   # SSD MobileNet v1 quantised: 0.5 is the TFLite example's default
    candidate_threshold: float | None = None
    nms_iou: float = 0.45
    max_detections: int = 100

    @property
    def floor(self) -> float:
        """The lowest score any call can ask for (what the graph run keeps)."""
        c = self.candidate_threshold
        return min(self.score_threshold, c) if c is not None else self.score_threshold


def detector_conf(spec: Any) -> DetectorConf:
    """The manifest's `config` fields that are DetectorConf's (others belong to the adapter)."""
    return DetectorConf(**{k: v for k, v in spec.config.items() if k in DetectorConf.__dataclass_fields__})


class LabelDetector(RoleModel):
    """A closed-set detector over `semantics.labels`: subclasses implement `_run(rgb) -> (boxes [N, 4] pixels x0
    y0 x1 y1 float32, class ids [N] int64, scores [N] float32)` with every detection at or above `conf.floor`;
    this class maps the question's names onto labels, filters by score and caches one graph run per image."""

    role = "detector"

    def __init__(self, spec, sessions, trace, conf: DetectorConf | None = None):
        super().__init__(spec, sessions, trace)
        self.role = spec.role  # one adapter class may serve the detector and the instance_segmenter role
        self.conf = conf or detector_conf(spec)
        self.score_threshold = self.conf.score_threshold  # the role's one confidence threshold (the manifest's)
        self.labels: list[str] = list(spec.semantics["labels"])
        self.vocabulary = "closed"
        self._input = self.session().input_names[0]
        # the search detects a frame with the question's names, perception and alignment again with every label:
        # one graph run. Every scored frame is kept (the planner scores <= 6 K; a frame's boxes are a few kB)
        self._raw = ImageLRU(512)

    def raw(self, rgb: np.ndarray) -> tuple[np.ndarray, ...]:
        """All detections at or above `conf.floor`: boxes [N, 4] pixels x0 y0 x1 y1, class ids [N], scores [N]
        (read-only arrays, shared by every call on the same image; adapters may append more per-detection
        arrays after these three)."""
        return self._raw.cached(rgb, self._run)

    def _run(self, rgb: np.ndarray) -> tuple[np.ndarray, ...]:
        raise NotImplementedError

    def detect(self, rgb: np.ndarray, names: Sequence[str], min_score: float | None = None) -> Detections:
        """rgb [H, W, 3] uint8, names: the question's object names -> Detections in those names with score >=
        `min_score` (default `conf.score_threshold`; at most down to `conf.floor`)."""
        with self._overhead(self.role):
            return self._detect(rgb, names, min_score)

    def _select(self, rgb: np.ndarray, names: Sequence[str], min_score: float | None
                ) -> tuple[np.ndarray, list[str], list[str]]:
        """(indices into `raw(rgb)`, their names, the names it cannot detect), by score then name order."""
        mapping, missing = map_names(names, self.labels)
        if missing and not getattr(self, "_warned", set()) >= set(missing):
            self._warned = getattr(self, "_warned", set()) | set(missing)
            self.trace.event("undetectable", f"{self.name}: closed label set cannot detect {missing}",
                             names=missing, stage=self.role)
        raw = self.raw(rgb)
        cls, sc = raw[1], raw[2]
        thr = self.conf.score_threshold if min_score is None else max(float(min_score), self.conf.floor)
        taken = sc < thr
        idx: list[np.ndarray] = []
        out_n: list[str] = []
        # one detection is one object whatever alias names it (COCO "chair" is both chair and stool): names that
        # are the label itself claim their detections first, an alias only gets the ones left
        order = sorted(mapping, key=lambda n: not any(normalize_name(self.labels[i]) == normalize_name(n)
                                                      for i in mapping[n]))
        for name in order:
            sel = np.isin(cls, mapping[name]) & ~taken
            taken |= sel
            idx.append(np.flatnonzero(sel))
            out_n += [name] * int(sel.sum())
        return (np.concatenate(idx) if idx else np.zeros(0, np.int64)), out_n, missing

    def _detect(self, rgb: np.ndarray, names: Sequence[str], min_score: float | None) -> Detections:
        idx, out_n, missing = self._select(rgb, names, min_score)
        if not out_n:
            return Detections.empty(missing)
        raw = self.raw(rgb)
        return Detections(raw[0][idx], raw[2][idx], out_n, undetectable=missing)


class ClosedSetDetector(LabelDetector):
    """TFLite-style SSD graph with NMS inside: outputs boxes [1, N, 4] (ymin, xmin, ymax, xmax normalised),
    classes [1, N] (index into semantics.labels), scores [1, N], count [1]."""

    def _run(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        H, W = rgb.shape[:2]
        x = preprocess_image(rgb, self.spec.preprocessing)
        with self._stage(self.role):
            boxes, classes, scores, count = self.session().run({self._input: x})
        n = int(np.asarray(count).reshape(-1)[0])
        b, c, s = boxes[0, :n], classes[0, :n].astype(np.int64), scores[0, :n].astype(np.float32)
        keep = s >= self.conf.floor
        b, c, s = b[keep], c[keep], s[keep]
        px = np.stack([b[:, 1] * W, b[:, 0] * H, b[:, 3] * W, b[:, 2] * H], 1).clip(0, [W, H, W, H])
        return px.astype(np.float32), c, s
