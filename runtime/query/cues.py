"""Cue words per question kind: one table (data), scored over a question's words.

`CUES[kind]` maps a cue (one word, or several in a row) to its weight. `score(words)` sums the weights of the cues
a question holds per kind; `kind_of(words)` is the kind with the highest score when it is the only one (a tie or
no cue at all is refused, saying which cues were found). The rule parser's own cue reading (`rules.intent`)
decides first; this table decides what it leaves undecided.

Phrase synonyms that reduce to these cues ("tally" -> "count", "square footage" -> "square feet") live in
`normalize.PHRASES`.
"""
from __future__ import annotations

import functools

CUES: dict[str, dict[str, float]] = {
    "count": {"how many": 3, "number of": 2, "count": 2, "counting": 2, "total": 1, "quantity": 2, "tally": 2,
              "how much of": 2, "many": 1, "amount of": 2, "number": 1,
              # "how many metres / square feet": a length or an area, not a count
              **{f"how many {u}": -4 for u in ("m", "meters", "metres", "cm", "centimeters", "centimetres", "mm",
                                              "feet", "foot", "ft", "inches", "in", "square")}},
    "size": {"how big": 2, "how large": 2, "how long": 2, "how tall": 2, "how wide": 2, "how high": 2,
             "how deep": 2, "size": 2, "length": 2, "height": 2, "width": 2, "depth": 2, "dimension": 2,
             "dimensions": 2, "longest": 1, "biggest": 1, "largest": 1, "measure": 1, "measurement": 1, "big": 1,
             "long": 1, "tall": 1, "wide": 1, "side": 1, "edge": 1, "span": 2, "extent": 2},
    "abs_distance": {"how far": 3, "distance": 2, "far": 1, "apart": 2, "gap": 2, "clearance": 2,
                     "separation": 2, "space between": 2, "between": 2, "away": 1, "from": 1},
    "room_size": {"floor area": 4, "floor space": 4, "square meters": 4, "square feet": 4, "area": 3,
                  "footprint": 3},
    "rel_distance": {"closest": 3, "nearest": 3, "closer": 3, "nearer": 3, "farthest": 3, "furthest": 3,
                     "farther": 3, "further": 3, "which": 1},
    "direction": {"left": 2, "right": 2, "behind": 1, "back": 1, "front": 1, "quadrant": 3, "o'clock": 3,
                  "facing": 2, "looking at": 2, "front-left": 3, "front-right": 3, "back-left": 3,
                  "back-right": 3, "which side": 2},
    "route": {"route": 3, "walk": 2, "turn": 3, "turns": 3, "navigate": 3, "get to": 1, "go to": 1, "waypoint": 3,
              "go forward": 2, "until": 1, "till": 1, "reach": 1, "destination": 3, "please fill in": 4, "robot": 2,
              "steps": 1},
    "obj_appearance_order": {"first": 2, "order": 2, "before": 1, "after": 1, "appear": 2, "appeared": 2,
                             "earliest": 2, "sequence": 2},
}


MIN_SCORE = 2  # one weak cue word ("long", "which") alone names no kind


@functools.lru_cache(maxsize=1)
def cue_words() -> frozenset[str]:
    """Every single word of every cue."""
    return frozenset(w for table in CUES.values() for cue in table for w in cue.split())


def _hits(words: list[str], cue: str) -> int:
    parts = cue.split()
    n = len(parts)
    return sum(words[i:i + n] == parts for i in range(len(words) - n + 1))


def score(words: list[str]) -> dict[str, float]:
    """kind -> the sum of the weights of its cues in `words` (each occurrence counts once); kinds without a cue
    are left out."""
    out = {}
    for kind, table in CUES.items():
        s = sum(w * _hits(words, cue) for cue, w in table.items())
        if s:
            out[kind] = s
    return out


def kind_of(words: list[str]) -> tuple[str | None, str]:
    """(the kind with the unique highest cue score, or None; a line saying why: the cues found per kind)."""
    every = score(words)
    s = {k: v for k, v in every.items() if v >= MIN_SCORE}
    if not s:
        weak = ", ".join(k.replace("_", " ") for k in every)
        return None, "no cue word of any question kind" + (f" (only weak cues of: {weak})" if weak else "")
    ranked = sorted(s.items(), key=lambda kv: -kv[1])
    found = ", ".join(f"{k.replace('_', ' ')} {v:g}" for k, v in ranked)
    if len(ranked) > 1 and ranked[0][1] == ranked[1][1]:
        return None, f"cue scores tie ({found})"
    return ranked[0][0], f"cue scores: {found}"
