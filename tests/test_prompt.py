"""Visual prompt content (colours, labels, scale bar, modes), the VLM prompt structure, robust multiple-choice
parsing, VLM answering/grounding paths (with scripted replies) and the answerer routing."""
from __future__ import annotations

import numpy as np
import pytest

from mosaicthinker.runtime.infra import errors
from mosaicthinker.runtime.answer import answer_question, answer_with_vlm, parse_choice, parse_number
from mosaicthinker.runtime.geometry import OrientedBox, rotation_about
from mosaicthinker.runtime.grounding import ground
from mosaicthinker.runtime.prompt import distinct_colours, render, text_block, vlm_prompt
from mosaicthinker.runtime.map import ObjectInstance, SemanticMap
from mosaicthinker.runtime.infra.trace import Trace


def _box(c, size, yaw=0.0):
    return OrientedBox(np.asarray(c, float), np.asarray(size, float), rotation_about([0, 0, 1], np.radians(yaw)).T)


def _map() -> SemanticMap:
    inst = [ObjectInstance(0, "sofa", _box([0.0, 2.0, 0.4], [2.0, 0.9, 0.8], 0), 1.0),
            ObjectInstance(1, "table", _box([2.5, 0.5, 0.35], [1.2, 0.7, 0.7], 30), 2.0),
            ObjectInstance(2, "chair", _box([-1.5, -0.5, 0.45], [0.5, 0.5, 0.9], 0), 3.0)]
    cams = [(0.0, np.eye(4)), (1.0, np.eye(4))]
    cams[1][1][:3, 3] = [1.0, -1.0, 1.5]
    return SemanticMap(inst, None, cams)


class Scripted:
    """A VLM stand-in that returns fixed replies (tests the parsing and routing around a VLM, not a model)."""

    def __init__(self, *replies: str):
        self.replies = list(replies)
        self.prompts: list[str] = []
        self.images: list[list[np.ndarray]] = []

    def generate(self, images, prompt, max_new_tokens=None):
        self.prompts.append(prompt)
        self.images.append(list(images))
        return self.replies.pop(0) if len(self.replies) > 1 else self.replies[0]


def test_grid_image_has_each_colour_label_and_a_correct_scale_bar():
    smap = _map()
    vp = render(smap, {"size_px": 640})
    img = vp.image
    assert img.dtype == np.uint8 and img.ndim == 3 and max(img.shape[:2]) <= 640
    cols = distinct_colours(3)
    assert len(set(cols)) == 3
    for o in smap.instances:
        # the box outline in the object's own colour is drawn around its centre
        c = vp.colours[o.id]
        assert c == cols[o.id]
        u, v = vp.world_to_px(o.center[None, :2])[0].round().astype(int)
        win = img[max(0, v - 60):v + 60, max(0, u - 80):u + 80].reshape(-1, 3).astype(int)
        assert np.any(np.abs(win - np.array(c)).sum(1) <= 6), f"colour of {o.name} missing"
        # the label (dark text in a darker shade of the colour) sits on the centre
        dark = tuple(int(x * 0.6) for x in c)
        lab = img[v - 8:v + 8, u - 40:u + 40].reshape(-1, 3).astype(int)
        assert np.any(np.abs(lab - np.array(dark)).sum(1) <= 40), f"label of {o.name} missing"
    # scale bar: its length in pixels is its length in metres times the image scale, and it is drawn
    assert vp.scale_bar_px == round(vp.scale_bar_m * vp.px_per_m)
    assert vp.scale_bar_m in (0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
    H = img.shape[0]
    y0, x0 = H - 48 // 2, 48 // 2
    row = (img[y0, :, :] < 40).all(1)
    run = np.flatnonzero(row)
    # (line caps and end ticks add up to 2 px on each side)
    assert abs(run.min() - x0) <= 2 and run.max() - run.min() + 1 == pytest.approx(vp.scale_bar_px + 1, abs=4)
    # metric consistency: two points 1 m apart are px_per_m pixels apart
    a, b = vp.world_to_px(np.array([[0.0, 0.0], [1.0, 0.0]]))
    assert np.linalg.norm(b - a) == pytest.approx(vp.px_per_m)
    # camera positions are drawn as black dots
    u, v = vp.world_to_px(np.array([[1.0, -1.0]]))[0].round().astype(int)
    assert (img[v - 2:v + 3, u - 2:u + 3] < 30).all(-1).any()


def test_text_block_and_modes():
    smap = _map()
    t = text_block(smap)
    assert "sofa #0: centre (0.00, 2.00, 0.40), size (2.00 x 0.90 x 0.80)" in t
    assert "table #1" in t and "yaw 30 deg" in t
    vp = render(smap, {"mode": "text"})
    assert vp.image is None and vp.text == t
    pts = np.array([[0.8, 2.3, 0.4]] * 10 + [[2.5, 0.5, 0.3]] * 10)  # away from the label
    ids = np.array([0] * 10 + [1] * 10)
    vp = render(smap, {"mode": "points"}, pts, ids)
    u, v = vp.world_to_px(pts[:1, :2])[0].round().astype(int)
    assert tuple(vp.image[v, u]) == vp.colours[0]
    with pytest.raises(errors.InputError, match="mode"):
        render(smap, {"mode": "3d"})
    p = vlm_prompt("Which is closest?", ["A. sofa", "B. chair"], t, "grid")
    assert p.index("top-down map") < p.index("Objects in the map") < p.index("Question:") < p.index("A. sofa")
    assert p.rstrip().endswith("Answer with the option's letter only.")
    assert "single number" in vlm_prompt("How many?", None, t, "text")


@pytest.mark.parametrize("reply,letter", [
    ("B", "B"), ("b", "B"), ("(B)", "B"), ("B.", "B"), ("Answer: B.", "B"), ("The answer is (b).", "B"),
    ("B. right", "B"), ("right", "B"), ("It is to my back.", "C"), ("**C**", "C"), ("Option C", "C"),
    ("<end_of_utterance>A", "A"), ("I think it is C", "C"),
    ("left or right", None), ("D", None), ("", None), ("back-left", None)])
def test_parse_choice(reply, letter):
    assert parse_choice(reply, ["A. left", "B. right", "C. back"]) == letter


def test_parse_choice_prefers_longest_option_text_and_parse_number():
    opts = ["A. front-left", "B. front-right", "C. back-left", "D. back-right"]
    assert parse_choice("back-left", opts) == "C"
    assert parse_choice("It is front-right of me", opts) == "B"
    assert parse_choice("left", opts) is None
    assert parse_number("about 2.5 meters") == 2.5
    assert parse_number("Answer: 1,200 cm") == 1200.0
    assert parse_number("2,5") == 2.5
    assert parse_number("no idea") is None


def test_vlm_answer_parsed_retried_and_unparsed_reported():
    smap = _map()
    q = "Which of these objects (sofa, chair) is the closest to the table?"
    opts = ["A. sofa", "B. chair"]
    vlm = Scripted("hmm, hard to say", "Answer: (A)")
    t = Trace()
    a = answer_with_vlm(vlm, q, opts, "PROMPT", [np.zeros((4, 4, 3), np.uint8)], trace=t)
    assert a.ok and a.text == "A" and len(vlm.prompts) == 2 and "exactly one letter" in vlm.prompts[1]
    a = answer_with_vlm(Scripted("no idea"), q, opts, "PROMPT", [], trace=t)
    assert a.status == "unparsed" and not a.ok
    assert any(e["kind"] == "degraded" and "could not be parsed" in e["message"] for e in t.events)


def test_answerer_routing_auto_map_vlm_and_not_found():
    smap = _map()
    t = Trace()
    q = "How many chair(s) are in this room?"
    a = answer_question(smap, q, None, "auto", None, None, t)
    assert a.text == "1" and t.decisions["answer.answerer"] == "map"
    # vlm answerer: the grid image and the text block go to the VLM
    vlm = Scripted("2")
    a = answer_question(smap, q, None, "vlm", vlm, None, t)
    assert a.text == "2" and len(vlm.images[0]) == 1 and vlm.images[0][0].ndim == 3
    assert "chair #2" in vlm.prompts[0] and "Question: How many chair(s)" in vlm.prompts[0]
    # a free-form question goes to the VLM under auto; without a VLM it is reported, not guessed
    free = "Is the sofa softer than the chair?"
    assert answer_question(smap, free, ["A. yes", "B. no"], "auto", Scripted("A"), None, t).text == "A"
    a = answer_question(smap, free, ["A. yes", "B. no"], "auto", None, None, t)
    assert a.status == "unsupported"
    # objects missing from the map: explicit not-found, the VLM is not asked
    vlm = Scripted("A")
    a = answer_question(smap, "How many bed(s) are in this room?", None, "vlm", vlm, None, t)
    assert a.status == "not_found" and a.missing == ["bed"] and vlm.prompts == []


class ScriptedProgram(Scripted):
    """A scripted VLM that decodes "under a schema": it records the guidance and replies with fixed text."""

    supports_guidance = True

    def __init__(self, *replies: str):
        super().__init__(*replies)
        self.guidance: list = []

    def generate(self, images, prompt, max_new_tokens=None, guidance=None):
        self.guidance.append(guidance)
        return super().generate(images, prompt, max_new_tokens)


def test_vlm_grounding_emits_a_validated_program_or_is_refused():
    import json

    q = "Is the couch bigger than whatever sits by the window?"  # the rules refuse it (no two objects to compare)
    t = Trace()
    frames = [np.zeros((8, 8, 3), np.uint8)] * 3
    assert ground(q, None, None, None, t).program is None
    vlm = ScriptedProgram('{"kind":"size_compare","measure":"biggest","candidates":[{"name":"couch"},'
                          '{"name":"unicorn"}],"form":"yesno"}')
    pq = ground(q, None, vlm, frames, t)  # auto: the rules refused, so the VLM reads it
    assert pq.how == "vlm" and pq.qtype == "object_size_compare" and pq.targets == ["sofa", "unicorn"]
    assert pq.node.candidates[0].phrase == "couch" and pq.unknown == ["unicorn"] and len(vlm.images[0]) == 3
    kind, schema = vlm.guidance[0]
    assert kind == "json_schema" and json.loads(schema)["$id"] == "mosaicthinker.query/1"
    assert t.decisions["grounding"]["method"] == "vlm"
    assert any(e["kind"] == "unknown_objects" and "unicorn" in e["message"] for e in t.events)
    # auto: what the rules read is never sent to the VLM
    vlm = ScriptedProgram('{"kind":"room_size"}')
    assert ground("How many chairs are there?", None, vlm, frames, Trace()).qtype == "object_counting"
    assert vlm.prompts == []
    # a reply that is not a valid program (cut off, wrong field) is refused with the reason, never repaired
    for bad, why in (('{"kind":"count","objects":[{"name":"chair"}', "not JSON"),
                     ('{"kind":"count","objects":[]}', "0 items"), ('{"kind":"fly"}', "kind 'fly'")):
        t = Trace()
        with pytest.warns(RuntimeWarning, match="refused"):
            pq = ground(q, None, ScriptedProgram(bad), frames, t, grounding="vlm")
        assert pq.program is None and pq.how == "none" and why in pq.notes[-1]
    # a VLM exported for another program version is still read under this runtime's schema, said loudly
    old = ScriptedProgram('{"kind":"room_size"}')
    old.query_schema = "mosaicthinker.query/0"
    with pytest.warns(RuntimeWarning, match="exported for question programs mosaicthinker.query/0"):
        assert ground(q, None, old, frames, Trace(), grounding="vlm").qtype == "room_size_estimation"
    # a VLM that cannot decode under a schema is refused, not asked for free text
    with pytest.warns(RuntimeWarning, match="cannot decode under a JSON schema"):
        pq = ground(q, None, Scripted("count chairs"), frames, Trace(), grounding="vlm")
    assert pq.program is None
    with pytest.raises(errors.InputError, match="grounding"):
        ground(q, None, None, None, Trace(), grounding="vlm")


def test_direct_input_baseline_sends_uniform_frames_to_the_vlm():
    from mosaicthinker.runtime import AskRequest, InputError, ask
    from mosaicthinker.runtime.types import Frame
    from mosaicthinker.runtime.frames import FrameList

    K = np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
    frames = [Frame(np.full((48, 64, 3), i, np.uint8), i / 10, i, K) for i in range(40)]
    vlm = Scripted("Answer: (C)")
    q = "If I am standing by the tv and facing the sofa, is the chair to my left, right, or back?"
    res = ask(FrameList(frames), q, ["A. left", "B. right", "C. back"], AskRequest(method="direct"), vlm=vlm)
    assert res.answer.text == "C" and res.method == "direct" and res.map is None
    sent = vlm.images[-1]
    assert len(sent) == 8 and [int(im[0, 0, 0]) for im in sent] == [2, 7, 12, 17, 22, 27, 32, 37]
    assert "frames sampled uniformly" in vlm.prompts[-1] and "Question: If I am standing" in vlm.prompts[-1]
    with pytest.raises(InputError, match="vlm"):
        ask(FrameList(frames), q, None, AskRequest(method="direct"))


def test_labels_of_overlapping_boxes_do_not_overlap_and_the_map_has_a_title():
    """Three chairs around one spot and a table under them: every label is drawn, no two label boxes
    intersect, all stay visible in the picture, and there is a title."""
    from mosaicthinker.runtime.prompt import place_labels

    inst = [ObjectInstance(i, n, _box(c, s), 1.0) for i, (n, c, s) in enumerate([
        ("table", [0.0, 0.0, 0.4], [1.4, 0.9, 0.8]), ("chair", [0.02, 0.01, 0.45], [0.5, 0.5, 0.9]),
        ("chair", [-0.01, 0.0, 0.45], [0.5, 0.5, 0.9]), ("chair", [0.0, -0.02, 0.45], [0.5, 0.5, 0.9])])]
    smap = SemanticMap(inst, None, [(0.0, np.eye(4))])
    anchors = np.array([[100, 100], [102, 101], [98, 100], [100, 97]], float)
    sizes = np.array([[60, 14], [60, 14], [60, 14], [60, 14]], float)
    tl = place_labels(anchors, sizes, (400, 300))
    boxes = np.concatenate([tl, tl + sizes], 1)
    for i in range(4):
        assert (boxes[i, :2] >= 0).all() and boxes[i, 2] <= 400 and boxes[i, 3] <= 300
        for j in range(i):
            a, b = boxes[i], boxes[j]
            assert a[0] >= b[2] or a[2] <= b[0] or a[1] >= b[3] or a[3] <= b[1], (i, j)
    assert np.allclose(tl[0], anchors[0] - sizes[0] / 2)  # the first label stays on its box centre
    # chairs on one spot: their labels are moved apart, so every label stays visible (a label drawn over
    # another would leave almost none of the first one's colour)
    vp = render(smap, {"size_px": 640})
    img = vp.image.reshape(-1, 3).astype(int)
    for o in smap.instances:
        dark = np.array([int(x * 0.6) for x in vp.colours[o.id]])
        assert (np.abs(img - dark).sum(1) <= 30).sum() >= 25, f"label of {o.name} {o.id} hidden"
    # a title in black along the top margin
    assert (vp.image[:24, 20:300] < 40).all(-1).sum() > 50


def test_prompt_reasoner_and_vlm_configs_merge_like_every_stage_config():
    """One merge rule (config.StageConf): overrides by mapping, unknown keys and bad values named."""
    from mosaicthinker.runtime.answer import MapReasoner, VLMConfig
    from mosaicthinker.runtime.infra.errors import InputError
    from mosaicthinker.runtime.prompt import PromptConfig, render

    smap = _map()
    small = render(smap, {"size_px": 256})
    assert max(small.image.shape[:2]) == 256
    with pytest.raises(InputError, match="unknown key"):
        render(smap, {"size": 3})
    with pytest.raises(InputError, match="mode"):
        PromptConfig.merged(mode="sketch")
    assert MapReasoner(smap, {"distance_decimals": 2}).conf.distance_decimals == 2
    with pytest.raises(InputError, match="unknown key"):
        MapReasoner(smap, {"decimals": 2})
    assert VLMConfig.merged({"max_new_tokens": 8}).max_new_tokens == 8
    with pytest.raises(InputError, match="max_new_tokens"):
        VLMConfig.merged(max_new_tokens=0)
def test_json_spatial_code_mode():
    import json

    smap = _map()
    vp = render(smap, {"mode": "json"})
    assert vp.image is None and vp.mode == "json"
    code = json.loads(vp.text)
    by_label = {o["label"]: o for o in code["objects"]}
    assert set(by_label) == {"sofa", "table", "chair"} and code["units"] == "m"
    assert by_label["table"]["center"] == [2.5, 0.5, 0.35] and by_label["table"]["size"] == [1.2, 0.7, 0.7]
    assert by_label["table"]["yaw_deg"] == 30 and by_label["sofa"]["id"] == 0
    assert code["camera"]["last"][:2] == [1.0, -1.0]
    assert " " not in vp.text.replace("x right, y forward, z up", "")  # compact separators
    p = vlm_prompt("How many chairs?", None, vp.text, "json")
    assert "JSON spatial code" in p and p.index(vp.text) < p.index("Question:")
