"""A map indexed for questions: instances by name (the question's words resolve to the map's own categories),
built once per map and shared by every question asked of it (it holds nothing about any one question)."""
from __future__ import annotations

import difflib
from typing import Any

from ..query.vocabulary import canonical_name, name_key
from .spatial import BoxSet


class MapIndex:
    """Instances of a `SemanticMap` by name key and by vocabulary name. `find(name, phrase)`: the question's words
    or the name as a map name, else the map names with the same vocabulary name (synonyms and kinds); never
    another category. A question costs O(instances of the named categories) to resolve."""

    def __init__(self, smap: Any):
        self.map = smap
        self.by_key: dict[str, list[Any]] = {}
        for o in smap.instances:
            self.by_key.setdefault(name_key(o.name), []).append(o)
        self.names = sorted({o.name for o in smap.instances})  # the map's own category names
        self.by_canon: dict[str, list[str]] = {}
        for k in self.by_key:
            self.by_canon.setdefault(canonical_name(k) or k, []).append(k)

    def find(self, name: str, phrase: str | None = None) -> list[Any]:
        """Instances for a question name (`phrase`: the question's words for it). [] when the map has none."""
        for cand in (phrase or name, name):
            k, canon = name_key(cand), canonical_name(cand)
            if k in self.by_key and canon != k:  # a specific map name ("office chair", "computer tower")
                return self.by_key[k]
            if canon in self.by_canon:  # the name and its kinds / synonyms ("chair": chair, office chair)
                return [o for key in self.by_canon[canon] for o in self.by_key[key]]
            if k in self.by_key:
                return self.by_key[k]
        return []

    @property
    def boxes(self) -> Any:
        """Every instance (in name order: `by_key`'s) in a `spatial.BoxSet`, built on first use and kept."""
        if getattr(self, "_boxes", None) is None:
            self._all = [o for v in self.by_key.values() for o in v]
            self._boxes = BoxSet(self._all)
        return self._boxes

    def has_category(self, phrase: str) -> bool:
        return name_key(phrase) in self.by_key

    def hints(self, phrase: str, n: int) -> list[str]:
        """Up to n map names close to a name the map lacks (spelled alike, or sharing a word)."""
        names = self.names
        words = set(name_key(phrase).split())
        close = difflib.get_close_matches(name_key(phrase), names, n, 0.6)
        share = [x for x in names if words & set(name_key(x).split())]
        return list(dict.fromkeys(close + share))[:n]
