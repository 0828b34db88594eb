"""The map reasoner: answers VSI-Bench question types exactly from a `SemanticMap`.

`MapReasoner(map).answer(question, options) -> Answer`. The question is parsed by `grounding.parse_question`;
an object the map does not hold gives `status="not_found"` (never a guess), a question the templates do not
cover or the map cannot decide gives `status="unsupported"`.

Conventions (general geometric rules; they reproduce the benchmark's own answers, see README / tests):
- object_counting: number of instances of the category.
- object_size_estimation: longest box dimension (m -> cm, rounded to an integer); several instances -> the
  largest (reported in the explanation).
- room_size_estimation: floor area (m^2, 1 decimal) of the map's room extent (`SemanticMap.room_area`).
- object_abs_distance: shortest distance between the two solid boxes (closest points), minimised over the
  instances of each category; metres, 1 decimal.
- object_rel_distance: the candidate whose closest instance (same box distance) is nearest (or farthest) to the
  reference object's instances.
- object_rel_direction_*: on the floor plane (x, y), standing at the centre of A's box and facing the centre of
  B's box; the angle θ of C's centre is measured counter-clockwise from the facing direction (left positive,
  z up). hard: front-left θ∈[0,90), back-left [90,180), back-right [180,270), front-right [270,360).
  medium: back when the turn |θ| >= 135° (the question's own rule), else left for θ>0, right for θ<0.
  easy ("is C to the left or the right of B"): the side of the line of sight A->B that C lies on (sign of θ).
- route_planning: start at A's centre heading to B's centre; "Go forward until X" moves to X's centre (nearest
  instance) and sets the heading along the move; each "[please fill in]" is the turn towards the next waypoint:
  back when |turn| >= 135°, else left/right by its sign.
- obj_appearance_order: categories ordered by their earliest `first_seen` time.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .geometry import box_distance
from .grounding import ParsedQuestion, parse_question, split_options
from .semantic_map import ObjectInstance, SemanticMap

NUMERIC_QTYPES = ("object_counting", "object_size_estimation", "room_size_estimation", "object_abs_distance")


@dataclass
class ReasonerConfig:
    """Question conventions (defaults reproduce VSI-Bench)."""

    back_deg: float = 135.0  # medium directions and route turns: "back" from this turn angle on
    distance_decimals: int = 1  # metres
    room_decimals: int = 1  # square metres


@dataclass
class Answer:
    """text: the answer as the benchmark writes it (the option letter for multiple choice, the number for
    numeric questions; "not found: ..." / "unsupported: ..." otherwise); value: the computed value (number,
    direction word, object name, or list of turns / categories); status: 'ok' | 'not_found' | 'unsupported'; explanation: how it was computed;
    missing: object names the question needs that the map lacks."""

    text: str
    value: Any = None
    status: str = "ok"
    explanation: str = ""
    missing: list[str] = field(default_factory=list)
    qtype: str | None = None
    parsed: ParsedQuestion | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_dict(self) -> dict[str, Any]:
        return {"text": self.text, "value": self.value, "status": self.status, "explanation": self.explanation,
                "missing": list(self.missing), "qtype": self.qtype,
                "parsed": None if self.parsed is None else self.parsed.to_dict()}


class _NotFound(Exception):
    def __init__(self, names: list[str]):
        super().__init__(", ".join(names))
        self.names = names


class _Unsupported(Exception):
    pass


def signed_angle_deg(facing: np.ndarray, target: np.ndarray) -> float:
    """Counter-clockwise angle (degrees, (-180, 180]) from 2D vector `facing [2]` to `target [2]` (z up:
    positive = to the left)."""
    f = np.asarray(facing, float)[:2]
    t = np.asarray(target, float)[:2]
    a = float(np.degrees(math.atan2(f[0] * t[1] - f[1] * t[0], f[0] * t[0] + f[1] * t[1])))
    return 180.0 if a <= -180.0 else a


def direction_label(theta_deg: float, level: str, back_deg: float = 135.0) -> str:
    """Direction word for a counter-clockwise angle `theta_deg` from the facing direction.

    level: 'easy' (left/right), 'medium' (left/right/back), 'hard' (front-left/front-right/back-left/back-right).
    """
    th = theta_deg % 360.0
    if level == "hard":
        return ("front-left", "back-left", "back-right", "front-right")[int(th // 90) % 4]
    if level == "medium":
        if back_deg <= th <= 360.0 - back_deg:
            return "back"
        return "left" if th < 180.0 else "right"
    if level == "easy":
        return "left" if 0.0 < th < 180.0 else "right"
    raise ValueError(f"direction level {level!r}: expected easy, medium or hard")


def turn_label(theta_deg: float, back_deg: float = 135.0) -> str:
    """'turn left' / 'turn right' / 'turn back' for a heading change of `theta_deg` (counter-clockwise +)."""
    if abs(theta_deg) >= back_deg:
        return "turn back"
    return "turn left" if theta_deg > 0 else "turn right"


def _norm(s: str) -> str:
    return " ".join(str(s).lower().replace(",", " , ").split())


class MapReasoner:
    """Answers questions from a `SemanticMap` (see the module docstring for the conventions)."""

    def __init__(self, smap: SemanticMap, conf: ReasonerConfig | dict | None = None):
        self.map = smap
        self.conf = conf if isinstance(conf, ReasonerConfig) else ReasonerConfig(**(conf or {}))

    # ------------------------------------------------------------------ entry point
    def answer(self, question: str, options: list[str] | None = None,
               parsed: ParsedQuestion | None = None) -> Answer:
        """Answer one question. `parsed` may be given (e.g. from a VLM grounding); else the templates parse it."""
        pq = parsed if parsed is not None else parse_question(question, options)
        if options is None:
            options = pq.options
        if pq.qtype is None:
            return Answer("unsupported: not a recognised question template", None, "unsupported",
                          "no VSI-Bench template matches; use the VLM answerer", [], None, pq)
        try:
            value, expl = getattr(self, "_" + pq.qtype)(pq)
        except _NotFound as e:
            return Answer(f"not found: {', '.join(e.names)}", 0 if pq.qtype == "object_counting" else None,
                          "not_found", f"not in the map: {', '.join(e.names)}", e.names, pq.qtype, pq)
        except _Unsupported as e:
            return Answer(f"unsupported: {e}", None, "unsupported", str(e), [], pq.qtype, pq)
        if pq.qtype in NUMERIC_QTYPES and not options:
            return Answer(self._format_number(pq.qtype, value), value, "ok", expl, [], pq.qtype, pq)
        letter, text = self._choose(value, options)
        if letter is None:
            return Answer(f"unsupported: computed {value!r} matches no option", value, "unsupported",
                          expl + f"; options: {options}", [], pq.qtype, pq)
        if options:
            expl += f" -> option {letter}. {text}"
        return Answer(letter, value, "ok", expl, [], pq.qtype, pq)

    # ------------------------------------------------------------------ helpers
    def _format_number(self, qtype: str, v: float) -> str:
        if qtype in ("object_counting", "object_size_estimation"):
            return str(int(round(v)))
        d = self.conf.room_decimals if qtype == "room_size_estimation" else self.conf.distance_decimals
        return f"{round(float(v), d):.{d}f}"

    def _choose(self, value: Any, options: list[str] | None) -> tuple[str | None, Any]:
        """Option letter for a computed value: exact text match (case/space-insensitive), or the nearest number."""
        if not options:
            return (str(value) if not isinstance(value, list) else ", ".join(value)), value
        opts = split_options(options)
        want = _norm(", ".join(value) if isinstance(value, list) else value)
        for letter, text in opts:
            if _norm(text) == want:
                return letter, text
        if isinstance(value, (int, float, np.floating, np.integer)):
            nums = []
            for letter, text in opts:
                m = re.match(r"\s*([-+]?\d+(?:\.\d+)?)", text)  # "2.5", "2.5 m", "160 cm"
                if m:
                    nums.append((abs(float(m.group(1)) - float(value)), letter, text))
            if nums:
                _, letter, text = min(nums)
                return letter, text
        return None, value

    def _instances(self, name: str) -> list[ObjectInstance]:
        inst = self.map.by_name(name)
        if not inst:
            raise _NotFound([name])
        return inst

    def _require(self, names: list[str]) -> dict[str, list[ObjectInstance]]:
        missing = [n for n in dict.fromkeys(names) if not self.map.by_name(n)]
        if missing:
            raise _NotFound(missing)
        return {n: self.map.by_name(n) for n in names}

    @staticmethod
    def _min_distance(a: list[ObjectInstance], b: list[ObjectInstance]) -> tuple[float, ObjectInstance,
                                                                              ObjectInstance]:
        best = None
        # Exact pairs only where a bounding-sphere lower bound does not exceed the distance of one candidate
        # pair (`upper`): pairs beyond it can never be the minimum, so the result (incl. ties: the first
        # minimal pair in a x b order) is unchanged, and chair-to-table on a 10 k-object map is not 1 M solves.
        upper, cb, eb = _distance_upper_bound(a, b)
        for x in a:
            lb = _lower_bounds(x, cb, eb)
            for j in np.flatnonzero(lb <= upper + 1e-9):
                y = b[j]
                if x is y or (best is not None and lb[j] > best[0] + 1e-9):
                    continue
                d = box_distance(x.box, y.box)
                if best is None or d < best[0]:
                    best = (d, x, y)
            if best is not None and best[0] <= 0.0:  # touching: nothing later can be smaller
                break
        if best is None:
            raise _Unsupported("the two objects are the same single instance")
        return best

    # ------------------------------------------------------------------ question types
    def _object_counting(self, pq: ParsedQuestion) -> tuple[Any, str]:
        n = len(self._instances(pq.params["object"]))
        return n, f"{n} instance(s) of {pq.params['object']} in the map"

    def _object_size_estimation(self, pq: ParsedQuestion) -> tuple[Any, str]:
        inst = self._instances(pq.params["object"])
        sizes = [float(np.max(o.box.axes_lengths)) * 100.0 for o in inst]
        i = int(np.argmax(sizes))
        note = "" if len(inst) == 1 else f" (largest of {len(inst)} instances)"
        return sizes[i], f"longest box dimension of {pq.params['object']} #{inst[i].id}: {sizes[i]:.1f} cm{note}"

    def _room_size_estimation(self, pq: ParsedQuestion) -> tuple[Any, str]:
        area = self.map.room_area()
        if area is None:
            raise _Unsupported("the map has no room extent and no objects")
        src = self.map.room.source if self.map.room is not None else "object_boxes_hull"
        return area, f"floor area of the map's room extent ({src}): {area:.2f} m^2"

    def _object_abs_distance(self, pq: ParsedQuestion) -> tuple[Any, str]:
        a, b = pq.params["a"], pq.params["b"]
        inst = self._require([a, b])
        d, x, y = self._min_distance(inst[a], inst[b])
        return d, f"closest points of {a} #{x.id} and {b} #{y.id}: {d:.3f} m"

    def _object_rel_distance(self, pq: ParsedQuestion) -> tuple[Any, str]:
        ref, cands = pq.params["reference"], pq.params["candidates"]
        inst = self._require([ref] + cands)
        dists = {c: self._min_distance(inst[c], inst[ref])[0] for c in cands}
        pick = (min if pq.params.get("extreme", "closest") == "closest" else max)(dists, key=dists.get)
        return pick, "closest-point distances to " + ref + ": " + ", ".join(f"{c} {d:.2f} m" for c, d in dists.items())

    def _pick_unique(self, name: str, near: list[np.ndarray]) -> tuple[ObjectInstance, str]:
        """The instance of `name` to use as a position: the only one, or the one nearest the other objects."""
        inst = self._instances(name)
        if len(inst) == 1 or not near:
            return inst[0], ""
        c = np.mean(near, 0)
        o = min(inst, key=lambda o: float(np.linalg.norm(o.center[:2] - c[:2])))
        return o, f"; {name}: {len(inst)} instances, used #{o.id} (nearest the other objects)"

    def _rel_direction(self, pq: ParsedQuestion, level: str) -> tuple[Any, str]:
        p = pq.params
        self._require([p["position"], p["facing"], p["query"]])
        others = lambda *ns: [o.center for n in ns for o in self.map.by_name(n)]  # noqa: E731
        A, na = self._pick_unique(p["position"], others(p["facing"], p["query"]))
        B, nb = self._pick_unique(p["facing"], [A.center])
        C, nc = self._pick_unique(p["query"], [A.center, B.center])
        f = B.center[:2] - A.center[:2]
        if np.linalg.norm(f) < 1e-9:
            raise _Unsupported(f"standing by {p['position']} and facing {p['facing']}: same position")
        th = signed_angle_deg(f, C.center[:2] - A.center[:2])
        lab = direction_label(th, level, self.conf.back_deg)
        return lab, (f"at {p['position']} facing {p['facing']}: {p['query']} at {th:+.1f} deg "
                     f"(counter-clockwise) -> {lab}{na}{nb}{nc}")

    def _object_rel_direction_easy(self, pq: ParsedQuestion) -> tuple[Any, str]:
        return self._rel_direction(pq, "easy")

    def _object_rel_direction_medium(self, pq: ParsedQuestion) -> tuple[Any, str]:
        return self._rel_direction(pq, "medium")

    def _object_rel_direction_hard(self, pq: ParsedQuestion) -> tuple[Any, str]:
        return self._rel_direction(pq, "hard")

    def _route_planning(self, pq: ParsedQuestion) -> tuple[Any, str]:
        p = pq.params
        if "steps" not in p:
            raise _Unsupported(p.get("parse_error", "route not parsed"))
        names = [p["start"], p["facing"]] + [s["until"] for s in p["steps"] if s["action"] == "forward"]
        self._require(names)
        start = self.map.by_name(p["start"])
        face = self.map.by_name(p["facing"])
        pairs = [(a, b) for a in start for b in face if a is not b]
        if not pairs:
            raise _Unsupported(f"beginning at {p['start']} facing the same {p['facing']}: heading unknown")
        a, b = min(pairs, key=lambda ab: float(np.linalg.norm(ab[0].center[:2] - ab[1].center[:2])))
        pos, heading = a.center[:2].copy(), b.center[:2] - a.center[:2]
        turns, log = [], []
        pending = False
        for s in p["steps"]:
            if s["action"] == "turn":
                pending = True
                continue
            tgt = min(self.map.by_name(s["until"]), key=lambda o: float(np.linalg.norm(o.center[:2] - pos)))
            move = tgt.center[:2] - pos
            if np.linalg.norm(move) < 1e-6:
                if pending:
                    raise _Unsupported(f"turn towards {s['until']}: already there")
                continue
            if pending:
                th = signed_angle_deg(heading, move)
                turns.append(turn_label(th, self.conf.back_deg))
                log.append(f"{turns[-1]} ({th:+.0f} deg) to {s['until']}")
                pending = False
            pos, heading = tgt.center[:2].copy(), move
        if pending:
            raise _Unsupported("a turn without a following waypoint")
        value = [t.title() for t in turns]
        return value, "; ".join(log)

    def _obj_appearance_order(self, pq: ParsedQuestion) -> tuple[Any, str]:
        cats = pq.params["categories"]
        inst = self._require(cats)
        first = {}
        for c in cats:
            ts = [o.first_seen for o in inst[c] if o.first_seen is not None]
            if not ts:
                raise _Unsupported(f"the map has no first-seen time for {c} (built without video)")
            first[c] = min(ts)
        order = sorted(cats, key=lambda c: first[c])
        return order, "first seen: " + ", ".join(f"{c} {first[c]:.2f} s" for c in order)


# ----------------------------------------------------------------------------- parsing free-text replies (VLM)

_LETTER_PATTERNS = (
    # whole reply is a letter: "B", "(B)", "B.", "[B]", "**B**"
    re.compile(r"^\W*([A-Za-z])\W*$"),
    # "Answer: B", "The answer is (B).", "final answer - B", "option B", "choice: b"
    re.compile(r"\b(?:final\s+answer|answer|option|choice)\s*(?:is|would be|:|-|=)?\s*(?:option\s*)?[\(\[\*\"']*"
               r"([A-Za-z])(?![A-Za-z])", re.I),
    # reply starts with a lettered option: "B. left", "(B) left", "B) left", "B: left"
    re.compile(r"^\W*([A-Z])\s*[\.\):\]]"),
)


def parse_choice(reply: str, options: list[str] | None) -> str | None:
    """Option letter of a free-text multiple-choice reply, or None when it cannot be decided.

    Accepts "B", "(B)", "B.", "Answer: B.", "The answer is (b)", "B. left", the option text itself ("left",
    "The tv is to my back.") and a single lone capital letter naming an option. The letter must be one of the
    options' letters; an option text counts only when exactly one option's text is found (the longest texts
    first, so "back-left" is not read as "left"); several different letters -> None (never a guess).
    """
    opts = split_options(options)
    letters = {l for l, _ in opts}
    text = str(reply or "").strip()
    if not text or not opts:
        return None
    text = re.sub(r"<[^>]{1,20}>", " ", text).strip()  # stray special tokens such as <end_of_utterance>
    for rx in _LETTER_PATTERNS:
        m = rx.search(text)
        if m and m.group(1).upper() in letters:
            return m.group(1).upper()
    # the option text: whole-word match, longest first, each span used once
    low = " " + _norm(re.sub(r"[^\w\s\-,.]", " ", text)) + " "
    found: list[str] = []
    for letter, body in sorted(opts, key=lambda lt: -len(lt[1])):
        b = _norm(body)
        if not b:
            continue
        rx = re.compile(r"(?<![\w\-])" + re.escape(b) + r"(?![\w\-])")
        if rx.search(low):
            found.append(letter)
            low = rx.sub(" ", low)
    if len(set(found)) == 1:
        return found[0]
    if found:
        return None
    lone = set(re.findall(r"(?<![A-Za-z])([A-Z])(?![A-Za-z])", text)) & letters
    lone.discard("I")  # "I think ..." is not option I
    return lone.pop() if len(lone) == 1 else None


def parse_number(reply: str) -> float | None:
    """First number in a free-text numeric reply ("2.5", "about 2.5 meters", "Answer: 1,200 cm", "2,5") or None."""
    s = re.sub(r"(?<=\d),(?=\d{3}\b)", "", str(reply or ""))  # thousands separators
    m = re.search(r"[-+]?\d+(?:[.,]\d+)?", s)
    return None if m is None else float(m.group(0).replace(",", "."))


# ----------------------------------------------------------------------------- the VLM answerer


@dataclass
class VLMConfig:
    """How the VLM is asked. max_new_tokens: reply length limit; retries: extra attempts (with a stricter format
    reminder) when the reply cannot be parsed."""

    max_new_tokens: int = 16
    retries: int = 1


def answer_with_vlm(vlm: Any, question: str, options: list[str] | None, prompt_text: str,
                    images: list[np.ndarray], conf: VLMConfig | None = None, trace: Any = None,
                    parsed: ParsedQuestion | None = None) -> Answer:
    """Ask a VLM (`.generate(images, prompt, max_new_tokens=...) -> str`) and parse its reply robustly.

    prompt_text: the full prompt (e.g. `prompt.vlm_prompt(...)`); images: [H, W, 3] uint8 RGB (the visual
    prompt image and/or frames). Multiple choice -> the option letter (`parse_choice`), numeric -> the number
    (`parse_number`). An unusable reply gives status "unparsed" with the raw reply in the explanation (and a
    "degraded" trace event), never a made-up letter.
    """
    conf = conf or VLMConfig()
    pq = parsed if parsed is not None else parse_question(question, options)
    opts = options if options is not None else pq.options
    replies: list[str] = []
    text = prompt_text
    for attempt in range(1 + max(0, conf.retries)):
        if trace is not None:
            with trace.stage("vlm"):
                reply = str(vlm.generate(images, text, max_new_tokens=conf.max_new_tokens))
        else:
            reply = str(vlm.generate(images, text, max_new_tokens=conf.max_new_tokens))
        replies.append(reply)
        if opts:
            letter = parse_choice(reply, opts)
            if letter is not None:
                body = dict(split_options(opts)).get(letter, "")
                return Answer(letter, body, "ok", f"VLM reply {reply!r} -> option {letter}. {body}", [], pq.qtype, pq)
            text = prompt_text + "\n\nReply with exactly one letter from: " + \
                ", ".join(l for l, _ in split_options(opts)) + "."
        else:
            num = parse_number(reply)
            if num is not None:
                value: Any = int(round(num)) if pq.qtype == "object_counting" else num
                return Answer(str(value), value, "ok", f"VLM reply {reply!r}", [], pq.qtype, pq)
            text = prompt_text + "\n\nReply with a single number only."
    if trace is not None:
        trace.event("degraded", f"VLM reply could not be parsed to an answer: {replies[-1]!r}", stage="answer",
                    replies=replies)
    return Answer("unparsed: " + replies[-1][:80], None, "unparsed",
                  f"VLM replies {replies!r} name no option/number", [], pq.qtype, pq)


ANSWERERS = ("map", "vlm", "auto")


def answer_question(smap: SemanticMap, question: str, options: list[str] | None = None,
                    answerer: str = "auto", vlm: Any = None, prompt: Any = None, trace: Any = None,
                    parsed: ParsedQuestion | None = None, vlm_conf: VLMConfig | None = None) -> Answer:
    """Answer from a map with the chosen answerer.

    answerer: "map" (the reasoner only), "vlm" (the VLM with the visual prompt), "auto" (the reasoner for
    questions it recognises, the VLM otherwise). prompt: a `prompt.VisualPrompt` of `smap` (rendered here when
    None and the VLM is used). Objects the question needs but the map lacks give status "not_found" whichever
    answerer is used (the VLM is not asked to guess them).
    """
    from .errors import InputError

    if answerer not in ANSWERERS:
        raise InputError(f"--answerer must be one of {ANSWERERS}, got {answerer!r}")
    pq = parsed if parsed is not None else parse_question(question, options)
    opts = options if options is not None else pq.options
    reasoner = MapReasoner(smap)
    if answerer == "map" or (answerer == "auto" and pq.qtype is not None):
        ans = reasoner.answer(question, opts, parsed=pq)
        if answerer == "auto" and ans.status == "unsupported" and vlm is not None and pq.qtype is not None:
            if trace is not None:
                trace.event("fallback", f"map reasoner: {ans.explanation}; asking the VLM", stage="answer")
        else:
            if trace is not None:
                trace.decide("answer.answerer", "map")
            return ans
    if answerer == "auto" and pq.qtype is None and vlm is None:
        if trace is not None:
            trace.decide("answer.answerer", "none")
            trace.event("degraded", "the question matches no template and the bundle has no VLM: unanswered",
                        stage="answer")
        return Answer("unsupported: not a recognised question template and no VLM in the bundle", None,
                      "unsupported", "add a `vlm` role to the bundle to answer free-form questions", [], None, pq)
    if vlm is None:
        raise InputError("--answerer vlm needs a bundle with a `vlm` role")
    missing = [n for n in pq.objects if not smap.by_name(n)]
    if missing:
        if trace is not None:
            trace.decide("answer.answerer", "vlm")
        return Answer(f"not found: {', '.join(missing)}", 0 if pq.qtype == "object_counting" else None,
                      "not_found", f"not in the map: {', '.join(missing)}", missing, pq.qtype, pq)
    from .prompt import render, vlm_prompt

    vp = prompt if prompt is not None else render(smap)
    text = vlm_prompt(question, opts, vp.text, vp.mode)
    images = [vp.image] if vp.image is not None else []
    if trace is not None:
        trace.decide("answer.answerer", "vlm")
        trace.decide("answer.prompt_mode", vp.mode)
    return answer_with_vlm(vlm, question, opts, text, images, vlm_conf, trace, pq)


def _half_extents(boxes: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    """Centroids [M, 3] and axis-aligned half extents [M, 3] of oriented boxes (their AABBs contain them)."""
    c = np.array([o.box.centroid for o in boxes], np.float64).reshape(-1, 3)
    ax = np.abs(np.array([o.box.axes for o in boxes], np.float64).reshape(-1, 3, 3))
    h = np.array([o.box.axes_lengths for o in boxes], np.float64).reshape(-1, 1, 3) / 2
    return c, (h @ ax).reshape(-1, 3)


def _lower_bounds(x: Any, cb: np.ndarray, eb: np.ndarray) -> np.ndarray:
    """Lower bounds [M] of the distance from box x to each box of b: the distance of their AABBs (exact for
    axis-aligned boxes)."""
    cx, ex = _half_extents([x])
    gap = np.maximum(np.abs(cb - cx) - ex - eb, 0.0)
    return np.linalg.norm(gap, axis=1)


def _distance_upper_bound(a: list[Any], b: list[Any]) -> tuple[float, np.ndarray, np.ndarray]:
    """(an upper bound of the smallest box distance between a and b, b's centroids [M, 3], b's AABB half
    extents [M, 3]): the exact distance of the pair with the smallest lower bound (inf when a, b are one
    single instance)."""
    cb, eb = _half_extents(b)
    best, pair = np.inf, None
    where_in_b = {id(y): j for j, y in enumerate(b)}
    for x in a:
        lb = _lower_bounds(x, cb, eb)
        if id(x) in where_in_b:
            lb[where_in_b[id(x)]] = np.inf
        j = int(np.argmin(lb)) if len(lb) else -1
        if j >= 0 and lb[j] < best:
            best, pair = float(lb[j]), (x, b[j])
    if pair is None:
        return np.inf, cb, eb
    return box_distance(pair[0].box, pair[1].box), cb, eb
