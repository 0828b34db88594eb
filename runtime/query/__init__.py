"""The question as a typed program (docs/query.md): the language (`ir`), its JSON and versioned schema (`schema`),
the VSI-Bench templates (`templates`) and the rule parser (`rules`) that read questions into programs, and the
VLM that emits them under constrained decoding (`vlm`). `parse_question` is the entry point."""
from .ir import SCHEMA_VERSION, Program
from .parse import ParsedQuestion, parse_question
from .schema import ProgramError, from_json, json_schema, to_json

__all__ = ["SCHEMA_VERSION", "ParsedQuestion", "Program", "ProgramError", "from_json", "json_schema", "parse_question",
           "to_json"]
