"""Which answerer answers: the map reasoner (the program executed on the map), the VLM (the visual prompt), or
auto (the reasoner for what it understands, the VLM otherwise)."""
from __future__ import annotations

from typing import Any

from ..infra.errors import InputError
from ..query.parse import ParsedQuestion, parse_question
from ..infra.trace import as_trace
from ..prompt import render, vlm_prompt
from .execute import MapReasoner
from .result import Answer
from .vlm import VLMConfig, answer_with_vlm

ANSWERERS = ("map", "vlm", "auto")


def answer_question(smap: Any, question: str, options: list[str] | None = None,
                    answerer: str = "auto", vlm: Any = None, prompt: Any = None, trace: Any = None,
                    parsed: ParsedQuestion | None = None, vlm_conf: VLMConfig | None = None) -> Answer:
    """Answer from a map with the chosen answerer.

    answerer: "map" (the reasoner only), "vlm" (the VLM with the visual prompt), "auto" (the reasoner for
    questions it recognises, the VLM otherwise). prompt: a `prompt.VisualPrompt` of `smap` (rendered here when
    None and the VLM is used). Objects the question needs but the map lacks give status "not_found" whichever
    answerer is used (the VLM is not asked to guess them).
    """
    trace = as_trace(trace)
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
    vp = prompt if prompt is not None else render(smap)
    hint = "" if pq.qtype is None else f"\nHow a text parser read the question (a hint, may be wrong): {pq.describe()}"
    text = vlm_prompt(question, opts, vp.text + hint, vp.mode)
    images = [vp.image] if vp.image is not None else []
    trace.decide("answer.answerer", "vlm")
    trace.decide("answer.prompt_mode", vp.mode)
    return answer_with_vlm(vlm, question, opts, text, images, vlm_conf, trace, pq)
