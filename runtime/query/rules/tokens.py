"""Tokens and object phrases: lower-case words, possessives split, runs of content words between function words."""
from __future__ import annotations

import re
from typing import Any

from ..vocabulary import NAME_SYNONYMS, name_key
from .lexicon import (COLOURS, COPULA, DET, DIR_RX, ORDINALS, SCENE, SOFT_AFTER_NOUN, SOFT_BEFORE_NOUN, STOP,
                      SUPERLATIVES, UNIT_WORDS)

_TOK = re.compile(r"[a-z0-9]+(?:[-'][a-z0-9]+)*|[?,.;:!()/&]")
_KEEP_S = {"what's", "where's", "it's", "that's", "there's", "here's", "who's", "how's", "let's"}
# contractions typed without the apostrophe ("whats the distance ..."): read as the contraction, not as a name
# ("its" stays the possessive; "wont", "cant" are words too but not object names)
_NO_APOSTROPHE = {w.replace("'", ""): w for w in (
    "what's", "where's", "that's", "there's", "here's", "who's", "how's", "let's", "i'm", "don't", "doesn't",
    "didn't", "isn't", "aren't", "wasn't", "weren't", "can't", "won't", "couldn't", "wouldn't", "shouldn't",
    "haven't", "hasn't", "i've", "you're", "they're")}  # not "we're": "were" is a word


def tokens(text: str) -> list[str]:
    """Lower-case word and punctuation tokens; a possessive "'s" is its own token."""
    s = text.lower().replace("\u2019", "'").replace("(s)", "").replace("(es)", "").replace("_", " ")
    s = re.sub(r"\s[-\u2013\u2014]+\s", " , ", s)  # a dash between words separates phrases ("the toilet - bed, ...")
    s = re.sub(r"(?<=[a-z0-9])-to-(?=[a-z0-9])", " to ", s)  # "the tv-to-bed distance"
    out: list[str] = []
    for t in _TOK.findall(s):
        t = _NO_APOSTROPHE.get(t, t)
        if t.endswith("'s") and len(t) > 2 and t not in _KEEP_S:
            out += [t[:-2], "'s"]
        else:
            out.append(t)
    return out


def is_content(toks: list[str], i: int, in_np: bool) -> bool:
    t = toks[i]
    if not re.match(r"[a-z0-9]", t) or t in DET or "'" in t:  # contractions: i'd, don't, what's ...
        return False
    if t.endswith("ed") and i > 0 and toks[i - 1] in COPULA:  # "are plugged in": a verb, not a name
        return False
    nxt = toks[i + 1] if i + 1 < len(toks) else ""
    nxt_content = bool(nxt) and re.match(r"[a-z]", nxt) is not None and nxt not in STOP and nxt not in DET
    if t in SOFT_AFTER_NOUN and in_np and nxt not in ("you", "i", "we", "one", "be", "it"):
        return True
    if t in SOFT_BEFORE_NOUN and nxt_content and nxt not in SCENE:
        return True
    return t not in STOP and not t.isdigit()


def noun_phrases(toks: list[str]) -> list[dict[str, Any]]:
    """Object phrases: maximal runs of content words. Each: start, end (token span), words, sel (selector words
    before the head: colours, ordinals, superlatives), scene (a room word, not an object)."""
    nps: list[dict[str, Any]] = []
    i = 0
    while i < len(toks):
        if not is_content(toks, i, False) and not (toks[i] in SUPERLATIVES and i + 1 < len(toks)
                                                     and is_content(toks, i + 1, False)):
            i += 1
            continue
        j, words = i, []
        while j < len(toks) and (is_content(toks, j, bool(words)) or (not words and toks[j] in SUPERLATIVES)):
            words.append(toks[j])
            j += 1
            if j + 1 < len(toks) and toks[j] == "'s" and is_content(toks, j + 1, False):
                words, j = [], j + 1  # "the kitchen's sink": the owner only qualifies the object
        sel = []
        while len(words) > 1 and (words[0] in SUPERLATIVES or words[0] in COLOURS or words[0] in ORDINALS):
            if name_key(" ".join(words)) in NAME_SYNONYMS:  # "white board" is a name, not a white board
                break
            sel.append(words.pop(0))
        if words:
            nps.append({"start": i, "end": j, "words": words, "sel": sel,
                        "scene": all(w in SCENE for w in words)})
        i = max(j, i + 1)
    return nps


def before(toks: list[str], np_: dict[str, Any], k: int = 3) -> list[str]:
    """Up to k tokens before a phrase, determiners skipped."""
    out, i = [], np_["start"] - 1
    while i >= 0 and len(out) < k:
        if toks[i] not in DET:
            out.insert(0, toks[i])
        i -= 1
    return out


def direction_words(text: str) -> list[str]:
    """Canonical directions named in a text, in order of appearance, each span once ("front-left", "left", "back",
    "front" ...)."""
    s = " " + " ".join(tokens(text)) + " "
    found: list[tuple[int, str]] = []
    for rx, lab in DIR_RX:
        for m in rx.finditer(s):
            found.append((m.start(), lab))
        s = rx.sub(lambda m: " " * len(m.group(0)), s)
    return [lab for _, lab in sorted(found)]


def unit_in(joined: str, default: str) -> str:
    m = re.search(r"\b(?:in|into|using|as|how many|number of|many)\s+(?:the\s+)?([a-z]+)\b", joined)
    if m and m.group(1) in UNIT_WORDS:
        return UNIT_WORDS[m.group(1)]
    for w in joined.split():  # "cm", "mm", "ft" are no other word ("..., cm?"); "m" and "in" only as said above
        if w in UNIT_WORDS and (len(w) > 2 or w in ("cm", "mm", "ft")):
            return UNIT_WORDS[w]
    m = re.search(r"(?:^|[,:;.?!-] )(m|in)(?: [?.!,]|$)", joined)  # a bare "m" / "in" only as a clause of its own
    return UNIT_WORDS[m.group(1)] if m else default


# ----------------------------------------------------------------------------- intents


def has(joined: str, rx: str) -> bool:
    return re.search(rx, joined) is not None
