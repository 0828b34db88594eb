"""The reliability campaign's classes of issue 36 (registered in campaign.EXTRA_CLASSES): numbers of any size in a
question, ground truth that is not there, objects that vanish or explode, maps far from the origin, files read
before they are checked, output places checked before the work, runs killed mid-way, and strict JSON.

Each class draws its cases from a seeded generator (`MOSAIC_CAMPAIGN_SEED`, default 0; the benchmark's `--seed N`
runs held-out variants nobody tuned on): digit counts, positions, objects, offsets and damages are drawn, not
listed. Outcomes as campaign.classify: crash / hang / silently wrong / clear error / flagged answer / answered.
"""
from __future__ import annotations

import copy
import json
import math
import os
import random
import signal
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from campaign_core import Record, _dump, classify, cli, start_run
from fuzz_files import base_map


def is_strict(text: str) -> bool:
    """JSON a strict reader accepts (no NaN / Infinity): judged here, not by the code under test."""
    def refuse(word: str) -> Any:
        raise ValueError(word)
    try:
        json.loads(text, parse_constant=refuse)
    except ValueError:
        return False
    return True


def seed() -> int:
    return int(os.environ.get("MOSAIC_CAMPAIGN_SEED", "0"))


def rng(name: str) -> random.Random:
    return random.Random(f"{name}:{seed()}")


def digits(r: random.Random) -> str:
    """A number as a person might type it: 1 to 1000 digits, sometimes a fraction, sometimes leading zeros."""
    n = r.choice([1, 1, 2, 3, 4, 7, 19, 20, 39, 308, 309, 310, 400, 1000])
    s = str(r.randint(1, 9)) + "".join(r.choice("0123456789") for _ in range(n - 1))
    if r.random() < 0.3:
        s += "." + "".join(r.choice("0123456789") for _ in range(r.choice([1, 2, 50])))
    if r.random() < 0.1:
        s = "000" + s
    return s


WORDINGS = [  # {n}: the number; each wording a kind of number the reader converts
    "Is the table within {n} m of the chair?", "Is the table more than {n} meters from the chair?",
    "Is the chair less than {n} cm from the table?", "Is the table longer than {n} cm?",
    "Is the chair taller than {n} feet?", "Is the room bigger than {n} square meters?",
    "Is the room smaller than {n} square feet?", "Are there at least {n} chairs?", "Are there {n} chairs?",
    "Are there more than {n} tables?", "If I stand by the chair facing the table and turn {n} degrees, is the "
    "sofa to my left?"]


def question_number_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """A number of any length in a question: `mosaic parse` prints a program the program reader accepts, or
    refuses naming the question (exit 2); `mosaic ask` on a map answers or refuses the same way."""
    from mosaicthinker.runtime.query.schema import ProgramError, from_json

    r = rng("question")
    f = work / "map.json"
    _dump(base_map(), f)
    for i in range(60 if full else 24):
        w = WORDINGS[i % len(WORDINGS)]
        n = digits(r)
        q = w.format(n=n)
        case = f"{w.split('{')[0].strip()} <{len(n.replace('.', ''))} digits>"
        code, out, err = cli(["parse", q, "--json"])
        got = classify(code, out, err, field="question")
        if code == 0:
            prog = json.loads(out).get("program")
            try:
                if prog is not None:
                    from_json(prog)
            except ProgramError as e:
                got = ("silently wrong", f"printed a program its reader rejects: {e}"[:200])
        if got[0] in ("answered", "clear error"):
            a = classify(*cli(["ask", f, q]), field="question")
            got = a if a[0] in ("crash", "hang") else got
        yield Record("question numbers", case, *got)


# ------------------------------------------------------------------------------------------- ground truth

def _rgbd(work: Path, name: str, n: int = 6) -> Path:
    from test_bad_inputs import rgbd_folder

    return rgbd_folder(work / name, n=n)


POSE_DAMAGE = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf}


def ground_truth_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """Pose files and dataset boxes whose values are not there (NaN / inf): every pose file so -> exit 2; a few
    (ScanNet's -inf tracking failures) -> answered with them listed; a box with a NaN part -> named in the
    result; every box so, or a non-finite axis_align_matrix -> exit 2, before any work; eval pose --json strict."""
    from mosaicthinker.host.evaluation.scene import ground_truth_for
    from mosaicthinker.runtime.infra.errors import InputError

    r = rng("gt")
    for k, (what, v) in enumerate(POSE_DAMAGE.items()):
        d = _rgbd(work, f"all-{k}")
        for p in d.glob("*.pose.txt"):
            a = np.loadtxt(p)
            a.flat[r.randrange(16) if r.random() < 0.5 else slice(None)] = v
            np.savetxt(p, a)
        got = classify(*cli(["eval", "pose", "--data", d, "--keyframes", "6", "--json"]), file=str(d))
        yield Record("ground truth", f"every pose file holds {what}", *got)
        d = _rgbd(work, f"few-{k}")
        bad = sorted(r.sample(range(6), r.randint(1, 3)))
        for i in bad:
            np.savetxt(d / f"frame-{i:06d}.pose.txt", np.full((4, 4), v))
        code, out, err = cli(["eval", "pose", "--data", d, "--keyframes", "6", "--json"])
        got = classify(code, out, err, file=str(d))
        if code == 0:
            res = json.loads(out) if is_strict(out) else None
            got = ("crash", f"not strict JSON: {out[:120]}") if res is None else got if \
                res.get("untracked_frames") == bad else ("silently wrong", f"untracked {res.get('untracked_frames')}"
                                                                          f" != {bad}")
        yield Record("ground truth", f"{len(bad)} pose file(s) hold {what}", *got)
    boxes = {"chair": [{"centroid": [0, 0, 0.5], "axesLengths": [0.5, 0.5, 1]},
                       {"centroid": [1, 1, 0.5], "axesLengths": [0.5, 0.5, 1]}],
             "table": [{"centroid": [2, 0, 0.4], "axesLengths": [1, 1, 0.8]}]}
    flat = [(c, j) for c, lst in boxes.items() for j in range(len(lst))]
    for case in range(8 if full else 5):
        doc = {"axis_align_matrix": np.eye(4).tolist(), "object_bbox": copy.deepcopy(boxes)}
        hit = sorted(r.sample(flat, r.randint(1, len(flat))))
        for c, j in hit:
            doc["object_bbox"][c][j][r.choice(["centroid", "axesLengths"])][r.randrange(3)] = \
                r.choice([math.nan, math.inf, -math.inf])
        f = work / f"gt{case}" / "gt_boxes.json"
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(json.dumps(doc))
        try:
            _, scene, _, _ = ground_truth_for(f.parent, None)
            named = all(any(d.startswith(f"{c} #{j} ") for d in scene.get("not_scored", [])) for c, j in hit)
            got = ("flagged answer", "") if named else ("silently wrong", f"not named: {scene.get('not_scored')}")
        except InputError as e:
            got = ("clear error", str(e)[:200]) if len(hit) == len(flat) and str(f) in str(e) else \
                ("crash", f"refused with boxes left / unnamed: {e}"[:200])
        yield Record("ground truth", f"{len(hit)} of {len(flat)} boxes non-finite", *got)
    for what, T in (("axis_align_matrix NaN", "nan"), ("axis_align_matrix inf", "inf"),
                    ("axis_align_matrix scaled", "scaled")):
        d = _rgbd(work, what.replace(" ", "_"), n=3)
        m = np.eye(4)
        if T == "scaled":
            m[:3, :3] *= 3
        else:
            m[r.randrange(3), r.randrange(4)] = float(T)
        (d / "gt_boxes.json").write_text(json.dumps({"axis_align_matrix": m.tolist(), "object_bbox": boxes}))
        t0 = time.time()
        code, out, err = cli(["eval", "scene", "--data", d, "--bundle", work / "no-bundle"])
        got = classify(code, out, err, file=str(d / "gt_boxes.json"))
        if code == 2 and "axis_align_matrix" not in err:
            got = ("crash", f"refused without naming the matrix: {err[:150]}")
        yield Record("ground truth", f"{what} ({time.time() - t0:.1f} s)", *got)


# ------------------------------------------------------------------------------------------- files, outputs

def input_file_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """Files decoded and checked before work: a non-UTF-8 byte anywhere in an annotation, a box file, a timestamps
    file; a number out of range in intrinsics / pose / gravity; an unwritable eval scene --out -> exit 2 at once,
    naming the file."""
    r = rng("files")
    ann = json.dumps({"axis_align_matrix": np.eye(4).tolist(), "object_bbox": {}}).encode()
    for k in range(4 if full else 2):
        d = _rgbd(work, f"utf{k}", n=3)
        pos = r.randrange(len(ann))
        f = d / ("gt_boxes.json" if k % 2 else "annotation.json")
        f.write_bytes(ann[:pos] + bytes([r.choice([0xff, 0xfe, 0xc3, 0x80, 0xe2])]) + ann[pos:])
        argv = ["eval", "scene", "--data", d, "--bundle", work / "no-bundle"] + ([] if k % 2 else
                                                                                   ["--annotations", f])
        yield Record("input files", f"{f.name}: a non-UTF-8 byte at {pos}", *classify(*cli(argv), file=str(f)))
    d = _rgbd(work, "ts", n=3)
    (d / "timestamps.txt").write_bytes(b"0.0\n0.1\n\xff0.2\n")
    yield Record("input files", "timestamps.txt: a non-UTF-8 byte",
                 *classify(*cli(["plan", "--profile", "cpu-generic", "--video", d]), file="timestamps.txt"))
    q = (b'{"scene_name": "s", "question_type": "object_counting", "question": "How many chair(s)?", '
         b'"ground_truth": 1}\n')
    box = {"centroid": [0, 0, 0.5], "axesLengths": [1, 1, 1], "normalizedAxes": [1, 0, 0, 0, 1, 0, 0, 0, 1]}
    meta = {"s": {"object_bbox": {"chair": [dict(box), dict(box)]}}}
    meta["s"]["object_bbox"]["chair"][r.randrange(2)][r.choice(["centroid", "axesLengths"])][r.randrange(3)] = \
        r.choice([math.nan, math.inf, -math.inf])
    pos = r.randrange(len(q))
    for name, qb, mb, named in (("questions.jsonl: a non-UTF-8 byte", q[:pos] + b"\xff" + q[pos:], b'{"s": {}}',
                                 "q.jsonl"),
                                ("meta_info.json: a box with NaN / inf", q, json.dumps(meta).encode(), "chair[")):
        (work / "q.jsonl").write_bytes(qb)
        (work / "meta.json").write_bytes(mb)
        got = classify(*cli(["eval", "vsibench", "--questions", work / "q.jsonl", "--meta", work / "meta.json"]),
                       field=named)
        yield Record("input files", name, *got)
    values = ["nan", "inf", "-inf", "1e300", "9" * 400, "-" + "9" * 320, "1e-320"]
    for k in range(8 if full else 4):
        d = _rgbd(work, f"num{k}", n=3)
        target = r.choice(["camera-intrinsics.txt", "frame-000001.pose.txt", "gravity-direction.txt"])
        v = r.choice(values)
        if target == "gravity-direction.txt":
            (d / target).write_text(f"0 {v} 0\n")
        else:
            a = np.loadtxt(d / target) if (d / target).exists() else np.eye(3)
            text = [[repr(float(x)) for x in row] for row in a]
            i, j = r.randrange(3), r.randrange(3)
            text[i][j] = v
            (d / target).write_text("\n".join(" ".join(row) for row in text) + "\n")
        code, out, err = cli(["eval", "pose", "--data", d, "--keyframes", "3"])
        got = classify(code, out, err, file=target)
        yield Record("input files", f"{target} holds {v[:12]}", *got)
    d = _rgbd(work, "scene-out", n=3)
    blocker = work / "a-file"
    blocker.write_text("x")
    for name, out in (("a file", blocker), ("below a file", blocker / "out"), ("a device", Path("/dev/null"))):
        t0 = time.time()
        got = classify(*cli(["eval", "scene", "--data", d, "--bundle", work / "no-bundle", "--out", out]),
                       file=str(out))
        yield Record("output places", f"eval scene --out is {name} ({time.time() - t0:.1f} s)", *got)


# ------------------------------------------------------------------------------------------- maps

def _translate(d: dict, off: np.ndarray) -> dict:
    d = copy.deepcopy(d)
    for o in d["instances"]:
        b = o["box"]
        for k in ("centroid", "min", "max"):
            if k in b:
                b[k] = (np.asarray(b[k]) + off).tolist()
        for v in o.get("views") or []:
            if v.get("centre") is not None:
                v["centre"] = (np.asarray(v["centre"]) + off).tolist()
    if d.get("room"):
        d["room"]["polygon"] = (np.asarray(d["room"]["polygon"]) + off[:2]).tolist()
        d["room"]["floor_z"] += off[2]
        d["room"]["ceiling_z"] += off[2]
    for c in d.get("cameras") or []:
        T = np.asarray(c["T_wc"])
        T[:3, 3] += off
        c["T_wc"] = T.tolist()
    return d


MAP_QUESTIONS = {"room size": "How big is the room (in square meters)?",
                 "room sides": "What are the dimensions of the room?",
                 "distance": "What is the distance between the chair and the table?",
                 "size": "What is the length of the longest dimension of the table in centimeters?",
                 "count": "How many chairs are in the room?"}


def far_map_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """The same map translated far from its world origin answers the same (room size, sides, distances, sizes)."""
    r = rng("far")
    base = base_map()
    variants = {"with room": base, "boxes only": {k: v for k, v in base.items() if k != "room"}}
    f0, f1 = work / "m0.json", work / "m1.json"
    for vname, doc in variants.items():
        _dump(doc, f0)
        for k in range(5 if full else 3):
            scale = r.choice([1e3, 1e5, 1e6, 3e6, 1e7])
            off = np.array([r.uniform(-1, 1) * scale, r.uniform(-1, 1) * scale, r.uniform(-1, 1) * min(scale, 1e3)])
            _dump(_translate(doc, off), f1)
            for qn, q in MAP_QUESTIONS.items():
                c0, o0, e0 = cli(["ask", f0, q, "--json"])
                c1, o1, e1 = cli(["ask", f1, q, "--json"])
                got = classify(c1, o1, e1, file=str(f1))
                if c0 == 0 and c1 == 0:
                    a0, a1 = json.loads(o0).get("answer"), json.loads(o1).get("answer")
                    if a0 != a1:
                        got = ("silently wrong", f"{a0!r} at the origin, {a1!r} at {np.round(off).tolist()}")
                yield Record("far from the origin", f"{vname}: {qn} at {scale:g} m", *got)


def implausible_object_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """Objects of sizes no room holds, in both directions: the answer names each one (`chair #0`)."""
    r = rng("implausible")
    f = work / "map.json"
    for k in range(12 if full else 6):
        d = base_map()
        j = r.randrange(len(d["instances"]))
        o = d["instances"][j]
        small = r.random() < 0.5
        e = r.uniform(-323, -2.1) if small else r.uniform(1.5, 300)
        sizes = [10 ** e * r.uniform(0.5, 1) for _ in range(3)]
        o["box"]["axesLengths"] = [max(s, 5e-324) for s in sizes]
        _dump(d, f)
        q = r.choice(list(MAP_QUESTIONS.values()))
        code, out, err = cli(["ask", f, q])
        got = classify(code, out, err, file=str(f), note=f"{o['name']} #{o['id']}")
        yield Record("implausible objects", f"{o['name']} of {max(sizes):.3g} m", *got)


# ------------------------------------------------------------------------------------------- runs, JSON

def killed_run_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """SIGKILL during `mosaic ask --out DIR` (at a drawn moment): a later `mosaic ask` on DIR's map, on DIR, and
    into DIR says the earlier run did not finish."""
    from test_bad_inputs import _big_map

    r = rng("killed")
    m = _big_map(work / "big.json", 30000)
    for k in range(2 if full else 1):
        out = work / f"o{k}"
        code, o, e = cli(["ask", m, "How many chairs?", "--out", out])
        p = start_run(["ask", out / "map.json", "How many chairs?", "--out", out], out)
        time.sleep(r.uniform(0, 0.5))
        p.send_signal(signal.SIGKILL)
        p.communicate()
        if json.loads((out / "run.json").read_text()).get("status") == "complete":
            yield Record("killed run", f"kill {k}", "answered", "finished before the kill")
            continue
        for name, argv in (("ask its map", ["ask", out / "map.json", "How many chairs?"]),
                           ("ask into the folder", ["ask", m, "How many chairs?", "--out", out])):
            got = classify(*cli(argv), note="did not finish")
            yield Record("killed run", f"kill {k}: {name}", *got)


def strict_json_cases(work: Path, full: bool = True) -> Iterator[Record]:
    """Every --json output and every JSON file written is strict JSON (no NaN / Infinity)."""
    f = work / "map.json"
    d = base_map()
    d["instances"][0]["box"]["axesLengths"] = [5e-324, 5e-324, 5e-324]
    _dump(d, f)
    d1 = _rgbd(work, "one", n=2)
    runs = {"ask a vanishing object": ["ask", f, "How big is the chair?", "--json", "--out", work / "o"],
            "eval pose, one frame aligned": ["eval", "pose", "--data", d1, "--keyframes", "2", "--json",
                                             "--out", work / "p"],
            "parse": ["parse", "Is the chair within 2 m of the table?", "--json"]}
    for name, argv in runs.items():
        code, out, err = cli(argv)
        got = classify(code, out, err)
        files = [p for p in (work / "o").glob("*.json")] + [p for p in (work / "p").glob("*.json")]
        bad = [str(p.name) for p in files if not is_strict(p.read_text())]
        if code == 0 and (not is_strict(out) or bad):
            got = ("crash", f"not strict JSON: {bad or out[:100]}")
        yield Record("strict JSON", name, *got)


ROUND4_CLASSES: dict[str, Callable[[Path, bool], Iterator[Record]]] = {
    "question_numbers": question_number_cases, "ground_truth": ground_truth_cases, "input_files": input_file_cases,
    "far_maps": far_map_cases, "implausible_objects": implausible_object_cases, "killed_run": killed_run_cases,
    "strict_json": strict_json_cases}
