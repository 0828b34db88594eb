"""The rule parser's state for one question: the object phrases read so far (name -> the question's words),
their selectors, and the notes that say what was and was not understood.

Handlers build nodes with bare references (`Ref(name)`); `finish` gives every reference its phrase, whether the
vocabulary knows it, and its selectors, once the whole question has been read (the first phrase of a name wins,
so a name reads the same wherever the question repeats it).
"""
from __future__ import annotations

from dataclasses import fields, is_dataclass, replace
from typing import Any

from ..ir import Described, NearestTo, Ref, Superlative, SUPERLATIVES, everything
from ..text import split_options
from ..vocabulary import canonical_name, name_key
from .tokens import noun_phrases, tokens


class Refused(Exception):
    """Raised by a parse step that refused the question (`State.refuse`: its notes say why)."""


class State:
    """One question being read: question text, options, phrases and selectors per name, notes."""

    def __init__(self, question: str, options: list[str] | None):
        self.question = question
        self.options = list(options) if options is not None else None
        self.phrases: dict[str, str] = {}
        self.known: dict[str, bool] = {}
        self.selectors: dict[str, dict[str, Any]] = {}
        self.notes: list[str] = []
        self.dropped: list[str] = []  # phrases read as no object (`parse.mentions`)
        self.weak: list[str] = []  # unknown phrases read as objects that nothing in the sentence holds as one

    def phrase(self, name: str) -> str:
        return self.phrases.get(name, name)

    def refs(self, nps: list[dict[str, Any]]) -> list[str]:
        """Record each phrase (its name: the vocabulary name, else the phrase itself; the question's words;
        selectors) and return the names in order."""
        names = []
        for p in nps:
            phrase = " ".join(p["words"])
            canon = canonical_name(phrase)
            name = canon or name_key(phrase)
            self.known.setdefault(name, canon is not None)
            self.phrases.setdefault(name, phrase)
            if p["sel"]:
                self.selectors[name] = {"words": p["sel"], "phrase": " ".join(p["sel"] + p["words"])}
            if p.get("attach") is not None:
                self.selectors.setdefault(name, {})["near"] = p["attach"]
            names.append(name)
        return names

    def option_names(self) -> list[str]:
        """The object each option names (its first object phrase, else its whole text)."""
        cands = []
        for _, text in split_options(self.options):
            onps = [p for p in noun_phrases(tokens(text)) if not p["scene"]]
            cands.append(self.refs(onps[:1])[0] if onps else name_key(text))
        return cands

    def fail(self, understood: str, missing: str) -> None:
        self.notes.append(f"understood: {understood}; not understood: {missing}")

    def refuse(self, understood: str, missing: str) -> None:
        self.fail(understood, missing)
        raise Refused

    # ------------------------------------------------------------------ the finished program

    def ref(self, name: str) -> Ref:
        """The full reference for a name read in this question."""
        if name == "*":
            return Ref("*", "everything")
        sel = self.selectors.get(name, {})
        select: list[Any] = []
        words = [w for w in sel.get("words", []) if w not in SUPERLATIVES]
        if words:
            select.append(Described(tuple(words), sel["phrase"]))
        select += [Superlative(w) for w in sel.get("words", []) if w in SUPERLATIVES]
        if sel.get("near"):
            near = sel["near"]
            select.append(NearestTo(near, "" if self.phrase(near) == near else self.phrase(near)))
        known = self.known.get(name, canonical_name(name) is not None)
        phrase = self.phrases.get(name, "")
        return Ref(name, "" if phrase == name else phrase, known, tuple(select))

    def finish(self, x: Any) -> Any:
        """`x` with every bare reference replaced by `ref(name)`."""
        if isinstance(x, Ref):
            return x if everything(x) and x.phrase else self.ref(x.name)
        if is_dataclass(x):
            return replace(x, **{f.name: self.finish(getattr(x, f.name)) for f in fields(x)})
        if isinstance(x, tuple):
            return tuple(self.finish(v) for v in x)
        return x


def R(name: str) -> Ref:
    """A bare reference (completed by `State.finish`)."""
    return Ref(name)
