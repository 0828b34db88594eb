"""The VLM as the answerer: its free-text reply read robustly (option letters, numbers), never guessed."""
from __future__ import annotations

import re
from typing import Any

import numpy as np

from ..query.parse import ParsedQuestion, parse_question
from ..query.text import split_options
from ..infra.trace import as_trace
from ..models.vlm import VLMConfig  # how the VLM is asked: the adapter's, below the planner too
from .result import Answer


def _norm(s: str) -> str:
    return " ".join(str(s).lower().replace(",", " , ").split())


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
