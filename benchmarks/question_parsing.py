"""Question parsing cost: parse_question at and around the length limit on adversarial text (repeated phrases, and
distinct made-up words), the refusal of longer questions, and the
inline-option splitter on long input (it must stay linear).

    python benchmarks/question_parsing.py   ->  benchmarks/results/question_parsing.json
"""
from __future__ import annotations

import json
import platform
import random
import string
import time
from pathlib import Path

from mosaicthinker.runtime.infra.errors import InputError
from mosaicthinker.runtime.grounding import MAX_QUESTION_CHARS, parse_question, split_inline_options

PATTERNS = {
    "direction_template": "If I am standing by the stove and facing the sofa, is the ",
    "distance_template": "Measuring from the closest point of each object, what is the distance between the a and ",
    "rel_distance_list": "which of these objects (chair, stool, stove, sofa, ",
    "natural_words": "how far is the red chair nearest the door from the tv stand or the couch ",
    "option_marks": "A. left B. right A. x ",
    "no_spaces": "x" * 50,
    "route_steps": "You are a robot beginning at the bed facing the tv. You want to navigate to the sink. 1. Go forward until the ",
}


def best_of(fn, n: int = 3) -> float:
    best = float("inf")
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def distinct_words(n: int, seed: int = 0) -> str:
    """n characters of distinct made-up words (no word seen before)."""
    rng = random.Random(seed)
    words = ["".join(rng.choice(string.ascii_lowercase) for _ in range(rng.randint(4, 10))) for _ in range(n // 4)]
    return " ".join(words)[:n]


def main() -> None:
    rows = []
    for n in (200, 1000, MAX_QUESTION_CHARS):
        q = distinct_words(n)

        def fresh() -> None:
            parse_question(q, names=["office chair"])  # with a map's names
        rows.append({"pattern": "distinct_unknown_words", "chars": n, "parse_s": round(best_of(fresh), 5)})
    for name, pat in PATTERNS.items():
        for n in (200, 1000, MAX_QUESTION_CHARS):
            q = (pat * (n // len(pat) + 1))[:n]
            rows.append({"pattern": name, "chars": n, "parse_s": round(best_of(lambda: parse_question(q)), 5)})
        big = pat * (100_000 // len(pat) + 1)

        def refuse() -> None:
            try:
                parse_question(big)
            except InputError:
                return
            raise AssertionError("a 100 kB question was not refused")

        rows.append({"pattern": name, "chars": len(big), "refused_s": round(best_of(refuse), 5),
                     "split_inline_options_s": round(best_of(lambda: split_inline_options(big)), 5)})
    out = {"schema": "mosaicthinker.bench.question_parsing/1", "max_question_chars": MAX_QUESTION_CHARS,
           "machine": platform.processor() or platform.machine(), "python": platform.python_version(),
           "worst_parse_s": max(r.get("parse_s", 0) for r in rows),
           "worst_split_100kB_s": max(r.get("split_inline_options_s", 0) for r in rows), "rows": rows}
    path = Path(__file__).resolve().parent / "results" / "question_parsing.json"
    path.write_text(json.dumps(out, indent=1))
    print(json.dumps({k: v for k, v in out.items() if k != "rows"}))


if __name__ == "__main__":
    main()
