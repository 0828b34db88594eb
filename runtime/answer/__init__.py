"""Answers from the map: the question's program executed on a `SemanticMap` (one executor per node), or the VLM.

`execute(program, map)` is the one executor the map reasoner, `mosaic eval vsibench`, `mosaic eval scene` and
the VLM's programs share; `MapReasoner(map).answer(question, options)` parses and executes; `answer_question`
picks the answerer (map | vlm | auto).
"""
from .angles import describe_direction, describe_from_camera, direction_label, in_direction, signed_angle_deg, turn_label
from .answerer import ANSWERERS, answer_question
from .boxes import measure, relation_holds
from .execute import EXECUTORS, MapReasoner, execute, format_number, not_understood
from .index import MapIndex
from .result import NUMERIC_QTYPES, UNIT_WORDS, Answer, ReasonerConfig, cannot_detect
from .vlm import VLMConfig, answer_with_vlm, parse_choice, parse_number
from ..query.ir import UNIT_M

__all__ = ["ANSWERERS", "Answer", "EXECUTORS", "MapIndex", "MapReasoner", "NUMERIC_QTYPES", "ReasonerConfig",
           "UNIT_M", "UNIT_WORDS", "VLMConfig", "answer_question", "answer_with_vlm", "cannot_detect",
           "describe_direction", "describe_from_camera", "direction_label", "execute", "format_number",
           "in_direction", "measure", "not_understood", "parse_choice", "parse_number", "relation_holds",
           "signed_angle_deg", "turn_label"]
