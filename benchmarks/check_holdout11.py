"""Checks of held-out wording set 11 (`python benchmarks/make_holdout11.py --check` runs them; stdlib only).

Apart from the generator: the unit of each numeric row is read back from its question text and the benchmark's
ground truth converted with this file's own table; objects, options, letters, list order, meaning words, sources,
slips, abbreviations and the runs of words shared with the earlier sets are tested on the written file. The
one-edit and dictionary helpers are set 10's (check_holdout10.py), imported.
"""
from __future__ import annotations

import argparse
import glob
import json
import re
import sys
from pathlib import Path

from check_holdout10 import english_words, one_edit
from holdout_common import FROM_BENCH, LIST_RE, OPTS_RE, read_checked_rows
from make_holdout10 import ROUTE_SYN as SET10_ROUTE_SYN, rename as set10_rename
from make_holdout11 import (EARLIER_SOURCES, HERE, ID_BASE, N_PATTERNS, NEVER_MISSPELT, OUT, PER_PATTERN, SYN, TYPES,
                            TYPO_OBJECTS, TYPO_PER_TYPE, TYPO_WORDS, VSI, _noun, build, earlier_uses,
                            load_questions, plural, route_parts, source_objects)

UNIT_WORDS = [  # (unit, regex over the lowercased question); exactly one may match a numeric row
    ("m2", r"square met(?:re|er)s?\b|\bsq ?m\b|\bm\^2|\bm²|\bm2\b"),
    ("ft2", r"square f(?:ee|oo)t|\bsq ?ft\b"),
    ("mm", r"millimet(?:re|er)s?\b|\bmm\b"),
    ("cm", r"centimet(?:re|er)s?\b|\bcms?\b"),
    ("m", r"(?<!square )\bmet(?:re|er)s?\b|(?<![\w'^])(?<!sq )m(?![\w'^²])"),
    ("in", r"\binch(?:es)?\b"),
    ("ft", r"(?<!square )\bfeet\b|(?<!square )\bfoot\b(?!age)|(?<!sq )\bft\b"),
]
MEANING = {  # what each row of a type must still say (lowercased, slip undone)
    "object_counting": r"how (?:many|much)|count|tally|number|headcount",
    "object_size_estimation": r"longest|biggest|largest|greatest|\bmax\b",
    "room_size_estimation": r"combin|together",
    "object_abs_distance": r"closest|nearest",
    "object_rel_distance": r"(?:closest|nearest) points?",
    "object_rel_direction_easy": r"\bleft\b.*\bright\b",
    "object_rel_direction_medium": r"\bleft\b.*\bright\b.*\b(?:back|behind)\b",
    "object_rel_direction_hard": r"front-left.*front-right.*back-left.*back-right",
    "route_planning": r"\bleft\b.*\bright\b.*\bback\b",
}
ABBREVIATIONS = {"ngl", "pls", "thx", "tbh", "r", "u", "ur", "btw", "lol", "idk"}


def unslip(text: str) -> str:
    """`text` with every slip of the lists put back to its word."""
    back = {s: w for t in (TYPO_WORDS, TYPO_OBJECTS) for w, v in t.items() for s in v}
    return re.sub(r"[a-z]+", lambda m: back.get(m.group(0), m.group(0)), text)


def units_read(text: str) -> set[str]:
    t = text.lower()
    return {u for u, rx in UNIT_WORDS if re.search(rx, t)}


def names_of(obj: str) -> set[str]:
    """Every way the set may name benchmark object `obj` (its name, everyday names, plurals, their slips)."""
    said = {obj, *SYN.get(obj, [])}
    said |= {plural(s) for s in said}
    for s in list(said):
        for w in re.findall(r"[A-Za-z]+", s):
            for slip in TYPO_OBJECTS.get(w.lower(), []):
                said.add(re.sub(rf"\b{w}\b", slip, s))
    return {s.lower() for s in said}


def _find(text: str, obj: str, start: int = 0) -> int:
    """Position of the first naming of `obj` in lowercased `text` at or after `start`, or -1."""
    hits = [m.start() for s in names_of(obj)
            for m in re.finditer(rf"(?<![a-z]){re.escape(s)}(?![a-z])", text) if m.start() >= start]
    return min(hits, default=-1)


# --- distance from the earlier sets (masked runs of words) ----------------------------------------------------------
_OBJ = ("tv", "table", "stove", "sofa", "stool", "refrigerator", "chair", "bed", "washer", "fireplace", "toilet",
        "bathtub", "dishwasher")
OBJ_MASK = {w for o in _OBJ for n in names_of(o) for w in n.split()} | {
    "settee", "settees", "couch", "couches", "fridge", "fridges", "hob", "cooker", "loo", "bath", "tub", "set",
    "washing", "machine", "machines", "television", "tvs"}


def _tokens(text: str, places: list[str]) -> list[str]:
    text = text.lower()
    for w in sorted(places, key=len, reverse=True):
        text = text.replace(w.lower(), " OBJ ")
    words = ["OBJ" if w in OBJ_MASK or w == "obj" else w for w in re.findall(r"[a-z0-9']+|OBJ", text)]
    return OPTS_RE.sub("OPTS", LIST_RE.sub("LIST", " ".join(words))).split()


def _places(q: dict) -> list[str]:
    start, face, goal, steps = route_parts(q["question"])
    out = [start, face, _noun(face), goal] + [s[1] for s in steps if s]
    out += [set10_rename(w, {k: v for k, v in SET10_ROUTE_SYN.items() if re.search(rf"\b{k}\b", w, re.I)})
            for w in out]
    return out + [re.sub(r"\byour\b", "my", s) for s in out]


def shared_runs(rows: list[dict], earlier: list[dict], src: dict[int, dict], n: int = 5) -> list[tuple]:
    """(length, run, question) for each new question sharing a run of `n`+ masked words with an earlier set."""
    def toks(r: dict) -> list[str]:
        s = src.get(r.get("source_id"))
        return _tokens(r["question"], _places(s) if r["question_type"] == "route_planning" and s else [])

    texts = [" " + " ".join(toks(r)) + " " for r in earlier]
    grams = set()
    for t in texts:
        w = t.split()
        grams |= {tuple(w[i:i + n]) for i in range(len(w) - n + 1)}
    found = []
    for r in rows:
        t, best = toks(r), ()
        for i in range(len(t) - n + 1):
            j = i + n
            if tuple(t[i:j]) not in grams:
                continue
            while j < len(t) and any(" " + " ".join(t[i:j + 1]) + " " in e for e in texts):
                j += 1
            best = max(best, tuple(t[i:j]), key=len)
        if best:
            found.append((len(best), " ".join(best), r["question"]))
    return sorted(set(found), reverse=True)


def run_checks(qs: list[dict], uses: dict[int, int], seed: int, out: Path) -> int:
    """Every check of the set; prints a summary and returns 0, or 1 when any check failed."""
    bad: list[str] = []
    src = {q["id"]: q for q in qs}
    read = read_checked_rows(lambda: build(qs, uses, seed), out, ID_BASE, N_PATTERNS * PER_PATTERN, bad)
    if read is None:
        return 2
    rows, counts = read
    routes = {q["id"] for q in qs if q["question_type"] == "route_planning"}
    route_src = [r["source_id"] for r in rows if r["question_type"] == "route_planning"]
    if sorted(route_src) != sorted(routes):
        bad.append(f"route_planning: {len(route_src)} rows, want every one of the {len(routes)} questions once")
    conv_checked = conv_bad = 0
    units: dict[str, dict[str, int]] = {}
    for r in rows:
        q = src.get(r["source_id"])
        if q is None:
            bad.append(f"row {r['id']}: source {r['source_id']} not in the benchmark")
            continue
        for f in ("dataset", "scene_name", "question_type", "options"):
            if r[f] != q[f]:
                bad.append(f"row {r['id']}: {f} differs from the source's")
        qt, text = r["question_type"], r["question"].lower()
        if qt in FROM_BENCH:
            found = units_read(r["question"])
            if len(found) != 1:
                bad.append(f"row {r['id']}: units read {sorted(found)} in {r['question']!r}")
                continue
            u = found.pop()
            per = units.setdefault(qt, {})
            per[u] = per.get(u, 0) + 1
            want = float(q["ground_truth"]) * FROM_BENCH[qt][u]
            conv_checked += 1
            if not abs(float(r["ground_truth"]) - want) <= 0.5e-4 + 1e-9 or len(r["ground_truth"].split(".")[-1]) > 4:
                conv_bad += 1
                bad.append(f"row {r['id']}: {r['ground_truth']} {u}, want {want:.6f}")
        elif r["ground_truth"] != q["ground_truth"]:
            bad.append(f"row {r['id']}: ground truth differs from the source's")
        if not re.search(MEANING[qt], unslip(text), re.S):
            bad.append(f"row {r['id']}: lost the benchmark's meaning ({MEANING[qt]}): {r['question']!r}")
        abbrev = [w for w in re.findall(r"[a-z]+", text) if w in ABBREVIATIONS]
        if len(abbrev) > 1:
            bad.append(f"row {r['id']}: {len(abbrev)} abbreviations {abbrev}")
        if qt != "route_planning":
            objs = source_objects(q)
            for o in objs:
                if _find(text, o) < 0:
                    bad.append(f"row {r['id']}: object {o!r} not named in {r['question']!r}")
            if qt == "object_rel_distance":  # candidates said in the options' order (lettered lists: same letters)
                pos = 0
                for o, opt in zip(objs[:-1], q["options"]):
                    if not opt.endswith(". " + o):
                        bad.append(f"row {r['id']}: option {opt!r} is not candidate {o!r}")
                    pos = _find(text, o, pos)
                    if pos < 0:
                        bad.append(f"row {r['id']}: candidates not in the options' order")
                        break
                    pos += 1
                for letter, name in re.findall(r"\b([abcd])\) ([a-z ]+?)(?= [abcd]\)|\?|$)", text):
                    if _find(name, objs["abcd".index(letter)]) != 0:
                        bad.append(f"row {r['id']}: letter {letter} names {name!r}")
        else:
            start, face, goal, steps = route_parts(q["question"])
            for w in [start, _noun(face), goal] + [x[1] for x in steps if x]:
                if w.lower() not in text and re.sub(r"\byour\b", "my", w).lower() not in text:
                    bad.append(f"row {r['id']}: route place {w!r} not kept")
            if text.count("?") < sum(x is None for x in steps) and "each" not in unslip(text):
                bad.append(f"row {r['id']}: fewer blanks than turns")
    print(f"conversions: {conv_checked} numeric rows re-derived from the unit in their text, {conv_bad} errors;",
          "units:", json.dumps(units))
    for qt in TYPES:
        ids = [r["source_id"] for r in rows if r["question_type"] == qt]
        fresh = {q["id"] for q in qs if q["question_type"] == qt and q["id"] not in uses}
        reused = [i for i in ids if i in uses]
        if len(set(ids)) != len(ids):
            bad.append(f"{qt}: a source drawn twice")
        if len(fresh) >= len(ids) and reused:
            bad.append(f"{qt}: {len(reused)} sources used by sets 8-10")
        if len(fresh) < len(ids) and not fresh <= set(ids):
            bad.append(f"{qt}: fresh sources left out")
        by_uses = {k: sum(uses[i] == k for i in reused) for k in (1, 2, 3)}
        print(f"  {qt}: {len(ids)} sources, {len(ids) - len(reused)} new, {len(reused)} reused from sets 8-10 "
              f"({len(fresh)} new ones existed; reused ones by earlier uses 1/2/3: {by_uses[1]}/{by_uses[2]}/"
              f"{by_uses[3]})")
    dictionary = english_words()
    for table in (TYPO_WORDS, TYPO_OBJECTS):
        for w, slips in table.items():
            for s in slips:
                if not one_edit(w, s):
                    bad.append(f"slip {s!r} is not one edit from {w!r}")
                if s in dictionary:
                    bad.append(f"slip {s!r} is an English word")
                if w in NEVER_MISSPELT:
                    bad.append(f"{w!r} may not be misspelt")
    slip_forms = {s for t in (TYPO_WORDS, TYPO_OBJECTS) for v in t.values() for s in v}
    typo_rows: dict[str, int] = {}
    for r in rows:
        hits = [w for w in re.findall(r"[a-z]+", r["question"].lower()) if w in slip_forms]
        if len(hits) > 1:
            bad.append(f"row {r['id']}: {len(hits)} slips")
        if hits and hits[0] in re.findall(r"[a-z]+", src[r["source_id"]]["question"].lower()):
            bad.append(f"row {r['id']}: slip {hits[0]!r} is the benchmark's own word")
        typo_rows[r["question_type"]] = typo_rows.get(r["question_type"], 0) + bool(hits)
    print("rows with a slip:", json.dumps(typo_rows), "total", sum(typo_rows.values()),
          f"(dictionary of {len(dictionary)} words)" if dictionary else "(no dictionary: English-word test skipped)")
    for qt in TYPES:
        if typo_rows.get(qt) != TYPO_PER_TYPE:
            bad.append(f"{qt}: {typo_rows.get(qt)} rows with a slip")
    if typo_rows.get("route_planning") != round(len(routes) / 5):
        bad.append(f"route_planning: {typo_rows.get('route_planning')} rows with a slip")
    earlier = []
    for p in sorted(glob.glob(str(HERE / "data" / "vsibench_paraphrases*.jsonl"))):
        if Path(p).resolve() != out.resolve():
            with open(p) as f:
                earlier += [json.loads(line) for line in f if line.strip()]
    late = [r for r in earlier if r["id"] >= 900000]  # sets 8, 9, 10 (ids from 900000, 1000000, 1100000)
    for name, pool in (("all earlier sets", earlier), ("sets 8-10", late)):
        runs = shared_runs(rows, pool, src)
        print(f"runs of 5+ masked words shared with {name} ({len(pool)} rows): {len(runs)} questions; longest:")
        for size, run, q in runs[:8]:
            print(f"  {size:2d} | {run} | {q[:100]}")
    for b in bad[:40]:
        print("FAIL", b)
    print("checks:", "all passed" if not bad else f"{len(bad)} failed")
    return 1 if bad else 0


def main() -> int:
    """`python benchmarks/check_holdout11.py` (what `make_holdout11.py --check` runs): every check on --out."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--questions", default=str(VSI / "questions.jsonl"))
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args()
    return run_checks(load_questions(a.questions), earlier_uses(EARLIER_SOURCES), a.seed, Path(a.out))


if __name__ == "__main__":
    sys.exit(main())
