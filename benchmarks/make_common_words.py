"""Write runtime/query/common_words.txt: English words that the spelling corrector must never change although
they lie within its bound of a word the parser uses ("loop" is not "loo", "batch" is not "bath", "instance" is
not "distance").

English words are taken from text at hand, counted, and kept when seen at least `--min-count` times: the comments
and docstrings of the Python standard library (the interpreter running this script; words of 4+ letters, not its
identifiers), the repository's own docs, and a short list of everyday words (`EVERYDAY`); then only
the words the corrector would otherwise read as something else are written (a few hundred). Words written as
typos on purpose in the repository's wording sets are never taken (the docs quote some: "chiars", "teh").

    python benchmarks/make_common_words.py [--min-count 5]
"""
from __future__ import annotations

import argparse
import collections
import os
import re
import sysconfig
import tokenize
from pathlib import Path

from mosaicthinker.runtime.query.spelling import candidates

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "runtime" / "query" / "common_words.txt"
_WORD = re.compile(r"(?<![\w'-])[a-z]{3,14}(?![\w'-])")
# everyday words of questions about rooms that the texts above are too technical to hold
EVERYDAY = """sight tune ram ray lab headroom sections arena basis batch jobs cost costs lack mean loop loops range line
lines weight root roots lose loses fine free full gain gave given grown halve hash heads holes honesty
known lane layer ledge lent lever log logs matching meta mode norm now once own plain plus power powers rare
reset round rounds save scan scans seeds seek seeks seems sift sign site sliver slots slow slower sort splitter
splitting stage stale starred stated stay stays string strings suits test tests tie ties tile tiling timers treat
tuned tuning warm weight widen wires yang alike always arrow aside ate bad band basis beat beats binds block blocks
border calls cast cause changing chat cross detached eye fail failing fails fate fell fix fixes flag float flock flow
flying lack accounting addressed degrades directional eighth estimation lingers mad occupied recovers unmeasured
unstable cos""".split()


def prose(path: Path) -> str:
    """The comments and the strings with spaces of a Python file (English prose, not its identifiers)."""
    out = []
    try:
        with path.open("rb") as f:
            for tok in tokenize.tokenize(f.readline):
                if tok.type == tokenize.COMMENT or (tok.type == tokenize.STRING and " " in tok.string):
                    out.append(tok.string)
    except (tokenize.TokenError, SyntaxError, UnicodeDecodeError):
        pass
    return "\n".join(out)


# programmers' words of the library's comments, not English a person asks a room question in; some are the very
# typos to read ("chars" for "chairs", "cpu" for "cup")
JARGON = set("""acme addr aexit barf bool bpnumber char chars closefd cpu ctypes dest doesn dtype dunder etree etype
fname flist imag imap info ints mmap mtime nbar nfrom optionals plat plist popen qname qsize rfile uname util wfile
tok res spam goto sash stub clamp fixer""".split())
# English words that in a question about a room are far more often a slip of a word of the question itself
SLIPS = {"form", "forms", "font", "fonts", "fro", "net", "nest"}  # from, front, next


def english(min_count: int) -> set[str]:
    cnt: collections.Counter[str] = collections.Counter()
    for dp, _, fn in os.walk(sysconfig.get_paths()["stdlib"]):
        if "site-packages" in dp or "test" in Path(dp).parts:
            continue
        for f in fn:
            if f.endswith(".py"):
                cnt.update(w for w in _WORD.findall(prose(Path(dp, f))) if len(w) >= 4)
    for p in list((REPO / "docs").glob("*.md")) + [REPO / "README.md"]:
        cnt.update(_WORD.findall(p.read_text(errors="ignore").lower()))
    return (({w for w, c in cnt.items() if c >= min_count} - JARGON) | set(EVERYDAY)) - SLIPS


def typos_of_wording_sets() -> set[str]:
    """Words of the wording sets the corrector changes: typos written on purpose, never English to keep."""
    out = set()
    for p in (REPO / "benchmarks" / "data").glob("vsibench_*.jsonl"):
        out |= {w for w in _WORD.findall(p.read_text().lower()) if candidates(w, protect=False)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--min-count", type=int, default=5)
    a = ap.parse_args()
    typos = typos_of_wording_sets()
    keep = sorted(w for w in english(a.min_count) - typos if candidates(w, protect=False))
    OUT.write_text("# written by benchmarks/make_common_words.py: English words never read as another word\n" +
                   "\n".join(keep) + "\n")
    print(f"{len(keep)} words -> {OUT.relative_to(REPO)}")


if __name__ == "__main__":
    main()
