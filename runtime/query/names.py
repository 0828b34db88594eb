"""Object names by meaning: a phrase that is not a name of the vocabulary, the map or the detector is matched to the
nearest of those names by the reader's own sentence embeddings ("telly" -> tv, "couch" -> sofa), above a threshold
and clear of the runner-up; otherwise it stays as written (looked for by name, "not found" naming it) and the notes
list the nearest names.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np

from .ir import Ref
from .vocabulary import VOCABULARY, canonical_name, name_key, singular


@dataclass(frozen=True)
class NamesConfig:
    min_cosine: float = 0.72  # all-MiniLM-L6-v2 cosine a name by meaning needs (docs/query.md: how it was set)
    margin: float = 0.03  # over the runner-up of another name
    nearest: int = 3  # names listed when none matches


class NameResolver:
    """phrase -> Ref: the vocabulary (`canonical_name`), then a name of `names` as written, then by meaning."""

    def __init__(self, reader: Any = None, names: Iterable[str] = (), conf: NamesConfig = NamesConfig()):
        self.reader = reader
        self.conf = conf
        self.extra = [n for n in dict.fromkeys(names) if n and n != "*"]
        self.by_key = {name_key(n): n for n in self.extra}
        self.pool = list(dict.fromkeys(list(VOCABULARY) + self.extra))

    def __call__(self, phrase: str, plural: bool = False) -> tuple[Ref, list[str]]:
        canon = canonical_name(phrase)
        if canon is not None:
            return Ref(canon, "" if phrase.lower() == canon else phrase, True), []
        key = name_key(phrase)
        for k in (key, name_key(singular(key)) if plural else key):
            if k in self.by_key:
                n = self.by_key[k]
                return Ref(n, "" if phrase == n else phrase, False), []
        if self.reader is None:
            return Ref(phrase, "", False), []
        pool = self.pool
        sims = self.reader.embed([phrase]) @ self.reader.embed(pool).T
        order = np.argsort(-sims[0])
        best, second = float(sims[0, order[0]]), float(sims[0, order[1]]) if len(order) > 1 else -1.0
        name = pool[order[0]]
        if best >= self.conf.min_cosine and best - second >= self.conf.margin:
            return Ref(name, phrase, name in VOCABULARY), [f"read '{phrase}' as '{name}' by meaning ({best:.2f})"]
        near = ", ".join(f"{pool[i]} {float(sims[0, i]):.2f}" for i in order[:self.conf.nearest])
        return Ref(phrase, "", False), [f"'{phrase}' names nothing known by meaning (nearest: {near})"]
