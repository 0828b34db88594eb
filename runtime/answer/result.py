"""What an answer is (`Answer`), the reasoner's conventions (`ReasonerConfig`), and the two ways a program fails
on a map: an object the map lacks (`NotFound`) and a question the map cannot decide (`Unsupported`)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Sequence

from ..infra.config import StageConf

NUMERIC_QTYPES = ("object_counting", "object_size_estimation", "room_size_estimation", "object_abs_distance")
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
    n_alternatives: int = 16  # a name matching several instances: the asked quantity with at most this many others
    # "A on B": A's bottom within this of B's top, A's centre over B's footprint; "A near B": closest points within
    # near_m; "A in B": A's centre inside B's box (`boxes.relation_holds`)
    on_gap_m: float = 0.15
    near_m: float = 0.5


@dataclass
class Answer:
    """text: the answer as the benchmark writes it (the option letter for multiple choice, the number for
    numeric questions; "not found: ..." / "unsupported: ..." otherwise); value: the computed value (number,
    direction word, object name, or list of turns / categories); status: 'ok' | 'not_found' | 'unsupported' |
    'unparsed' (a VLM reply); explanation: how it was computed; missing: object names the question needs that
    the map lacks; parsed: the question as read (`query.ParsedQuestion`, with its program)."""

    text: str
    value: Any = None
    status: str = "ok"
    explanation: str = ""
    missing: list[str] = field(default_factory=list)
    qtype: str | None = None
    parsed: Any = None
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


class NotFound(Exception):
    """Objects the program needs that the map does not hold (the question's words), with similar map names."""

    def __init__(self, names: list[str], hints: list[str] | None = None):
        super().__init__(", ".join(names))
        self.names = names
        self.hints = hints or []


class Unsupported(Exception):
    """A program the map cannot decide (the message says why and what to ask instead)."""


def cannot_detect(pq: Any, names: Sequence[str], n_labels: int = 0, close: dict[str, str] | None = None) -> Answer:
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
