"""One least-recently-used map for the runtime's caches: decoded frames, features, pairwise matches and per-image
model results (`stages.ImageLRU` adds content keys). Plain dict semantics with a size bound; size <= 0 keeps
nothing (a cache switched off), so callers never branch on it."""
from __future__ import annotations

from collections import OrderedDict
from typing import Any, Hashable


class LRU:
    """`get` marks a key used and counts a hit; `put` stores and drops the least recently used past `size`."""

    def __init__(self, size: int):
        self.size = int(size)
        self._d: OrderedDict[Hashable, Any] = OrderedDict()
        self.hits = 0

    def __contains__(self, key: Hashable) -> bool:
        return key in self._d

    def __len__(self) -> int:
        return len(self._d)

    def get(self, key: Hashable, default: Any = None) -> Any:
        """The value (marked most recently used), or `default`."""
        if key not in self._d:
            return default
        self._d.move_to_end(key)
        self.hits += 1
        return self._d[key]

    def put(self, key: Hashable, value: Any) -> Any:
        """Store `value` as the most recently used; returns it."""
        if self.size > 0:
            self._d[key] = value
            self._d.move_to_end(key)
            while len(self._d) > self.size:
                self._d.popitem(last=False)
        return value

    def hold(self, n: int) -> None:
        """Grow the bound to at least `n` entries (a caller that will revisit n keys); never shrinks, never turns
        a switched-off cache (size <= 0) on."""
        if self.size > 0:
            self.size = max(self.size, int(n))

    def pop(self, key: Hashable, default: Any = None) -> Any:
        return self._d.pop(key, default)

    def clear(self) -> None:
        self._d.clear()
