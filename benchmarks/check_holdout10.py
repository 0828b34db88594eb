"""Checks of held-out wording set 10 (`python benchmarks/make_holdout10.py --check` runs them; stdlib only).

Apart from the generator: the unit of each numeric row is read back from its question text and the benchmark's
ground truth converted with this file's own table; objects, options, letters, meaning words, sources, slips and the
runs of words shared with the earlier sets are tested on the written file (see make_holdout10.py's docstring).
"""
from __future__ import annotations

import argparse
import glob
import json
import re
import sys
from pathlib import Path

from holdout_common import FROM_BENCH, LIST_RE, OPTS_RE, read_checked_rows
from make_holdout10 import (EARLIER_SOURCES, HERE, ID_BASE, N_PATTERNS, NEVER_MISSPELT, OUT, PER_PATTERN, ROUTE_SYN,
                            SYN, TYPES, TYPO_OBJECTS, TYPO_PER_TYPE, TYPO_WORDS, VSI, _noun, build,
                            earlier_sources, load_questions, plural, rename, route_parts, source_objects)

UNIT_WORDS = [  # (unit, regex over the lowercased question); exactly one may match a numeric row
    ("m2", r"square met(?:re|er)s|\bsq ?m\b|\bsqm\b|\bm\^2|\bm²|met(?:re|er)s squared"),
    ("ft2", r"square f(?:ee|oo)t|\bsq ?ft\b|\bsqft\b|\bft\^2|\bft²"),
    ("mm", r"millimet(?:re|er)s?|\bmm\b"),
    ("cm", r"centimet(?:re|er)s?|\bcms?\b"),
    ("m", r"(?<!square )\bmet(?:re|er)s\b(?! squared)|(?<![\w'^])(?<!sq )m(?![\w'^²])"),
    ("in", r"\binch(?:es)?\b"),
    ("ft", r"(?<!square )\bfeet\b|(?<!square )\bfoot\b|(?<!sq )\bft\b(?!\^|²)"),
]
MEANING = {  # what each row of a type must still say (lowercased)
    "room_size_estimation": r"combin|together",
    "object_abs_distance": r"closest|nearest",
    "object_rel_distance": r"(?:closest|nearest)[- ](?:points?|pts|parts)|closest point to closest point",
    "object_rel_direction_easy": r"\bleft\b.*\bright\b",
    "object_rel_direction_medium": r"\bleft\b.*\bright\b.*\b(?:back|behind|turn round)\b",
    "object_rel_direction_hard": r"front[- ]left.*front[- ]right.*back[- ]left.*back[- ]right",
    "route_planning": r"\bleft\b.*\bright\b.*\bback\b",
}


def unslip(text: str) -> str:
    """`text` with every slip of the lists put back to its word (for the meaning test of a row with a slip)."""
    back = {s: w for t in (TYPO_WORDS, TYPO_OBJECTS) for w, v in t.items() for s in v}
    return re.sub(r"[a-z]+", lambda m: back.get(m.group(0), m.group(0)), text)


def units_read(text: str) -> set[str]:
    t = text.lower()
    return {u for u, rx in UNIT_WORDS if re.search(rx, t)}


def one_edit(a: str, b: str) -> bool:
    """True when `b` is `a` with one letter dropped, added, changed, or two neighbours swapped."""
    if a == b:
        return False
    if len(a) == len(b):
        diff = [i for i in range(len(a)) if a[i] != b[i]]
        return len(diff) == 1 or (len(diff) == 2 and diff[1] == diff[0] + 1 and a[diff[0]] == b[diff[1]]
                                  and a[diff[1]] == b[diff[0]])
    if abs(len(a) - len(b)) != 1:
        return False
    s, t = (a, b) if len(a) < len(b) else (b, a)
    return any(t[:i] + t[i + 1:] == s for i in range(len(t)))


def english_words() -> set[str]:
    words: set[str] = set()
    for p in ("/usr/share/dict/words", "/usr/share/dict/american-english", "/usr/share/dict/british-english"):
        if Path(p).exists():
            words |= {w.strip().lower() for w in Path(p).read_text(errors="replace").splitlines()}
    return words


def names_of(obj: str) -> set[str]:
    """Every way the set may name benchmark object `obj` (its name, everyday names, plurals, their slips)."""
    said = {obj, *SYN.get(obj, [])}
    said |= {plural(s) for s in said}
    for s in list(said):
        for w in re.findall(r"[A-Za-z]+", s):
            for slip in TYPO_OBJECTS.get(w.lower(), []):
                said.add(re.sub(rf"\b{w}\b", slip, s))
    return {s.lower() for s in said}


OBJ_MASK = {w for o in ("tv", "table", "stove", "sofa", "stool", "refrigerator", "chair", "bed", "washer",
                        "fireplace", "toilet", "bathtub", "dishwasher") for n in names_of(o) for w in n.split()}


def _tokens(text: str, waypoints: list[str]) -> list[str]:
    """Words of a question with the benchmark's content masked (objects -> OBJ, lists -> LIST, runs of direction
    option words -> OPTS, route waypoints -> OBJ)."""
    text = text.lower()
    for w in sorted(waypoints, key=len, reverse=True):
        text = text.replace(w.lower(), " OBJ ")
    words = ["OBJ" if w in OBJ_MASK or w == "obj" else w for w in re.findall(r"[a-z0-9']+|OBJ", text)]
    return OPTS_RE.sub("OPTS", LIST_RE.sub("LIST", " ".join(words))).split()


def _waypoints(q: dict) -> list[str]:
    start, face, goal, steps = route_parts(q["question"])
    out = [start, face, _noun(face), goal] + [w for s in steps if s for w in [s[1]]]
    out += [rename(w, {k: v for k, v in ROUTE_SYN.items() if re.search(rf"\b{k}\b", w, re.I)}) for w in out]
    return out + [re.sub(r"\byour\b", "my", s) for s in out]


def canon(text: str) -> str:
    """`text` lowercased with the British route names put back to the benchmark's (for the places test)."""
    back = {**{v: k for k, v in ROUTE_SYN.items()}, **{k: k for k in ROUTE_SYN}}
    pat = re.compile(r"\b(" + "|".join(sorted(back, key=len, reverse=True)) + r")\b")
    return pat.sub(lambda m: back[m.group(0)], text.lower())


def shared_runs(rows: list[dict], earlier: list[dict], src: dict[int, dict], n: int = 5) -> list[tuple]:
    """(length, run, question) for each new question sharing a run of `n`+ masked words with an earlier set."""
    def toks(r: dict) -> list[str]:
        s = src.get(r.get("source_id"))
        return _tokens(r["question"], _waypoints(s) if r["question_type"] == "route_planning" and s else [])

    grams = set()
    for r in earlier:
        t = toks(r)
        grams |= {tuple(t[i:i + n]) for i in range(len(t) - n + 1)}
    found = []
    for r in rows:
        t, best, i = toks(r), (), 0
        while i <= len(t) - n:
            j = i + n
            if tuple(t[i:j]) in grams:
                while j < len(t) and _shares(t[i:j + 1], earlier, toks):
                    j += 1
                best = max(best, tuple(t[i:j]), key=len)
            i += 1
        if best:
            found.append((len(best), " ".join(best), r["question"]))
    return sorted(set(found), reverse=True)


_EARLIER_TOKS: dict[int, str] = {}


def _shares(run: list[str], earlier: list[dict], toks) -> bool:
    if not _EARLIER_TOKS:
        for i, r in enumerate(earlier):
            _EARLIER_TOKS[i] = " " + " ".join(toks(r)) + " "
    needle = " " + " ".join(run) + " "
    return any(needle in t for t in _EARLIER_TOKS.values())


def run_checks(qs: list[dict], used: set[int], seed: int, out: Path) -> int:
    """Every check of the set; prints a summary and returns 0, or 1 when any check failed."""
    bad: list[str] = []
    src = {q["id"]: q for q in qs}
    read = read_checked_rows(lambda: build(qs, used, seed), out, ID_BASE, N_PATTERNS * PER_PATTERN, bad)
    if read is None:
        return 2
    rows, counts = read
    n_routes = sum(q["question_type"] == "route_planning" for q in qs)
    if counts.get("route_planning") != 2 * n_routes:
        bad.append(f"route_planning: {counts.get('route_planning')} rows, want {2 * n_routes}")
    # same question: scene, type, options, letter; converted numbers read back from the text
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
        qt = r["question_type"]
        if qt in FROM_BENCH:
            found = units_read(r["question"])
            if len(found) != 1:
                bad.append(f"row {r['id']}: units read {sorted(found)} in {r['question']!r}")
                continue
            u = found.pop()
            per = units.setdefault(qt, {})
            per[u] = per.get(u, 0) + 1
            want = float(q["ground_truth"]) * FROM_BENCH[qt].get(u, float("nan"))
            conv_checked += 1
            if not abs(float(r["ground_truth"]) - want) <= 0.5e-4 + 1e-9 or len(r["ground_truth"].split(".")[-1]) > 4:
                conv_bad += 1
                bad.append(f"row {r['id']}: {r['ground_truth']} {u}, want {want:.6f}")
        elif r["ground_truth"] != q["ground_truth"]:
            bad.append(f"row {r['id']}: ground truth differs from the source's")
        if qt in MEANING and not re.search(MEANING[qt], unslip(r["question"].lower()), re.S):
            bad.append(f"row {r['id']}: lost the benchmark's meaning ({MEANING[qt]}): {r['question']!r}")
        if qt != "route_planning":
            text = r["question"].lower()
            for o in source_objects(q):
                if not any(re.search(rf"(?<![a-z]){re.escape(s)}(?![a-z])", text) for s in names_of(o)):
                    bad.append(f"row {r['id']}: object {o!r} not named in {r['question']!r}")
        else:
            start, face, goal, steps = route_parts(q["question"])
            for w in [start, _noun(face), goal] + [x[1] for x in steps if x]:
                if canon(w) not in canon(r["question"]) and canon(re.sub(r"\byour\b", "my", w)) not in canon(
                        r["question"]):
                    bad.append(f"row {r['id']}: route place {w!r} not kept")
    print(f"conversions: {conv_checked} numeric rows re-derived from the unit in their text, {conv_bad} errors;",
          "units:", json.dumps(units))
    # sources: none of sets 8/9 while enough fresh ones remain
    for qt in TYPES:
        ids = [r["source_id"] for r in rows if r["question_type"] == qt]
        fresh = {q["id"] for q in qs if q["question_type"] == qt and q["id"] not in used}
        reused = [i for i in ids if i in used]
        if len(set(ids)) != len(ids):
            bad.append(f"{qt}: a source drawn twice")
        if len(fresh) >= len(ids) and reused:
            bad.append(f"{qt}: {len(reused)} sources used by set 8/9")
        if len(fresh) < len(ids) and not fresh <= set(ids):
            bad.append(f"{qt}: fresh sources left out")
        print(f"  {qt}: {len(ids)} sources, {len(ids) - len(reused)} new, {len(reused)} also used by set 8/9 "
              f"({len(fresh)} new ones existed)")
    # slips: one edit, not English, never a protected word, exactly one in 1 of 5 rows of each type
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
        hits = [w for w in re.findall(r"[a-z]+(?:'[a-z]+)?", r["question"].lower())
                if w in slip_forms or w.split("'")[0] in slip_forms]
        if len(hits) > 1:
            bad.append(f"row {r['id']}: {len(hits)} slips")
        if hits and hits[0] in src[r["source_id"]]["question"].lower().split():
            bad.append(f"row {r['id']}: slip {hits[0]!r} is the benchmark's own word")
        typo_rows[r["question_type"]] = typo_rows.get(r["question_type"], 0) + bool(hits)
    print("rows with a slip:", json.dumps(typo_rows), "total", sum(typo_rows.values()),
          f"(dictionary of {len(dictionary)} words)" if dictionary else "(no dictionary: English-word test skipped)")
    for qt in TYPES:
        if typo_rows.get(qt) != TYPO_PER_TYPE:
            bad.append(f"{qt}: {typo_rows.get(qt)} rows with a slip")
    if typo_rows.get("route_planning") != round(2 * n_routes / 5):
        bad.append(f"route_planning: {typo_rows.get('route_planning')} rows with a slip")
    # distance from the earlier sets' wordings
    earlier = []
    for p in sorted(glob.glob(str(HERE / "data" / "vsibench_paraphrases*.jsonl"))):
        if Path(p).resolve() != out.resolve():
            with open(p) as f:
                earlier += [json.loads(line) for line in f if line.strip()]
    runs = shared_runs(rows, earlier, src)
    print(f"runs of 5+ masked words shared with the {len(earlier)} earlier rows: {len(runs)} questions; longest:")
    for size, run, q in runs[:12]:
        print(f"  {size:2d} | {run} | {q[:110]}")
    for b in bad[:40]:
        print("FAIL", b)
    print("checks:", "all passed" if not bad else f"{len(bad)} failed")
    return 1 if bad else 0


def main() -> int:
    """`python benchmarks/check_holdout10.py` (what `make_holdout10.py --check` runs): every check on --out."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--questions", default=str(VSI / "questions.jsonl"))
    ap.add_argument("--seed", type=int, default=10)
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args()
    return run_checks(load_questions(a.questions), earlier_sources(EARLIER_SOURCES), a.seed, Path(a.out))


if __name__ == "__main__":
    sys.exit(main())
