"""Checks of held-out wording set 12 (`python benchmarks/make_holdout12.py --check` runs them; stdlib only).

Each row is read back from its written text, apart from the generator's build: the text (slips undone) must match
its pattern's template with the slots as wildcards, and what fills the slots must name the source question's objects
in their roles (stand / face / asked about; the reference and the four candidates in the options' order; the two
ends of a distance), under the benchmark's name or the pattern's everyday name. The unit of each numeric row is read
from the text with this file's own regexes and the benchmark's ground truth converted with this file's own table.
Also: options, letters and fields as the source's, sources fresh where they can be, the slips (one edit, not an
English word, 8 rows in 40, 21 routes in 104), route places kept, and the runs of words shared with sets 1-11.
The one-edit and dictionary helpers are set 10's (check_holdout10.py), imported.
"""
from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
from pathlib import Path

from check_holdout10 import english_words, one_edit
from holdout_common import (LIST_RE, N_PATTERNS, OPTS_RE, PER_PATTERN, TYPES, TYPO_PER_TYPE, _noun, read_checked_rows,
                            source_objects)
from make_holdout10 import ROUTE_SYN as SET10_ROUTE_SYN, rename as set10_rename
from make_holdout12 import (ABS, COUNT, EARLIER_SOURCES, EASY, HARD, ID_BASE, MEDIUM, NEVER_MISSPELT, OUT, REGION,
                            REL, ROOM, ROUTES, SIZE, SYN, TYPO_OBJECTS, TYPO_WORDS, VSI, build, earlier_uses,
                            load_questions, plural, route_parts)

FROM_BENCH = {  # benchmark unit -> unit read: cm for sizes, m for distances, m^2 for areas (1 in = 2.54 cm exactly)
    "object_size_estimation": {"cm": 1.0, "mm": 10.0, "m": 0.01, "in": 1 / 2.54, "ft": 1 / 30.48},
    "object_abs_distance": {"m": 1.0, "cm": 100.0, "mm": 1000.0, "in": 100 / 2.54, "ft": 100 / 30.48},
    "room_size_estimation": {"m2": 1.0, "ft2": 1 / (0.3048 * 0.3048)}}
UNIT_WORDS = [  # (unit, regex over the lowercased question); exactly one may match a numeric row
    ("m2", r"square met(?:re|er)s?\b|\bmet(?:re|er)s? squared\b|\bsq ?m\b|\bm\^2|\bm²|\bm2\b"),
    ("ft2", r"square f(?:ee|oo)t\b|\bf(?:ee|oo)t squared\b|\bsq ?ft\b"),
    ("mm", r"millimet(?:re|er)s?\b|\bmm\b"),
    ("cm", r"centimet(?:re|er)s?\b|\bcms?\b"),
    ("m", r"(?<!square )\bmet(?:re|er)s?\b(?! squared)|(?<![\w'^])(?<!sq )m(?![\w'^²])"),
    ("in", r"\binch(?:es)?\b"),
    ("ft", r"(?<!square )\bf(?:ee|oo)t\b(?! squared)|(?<!sq )\bft\b"),
]
MEANING = {  # what each row of a type must still say (lowercased, slips undone); every regex of the list
    "object_counting": [r"how many|count|number|total"],
    "object_size_estimation": [r"longest|biggest|largest|greatest|most long", r"length", r"width", r"height"],
    "room_size_estimation": [r"combin|together|added up|\bsum\b|\btotal", r"more than one|several|many rooms|every "
                             r"(?:other )?room|all the rooms"],
    "object_abs_distance": [r"closest|nearest|most near"],
    "object_rel_distance": [r"(?:closest|nearest) points?|closest point to closest point",
                            r"closest|nearest|nearer|more near"],
    "object_rel_direction_easy": [r"\bleft\b", r"\bright\b"],
    "object_rel_direction_medium": [r"\bleft\b", r"\bright\b", r"\b(?:back|behind)\b"],
    "object_rel_direction_hard": [r"front[- ]left", r"front[- ]right", r"back[- ]left", r"back[- ]right"],
    "route_planning": [r"\bleft\b", r"\bright\b", r"\bback\b"],
}
PATTERNS = {"object_counting": COUNT, "object_size_estimation": [t for t, _ in SIZE],
            "room_size_estimation": [t for t, _ in ROOM], "object_abs_distance": [t for t, _ in ABS],
            "object_rel_distance": [t for t, _ in REL], "object_rel_direction_easy": EASY,
            "object_rel_direction_medium": MEDIUM, "object_rel_direction_hard": HARD}
LISTS = {  # each list style of REL read back into its four names
    "spoken": r"the (.+) the (.+) the (.+) or the (.+)", "the_comma_or": r"the (.+), the (.+), the (.+), or the (.+)",
    "the_or": r"the (.+), the (.+), the (.+) or the (.+)", "comma_and": r"(.+), (.+), (.+) and (.+)",
    "lettered": r"\(a\) (.+) \(b\) (.+) \(c\) (.+) \(d\) (.+)"}


def unslip(text: str) -> str:
    """`text` with every slip of the tables put back to its word (first letter's case kept)."""
    back = {s: w for t in (TYPO_WORDS, TYPO_OBJECTS) for w, v in t.items() for s in v}

    def put(m: re.Match) -> str:
        w = back.get(m.group(0).lower())
        return m.group(0) if w is None else (w[:1].upper() + w[1:] if m.group(0)[:1].isupper() else w)
    return re.sub(r"[A-Za-z]+", put, text)


def units_read(text: str) -> set[str]:
    t = text.lower()
    return {u for u, rx in UNIT_WORDS if re.search(rx, t)}


def template_re(tpl: str) -> re.Pattern:
    """Template `tpl` as a regex over the whole question: literal words kept, each {slot} a group (repeats must
    say the same words)."""
    out, seen = [], set()
    for part in re.split(r"(\{\w+\})", tpl):
        slot = re.fullmatch(r"\{(\w+)\}", part)
        if slot and slot.group(1) in seen:
            out.append(f"(?P={slot.group(1)})")
        elif slot:
            seen.add(slot.group(1))
            out.append(f"(?P<{slot.group(1)}>.+?)")
        else:
            out.append(re.escape(part))
    return re.compile("".join(out), re.I | re.S)


def names_of(obj: str, k: int) -> set[str]:
    """Every way pattern `k` may name benchmark object `obj`: its own name or the pattern's everyday name."""
    said = {obj} | ({SYN[REGION[k]][obj]} if obj in SYN[REGION[k]] else set())
    return {s.lower() for s in said}


def pattern_of(r: dict) -> tuple[int, re.Match] | None:
    """(pattern index, match) of the first template of the row's type its text (slips undone) matches in full."""
    text = unslip(r["question"])
    for k, tpl in enumerate(PATTERNS[r["question_type"]]):
        m = template_re(tpl).fullmatch(text)
        if m:
            return k, m
    return None


def roles_ok(q: dict, k: int, m: re.Match) -> list[str]:
    """What is wrong with the objects the slots of match `m` name (empty when each names its source object)."""
    qt, objs, bad = q["question_type"], source_objects(q), []
    slots = {s: v.lower() for s, v in m.groupdict().items()}
    want: dict[str, str] = {}
    if qt == "object_counting":
        names = names_of(objs[0], k)
        for slot, said in slots.items():
            if said not in (names if slot == "P" else {plural(n).lower() for n in names}):
                bad.append(f"counted {said!r}, want {objs[0]!r}")
        return bad
    if qt == "object_size_estimation":
        want = {"X": objs[0]}
    elif qt == "object_abs_distance":
        want = {"A": objs[0], "B": objs[1]}
    elif qt.startswith("object_rel_direction"):
        want = {"A": objs[0], "B": objs[1], "C": objs[2]}
    elif qt == "object_rel_distance":
        want = {"R": objs[-1]}
        style = REL[k][1]
        lm = re.fullmatch(LISTS[style], slots["L"])
        if lm is None:
            return [f"candidate list {slots['L']!r} is not a {style} list"]
        for i, (said, cand) in enumerate(zip(lm.groups(), objs[:-1])):
            if not q["options"][i].endswith(". " + cand):
                bad.append(f"option {q['options'][i]!r} is not candidate {cand!r}")
            if said not in names_of(cand, k):
                bad.append(f"candidate {i + 1} said {said!r}, want {cand!r}")
    for slot, obj in want.items():
        if slots.get(slot) not in names_of(obj, k):
            bad.append(f"slot {slot} says {slots.get(slot)!r}, want {obj!r}")
    return bad


def route_pattern(text: str) -> int | None:
    text = unslip(text)
    for k, r in enumerate(ROUTES):
        head = re.escape(r[0].split("{start}")[0])
        if re.match(head, text, re.I):
            return k
    return None


# --- distance from the earlier sets (masked runs of words) ----------------------------------------------------------
OBJ_WORDS = {"tv", "tvs", "table", "tables", "stove", "stoves", "sofa", "sofas", "stool", "stools", "refrigerator",
             "refrigerators", "chair", "chairs", "bed", "beds", "washer", "washers", "fireplace", "fireplaces",
             "toilet", "toilets", "bathtub", "bathtubs", "dishwasher", "dishwashers", "settee", "settees", "couch",
             "couches", "fridge", "fridges", "freezer", "freezers", "hob", "cooker", "cookers", "loo", "bath",
             "baths", "tub", "tubs", "set", "sets", "washing", "machine", "machines", "television", "televisions",
             "telly", "tellies", "lavatory", "lavatories", "clothes", "stovetop"}


def _tokens(text: str, places: list[str]) -> list[str]:
    text = text.lower()
    for w in sorted(places, key=len, reverse=True):
        text = text.replace(w.lower(), " OBJ ")
    words = ["OBJ" if w in OBJ_WORDS or w == "obj" else w for w in re.findall(r"[a-z0-9']+|OBJ", text)]
    # a list of objects or of directions counts as one word
    return OPTS_RE.sub("OPTS", LIST_RE.sub("LIST", " ".join(words))).split()


def _places(q: dict) -> list[str]:
    start, face, goal, steps = route_parts(q["question"])
    out = [start, face, _noun(face), goal] + [s[1] for s in steps if s]
    out += [set10_rename(w, {k: v for k, v in SET10_ROUTE_SYN.items() if re.search(rf"\b{k}\b", w, re.I)})
            for w in out]
    return out + [re.sub(r"\byour\b", o, s) for s in out for o in ("my", "her")]


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


# --- the checks -----------------------------------------------------------------------------------------------------


def check_rows(rows: list[dict], src: dict[int, dict], bad: list[str]) -> None:
    """Fields, sources, patterns, roles, units and conversions, meaning and route places of every row."""
    conv = 0
    units: dict[str, dict[str, int]] = {}
    per_pattern: dict[str, list[int]] = {}
    for i, r in enumerate(rows):
        q = src.get(r["source_id"])
        if q is None:
            bad.append(f"row {r['id']}: source {r['source_id']} not in the benchmark")
            continue
        for f in ("dataset", "scene_name", "question_type", "options"):
            if r[f] != q[f]:
                bad.append(f"row {r['id']}: {f} differs from the source's")
        qt, text = r["question_type"], unslip(r["question"]).lower()
        for rx in MEANING[qt]:
            if not re.search(rx, text, re.S):
                bad.append(f"row {r['id']}: lost the benchmark's meaning ({rx}): {r['question']!r}")
        if qt == "route_planning":
            k = route_pattern(r["question"])
            per_pattern.setdefault(qt, [0] * len(ROUTES))[k if k is not None else 0] += k is not None
            if k is None:
                bad.append(f"row {r['id']}: no route pattern opens {r['question'][:60]!r}")
                continue
            start, face, goal, steps = route_parts(q["question"])
            owner = ROUTES[k][7]
            for w in [start, _noun(face), goal] + [x[1] for x in steps if x]:
                if re.sub(r"\byour\b", owner, w).lower() not in r["question"].lower():
                    bad.append(f"row {r['id']}: route place {w!r} not kept")
            blanks = sum(x is None for x in steps)
            said = len(re.findall(r"some way|\[\?\]|\(where\?\)|\(unresolved\)", text))
            if said != blanks:
                bad.append(f"row {r['id']}: {said} blanks for {blanks} turns")
            if r["ground_truth"] != q["ground_truth"]:
                bad.append(f"row {r['id']}: ground truth differs from the source's")
            continue
        found = pattern_of(r)
        if found is None:
            bad.append(f"row {r['id']}: matches no pattern of its type: {r['question']!r}")
            continue
        k, m = found
        pos = sum(1 for x in rows[:i] if x["question_type"] == qt)
        if k != pos // PER_PATTERN:
            bad.append(f"row {r['id']}: pattern {k}, want {pos // PER_PATTERN} (rows 4k..4k+3 use pattern k)")
        per_pattern.setdefault(qt, [0] * N_PATTERNS)[k] += 1
        bad += [f"row {r['id']}: {b}" for b in roles_ok(q, k, m)]
        if qt in FROM_BENCH:
            found_units = units_read(r["question"])
            if len(found_units) != 1:
                bad.append(f"row {r['id']}: units read {sorted(found_units)} in {r['question']!r}")
                continue
            u = found_units.pop()
            units.setdefault(qt, {}).setdefault(u, 0)
            units[qt][u] += 1
            want = float(q["ground_truth"]) * FROM_BENCH[qt][u]
            if abs(float(r["ground_truth"]) - want) > 0.5e-4 + 1e-9 or len(r["ground_truth"].split(".")[-1]) > 4:
                conv += 1
                bad.append(f"row {r['id']}: {r['ground_truth']} {u}, want {want:.6f}")
        elif r["ground_truth"] != q["ground_truth"]:
            bad.append(f"row {r['id']}: ground truth differs from the source's")
    for qt, counts in per_pattern.items():
        want = PER_PATTERN if qt != "route_planning" else None
        if want and any(c != want for c in counts):
            bad.append(f"{qt}: rows per pattern {counts}, want {want} each")
    print("rows per pattern:", json.dumps(per_pattern))
    n_num = sum(sum(v.values()) for v in units.values())
    print(f"conversions: {n_num} numeric rows re-derived from the unit in their text, {conv} errors; units:",
          json.dumps(units))


def check_sources(rows: list[dict], qs: list[dict], uses: dict[int, int], bad: list[str]) -> None:
    for qt in TYPES:
        ids = [r["source_id"] for r in rows if r["question_type"] == qt]
        fresh = {q["id"] for q in qs if q["question_type"] == qt and q["id"] not in uses}
        reused = [i for i in ids if i in uses]
        if len(set(ids)) != len(ids):
            bad.append(f"{qt}: a source drawn twice")
        if len(fresh) >= len(ids) and reused:
            bad.append(f"{qt}: {len(reused)} sources used by earlier sets")
        if len(fresh) < len(ids) and not fresh <= set(ids):
            bad.append(f"{qt}: fresh sources left out")
        spare = sorted(uses[q["id"]] for q in qs if q["question_type"] == qt and q["id"] in uses
                       and q["id"] not in set(ids))
        if reused and spare and max(uses[i] for i in reused) > spare[0]:
            bad.append(f"{qt}: a source used {max(uses[i] for i in reused)} times drawn while one used {spare[0]} "
                       "times was left")
        most = max((uses[i] for i in reused), default=0)
        print(f"  {qt}: {len(ids)} sources, {len(ids) - len(reused)} new, {len(reused)} reused from sets 1-11 "
              f"({len(fresh)} new ones existed; reused ones' earlier uses: max {most})")


def check_slips(rows: list[dict], src: dict[int, dict], n_routes: int, bad: list[str]) -> None:
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
    if typo_rows.get("route_planning") != round(n_routes / 5):
        bad.append(f"route_planning: {typo_rows.get('route_planning')} rows with a slip")


def everyday_share(rows: list[dict]) -> None:
    """How often an object that has an everyday name in its pattern's region is said by that name."""
    said = every = 0
    for r in rows:
        if r["question_type"] in ("route_planning", "room_size_estimation"):
            continue
        found = pattern_of(r)
        if found is None:
            continue
        k, m = found
        table = SYN[REGION[k]]
        for v in m.groupdict().values():
            for alt in table.values():
                if re.search(rf"(?<![a-z]){re.escape(alt)}", v, re.I):
                    said += 1
            every += sum(1 for obj in table if re.search(rf"(?<![a-z-]){obj}(?![a-z-])", v, re.I))
    print(f"everyday names: {said} of {said + every} mentions of objects that have one "
          f"({100 * said / max(1, said + every):.0f}%)")


def run_checks(qs: list[dict], uses: dict[int, int], seed: int, out: Path) -> int:
    """Every check of the set; prints a summary and returns 0, or 1 when any check failed (2: no file)."""
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
    check_rows(rows, src, bad)
    check_sources(rows, qs, uses, bad)
    check_slips(rows, src, len(routes), bad)
    everyday_share(rows)
    earlier = []
    for p in EARLIER_SOURCES:
        with open(p) as f:
            earlier += [json.loads(line) for line in f if line.strip()]
    late = [r for r in earlier if r["id"] >= 900000]  # sets 8-11 (ids from 900000)
    for name, pool in (("sets 1-11", earlier), ("sets 8-11", late)):
        runs = shared_runs(rows, pool, src)
        lengths = [s for s, *_ in runs]
        print(f"runs of 5+ masked words shared with {name} ({len(pool)} rows): {len(runs)} of {len(rows)} "
              f"questions; median {statistics.median(lengths) if lengths else 0}, longest:")
        for size, run, q in runs[:6]:
            print(f"  {size:2d} | {run} | {q[:90]}")
    for b in bad[:40]:
        print("FAIL", b)
    print("checks:", "all passed" if not bad else f"{len(bad)} failed")
    return 1 if bad else 0


def main() -> int:
    """`python benchmarks/check_holdout12.py` (what `make_holdout12.py --check` runs): every check on --out."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--questions", default=str(VSI / "questions.jsonl"))
    ap.add_argument("--seed", type=int, default=12)
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args()
    return run_checks(load_questions(a.questions), earlier_uses(EARLIER_SOURCES), a.seed, Path(a.out))


if __name__ == "__main__":
    sys.exit(main())
