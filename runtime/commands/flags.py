"""One vocabulary of command-line flags: each flag that several commands take is defined once, here.

`tests/test_cli_vocabulary.py` walks every command's parser and checks that a flag name means the same thing
everywhere (same type, choices and default), that a command only lists the common flags it reads, and that
the deprecated aliases still work and warn.
"""
from __future__ import annotations

import argparse
import sys
from typing import Any, Sequence

from ..infra.numbers import read_number, show_number
from ..keyframes import KeyFrameConf
import re

# API parameter / config field -> the flag that sets it: the CLI rewrites a MosaicError's backticked `field`
# (or `field=value`) as `--flag` (`--flag value`); the library's messages name the parameters (errors.py).
FLAG_FOR_FIELD = {
    "answerer": "--answerer", "grounding": "--grounding", "method": "--method", "depth": "--depth", "matcher": "--matcher",
    "detector": "--detector", "bundle": "--bundle", "profile": "--profile", "out": "--out",
    "candidates": "--candidates", "fps": "--fps", "duration": "--duration", "models": "--models",
    "keyframes": "--keyframes", "sampling": "--sampling", "update_profile": "--update-profile",
    "SceneConfig.objects": "--complexity", "SceneConfig.room": "--room", "SceneConfig.duration": "--duration",
    "SceneConfig.fps": "--fps", "SceneConfig.size": "--size",
    "video=False": "--no-video",  # a field=value with a flag of its own
}
_FIELD_RE = None


def cli_message(message: str, fields: Sequence[str]) -> str:
    """A library message in the CLI's words: each backticked `field` / `field=value` of `fields` that has a
    flag becomes `--flag` / `--flag value`; everything else is left as written."""
    global _FIELD_RE
    _FIELD_RE = _FIELD_RE or re.compile(r"`([A-Za-z_][\w.]*)(?:=([^`]*))?`")

    def sub(m: "re.Match[str]") -> str:
        if m.group(1) not in fields:
            return m.group(0)
        if m.group(2) and f"{m.group(1)}={m.group(2)}" in FLAG_FOR_FIELD:
            return FLAG_FOR_FIELD[f"{m.group(1)}={m.group(2)}"]
        flag = FLAG_FOR_FIELD.get(m.group(1))
        return m.group(0) if flag is None else flag + (f" {m.group(2)}" if m.group(2) else "")

    return _FIELD_RE.sub(sub, message)


MAX_CLIP_S = 86400.0  # 24 h, as the planner (budget.MAX_CLIP_S): longer is not one question's video
MAX_FPS = 1000.0
COMPLEXITY = ("low", "med", "high")   # object-number levels of a generated scene (VSI-Bench terciles)
ANSWERERS = ("map", "vlm", "auto")    # map reasoner, VLM on the visual prompt, auto (reasoner when it knows)
GROUNDINGS = ("rules", "model", "vlm", "auto")  # question -> program: rule parser, trained reader, VLM, auto (all)


MAX_SIDE_PX = 16384   # a frame side (the largest video frames are 8K: 7680 px)
MAX_COUNT = 100_000   # key frames, scenes: more than any clip holds


def parse_size(text: str) -> tuple[int, int]:
    """'640x480' -> (640, 480): frame size as WxH (argparse type)."""
    parts = str(text).lower().split("x")
    if len(parts) != 2 or not all(x.strip().isdigit() for x in parts):
        raise argparse.ArgumentTypeError(f"--size must be WxH, e.g. 640x480 (got {show_number(text)!r})")
    w, h = (read_number(x, f"--size {side}", lo=16, hi=MAX_SIDE_PX, integer=True, unit="px",
                        error=argparse.ArgumentTypeError) for x, side in zip(parts, ("width", "height")))
    return w, h


def add_size(p: argparse.ArgumentParser, default: str, what: str = "frame size") -> None:
    p.add_argument("--size", type=parse_size, default=parse_size(default), metavar="WxH",
                   help=f"{what} WxH (default {default})")


def parse_duration(text: str) -> float:
    """'45' -> 45.0 s; 'short' | 'medium' | 'long' -> the synthetic levels (30 | 60 | 120 s) (argparse type)."""
    from mosaicthinker.host.synth.scene import DURATION_LEVELS

    if text in DURATION_LEVELS:
        return float(DURATION_LEVELS[text])
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--duration: seconds or one of {list(DURATION_LEVELS)}, got {text!r}") \
            from None
    if not (0 < v <= MAX_CLIP_S):  # also NaN and inf: 1e308 s would overflow every frame count downstream
        raise argparse.ArgumentTypeError(f"--duration must be > 0 and at most {MAX_CLIP_S:g} s (24 h), got {text!r}")
    return v


def parse_fps(text: str) -> float:
    """'15' -> 15.0 frames per second, > 0 and at most MAX_FPS (argparse type)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--fps: a number of frames per second, got {text!r}") from None
    if not (0 < v <= MAX_FPS):
        raise argparse.ArgumentTypeError(f"--fps must be > 0 and at most {MAX_FPS:g}, got {text!r}")
    return v


def add_clip(p: argparse.ArgumentParser, duration: float | None, fps: float | None, what: str = "video") -> None:
    """--duration S and --fps F of a clip (generated, or planned). None: no default (given or derived)."""
    p.add_argument("--duration", type=parse_duration, default=duration, metavar="S",
                   help=f"{what} length in seconds, or short|medium|long (30|60|120 s)"
                        + (f" (default {duration:g})" if duration is not None else ""))
    p.add_argument("--fps", type=parse_fps, default=fps, metavar="F",
                   help="frames per second" + (f" (default {fps:g})" if fps is not None else ""))


def _at_least_one(flag: str, what: str, text: str) -> int:
    t = str(text).strip()
    if not t.lstrip("+-").isdigit():
        raise argparse.ArgumentTypeError(f"{flag}: a whole number of {what}, got {show_number(text)!r}")
    if t.startswith("-") or not t.lstrip("+0"):
        raise argparse.ArgumentTypeError(f"{flag} must be at least 1, got {show_number(text)!r}")
    return read_number(t, flag, lo=1, hi=MAX_COUNT, integer=True, unit=what, error=argparse.ArgumentTypeError)


def parse_keyframes(text: str) -> int:
    """'16' -> 16 key frames, >= 1 (argparse type: 0 used to mean the default, silently)."""
    return _at_least_one("--keyframes", "key frames", text)


def parse_scenes(text: str) -> int:
    """'3' -> 3 scenes, >= 1 (argparse type: `eval e2e --scenes -1` printed an empty table and exit 0)."""
    return _at_least_one("--scenes", "scenes", text)


def add_scenes(p: argparse.ArgumentParser, default: int, what: str = "number of scenes") -> None:
    p.add_argument("--scenes", type=parse_scenes, default=default, help=f"{what} (default {default})")


def pipeline_keyframes() -> int:
    """The pipeline's key-frame budget K: the one owner of the default (`KeyFrameConf.keyframes`)."""
    return int(KeyFrameConf.keyframes)


def add_keyframes(p: argparse.ArgumentParser, default: int | None = None, why: str = "") -> None:
    """--keyframes K. default None: the pipeline's K; a command with its own default says why in its help."""
    if default is None:
        help_ = f"key-frame budget K (default {pipeline_keyframes()}, the pipeline's; the budget may lower it)"
    else:
        help_ = f"key-frame budget K (default {default}: {why})"
    p.add_argument("--keyframes", type=parse_keyframes, default=default, metavar="K", help=help_)


def add_answerer(p: argparse.ArgumentParser, help_: str | None = None) -> None:
    p.add_argument("--answerer", choices=list(ANSWERERS), default="auto",
                   help=help_ or "map reasoner, VLM on the visual prompt, or auto (the reasoner when it recognises "
                                 "the question, else the VLM) (default auto)")


def add_grounding(p: argparse.ArgumentParser) -> None:
    p.add_argument("--grounding", choices=list(GROUNDINGS), default="auto",
                   help="who reads the question into a program: the rule parser, the trained reader (the bundle's "
                        "`reader` role), the bundle's VLM under the program's JSON schema, or auto (the rules, the "
                        "trained reader for what they refuse, then the VLM) (default auto)")


class _Deprecated(argparse.Action):
    """An old flag name kept working: sets the new flag's value and says on stderr to use the new name."""

    def __init__(self, option_strings: Sequence[str], dest: str, new: str = "", append: bool = False, **kw: Any):
        self.new, self.append = new, append
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(f"warning: {option_string} is deprecated here, use {self.new}", file=sys.stderr)
        if self.append:  # a repeatable flag: add to the new flag's list
            values = list(getattr(namespace, self.dest, None) or []) + [values]
        setattr(namespace, self.dest, values)


def add_gravity(p: argparse.ArgumentParser, default: str) -> None:
    """--gravity: where the map's "down" comes from (PipelineConfig.gravity), the default named by the command."""
    p.add_argument("--gravity", choices=["auto", "source", "floor"], default=default,
                   help="'down' for the map: auto/source = the source's gravity (for synthetic scenes and 7-Scenes "
                        "the root frame's ground-truth rotation, an IMU stand-in); floor = the floor-plane fit "
                        f"alone (default {default})")


def deprecated_alias(p: argparse.ArgumentParser, old: str, new: str, dest: str, **kw: Any) -> None:
    """`old` keeps working as `new` (same dest), hidden from --help, with a warning on stderr."""
    p.add_argument(old, dest=dest, action=_Deprecated, new=new, help=argparse.SUPPRESS, **kw)


def add_complexity(p: argparse.ArgumentParser, default: str) -> None:
    """--complexity low|med|high (object number of a generated scene). `--objects` names objects to map in
    `mosaic map`; here it is kept as a deprecated alias of --complexity."""
    p.add_argument("--complexity", choices=list(COMPLEXITY), default=default,
                   help=f"object-number level: low 1-3, med 4-7, high 8-17 objects (default {default})")
    deprecated_alias(p, "--objects", "--complexity", "complexity", choices=list(COMPLEXITY))


def add_deprecated_size_parts(p: argparse.ArgumentParser) -> None:
    """--width W / --height H, kept as deprecated aliases of --size WxH (read by `size_of`)."""
    for name in ("width", "height"):
        deprecated_alias(p, f"--{name}", "--size WxH", f"old_{name}", type=int, default=None)


def size_of(args: argparse.Namespace) -> tuple[int, int]:
    """--size, with the deprecated --width/--height overriding their part when given."""
    w, h = args.size
    return (getattr(args, "old_width", None) or w, getattr(args, "old_height", None) or h)
