"""Clauses of a question that are not the question: yes/no lead-ins, clauses with neither an object nor a cue,
a topic named first and then asked about by a pronoun, and the viewer addressed as "you".

`read_clauses(tokens, known) -> (tokens, notes)` works on the parser's tokens (`tokens.tokens`) before anything
else reads them:
- a lead-in (`LEAD_INS`: "is it true that", "can you tell me", "I'd like to know", "do you know") is removed; when
  what remains is a statement ("the sofa is closer to the tv than the bed"), its verb goes first, as a question;
- a clause (between ? . ! ; : or a dash) that names no known object and holds no cue word of any kind
  ("honestly can't picture it.", "I need help:", "quick one -") is left out when another clause remains;
- a topic ("the fridge - how long is it?", "the tv... how far is that from the bed?", "you see the table? how big
  is it?"): a clause naming one known object and nothing asked, then a clause asking about "it" / "that": the
  pronoun is that object;
- "you're standing at the stove ... nearest to you": the viewer addressed as "you" is the asker ("I am standing
  at the stove ... nearest to me").
Each step is said in the notes. `known(words) -> bool`: whether a phrase names a known object.
"""
from __future__ import annotations

import re
from typing import Callable

from ..cues import cue_words
from .lexicon import DET, FACE1, LOCATION, UNIT_WORDS

LEAD_INS = [  # (tokens of a lead-in, optionally followed by if / whether / that)
    "is it true that", "is it true", "can you tell me", "could you tell me", "would you tell me", "will you tell me",
    "tell me", "please tell me", "i'd like to know", "i would like to know", "i want to know", "i wanna know",
    "do you know", "do you happen to know", "i wonder", "i was wondering", "i'm wondering", "any idea",
    "would you mind checking", "can you check", "could you check", "can you work out", "could you work out",
    "can you figure out", "i need to know", "let me know", "i'd love to know", "i would love to know",
    "can you please tell me", "could you please tell me", "tell me please", "would you be able to tell me",
    "are you able to tell me", "can you let me know", "could you let me know", "i'm curious", "i am curious",
    "i'm curious to know", "is it the case that", "would you say that", "would you say", "am i right that",
    "am i right in thinking that", "true or false", "do you remember", "do you recall", "can you say",
]
_LEAD = sorted((tuple(x.split()) for x in LEAD_INS), key=len, reverse=True)
_THEN = {"if", "whether", "that"}
_COPULA = {"is", "are", "was", "were"}
_BREAK = {"?", ".", "!", ";", ":", "...", "-", ","}
_PRONOUN = {"it", "that", "this", "them"}
# cue words too common alone to keep a clause (function words of multi-word cues: "get to", "number of")
_NOT_CUE = {"to", "of", "at", "get", "go", "between", "side", "room", "space", "edge", "after", "before", "first",
            "please", "fill", "in", "from", "until", "till", "steps", "robot", "reach", "m", "ft"}
# words that keep a clause (besides a known object and the cue table): directions, the viewer, wh-words
_KEEP = {"left", "right", "behind", "front", "ahead", "back", "facing", "how", "what", "what's", "where", "where's",
         "which", "whichever", "closest", "nearest", "farthest", "furthest", "start", "begin", "turn", "walk", "go",
         "options", "option", "both", "or", "than", "square", "sq", "is", "are", "was", "were", "there", "any",
         "list", "see", "exist", "exists"} | set(UNIT_WORDS)
_MARKERS = LOCATION | FACE1 | {"from", "until", "till", "past", "to", "of", "than", "between"}
_OBJECT_PRONOUNS = {"it", "them", "me", "you", "us", "him", "her"}  # "picture it": a verb, not the object


def _clauses(toks: list[str]) -> list[tuple[int, int]]:
    """(start, end) token spans between clause breaks (the break belongs to the clause before it)."""
    spans, s = [], 0
    for i, t in enumerate(toks):
        if t in _BREAK:
            if i > s:
                spans.append((s, i + 1))
            s = i + 1
    if s < len(toks):
        spans.append((s, len(toks)))
    return spans


def _mentions(words: list[str], known: Callable[[str], bool]) -> list[tuple[int, int]]:
    """Spans of known object names in `words` (longest first, no overlaps)."""
    out, i = [], 0
    while i < len(words):
        if words[i] in DET:
            i += 1
            continue
        for n in range(min(4, len(words) - i), 0, -1):
            after = words[i + n] if i + n < len(words) else ""
            if words[i + n - 1].isalpha() and words[i].isalpha() and known(" ".join(words[i:i + n])) and \
                    after not in _OBJECT_PRONOUNS:
                out.append((i, i + n))
                i += n
                break
        else:
            i += 1
    return out


def _cued(words: list[str]) -> bool:
    """A cue word of some kind, a direction, a unit, a number, or a place marked by the sentence ("I'm at the
    doorframe": an object the vocabulary does not know is still an object there)."""
    cues = cue_words() - _NOT_CUE
    marked = any(w in _MARKERS and n in DET for w, n in zip(words, words[1:]))
    return marked or any(_stem(w) & (cues | _KEEP) or any(c.isdigit() for c in w) for w in words)


def _stem(w: str) -> set[str]:
    """A word and its stems ("turns", "turned" -> "turn")."""
    out = {w}
    for suf in ("s", "es", "ed", "ing", "d"):
        if w.endswith(suf) and len(w) - len(suf) >= 3:
            out.add(w[:-len(suf)])
    return out


def _lead_in(toks: list[str]) -> tuple[list[str], str | None]:
    """Tokens with a lead-in at the start of a clause removed (and a statement after it turned into a question)."""
    for a, b in _clauses(toks):
        words = toks[a:b]
        for lead in _LEAD:
            if tuple(words[:len(lead)]) != lead:
                continue
            rest = words[len(lead):]
            rest = rest[1:] if rest[:1] and (rest[0] in _THEN or rest[0] in (":", ",", "-")) else rest
            if not rest and b < len(toks):  # "true or false: the sofa is ...": the lead-in is its own clause
                rest, b = toks[b:], len(toks)
            if not rest or rest[0] in _BREAK:
                continue
            said = " ".join(lead)
            k = next((i for i, w in enumerate(rest[:8]) if w in _COPULA), None)
            if k and rest[0] in DET | {"there"}:  # "the sofa is closer ...": "is the sofa closer ..."
                rest = [rest[k]] + rest[:k] + rest[k + 1:]
            return toks[:a] + rest + toks[b:], said
    return toks, None


def _viewer_you(toks: list[str]) -> tuple[list[str], bool]:
    """"you're standing at X ... nearest to you": the asker's own place (only when "you" is placed)."""
    s = " ".join(toks)
    if not re.search(r"\byou(?:'re| are| were| stand| start| sit) (?:standing |sitting |stood )?(?:at|by|next to|"
                     r"beside|near|in front of)\b", s):
        return toks, False
    s = re.sub(r"\byou(?:'re| are| were)\b", "i am", s)
    s = re.sub(r"\byou (stand|start|sit)\b", r"i \1", s)
    s = re.sub(r"\b(to|from|of|behind|near) you\b", r"\1 me", s)
    s = re.sub(r"\byour\b", "my", s)
    return s.split(), True


def read_clauses(toks: list[str], known: Callable[[str], bool]) -> tuple[list[str], list[str]]:
    """The tokens of the question proper and notes saying what was set aside (see the module)."""
    notes: list[str] = []
    toks, lead = _lead_in(toks)
    if lead:
        notes.append(f"read past the lead-in '{lead}'")
    toks, you = _viewer_you(toks)
    if you:
        notes.append("'you' read as the asker (where 'you' stand)")
    toks = _asides(toks, known, notes)
    spans = _clauses(toks)
    keep = []
    for i, (a, b) in enumerate(spans):
        words = [w for w in toks[a:b] if w not in _BREAK]
        if not words:
            continue
        # a clause between commas in the middle of a sentence is part of it ("walk to the tv, turn, ..."): only
        # sentences, and a sentence's first or last comma clause ("honestly, ...", "..., please"), are left out
        inner = toks[b - 1] == "," and i > 0 and toks[a - 1] == "," and i + 1 < len(spans)
        if inner or _mentions(words, known) or _cued(words):
            keep.append((a, b))
        else:
            notes.append(f"left out '{' '.join(words)}' (no object and nothing asked)")
    if not keep:
        return toks, []
    toks = [t for a, b in keep for t in toks[a:b]]
    return _topic(toks, known, notes), notes


def _asides(toks: list[str], known: Callable[[str], bool], notes: list[str]) -> list[str]:
    """A parenthesis that names no known object and holds no cue word, unit or number ("(ballpark is fine)",
    "(thanks!)") is an aside: left out, said in the notes."""
    if any(t.startswith("turn") for t in toks):  # a route's "(blank)" is a turn to fill in, not an aside
        return toks
    out, i = [], 0
    cues = cue_words() - _NOT_CUE
    while i < len(toks):
        j = toks.index(")", i) if toks[i] == "(" and ")" in toks[i:] else -1
        words = [w for w in toks[i + 1:j] if w not in _BREAK] if j > 0 else []
        if words and not _mentions(words, known) and (not any(
                _stem(w) & cues or w in UNIT_WORDS or any(c.isdigit() for c in w) for w in words)
                ):
            notes.append(f"left out the aside '({' '.join(words)})'")
            i = j + 1
            continue
        out.append(toks[i])
        i += 1
    return out


def _topic(toks: list[str], known: Callable[[str], bool], notes: list[str]) -> list[str]:
    """"the fridge - how long is it ...": the pronoun of the clause after a topic is the topic."""
    spans = _clauses(toks)
    if len(spans) < 2:
        return toks
    (a, b), (c, d) = spans[0], spans[1]
    first = [w for w in toks[a:b] if w not in _BREAK]
    ment = _mentions(first, known)
    rest = [w for w in first if w not in DET]
    name = first[ment[0][0]:ment[0][1]] if len(ment) == 1 else []
    if not name or any(w not in name and w not in _TOPIC_WORDS for w in rest) or _cued(first):
        return toks  # a topic is the name alone ("the fridge -"), or "about the fridge:", "you see the fridge?"
    second = toks[c:]
    for i, w in enumerate(second):
        nxt = second[i + 1] if i + 1 < len(second) else ""
        if w in ("it", "them") or (w in _PRONOUN and (not nxt.isalpha() or nxt in _AFTER_PRONOUN)):
            notes.append(f"'{w}' read as the {' '.join(name)}")
            return second[:i] + ["the"] + name + second[i + 1:]
    return toks


_TOPIC_WORDS = {"about", "regarding", "re", "so", "quick", "one", "q", "question", "you", "see", "ok", "okay", "now",
                "and", "then", "what", "hey"}
# after "that" / "this" used as a pronoun ("how far is that from the bed"), not as a determiner ("that chair")
_AFTER_PRONOUN = {"is", "are", "was", "from", "to", "in", "at", "on", "sit", "sits", "measure", "measures", "one"}
