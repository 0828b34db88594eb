"""The map reasoner: answers VSI-Bench question types exactly from a `SemanticMap`.

`MapReasoner(map).answer(question, options) -> Answer`. The question is parsed by `grounding.parse_question`
(the VSI-Bench templates, then natural wording: `grounding_nl`, which adds existence, where, list, nearest among
everything and free-form directions; see docs/reasoner-vsibench.md); names resolve to the map's own categories
(`MapReasoner._find`), units follow the question (`Answer.unit`);
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
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, ClassVar, Sequence

import numpy as np

from . import evidence as ev
from .infra.config import StageConf
from .infra.errors import InputError
from .geometry import box_distance, point_box_distance
from .grounding import (ParsedQuestion, canonical_name, name_key, parse_question, plural, safe_text,
                        split_options)
from .grounding_nl import COMPARATIVES, SUPERLATIVES
from .map.model import ObjectInstance, SemanticMap
from .infra.trace import as_trace

NUMERIC_QTYPES = ("object_counting", "object_size_estimation", "room_size_estimation", "object_abs_distance")
UNIT_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "ft": 0.3048, "in": 0.0254}
UNIT_WORDS = {"m": "m", "cm": "cm", "mm": "mm", "ft": "feet", "in": "inches", "m2": "m^2", "ft2": "sq ft"}


@dataclass
class ReasonerConfig(StageConf):
    """Question conventions (defaults reproduce VSI-Bench)."""

    conf_name: ClassVar[str] = "reasoner config"

    back_deg: float = 135.0  # medium directions and route turns: "back" from this turn angle on
    distance_decimals: int = 1  # metres
    room_decimals: int = 1  # square metres
    option_rel_tol: float = 0.5  # a number picks the nearest option only within this relative difference
    n_landmarks: int = 2  # "where is X": the nearest other objects named
    n_hints: int = 3  # "not in the map": this many similar map names offered
    # "A on B": A's bottom within this of B's top, A's centre over B's footprint; "A near B": closest points within
    # near_m; "A in B": A's centre inside B's box (`relation_holds`)
    on_gap_m: float = 0.15
    near_m: float = 0.5


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
    unit: str | None = None  # of a numeric value: cm / m / mm / ft / in / m2 / ft2
    hints: list[str] = field(default_factory=list)  # map names close to a name that is not in the map
    evidence: dict[str, Any] | None = None  # instances, views, fused detections, per-view spread (`evidence.build`)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_dict(self) -> dict[str, Any]:
        return {"text": self.text, "value": self.value, "status": self.status, "explanation": self.explanation,
                "missing": list(self.missing), "qtype": self.qtype, "unit": self.unit, "hints": list(self.hints),
                "evidence": self.evidence, "parsed": None if self.parsed is None else self.parsed.to_dict()}


def cannot_detect(pq: ParsedQuestion, names: Sequence[str], n_labels: int = 0,
                  close: dict[str, str] | None = None) -> Answer:
    """The answer to a question that needs objects the detector cannot detect: "unsupported", never "not found"
    (no frame was searched for them, so "no" or "not found" would be a guess). close: {name: a name it can
    detect spelled alike} ("chiars": "chair"), offered as "did you mean"."""
    what, it = ", ".join(names), "it" if len(names) == 1 else "them"
    classes = f"the {n_labels} classes" if n_labels else "the classes"
    mean = "; ".join(f"'{n}': did you mean {c}?" for n, c in (close or {}).items())
    return Answer(f"unsupported: the detector cannot recognise {what}" + (f" ({mean})" if mean else ""), None,
                  "unsupported", f"{what}: not among {classes} of this bundle's closed-set detector, so no frame was "
                  f"searched for {it}; a bundle with an open-vocabulary detector (OWLv2, docs/export-hf.md) looks "
                  f"for any name", list(names), pq.qtype, pq, hints=sorted(set((close or {}).values())))


class _NotFound(Exception):
    def __init__(self, names: list[str], hints: list[str] | None = None):
        super().__init__(", ".join(names))
        self.names = names
        self.hints = hints or []


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


def _measure(o: ObjectInstance, what: str) -> float:
    """A box measure in metres: longest side, height (vertical extent), length and width (the longer horizontal
    side, as furniture is sold: W x D x H), depth (the shorter horizontal side), volume (m^3), top (highest z) or
    bottom (lowest z)."""
    b = o.box
    lengths = np.asarray(b.axes_lengths, float)
    if what == "longest":
        return float(np.max(lengths))
    if what == "volume":
        return float(np.prod(lengths))
    z = b.corners()[:, 2]
    if what == "height":
        return float(z.max() - z.min())
    if what == "top":
        return float(z.max())
    if what == "bottom":
        return float(z.min())
    up = int(np.argmax(np.abs(np.asarray(b.axes, float)[:, 2])))
    horiz = sorted((float(lengths[i]) for i in range(3) if i != up), reverse=True)
    return horiz[1] if what == "depth" else horiz[0]  # length / width: the longer horizontal side (W x D x H)


_MEASURE_WORDS = {"volume": "box volume", "height": "height", "top": "top height", "length": "length",
                  "width": "width"}


def relation_holds(a: ObjectInstance, b: ObjectInstance, relation: str, conf: ReasonerConfig,
                   c: ObjectInstance | None = None) -> bool:
    """Whether instance a is `relation` ("on", "near", "in", "under", "above"; "between" b and c) instance b,
    from their boxes (z up)."""
    if relation == "near":
        return box_distance(a.box, b.box) <= conf.near_m
    if relation == "in":
        return bool(b.box.contains(a.center[None])[0])
    if relation == "between":
        return c is not None and _between(a, b, c)
    bottom = _measure(a, "bottom")
    over = b.box.contains(np.array([[a.center[0], a.center[1], b.center[2]]]))[0]  # within b's footprint
    if relation == "under":  # centre within b's footprint and below b's top ("the bin under the desk")
        return bool(over) and float(a.center[2]) < _measure(b, "top") - conf.on_gap_m
    if relation == "above":  # over b's footprint, bottom at or above b's top ("the lamp above the table")
        return bool(over) and bottom >= _measure(b, "top") - conf.on_gap_m
    return bool(over) and abs(bottom - _measure(b, "top")) <= conf.on_gap_m


def _between(a: ObjectInstance, b: ObjectInstance, c: ObjectInstance) -> bool:
    """a's centre inside the top-view convex hull of b's and c's footprints, and in neither footprint."""
    import cv2

    pts = np.concatenate([b.box.corners()[:, :2], c.box.corners()[:, :2]]).astype(np.float32)
    hull = cv2.convexHull(pts)
    p = (float(a.center[0]), float(a.center[1]))
    inside = cv2.pointPolygonTest(hull, p, False) >= 0
    own = any(o.box.contains(np.array([[p[0], p[1], o.center[2]]]))[0] for o in (b, c))
    return bool(inside) and not own



def describe_direction(theta_deg: float, back_deg: float = 135.0) -> dict[str, Any]:
    """Every reading of a counter-clockwise angle from the facing direction: side (left/right), front_back,
    quadrant (front-left ...), medium (left/right/back), eight-way words and the angle."""
    side = direction_label(theta_deg, "easy")
    quad = direction_label(theta_deg, "hard")
    med = direction_label(theta_deg, "medium", back_deg)
    a = abs(((theta_deg + 180.0) % 360.0) - 180.0)
    fb = "front" if a < 90.0 else "back"
    if a <= 22.5:
        words = "straight ahead"
    elif a >= 157.5:
        words = "behind"
    elif 67.5 <= a <= 112.5:
        words = f"to the {side}"
    else:
        words = f"{'ahead' if fb == 'front' else 'behind'} and to the {side}"
    return {"side": side, "front_back": fb, "quadrant": quad, "medium": med, "words": words,
            "angle_deg": round(float(theta_deg), 1)}


def in_direction(d: dict[str, Any], asked: str) -> bool:
    """Whether a `describe_direction` reading is in the asked direction: its quadrant, front / back, or left /
    right (not straight ahead or behind)."""
    return asked in (d["quadrant"], d["front_back"]) or (asked == d["side"] and
                                                         d["words"] not in ("straight ahead", "behind"))


# a side of a viewer or of an object, in words ("what is to the left of the desk?")
_SIDE_WORDS = {"left": "to the left of", "right": "to the right of", "front": "in front of", "back": "behind"}


def describe_from_camera(T_wc: np.ndarray, point: np.ndarray, back_deg: float = 135.0) -> dict[str, Any]:
    """Direction of a world point `[3]` from a camera `T_wc [4, 4]` (OpenCV axes: x right, z forward), on the
    floor plane: `describe_direction` of the angle plus the horizontal distance (m)."""
    T = np.asarray(T_wc, float)
    fwd = T[:3, 2][:2]
    if np.linalg.norm(fwd) < 1e-6:  # looking straight down: the image's up direction is "forward"
        fwd = -T[:3, 1][:2]
    v = np.asarray(point, float)[:2] - T[:2, 3]
    d = describe_direction(signed_angle_deg(fwd, v), back_deg)
    d["distance_m"] = round(float(np.linalg.norm(v)), 3)
    return d


class MapReasoner:
    """Answers questions from a `SemanticMap` (see the module docstring for the conventions).

    Names resolve against the map's own categories (`_find`): the question's words when they are a map name,
    else the vocabulary name or a listed synonym (`grounding.canonical_name`); never another category. Instances
    are indexed by name once, so a question costs O(instances of the named categories)."""

    def __init__(self, smap: SemanticMap, conf: ReasonerConfig | dict | None = None):
        self.map = smap
        self.conf = ReasonerConfig.merged(conf)
        self._idx: dict[str, list[ObjectInstance]] = {}
        for o in smap.instances:
            self._idx.setdefault(name_key(o.name), []).append(o)
        self._by_canon: dict[str, list[str]] = {}
        for k in self._idx:
            self._by_canon.setdefault(canonical_name(k) or k, []).append(k)
        self._pq: ParsedQuestion | None = None
        self._used: list[ObjectInstance] = []  # instances the current answer read (its evidence)
        self._spread: tuple[str, list[float], str | None] | None = None  # (quantity, per-view values, unit)
        self._ambiguous: list[dict[str, Any]] = []  # question names that matched several instances (`_choice`)

    # ------------------------------------------------------------------ entry point
    def answer(self, question: str, options: list[str] | None = None,
               parsed: ParsedQuestion | None = None) -> Answer:
        """Answer one question. `parsed` may be given (e.g. from a VLM grounding); else `parse_question`."""
        pq = parsed if parsed is not None else parse_question(question, options)
        if options is None:
            options = pq.options
        self._pq = pq
        if pq.qtype is None:
            return self._not_understood(pq)
        ans = self._answer(pq, options)
        if ans.ok:
            q = self._spread or (None, [], None)
            ans.evidence = ev.build(self._used, q[0], q[1], q[2], self._ambiguous)
            if self._ambiguous:  # said in the answer itself, not only in the evidence
                ans.explanation += "; " + "; ".join(ev.ambiguity_text(a) for a in self._ambiguous)
        return ans

    def _answer(self, pq: ParsedQuestion, options: list[str] | None) -> Answer:
        self._used, self._spread, self._ambiguous = [], None, []
        try:
            value, expl = getattr(self, "_" + pq.qtype)(pq)
        except _NotFound as e:
            hint = f" (the map has no such name; similar names in the map: {', '.join(e.hints)})" if e.hints else ""
            return Answer(f"not found: {', '.join(e.names)}", 0 if pq.qtype == "object_counting" else None,
                          "not_found", f"not in the map: {', '.join(e.names)}{hint}", e.names, pq.qtype, pq,
                          hints=e.hints)
        except _Unsupported as e:
            return Answer(f"unsupported: {e}", None, "unsupported", str(e), [], pq.qtype, pq)
        unit = pq.params.get("unit") if pq.qtype in NUMERIC_QTYPES else None
        if not options and isinstance(value, dict) and "text" in value:  # e.g. a count per object
            return Answer(value["text"], value, "ok", expl, [], pq.qtype, pq)
        if pq.qtype in NUMERIC_QTYPES and not options:
            return Answer(self._format_number(pq.qtype, value, unit), value, "ok", expl, [], pq.qtype, pq, unit)
        if not options and isinstance(value, str):  # an object or a direction, in the question's own words
            return Answer(pq.phrase(value), value, "ok", expl, [], pq.qtype, pq)
        letter, text = self._choose(value, options)
        if letter is None:
            return Answer(f"unsupported: the answer {value!r} fits none of the options", value, "unsupported",
                          expl + f"; options: {options}", [], pq.qtype, pq, unit)
        if options:
            expl += f" -> option {letter}. {text}"
        return Answer(letter, value, "ok", expl, [], pq.qtype, pq, unit)

    def _not_understood(self, pq: ParsedQuestion) -> Answer:
        from .grounding_nl import examples

        why = "; ".join(pq.notes) or "not a question type the map reasoner knows"
        ex = examples()[::4][:4]
        return Answer(f"unsupported: {safe_text(why, 240)}. Try e.g.: " + " | ".join(ex), None, "unsupported",
                      f"{why}; `mosaic ask --examples` lists the wordings the map reasoner understands", [], None, pq)

    # ------------------------------------------------------------------ names and instances
    def _find(self, name: str) -> list[ObjectInstance]:
        """Instances for a question name: the question's words or the name as a map name, else the map names
        with the same vocabulary name (synonyms). [] when the map has none."""
        phrase = self._pq.phrase(name) if self._pq is not None else name
        for cand in (phrase, name):
            k, canon = name_key(cand), canonical_name(cand)
            if k in self._idx and canon != k:  # a specific map name ("office chair", "computer tower")
                return self._idx[k]
            if canon in self._by_canon:  # the name and its kinds / synonyms ("chair": chair, office chair)
                return [o for key in self._by_canon[canon] for o in self._idx[key]]
            if k in self._idx:
                return self._idx[k]
        return []

    def _hints(self, name: str) -> list[str]:
        import difflib

        phrase = self._pq.phrase(name) if self._pq is not None else name
        names = sorted({o.name for v in self._idx.values() for o in v})
        words = set(name_key(phrase).split())
        close = difflib.get_close_matches(name_key(phrase), names, self.conf.n_hints, 0.6)
        share = [n for n in names if words & set(name_key(n).split())]
        return list(dict.fromkeys(close + share))[:self.conf.n_hints]

    def _missing(self, names: list[str]) -> None:
        missing = [n for n in dict.fromkeys(names) if not self._find(n)]
        if missing:
            shown = [self._one(n) for n in missing]
            raise _NotFound(shown, [h for n in missing for h in self._hints(n)])

    def _instances(self, name: str) -> list[ObjectInstance]:
        self._missing([name])
        out = self._select(name, self._find(name))
        self._used += out
        return out

    def _require(self, names: list[str]) -> dict[str, list[ObjectInstance]]:
        self._missing(names + [s["near"] for n in names for s in [self._sel(n)] if s.get("near")])
        out = {n: self._select(n, self._find(n)) for n in names}
        self._used += [o for v in out.values() for o in v]
        return out

    def _choice(self, name: str, inst: list[ObjectInstance], used: ObjectInstance, rule: str,
                values: dict[int, float] | None = None, unit: str | None = None) -> None:
        """Record that the question's `name` matched several instances and which one the answer used (`rule`:
        how it was picked; `values`: the asked quantity with each instance instead, by id)."""
        if len(inst) < 2:
            return
        self._ambiguous.append({"name": self._one(name), "instances": [int(o.id) for o in inst], "used": int(used.id),
                                "rule": rule, "unit": unit,
                                "alternatives": None if values is None else
                                {int(k): round(float(v), 3) for k, v in values.items()}})

    def _sel(self, name: str) -> dict[str, Any]:
        return self._pq.selectors.get(name, {}) if self._pq is not None else {}

    def _select(self, name: str, inst: list[ObjectInstance]) -> list[ObjectInstance]:
        """Apply the question's selector for `name` ("the biggest table", "the chair nearest the door"); colours,
        materials and ordinals are not in a map: unsupported, said so."""
        sel = self._sel(name)
        if not sel:
            return inst
        words = [w for w in sel.get("words", []) if w not in SUPERLATIVES]
        if words and name_key(sel.get("phrase", "")) not in self._idx:
            raise _Unsupported(f"'{sel['phrase']}': the map has no colours, materials or order of instances, so "
                               f"it cannot tell which {self._pq.phrase(name)} that is; ask about the "
                               f"{self._pq.phrase(name)} without '{' '.join(words)}'")
        out = inst
        if not out:
            return out  # nothing to pick from: the caller says the name is missing
        for w in sel.get("words", []):
            if w in SUPERLATIVES:
                key, pick = SUPERLATIVES[w]
                out = [pick(out, key=lambda o: _measure(o, key))]
        if sel.get("near"):
            self._missing([sel["near"]])  # "the chair nearest the door" needs a door in the map
            ref = self._find(sel["near"])
            out = [min(out, key=lambda o: min((box_distance(o.box, r.box) for r in ref if r is not o),
                                              default=np.inf))]
        return out

    # ------------------------------------------------------------------ helpers
    def _format_number(self, qtype: str, v: float, unit: str | None = None) -> str:
        if qtype == "object_counting":
            return str(int(round(v)))
        if qtype == "object_size_estimation" and unit in (None, "cm", "mm"):
            return str(int(round(v)))
        if qtype == "room_size_estimation":
            d = self.conf.room_decimals
        elif qtype == "object_abs_distance" and unit in (None, "m"):
            d = self.conf.distance_decimals
        else:  # other units keep the precision of a centimetre
            d = {"m": 2, "ft": 2, "in": 1, "cm": 0, "mm": 0}.get(unit or "m", 2)
        return f"{round(float(v), d):.{d}f}"

    def _option_key(self, text: str) -> str:
        """An option's text as a comparable value: a direction word, a turn list, or an object's map key."""
        from .grounding_nl import direction_words

        t = _norm(text)
        dirs = direction_words(t)
        if dirs and len(t.split()) <= 6 and not re.search(r"\bturn\b", t):
            return dirs[0]
        return t

    def _value_key(self, value: Any) -> str:
        return _norm(", ".join(value) if isinstance(value, list) else value)

    def _choose(self, value: Any, options: list[str] | None) -> tuple[str | None, Any]:
        """Option letter for a computed value: the same text, direction or object (through the map's names and
        synonyms), else the nearest number when it is plausibly close (`option_rel_tol`)."""
        if not options:
            return (str(value) if not isinstance(value, list) else ", ".join(value)), value
        opts = split_options(options)
        want = self._value_key(value)
        for letter, text in opts:
            if _norm(text) == want or (isinstance(value, str) and self._option_key(text) == want):
                return letter, text
        if isinstance(value, str) and self._find(value):  # "A. couch" for the map's sofa
            ids = {id(o) for o in self._find(value)}
            for letter, text in opts:
                from .grounding_nl import noun_phrases, tokens

                nps = [p for p in noun_phrases(tokens(text)) if not p["scene"]]
                name = " ".join(nps[0]["words"]) if nps else text
                saved, self._pq = self._pq, None
                hit = {id(o) for o in self._find(name)}
                self._pq = saved
                if hit and hit == ids:
                    return letter, text
        if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
            nums = []
            for letter, text in opts:
                m = re.match(r"\s*([-+]?\d+(?:\.\d+)?)", text)  # "2.5", "2.5 m", "160 cm"
                if m:
                    nums.append((abs(float(m.group(1)) - float(value)), letter, text, float(m.group(1))))
            if nums:
                d, letter, text, x = min(nums)
                if d <= self.conf.option_rel_tol * max(abs(x), abs(float(value)), 1e-9):
                    return letter, text
        return None, value

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

    def _ph(self, name: str) -> str:
        return self._pq.phrase(name) if self._pq is not None else name

    def _one(self, name: str) -> str:
        """The question's words for one instance of `name`, singular ("the office chairs" -> "office chair"): a
        plural phrase labels "chair #3", and the ambiguity text pluralises it by count (`evidence.ambiguity_text`)."""
        return name_key(self._ph(name)) or name

    # ------------------------------------------------------------------ question types
    def _located(self, name: str, where: dict[str, Any]) -> tuple[list[ObjectInstance], list[ObjectInstance], str]:
        """(instances of `name` (every object but the reference's category for "*") that are `where["relation"]`
        an instance of `where["object"]`, the candidates, the rule in words)."""
        refs = self._instances(where["object"])
        rel = where["relation"]
        pairs = [(r, None) for r in refs]
        if rel == "between":  # "between the desk and the couch": any instance of each
            pairs = [(r, q) for r in refs for q in self._instances(where["object2"]) if q is not r]
        if name == "*":
            own = {id(o) for k in ("object", "object2") if where.get(k) for o in self._find(where[k])}
            cands = [o for o in self.map.instances if id(o) not in own]
        else:
            self._missing([name])
            cands = self._select(name, self._find(name))
        keep = [o for o in cands if any(relation_holds(o, r, rel, self.conf, q) for r, q in pairs
                                        if r is not o and q is not o)]
        if where.get("negate"):  # "cups not on the table": the candidates the relation does not hold for
            keep = [o for o in cands if not any(o is k for k in keep)]
        self._used += keep  # the evidence: the reference and what was counted, not every candidate
        rule = {"on": f"bottom within {self.conf.on_gap_m * 100:.0f} cm of its top, centre over it",
                "near": f"closest points within {self.conf.near_m:.2f} m", "in": "centre inside its box",
                "under": "centre within its footprint, below its top",
                "above": "over its footprint, bottom at or above its top",
                "between": "centre inside the top-view hull of their footprints"}[rel]
        ids = " ".join(f"#{o.id}" for o in keep)
        neg = "not " if where.get("negate") else ""
        ref = f"the {self._ph(where['object'])}" + (f" and the {self._ph(where['object2'])}" if rel == "between"
                                                    else "")
        return keep, cands, f"{neg}{rel} {ref} ({rule}){': ' + ids if ids else ''}"

    def _object_counting(self, pq: ParsedQuestion) -> tuple[Any, str]:
        if pq.params.get("where"):
            keep, cands, how = self._located(pq.params["object"], pq.params["where"])
            what = "object(s)" if pq.params["object"] == "*" else self._ph(pq.params["object"])
            return len(keep), f"{len(keep)} of {len(cands)} {what} {how}"
        if len(pq.params.get("objects", ())) > 1:  # one count per object; a name the map lacks counts 0
            inst = {n: self._find(n) for n in pq.params["objects"]}
            self._used += [o for v in inst.values() for o in v]
            counts = {self._ph(n): len(v) for n, v in inst.items()}
            text = ", ".join(f"{len(v)} {n if len(v) == 1 else plural(n)}" for n, v in inst.items())
            return {"text": text, "counts": counts}, "; ".join(f"{n}: {k} in the map" for n, k in counts.items())
        if self._sel(pq.params["object"]):
            sel = self._sel(pq.params["object"])
            raise _Unsupported(f"counting only some {self._ph(pq.params['object'])} "
                               f"('{sel.get('phrase') or 'near the ' + sel['near']}') is not supported; ask how many "
                               f"{self._ph(pq.params['object'])} there are")
        if pq.params["object"] == "*" or name_key(pq.params["object"]) in ("thing", "object", "item"):
            everything = list(self.map.instances)
            self._used += everything  # the evidence: every instance counted
            by = Counter(o.name for o in everything)
            parts = ", ".join(f"{k} {name if k == 1 else plural(name)}" for name, k in by.most_common())
            return len(everything), f"{len(everything)} object(s) in the map" + (f": {parts}" if parts else "")
        inst = self._instances(pq.params["object"])
        n = len(inst)
        self._spread = ("per-view count", ev.count_values(inst), None)
        return n, f"{n} instance(s) of {self._ph(pq.params['object'])} in the map"

    def _object_count_compare(self, pq: ParsedQuestion) -> tuple[Any, str]:
        """More (fewer) of A than of B: instance counts in the map (a name the map lacks counts 0, said so, as
        an is-there question says "no"); yes/no, the name with more (fewer), or the difference."""
        a, b = pq.params["objects"]
        inst = {n: self._find(n) for n in (a, b)}
        self._used += inst[a] + inst[b]
        na, nb = len(inst[a]), len(inst[b])
        expl = "; ".join(f"{self._ph(n)}: {len(inst[n])} in the map" for n in (a, b))
        more = pq.params["compare"] == "more"
        if pq.params["form"] == "difference":
            d = (na - nb) if more else (nb - na)
            word = "more" if more else "fewer"
            text = str(d) if d >= 0 else f"none: {-d} {'fewer' if more else 'more'}, not {word}"
            return {"text": text, "difference": d, "counts": {self._ph(a): na, self._ph(b): nb}}, expl
        if pq.params["form"] == "which":
            if na == nb:
                return {"text": f"neither: {na} each", "counts": {self._ph(a): na, self._ph(b): nb}}, expl
            return (a if (na > nb) == more else b), expl
        yes = na > nb if more else na < nb
        return {"text": "yes" if yes else "no", "counts": {self._ph(a): na, self._ph(b): nb}}, expl

    @staticmethod
    def _count_holds(pq: ParsedQuestion, found: dict[str, int]) -> tuple[bool, str]:
        """Is-there with a number ("are there two chairs?": exactly 2; "more than one"): (holds, the rule in
        words); without one, whether any was found."""
        c = pq.params.get("count")
        if not c:
            return any(found.values()), ""
        n = sum(found.values())
        holds = {"==": n == c["n"], ">": n > c["n"], ">=": n >= c["n"], "<": n < c["n"], "<=": n <= c["n"]}[c["op"]]
        return holds, f" (asked: {c['op']} {c['n']})"

    def _object_existence(self, pq: ParsedQuestion) -> tuple[Any, str]:
        names = pq.params["objects"]
        if pq.params.get("where"):  # "is there a cup on the table?": a missing cup is "no", a missing table not found
            self._missing([pq.params["where"]["object"]])
            found, parts = {}, []
            for n in names:
                keep, _, how = self._located(n, pq.params["where"]) if n == "*" or self._find(n) else \
                    ([], [], "in the map")
                what = "object(s)" if n == "*" else self._ph(n)
                found[what] = len(keep)
                parts.append(f"{what}: {len(keep)} {how}")
            yes, asked = self._count_holds(pq, found)
            return {"text": "yes" if yes else "no", "exists": yes, "counts": found}, "; ".join(parts) + asked
        for n in names:
            if self._sel(n):
                raise _Unsupported(f"'is there a {self._ph(n)} ...' with a condition is not supported; ask whether "
                                   f"there is a {self._ph(n)} at all")
        self._used += [o for n in names for o in self._find(n)]  # the evidence: what was found
        found = {self._ph(n): len(self._find(n)) for n in names}
        yes = all(found.values()) if pq.params.get("all") else any(found.values())
        if pq.params.get("count"):
            yes, asked = self._count_holds(pq, found)
            return {"text": "yes" if yes else "no", "exists": yes, "counts": found}, "; ".join(
                f"{k}: {v} in the map" for k, v in found.items()) + asked
        hints = {self._ph(n): self._hints(n) for n in names if not found[self._ph(n)]}
        expl = "; ".join(f"{k}: {v} in the map" for k, v in found.items())
        if any(hints.values()):  # a name the map may hold in other words ("desk lamp": the map's lamp)
            expl += "; similar names in the map: " + "; ".join(f"{k} -> {', '.join(v)}" for k, v in hints.items() if v)
        return {"text": "yes" if yes else "no", "exists": yes, "counts": found}, expl

    def _object_size_estimation(self, pq: ParsedQuestion) -> tuple[Any, str]:
        inst = self._instances(pq.params["object"])
        dim = pq.params.get("dimension", "longest")
        unit = pq.params.get("unit", "cm")
        if dim == "all":  # width x depth x height of the largest instance (as furniture is sold)
            o = max(inst, key=lambda x: _measure(x, "longest"))
            if len(inst) > 1:
                self._choice(pq.params["object"], inst, o, "the largest",
                             {x.id: _measure(x, "longest") / UNIT_M[unit] for x in inst}, unit)
            self._used = [o]
            d = {k: round(_measure(o, k) / UNIT_M[unit], 1) for k in ("width", "depth", "height")}
            text = f"{d['width']:g} x {d['depth']:g} x {d['height']:g} {unit}"
            return ({"text": text, **d, "unit": unit},
                    f"box width x depth x height of {self._one(pq.params['object'])} #{o.id}: {text}")
        if dim == "elevation":
            return self._elevation(pq, inst, unit)
        scale = 1.0 if dim == "volume" else UNIT_M[unit]  # volume: m^3
        sizes = [_measure(o, dim) / scale for o in inst]
        i = int(np.argmax(sizes))
        self._spread = (f"per-view {'longest side' if dim == 'longest' else dim}",
                        ev.size_values(inst[i], lambda o: _measure(o, dim), scale), unit)
        note = "" if len(inst) == 1 else f" (largest of {len(inst)} instances)"
        self._choice(pq.params["object"], inst, inst[i], "the largest", {o.id: v for o, v in zip(inst, sizes)}, unit)
        what = "longest box dimension" if dim == "longest" else f"box {dim}"
        shown = f"{sizes[i]:.2f} m^3" if dim == "volume" else f"{sizes[i]:.1f} {unit}"
        return sizes[i], f"{what} of {self._one(pq.params['object'])} #{inst[i].id}: {shown}{note}"

    def _elevation(self, pq: ParsedQuestion, inst: list[ObjectInstance], unit: str) -> tuple[Any, str]:
        """"How high above the floor is the lamp?": its box bottom over the map's floor (the room's floor height,
        else the lowest box bottom); several instances: the highest, the others listed."""
        floor, source = self.map.floor_z()
        lift = {o.id: (_measure(o, "bottom") - floor) / UNIT_M[unit] for o in inst}
        o = max(inst, key=lambda x: lift[x.id])
        self._choice(pq.params["object"], inst, o, "the highest", lift, unit)
        self._used = [o]
        d = {"m": 2, "ft": 2, "in": 1}.get(unit, 0)
        return round(lift[o.id], 2), (f"bottom of {self._one(pq.params['object'])} #{o.id} above the floor "
                                      f"({source}): {lift[o.id]:.{d}f} {unit}")

    def _room_size_estimation(self, pq: ParsedQuestion) -> tuple[Any, str]:
        area = self.map.room_area()
        if area is None:
            raise _Unsupported("the map has no room extent and no objects")
        src = self.map.extent().source
        if pq.params.get("dimension"):
            return self._room_sides(pq, src)
        unit = pq.params.get("unit", "m2")
        if unit == "ft2":
            area = area / 0.3048 ** 2
        expl = f"floor area of the map's room extent ({src}): {area:.2f} {unit}"
        than = pq.params.get("than")
        if than:  # "is the room bigger than 20 square meters?"
            yes = area > than["value"] if than["op"] == ">" else area < than["value"]
            return {"text": f"{'yes' if yes else 'no'} ({area:.1f} {unit})", "answer": yes, "area": round(area, 2),
                    "unit": unit}, f"{expl} (asked: {than['op']} {than['value']:g} {unit})"
        return area, expl

    def _room_sides(self, pq: ParsedQuestion, src: str) -> tuple[Any, str]:
        """"How long / wide is the room?": the sides of the smallest rectangle around the room's floor outline
        (length the longer)."""
        import cv2

        (_, _), (w, h), _ = cv2.minAreaRect(np.asarray(self.map.extent().polygon, np.float32))
        unit = pq.params.get("unit", "m")
        length, width = max(w, h) / UNIT_M[unit], min(w, h) / UNIT_M[unit]
        dim = pq.params["dimension"]
        how = f"sides of the smallest rectangle around the map's room extent ({src})"
        if dim == "all":
            text = f"{length:.1f} x {width:.1f} {unit}"
            return {"text": text, "length": round(length, 2), "width": round(width, 2), "unit": unit}, f"{how}: {text}"
        v = length if dim == "length" else width
        return {"text": f"{v:.1f} {unit}", dim: round(v, 2), "unit": unit}, f"{how}: {length:.2f} x {width:.2f} {unit}"

    def _camera_distance(self, pq: ParsedQuestion) -> tuple[Any, str]:
        """"How far am I from the tv?": the last camera's centre to the object's box (closest point; the nearest
        instance), the viewer being where the video ended."""
        cam = self._viewer("'how far am I' needs", "how far two objects are apart")[:3, 3]
        a, unit = pq.params["a"], pq.params.get("unit", "m")
        inst = self._instances(a)
        dist = {o.id: point_box_distance(cam, o.box) for o in inst}
        far = pq.params.get("which") == "farthest"
        o = (max if far else min)(inst, key=lambda x: dist[x.id])
        self._choice(a, inst, o, f"the {'farthest from' if far else 'nearest to'} the camera",
                     {i: d / UNIT_M[unit] for i, d in dist.items()}, unit)
        v = dist[o.id] / UNIT_M[unit]
        expl = (f"from the last camera position (where the video ended) to the closest point of {self._ph(a)} "
                f"#{o.id}: {v:.3f} {unit}")
        if pq.params.get("which"):  # "what's the closest chair to me?": that chair, and how far
            return {"text": f"{self._ph(a)} #{o.id}, {v:.1f} {unit} away", "object": o.name, "instance": int(o.id),
                    "distance": round(v, 3), "unit": unit}, expl
        return v, expl

    def _object_abs_distance(self, pq: ParsedQuestion) -> tuple[Any, str]:
        if pq.params.get("from") == "camera":
            return self._camera_distance(pq)
        a, b = pq.params["a"], pq.params["b"]
        inst = self._require([a, b])
        unit = pq.params.get("unit", "m")
        if a == b:
            return self._pair_distance(a, inst[a], unit)
        d, x, y = self._min_distance(inst[a], inst[b])
        v = d / UNIT_M[unit]
        self._spread = ("per-view-pair distance", ev.distance_values(x, y, UNIT_M[unit]), unit)
        for n, own, other, used in ((a, inst[a], inst[b], x), (b, inst[b], inst[a], y)):
            self._choice(n, own, used, "the nearest", {o.id: self._min_distance([o], other)[0] / UNIT_M[unit]
                                                       for o in own if [p for p in other if p is not o]}, unit)
        expl = f"closest points of {self._one(a)} #{x.id} and {self._one(b)} #{y.id}: {v:.3f} {unit}"
        cond = pq.params.get("within")
        if cond:  # "is the sofa within 2 m of the tv?": yes or no, the distance said
            t = cond["threshold_m"]
            yes = {"<": d < t, "<=": d <= t, ">": d > t, ">=": d >= t}[cond["op"]]
            return ({"text": f"{'yes' if yes else 'no'} ({v:.{2 if unit in ('m', 'ft') else 0}f} {unit})",
                     "answer": yes, "distance": round(v, 3), "unit": unit}, f"{expl} (asked: {cond['text']})")
        return v, expl

    def _pair_distance(self, name: str, inst: list[ObjectInstance], unit: str) -> tuple[Any, str]:
        """"The distance between the two chairs": two instances of one name; with more, the nearest two (said
        as ambiguous); with fewer, unsupported."""
        if len(inst) < 2:  # (the map's name: the phrase may say "two")
            raise _Unsupported(f"the map holds {len(inst)} {name if len(inst) == 1 else plural(name)}: no two to "
                               f"measure between")
        d, x, y = self._min_distance(inst, inst)
        v = d / UNIT_M[unit]
        self._used = [x, y]
        if len(inst) > 2:
            self._choice(name, inst, x, f"the nearest two (#{x.id} and #{y.id})")
        return v, f"closest points of {name} #{x.id} and #{y.id}: {v:.3f} {unit}"

    def _object_rel_distance(self, pq: ParsedQuestion) -> tuple[Any, str]:
        if pq.params.get("from") == "camera":
            return self._viewer_rel_distance(pq)
        ref, cands = pq.params["reference"], pq.params["candidates"]
        inst = self._require([ref] + cands)
        if len(cands) == 1 and cands[0] != ref and not pq.options and not pq.params.get("yesno"):
            return self._which_instance(cands[0], ref, inst, pq.params.get("extreme") == "farthest")
        pairs = {c: self._min_distance(inst[c], inst[ref]) for c in cands if c != ref}
        dists = {c: p[0] for c, p in pairs.items()}
        if not dists:
            raise _Unsupported("no candidate other than the reference object itself")
        pick = (min if pq.params.get("extreme", "closest") == "closest" else max)(dists, key=dists.get)
        for c in [ref] + list(pairs):
            if c == ref:
                self._choice(ref, inst[ref], pairs[pick][2], f"the one nearest the {self._ph(pick)}")
            else:
                self._choice(c, inst[c], pairs[c][1], "the nearest", {
                    o.id: self._min_distance([o], inst[ref])[0] for o in inst[c]
                    if [r for r in inst[ref] if r is not o]}, "m")
        self._spread = (f"per-view-pair distance of {self._ph(pick)}",
                        ev.distance_values(pairs[pick][1], pairs[pick][2]), "m")
        expl = f"closest-point distances to {self._ph(ref)}: " + ", ".join(
            f"{self._ph(c)} {d:.2f} m" for c, d in dists.items())
        if pq.params.get("yesno"):  # "is the tv closer to the table than the cup?": the first candidate wins?
            yes = pick == cands[0] and len(set(dists.values())) > 1
            return {"text": "yes" if yes else "no", "object": pick, "distances_m": {
                self._ph(c): round(d, 3) for c, d in dists.items()}}, expl
        return pick, expl

    def _viewer_rel_distance(self, pq: ParsedQuestion) -> tuple[Any, str]:
        """"Am I closer to the desk or the sofa?": the candidates' distances from the last camera (where the video
        ended; the nearest instance of each)."""
        cam = self._viewer("'closer to me' needs", "which object is closer to another object")[:3, 3]
        inst = self._require(pq.params["candidates"])
        dists = {c: min(point_box_distance(cam, o.box) for o in v) for c, v in inst.items()}
        pick = (max if pq.params.get("extreme") == "farthest" else min)(dists, key=dists.get)
        return pick, "from the last camera position (where the video ended): " + ", ".join(
            f"{self._ph(c)} {d:.2f} m" for c, d in dists.items())

    def _which_instance(self, name: str, ref: str, inst: dict[str, list[ObjectInstance]], far: bool
                        ) -> tuple[Any, str]:
        """"Which chair is closest to (farthest from) the tv?": the chair instance by its closest-point distance
        to the tv (the nearest tv to it), not the category name."""
        per = {o.id: self._min_distance([o], inst[ref]) for o in inst[name]
               if [r for r in inst[ref] if r is not o]}
        if not per:
            raise _Unsupported("no candidate other than the reference object itself")
        oid = (max if far else min)(per, key=lambda k: per[k][0])
        d, o, r = per[oid]  # which instance is the question, not an ambiguity: only the reference's is one
        self._choice(ref, inst[ref], r, f"the one nearest {self._one(name)} #{o.id}")
        self._spread = (f"per-view-pair distance of {self._one(name)} #{o.id}", ev.distance_values(o, r), "m")
        ranked = sorted(per, key=lambda k: per[k][0], reverse=far)[:6]
        expl = f"closest-point distances to {self._ph(ref)}: " + ", ".join(
            f"{self._one(name)} #{k} {per[k][0]:.2f} m" for k in ranked)
        return {"text": f"{self._one(name)} #{o.id}", "object": o.name, "instance": int(o.id),
                "distance_m": round(d, 3)}, expl

    def _object_nearest(self, pq: ParsedQuestion) -> tuple[Any, str]:
        """Nearest (farthest) object among everything in the map, other than the reference's own category."""
        ref = pq.params["reference"]
        rinst = self._instances(ref)
        own = {id(o) for o in self._find(ref)}
        dist: dict[str, tuple[float, ObjectInstance]] = {}
        own |= {id(o) for n in pq.params.get("exclude", []) for o in self._find(n)}  # "..., apart from the bin"
        for key, inst in self._idx.items():
            others = [o for o in inst if id(o) not in own]
            if others:
                d, o, _ = self._min_distance(others, rinst)
                dist[key] = (d, o)
        if not dist:
            raise _Unsupported(f"the map holds nothing but {self._ph(ref)}")
        far = pq.params.get("extreme") == "farthest"
        key = (max if far else min)(dist, key=lambda k: dist[k][0])
        d, o = dist[key]
        ranked = sorted(dist, key=lambda k: dist[k][0], reverse=far)[:4]
        value = {"text": o.name, "object": o.name, "instance": int(o.id), "distance_m": round(d, 3)}
        if pq.options:
            value = o.name
        return value, f"{'farthest' if far else 'nearest'} to {self._ph(ref)}: " + ", ".join(
            f"{k} {dist[k][0]:.2f} m" for k in ranked)

    def _object_size_compare(self, pq: ParsedQuestion) -> tuple[Any, str]:
        """The object with the largest (smallest) box measure among the candidates, or among every object of the
        map ("*"); a category with several instances counts by its extreme one (recorded as ambiguity)."""
        key, pick = SUPERLATIVES[pq.params["measure"]]
        cands, unit = pq.params["candidates"], "m3" if key == "volume" else "m"
        if "threshold_m" in pq.params:  # "is the couch longer than 2 m?"
            return self._size_against(pq, cands[0], key, pick)
        if cands != "*" and len(cands) == 1:  # "which chair is the tallest?": one of its instances
            inst = self._instances(cands[0])
            o = pick(inst, key=lambda x: _measure(x, key))
            ranked = sorted(inst, key=lambda x: _measure(x, key), reverse=pick is max)[:6]
            return ({"text": f"{self._one(cands[0])} #{o.id}", "object": o.name, "instance": int(o.id),
                     "value": round(_measure(o, key), 3)},
                    f"{_MEASURE_WORDS[key]}: " + ", ".join(f"#{x.id} {_measure(x, key):.2f} {unit}" for x in ranked))
        groups = dict(self._idx) if cands == "*" else self._require(cands)
        best = {n: pick(inst, key=lambda o: _measure(o, key)) for n, inst in groups.items() if inst}
        if len(best) < 2:
            raise _Unsupported("fewer than two objects to compare")
        vals = {n: _measure(o, key) for n, o in best.items()}
        win = pick(vals, key=vals.get)
        if cands == "*":
            self._used.append(best[win])
        else:
            for n, inst in groups.items():
                self._choice(n, inst, best[n], f"the {pq.params['measure']}", {o.id: _measure(o, key) for o in inst},
                             unit)
        ranked = sorted(vals, key=vals.get, reverse=pick is max)[:6]
        expl = f"{_MEASURE_WORDS[key]}: " + ", ".join(f"{self._one(n)} #{best[n].id} {vals[n]:.2f} {unit}"
                                                      for n in ranked)
        if pq.params.get("difference"):
            return self._size_difference(pq, vals, key), expl
        if pq.params.get("yesno"):
            a = cands[0]
            yes = win == a and vals[cands[0]] != vals[cands[1]]
            return {"text": "yes" if yes else "no", "answer": yes, "values_m": vals}, expl
        if cands == "*" and not pq.options:
            o = best[win]
            text = o.name
            if pq.params.get("with_value"):  # "how tall is the tallest object?": which, and how tall
                text += f", {vals[win]:.2f} m^3" if key == "volume" else f", {vals[win] * 100:.0f} cm"
            return {"text": text, "object": o.name, "instance": int(o.id), "value": round(vals[win], 3)}, expl
        tied = [n for n in vals if n != win and abs(vals[n] - vals[win]) <= 0.005 * abs(vals[win])]  # within 0.5%
        if tied and not pq.options:  # "which is longer, the couch or the whiteboard?" when both are 2.00 m
            names = " and the ".join(self._ph(n) for n in [win] + tied)
            return {"text": f"equal: the {names} ({vals[win]:.2f} {unit})", "equal": [win] + tied}, expl
        return win, expl

    def _size_against(self, pq: ParsedQuestion, name: str, key: str, pick: Any) -> tuple[Any, str]:
        """Yes / no: the object's box measure beyond (`pick` max: above, min: below) a length; with several
        instances the one most in that direction (said as ambiguous)."""
        inst = self._require([name])[name]
        o = pick(inst, key=lambda x: _measure(x, key))
        v, thr = _measure(o, key), pq.params["threshold_m"]
        self._choice(name, inst, o, f"the {pq.params['measure']}", {x.id: _measure(x, key) for x in inst}, "m")
        self._used = [o]
        yes = v > thr if pick is max else v < thr
        return ({"text": "yes" if yes else "no", "answer": yes, "value_m": round(v, 3)},
                f"{_MEASURE_WORDS[key]} of {self._one(name)} #{o.id}: {v:.2f} m against {pq.params['threshold_text']}"
                + ("" if pq.params["threshold_text"].endswith(" m") else f" ({thr:.2f} m)"))

    def _size_difference(self, pq: ParsedQuestion, vals: dict[str, float], key: str) -> dict[str, Any]:
        """"How much taller (shorter) is A than B?": how far A's measure exceeds (falls short of) B's (m^3 for
        volume, else the asked length unit); a negative difference is said with the opposite comparative, or,
        where the vocabulary has none (longer), with B as the subject."""
        a, b = pq.params["candidates"]
        _, pick = SUPERLATIVES[pq.params["measure"]]
        word = next(w for w, sup in COMPARATIVES.items() if sup == pq.params["measure"])
        d = (vals[a] - vals[b]) * (1 if pick is max else -1)
        unit = "m3" if key == "volume" else pq.params.get("unit", "cm")
        v = d if key == "volume" else d / UNIT_M[unit]
        shown = f"{abs(v):.2f} m^3" if key == "volume" else f"{abs(v):.{0 if unit in ('cm', 'mm') else 2}f} {UNIT_WORDS[unit]}"
        other = next((c for c, sup in COMPARATIVES.items() if SUPERLATIVES[sup] == (key, min if pick is max else max)),
                     None)
        text = shown if d >= 0 else f"none: the {self._ph(a)} is {shown} {other}" if other else \
            f"none: the {self._ph(b)} is {shown} {word}"
        return {"text": text, "difference": round(v, 4), "unit": unit}

    def _pick_unique(self, name: str, near: list[np.ndarray]) -> tuple[ObjectInstance, str]:
        """The instance of `name` to use as a position: the only one, or the one nearest the other objects."""
        inst = self._instances(name)
        if len(inst) == 1 or not near:
            return inst[0], ""
        c = np.mean(near, 0)
        o = min(inst, key=lambda o: float(np.linalg.norm(o.center[:2] - c[:2])))
        self._choice(name, inst, o, "the one nearest the other objects")
        return o, f"; {self._ph(name)}: {len(inst)} instances, used #{o.id} (nearest the other objects)"

    def _angle(self, pq: ParsedQuestion) -> tuple[float, str]:
        p = pq.params
        inst = self._require([p["position"], p["facing"], p["query"]])
        others = lambda *ns: [o.center for n in ns for o in inst[n]]  # noqa: E731
        A, na = self._pick_unique(p["position"], others(p["facing"], p["query"]))
        B, nb = self._pick_unique(p["facing"], [A.center])
        C, nc = self._pick_unique(p["query"], [A.center, B.center])
        f = B.center[:2] - A.center[:2]
        if np.linalg.norm(f) < 1e-9:
            raise _Unsupported(f"standing by {self._ph(p['position'])} and facing {self._ph(p['facing'])}: "
                               f"same position")
        th = signed_angle_deg(f, C.center[:2] - A.center[:2])
        self._spread = ("per-view angle", ev.angle_values(A, B, C, th), "deg")
        by_order = (f"; where I stand read as the {self._ph(p['position'])}: the object named before what I face "
                    f"(no place word such as 'at' or 'by')") if p.get("position_by_order") else ""
        return th, (f"at {self._ph(p['position'])} facing {self._ph(p['facing'])}: {self._ph(p['query'])} at "
                    f"{th:+.1f} deg (counter-clockwise){na}{nb}{nc}{by_order}")

    def _rel_direction(self, pq: ParsedQuestion, level: str) -> tuple[Any, str]:
        th, expl = self._angle(pq)
        lab = direction_label(th, level, pq.params.get("back_deg", self.conf.back_deg))
        return lab, f"{expl} -> {lab}"

    def _object_rel_direction_easy(self, pq: ParsedQuestion) -> tuple[Any, str]:
        return self._rel_direction(pq, "easy")

    def _object_rel_direction_medium(self, pq: ParsedQuestion) -> tuple[Any, str]:
        return self._rel_direction(pq, "medium")

    def _object_rel_direction_hard(self, pq: ParsedQuestion) -> tuple[Any, str]:
        return self._rel_direction(pq, "hard")

    def _object_direction(self, pq: ParsedQuestion) -> tuple[Any, str]:
        """Free-form direction: every reading of the angle; "is it on my left?" -> yes/no for the asked word."""
        asked = pq.params.get("asked") or []
        if pq.params.get("candidates"):
            return self._direction_choice(pq, asked)
        th, expl = self._angle(pq)
        back = pq.params.get("back_deg", self.conf.back_deg)
        d = describe_direction(th, back)
        if len(asked) == 1:
            hit = in_direction(d, asked[0])
            shown = d["words"]
            if asked[0] in ("front", "back") and shown in ("to the left", "to the right"):  # 67-113 deg: say the
                shown = f"{'ahead' if d['front_back'] == 'front' else 'behind'} and {shown}"  # half it is in
            d["text"] = ("yes" if hit else "no") + f" ({shown})"
            d["asked"], d["answer"] = asked[0], hit
        else:
            d["text"] = d["words"]
        return d, f"{expl} -> {d['words']}"

    def _direction_choice(self, pq: ParsedQuestion, asked: list[str]) -> tuple[Any, str]:
        """"Standing by A facing B, what's on my right: the C or the D?" -> the candidates in that direction."""
        from dataclasses import replace

        if len(asked) != 1:
            raise _Unsupported("several objects and several directions: ask 'is the C on my left?' per object")
        where: dict[str, dict[str, Any]] = {}
        expls = []
        for c in pq.params["candidates"]:
            sub = replace(pq, params={**pq.params, "query": c, "candidates": None}, selectors=pq.selectors)
            th, e = self._angle(sub)
            where[c] = describe_direction(th, pq.params.get("back_deg", self.conf.back_deg))
            expls.append(e)
        hits = [c for c, d in where.items() if in_direction(d, asked[0])]
        text = " and ".join(self._ph(c) for c in hits) if hits else "none of them"
        return {"text": text, "matches": hits, "asked": asked[0], "directions": where}, "; ".join(expls)

    def _object_view_direction(self, pq: ParsedQuestion) -> tuple[Any, str]:
        """"Is A to the left of B?" as the viewer sees them: from the last camera, looking at B, A's bearing left
        or right of B's, and in front of / behind B by its distance along that line."""
        T = self._viewer("'left of' and 'behind' need", "'standing by the X facing the Y, is the Z on my left?'")
        a, b, asked = pq.params["object"], pq.params["reference"], pq.params["asked"]
        inst = self._require([a, b])
        B, nb = self._pick_unique(b, [o.center for o in inst[a]])
        A, na = self._pick_unique(a, [B.center])
        side, fb, th, along = self._view_relation(A, B, T)
        yes = asked == side if asked in ("left", "right") else asked == fb
        words = (f"seen from the last camera view: the {self._ph(a)} is {abs(th):.0f} deg to the {side} of the "
                 f"{self._ph(b)} and {abs(along):.1f} m {'behind' if fb == 'back' else 'in front of'} it{na}{nb}")
        return {"text": "yes" if yes else "no", "answer": yes, "side": side, "front_back": fb,
                "angle_deg": round(th, 1), "behind_m": round(along, 3)}, words

    def _object_where(self, pq: ParsedQuestion) -> tuple[Any, str]:
        """Where an object is: its nearest other objects (closest points) and, when the map has a camera track,
        its direction from the last camera; several instances: each of them (the first four by id)."""
        name = pq.params["object"]
        inst = self._instances(name)
        ref = pq.params.get("relative_to")
        refs = {id(x) for x in self._instances(ref)} - {id(x) for x in inst} if ref else set()
        if ref and not refs:
            raise _Unsupported(f"'{self._ph(name)}' relative to itself")
        each = [self._where_one(o, inst, refs) for o in sorted(inst, key=lambda x: x.id)[:4]]
        if len(inst) == 1:
            verb = "are" if name_key(self._ph(name)) != self._ph(name).lower() else "is"  # "the office chairs are"
            words = each[0].pop("words")
            text = f"the {self._ph(name)} {verb} " + (", ".join(words) if words else "the only object in the map")
            return {**each[0], "text": text}, text
        many = self._ph(name) if name_key(self._ph(name)) != self._ph(name).lower() else plural(self._ph(name))
        text = f"{len(inst)} {many}: " + "; ".join(f"#{v['instance']} " + ", ".join(v.pop("words")) for v in each)
        if len(inst) > len(each):
            text += f"; and {len(inst) - len(each)} more"
        return {"text": text, "object": inst[0].name, "n_instances": len(inst), "instances": each}, text

    def _where_one(self, o: ObjectInstance, own: list[ObjectInstance], refs: set[int]) -> dict[str, Any]:
        """One instance's place: its `n_landmarks` nearest other objects (those in `refs` first: "relative to
        the desk") and its direction from the last camera; "words" is the text of each."""
        skip = {id(x) for x in own}
        near = sorted(((box_distance(o.box, x.box), x) for v in self._idx.values() for x in v if id(x) not in skip),
                      key=lambda t: t[0])
        if refs:  # the reference's nearest instance, then the nearest others
            near = [next(t for t in near if id(t[1]) in refs)] + [t for t in near if id(t[1]) not in refs]
        marks = [{"object": x.name, "instance": int(x.id), "distance_m": round(float(d), 3)}
                 for d, x in near[:self.conf.n_landmarks]]
        value: dict[str, Any] = {"object": o.name, "instance": int(o.id), "centre": np.round(o.center, 3).tolist(),
                                 "landmarks": marks}
        words = [f"touching the {m['object']}" if m["distance_m"] < 0.05 else
                 f"{m['distance_m']:.1f} m from the {m['object']}" for m in marks]
        if self.map.cameras:
            cam = describe_from_camera(self.map.cameras[-1][1], o.center, self.conf.back_deg)
            value["camera"] = cam
            of = "" if cam["words"] == "behind" else " of"  # "behind the last camera view", not "behind of"
            words.insert(0, f"{cam['words']}{of} the last camera view, {cam['distance_m']:.1f} m away")
        value["words"] = words
        return value

    def _on_my_side(self, side: str) -> tuple[list[ObjectInstance], str]:
        """Every object on that side (left | right | front | back) of the viewer: the last camera (where the video
        ended), as `describe_from_camera` reads their centres; left/right exclude straight ahead and behind."""
        words = _SIDE_WORDS[side]
        T = self._viewer(f"'{words} me' needs", "'standing by the X facing the Y, is the Z on my left?'")
        inst = [o for o in self.map.instances if in_direction(describe_from_camera(T, o.center, self.conf.back_deg),
                                                              side)]
        return inst, f"{words} the last camera view (where the video ended)"

    def _seen_beside(self, reference: str, asked: str) -> tuple[list[ObjectInstance], str]:
        """Every other object to the left / right of, in front of / behind `reference` as seen from the last
        camera (`_view_relation`)."""
        T = self._viewer("'left of' and 'behind' need", "'standing by the X facing the Y, what is on my left?'")
        refs = self._instances(reference)
        B, nb = self._pick_unique(reference, [])
        inst = []
        for o in self.map.instances:
            if any(o is r for r in refs):
                continue
            side, fb, _, _ = self._view_relation(o, B, T)
            if (side if asked in ("left", "right") else fb) == asked:
                inst.append(o)
        return inst, f"{_SIDE_WORDS[asked]} the {self._ph(reference)} #{B.id} seen from the last camera view{nb}"

    def _viewer(self, need: str, instead: str) -> np.ndarray:
        """The viewer's pose T_wc [4, 4]: the last camera (where the video ended). Without a camera track the
        question is unsupported: "{need} a viewpoint ...; ask {instead}"."""
        if not self.map.cameras:
            raise _Unsupported(f"{need} a viewpoint: this map has no camera track; ask {instead}")
        return np.asarray(self.map.cameras[-1][1], float)

    @staticmethod
    def _view_relation(A: ObjectInstance, B: ObjectInstance, T: np.ndarray) -> tuple[str, str, float, float]:
        """(left | right, front | back, angle deg, metres beyond B) of A against B as seen from the camera T_wc,
        looking at B: A's bearing left or right of B's, and in front of / behind B along that line."""
        cam = T[:2, 3]
        vb, va = B.center[:2] - cam, A.center[:2] - cam
        if np.linalg.norm(vb) < 1e-6:
            raise _Unsupported(f"the last camera stands at the {B.name}")
        th = signed_angle_deg(vb, va)  # counter-clockwise: left of B as seen from the camera
        along = float(va @ vb / np.linalg.norm(vb) - np.linalg.norm(vb))  # > 0: beyond B (behind it)
        return ("left" if th > 0 else "right"), ("back" if along > 0 else "front"), th, along

    def _on_side_of(self, position: str, facing: str, side: str) -> tuple[list[ObjectInstance], str]:
        """Every other object on that side of someone standing at `position` facing `facing` (box centres, the
        same readings as a direction question: left / right exclude straight ahead and behind)."""
        A, na = self._pick_unique(position, [o.center for o in self._instances(facing)])
        B, nb = self._pick_unique(facing, [A.center])
        f = B.center[:2] - A.center[:2]
        if np.linalg.norm(f) < 1e-9:
            raise _Unsupported(f"standing by {self._ph(position)} and facing {self._ph(facing)}: same position")
        inst = [o for o in self.map.instances if o is not A and o is not B and in_direction(
            describe_direction(signed_angle_deg(f, o.center[:2] - A.center[:2]), self.conf.back_deg), side)]
        return inst, f"{_SIDE_WORDS[side]} someone at the {self._ph(position)} facing the {self._ph(facing)}{na}{nb}"

    def _object_list(self, pq: ParsedQuestion) -> tuple[Any, str]:
        names = pq.params.get("objects") or []
        how = ""
        if pq.params.get("from_viewer"):  # "what is to my left?"
            inst, how = self._on_my_side(pq.params["from_viewer"])
        elif pq.params.get("view"):  # "what is to the left of the couch?", as the viewer sees it
            inst, how = self._seen_beside(**pq.params["view"])
        elif pq.params.get("from_stance"):  # "standing at the desk facing the door, what is on my left?"
            inst, how = self._on_side_of(**pq.params["from_stance"])
        elif pq.params.get("where"):  # "what's on the table?": every object there
            inst, _, how = self._located("*", pq.params["where"])
        elif names:
            self._missing(names)
            inst = [o for n in names for o in self._find(n)]
        else:
            inst = list(self.map.instances)
        if not pq.params.get("where"):  # the evidence: what was listed (`_located` records its own)
            self._used += inst
        counts = dict(Counter(o.name for o in inst))  # in order of first appearance, as the JSON lists them
        text = ", ".join(f"{c} {n if c == 1 else plural(n)}" for n, c in sorted(counts.items())) or "nothing"
        value = {"text": text, "counts": counts,
                 "instances": [{"object": o.name, "instance": int(o.id), "centre": np.round(o.center, 3).tolist()}
                               for o in inst]}
        return value, f"{len(inst)} object(s) {how or 'in the map'}: {text}"

    def _route_planning(self, pq: ParsedQuestion) -> tuple[Any, str]:
        p = pq.params
        if "steps" not in p:
            raise _Unsupported(p.get("parse_error", "route not parsed"))
        names = [p["start"], p["facing"]] + [s["until"] for s in p["steps"] if s["action"] == "forward"]
        self._require(names)
        start = self._find(p["start"])
        face = self._find(p["facing"])
        pairs = [(a, b) for a in start for b in face if a is not b]
        if not pairs:
            raise _Unsupported(f"beginning at {p['start']} facing the same {p['facing']}: heading unknown")
        a, b = min(pairs, key=lambda ab: float(np.linalg.norm(ab[0].center[:2] - ab[1].center[:2])))
        self._choice(p["start"], start, a, f"the one nearest the {self._ph(p['facing'])}")
        self._choice(p["facing"], face, b, f"the one nearest the {self._ph(p['start'])}")
        pos, heading = a.center[:2].copy(), b.center[:2] - a.center[:2]
        turns, log = [], []
        pending = False
        for s in p["steps"]:
            if s["action"] == "turn":
                pending = True
                continue
            tgt = min(self._find(s["until"]), key=lambda o: float(np.linalg.norm(o.center[:2] - pos)))
            self._choice(s["until"], self._find(s["until"]), tgt, "the one nearest the previous waypoint")
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
class VLMConfig(StageConf):
    """How the VLM is asked. max_new_tokens: reply length limit; retries: extra attempts (with a stricter format
    reminder) when the reply cannot be parsed."""

    max_new_tokens: int = 16
    retries: int = 1

    conf_name: ClassVar[str] = "vlm config"

    def validate(self) -> None:
        if not (1 <= self.max_new_tokens <= 4096 and 0 <= self.retries <= 5):
            raise InputError(f"vlm config: need 1 <= max_new_tokens <= 4096 and 0 <= retries <= 5 (got "
                             f"{self.max_new_tokens}, {self.retries})")


def answer_with_vlm(vlm: Any, question: str, options: list[str] | None, prompt_text: str,
                    images: list[np.ndarray], conf: VLMConfig | None = None, trace: Any = None,
                    parsed: ParsedQuestion | None = None) -> Answer:
    """Ask a VLM (`.generate(images, prompt, max_new_tokens=...) -> str`) and parse its reply robustly.

    prompt_text: the full prompt (e.g. `prompt.vlm_prompt(...)`); images: [H, W, 3] uint8 RGB (the visual
    prompt image and/or frames). Multiple choice -> the option letter (`parse_choice`), numeric -> the number
    (`parse_number`). An unusable reply gives status "unparsed" with the raw reply in the explanation (and a
    "degraded" trace event), never a made-up letter.
    """
    trace = as_trace(trace)
    conf = VLMConfig.merged(conf)
    pq = parsed if parsed is not None else parse_question(question, options)
    opts = options if options is not None else pq.options
    replies: list[str] = []
    text = prompt_text
    for attempt in range(1 + max(0, conf.retries)):
        with trace.stage("vlm"):
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
    trace = as_trace(trace)
    from .infra.errors import InputError

    if answerer not in ANSWERERS:
        raise InputError(f"`answerer` must be one of {ANSWERERS}, got {answerer!r}", fields=("answerer",))
    pq = parsed if parsed is not None else parse_question(question, options)
    opts = options if options is not None else pq.options
    reasoner = MapReasoner(smap)
    if answerer == "map" or (answerer == "auto" and pq.qtype is not None):
        ans = reasoner.answer(question, opts, parsed=pq)
        if answerer == "auto" and ans.status == "unsupported" and vlm is not None and pq.qtype is not None:
            trace.event("fallback", f"map reasoner: {ans.explanation}; asking the VLM", stage="answer")
        else:
            trace.decide("answer.answerer", "map")
            return ans
    if answerer == "auto" and pq.qtype is None and vlm is None:
        trace.decide("answer.answerer", "none")
        trace.event("degraded", "the question matches no template and the bundle has no VLM: unanswered",
                    stage="answer")
        ans = reasoner.answer(question, opts, parsed=pq)  # the "not understood" reply with example wordings
        ans.explanation += "; no VLM in the bundle (add a `vlm` role to answer free-form questions)"
        return ans
    if vlm is None:
        raise InputError("`answerer=vlm` needs a bundle with a `vlm` role", fields=("answerer",))
    missing = [n for n in pq.objects if not smap.by_name(n)]
    if missing:
        trace.decide("answer.answerer", "vlm")
        return Answer(f"not found: {', '.join(missing)}", 0 if pq.qtype == "object_counting" else None,
                      "not_found", f"not in the map: {', '.join(missing)}", missing, pq.qtype, pq)
    from .prompt import render, vlm_prompt

    vp = prompt if prompt is not None else render(smap)
    hint = "" if pq.qtype is None else f"\nHow a text parser read the question (a hint, may be wrong): {pq.describe()}"
    text = vlm_prompt(question, opts, vp.text + hint, vp.mode)
    images = [vp.image] if vp.image is not None else []
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
