"""Spelling against the parser's CLOSED vocabulary: a word the parser does not know is read as the one word it
knows within a small edit distance ("chiars" -> "chairs", "sqaure" -> "square", "teh" -> "the").

The vocabulary is what the parser can use: object names and synonyms (singular and plural) and the map's own
names, the cue words of every question kind (`cues.CUES`), the markers of roles, units, and the function words of
`rules.lexicon`. Words it must never change are these and `COMMON` (frequent English words near a vocabulary
word: "tablet" is not "table", "hear" is not "near").

Distance: Damerau-Levenshtein (optimal string alignment) where a substitution costs 1 between keys that touch on
a QWERTY keyboard and 1.5 otherwise (a phone typo hits a neighbouring key; "cable" is not a typo of "table"), and
a swap of two neighbouring letters 0.75 (the commonest slip: "waht" is "what", not "want").
Bound by the typed word's length: <= 2 letters never; 3 letters only a swap of two neighbouring letters ("teh",
"hwo") or one letter dropped from a four-letter word ("soa", "frm", "lft": the commonest phone slip in short
words); 4-7 letters 1; 8 or more 2. The best candidate must be unique: ties are broken only by the candidate's
use (object names and cue words before other function words: "hwo" -> "how", not "who"); otherwise the word is
left as typed (and the parser reads it, or refuses, as before).
"""
from __future__ import annotations

import functools
import re
from pathlib import Path
from typing import Iterable

from .cues import cue_words
from .rules.lexicon import (COLOURS, DET, FACE1, FACE2, LOCATION, NUMBERS, ORDINALS, SCENE, STOP, UNIT_WORDS,
                            COMPARATIVES, SUPERLATIVES)
from .vocabulary import NAME_SYNONYMS, plural, singular

# frequent English words one edit from a vocabulary word, and other words of questions: never corrected
COMMON = frozenset("""
a i am be as at by in is it of on or so to up us we do go he me my no oh ok
tablet tablets stable cable fable bead beads tube tubes tool tools plan plans planet pants case cases base bases
showed hear bear bears year wear hook hooks lock locks heated header washed printed dressed counted stars walks
walked talk talks wife fight tight hack soda closet closets county court lamb chain chains mount seat seats
cook cooks took look looks boom bunch sing link store stone stave even over open lift loft felt touch cough
room rooms video place here there honestly tell know need help trying try figure out work checking check mind
would could should went counting spotted remember forgot layout imagine sat said says got getting one ones
whole every rough ballpark estimate answer answers actual add added shown shows just lost confused idea sure fit
through doorway doorways hallway hall entrance exit sees saw thing things stuff also then when where why what
which who whom whose while with within without this that these those them they their there's here's its it's
your you yours you're our ours out been being done doing did does have has had having make makes made
need needs want wants like likes love think thinks thought wonder wondering curious quick question questions
again still only ever never really very much more most less least few little lot lots bit some any all both
each either neither none nothing something anything everything someone anyone around about above below
between across along among behind beside besides beyond near nearby next past since until upon toward towards
day days time times way ways side sides end ends top tops bottom middle centre center corner corners edge
edges front back left right ahead straight first last second third start starts started begin begins began
walk walking turn turns turned turning reach reached facing faced standing stood sitting seated lying
swing swings swung tally clearance neighbour neighbours neighbor neighbors footage diagonal
note fill able tree flower stall pot pan mat box ball bag bar car cat dog man woman person people kid child
baby toy toys game games food fruit water glass glasses plate plates bowl bowls basket drawer drawer blind
blinds sheet blanket quilt duvet tap taps rail rails hanger light lights switch socket outlet vent fence gate
yard garden porch deck step cant great stop stops stopped tops move moves moved cover covers span spans roomy self
""".split())

# keys that touch on a QWERTY keyboard (a substitution between them costs 1, else 1.5)
_ROWS = ("1234567890", "qwertyuiop", "asdfghjkl", "zxcvbnm")


def _neighbours() -> dict[str, set[str]]:
    pos = {c: (r, i) for r, row in enumerate(_ROWS) for i, c in enumerate(row)}
    out: dict[str, set[str]] = {c: set() for c in pos}
    for a, (ra, ia) in pos.items():
        for b, (rb, ib) in pos.items():
            if a != b and ((ra == rb and abs(ia - ib) == 1) or (rb == ra + 1 and ib in (ia - 1, ia))
                           or (rb == ra - 1 and ib in (ia, ia + 1))):
                out[a].add(b)
    return out


_NEAR = _neighbours()


SWAP = 0.75  # two neighbouring letters swapped: the commonest slip of two thumbs ("waht" is "what", not "want")


def _swapped(a: str, b: str) -> bool:
    """`b` is `a` with two neighbouring letters swapped."""
    return len(a) == len(b) and any(a[:i] + a[i + 1] + a[i] + a[i + 2:] == b for i in range(len(a) - 1))


def distance(a: str, b: str, limit: float = 2.0) -> float:
    """Optimal-string-alignment distance with keyboard-weighted substitutions (see the module); stops early and
    returns a value over `limit` when the distance is over it."""
    if abs(len(a) - len(b)) > limit:
        return limit + 1
    prev2: list[float] = []
    prev = [float(j) for j in range(len(b) + 1)]
    for i in range(1, len(a) + 1):
        cur = [float(i)] + [0.0] * len(b)
        for j in range(1, len(b) + 1):
            ca, cb = a[i - 1], b[j - 1]
            sub = 0.0 if ca == cb else (1.0 if cb in _NEAR.get(ca, ()) else 1.5)
            cur[j] = min(prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + sub)
            if i > 1 and j > 1 and ca == b[j - 2] and a[i - 2] == cb:
                cur[j] = min(cur[j], prev2[j - 2] + SWAP)
        if min(cur) > limit:
            return limit + 1
        prev2, prev = prev, cur
    return prev[-1]


def bound(word: str) -> float:
    """How far a word of this length may be from what it is read as (see the module)."""
    n = len(word)
    return 0.0 if n <= 2 else 1.0 if n <= 7 else 2.0  # 3 letters: a swap or one dropped letter only


def _object_words(names: Iterable[str]) -> set[str]:
    out: set[str] = set()
    for n in names:
        ws = n.lower().split()
        out.update(ws)
        if ws:
            out.add(plural(ws[-1]))
    return out


@functools.lru_cache(maxsize=1)
def _static() -> tuple[frozenset[str], frozenset[str]]:
    """(words of meaning: one-word object names, cue words, markers and units; other known words, the words of
    longer names among them: "wash" of "wash basin" is no object alone)."""
    names = set(NAME_SYNONYMS)
    heads = {n for n in names if " " not in n} | {plural(n) for n in names if " " not in n}
    meaning = heads | cue_words() | set(UNIT_WORDS) | FACE1 | LOCATION | \
        {w for p in FACE2 for w in p.split()} | set(COMPARATIVES) | set(SUPERLATIVES)
    known = set(STOP) | DET | SCENE | COLOURS | ORDINALS | set(NUMBERS) | COMMON | _object_words(names)
    return frozenset(w for w in meaning if w.isalpha()), frozenset(w for w in known | meaning if w.isalpha())


_SUFFIXES = ("s", "es", "ed", "d", "ing", "er", "est", "ly", "'s")


def is_known(word: str, known: frozenset[str]) -> bool:
    """A known word, or one of its inflections ("steps", "spots", "greatest", "others", "walked")."""
    if word in known or singular(word) in known:
        return True
    for suf in _SUFFIXES:
        if word.endswith(suf) and len(word) - len(suf) >= 2:
            stem = word[:-len(suf)]
            if suf == "ing" and len(stem) > 2 and stem[-1] == "e" and stem[-2] not in "aeiouy":
                continue  # "faceing" is no inflection of "face" (that is "facing"): a typo to read
            if stem in known or stem + "e" in known or (len(stem) > 2 and stem[-1] == stem[-2] and stem[:-1] in known):
                return True
    return False


def best(word: str, extra: frozenset[str] = frozenset()) -> str | None:
    """The one known word `word` is read as (None: it is known, too short, too far, or ambiguous)."""
    top = candidates(word, extra)
    return top[0] if len(top) == 1 else None


def candidates(word: str, extra: frozenset[str] = frozenset(), protect: bool = True) -> list[str]:
    """The known words closest to `word` within the bound, best use first (see the module): one word, several
    (a tie: the word cannot be read), or none (known, too short or too far, or an English word of
    `common_words.txt`; `protect=False` reads past that list, for the script that writes it)."""
    meaning, known = _static()
    meaning = meaning | extra
    if not word.isalpha() or len(word) <= 2 or word in extra or is_known(word, known):
        return []
    if protect and (word in _english() or singular(word) in _english()):
        return []
    lim = bound(word)
    cands: list[tuple[float, int, str]] = []
    if len(word) == 3:  # three letters: two neighbouring letters swapped, or one letter dropped from four
        pool: set[str] = {word[:i] + word[i + 1] + word[i] + word[i + 2:] for i in range(2)} & (known | extra)
        pool |= {w for w in _deletes_index().get(word, frozenset()) | {x for x in extra if len(x) == 4}
                 if len(w) == 4 and word in _deletes(w, 1)}
    else:  # the known words that share a deletion variant with it (SymSpell): a few, not the whole vocabulary
        index = _deletes_index()
        pool = {w for v in _deletes(word, int(lim)) for w in index.get(v, ())}
        pool |= {w for w in extra if abs(len(w) - len(word)) <= lim}
    for w in sorted(pool):
        d = (SWAP if len(w) == 3 else 1.0) if len(word) == 3 else distance(word, w, lim)
        if d <= lim:
            cands.append((d, 0 if w in meaning else 1, w))
    if not cands:
        stem = _plural_stem(word, meaning, known)
        return [stem] if stem else []
    cands.sort()
    top = [c for c in cands if c[:2] == cands[0][:2]]
    if len({singular(c[2]) for c in top}) == 1:  # "sofaa": sofa or sofas, one name either way
        top = sorted(top, key=lambda c: (c[2][-1] != word[-1], abs(len(c[2]) - len(word)), c[2]))[:1]  # "sofs"
    if len(top) > 1 and top[0][1] == 1:  # a tie among words of no use to the parser: nothing to read, unless one is
        # a number or the "there" of counting ("thre": the, there or three?; "ther"): read as an object, a guess
        return [c[2] for c in top] if any(c[2] in NUMBERS or c[2] == "there" for c in top) else []
    return [c[2] for c in top]


@functools.lru_cache(maxsize=1)
def _english() -> frozenset[str]:
    """English words within the bound of a word the parser uses, never changed ("loop" is not "loo"):
    `common_words.txt`, written by benchmarks/make_common_words.py from counted English text."""
    path = Path(__file__).with_name("common_words.txt")
    return frozenset(w for w in path.read_text().split() if w.isalpha()) if path.is_file() else frozenset()


def _deletes(word: str, k: int) -> set[str]:
    """`word` and every string made from it by deleting up to `k` letters."""
    out, frontier = {word}, {word}
    for _ in range(k):
        frontier = {w[:i] + w[i + 1:] for w in frontier for i in range(len(w))}
        out |= frontier
    return out


@functools.lru_cache(maxsize=1)
def _deletes_index() -> dict[str, frozenset[str]]:
    """Deletion variant -> the known words that have it (SymSpell). Two words within k edits share a variant
    of up to k deletions each, so a typed word's own variants find every candidate the bound allows: 1 edit for
    4-7 typed letters (targets of <= 8 letters), 2 for 8+ (targets of 6+ letters, indexed with 2 deletions)."""
    _, known = _static()
    index: dict[str, set[str]] = {}
    for w in known:
        if len(w) >= 3:  # a word typed with 8+ letters may be 2 edits away, and its words have 6+ letters
            for v in _deletes(w, 2 if len(w) >= 6 else 1):
                index.setdefault(v, set()).add(w)
    return {v: frozenset(ws) for v, ws in index.items()}


def _plural_stem(word: str, meaning: frozenset[str], known: frozenset[str]) -> str | None:
    """"cocuhs" -> "couches": a plural whose stem is one edit from an object name (the plural adds letters the
    bound would count)."""
    if not word.endswith("s") or len(word) < 5:
        return None
    stem = singular(word)
    if stem == word or is_known(stem, known):
        return None
    w = best(stem, frozenset())
    return plural(w) if w is not None and w in meaning else None


# a word, also before a possessive "'s" ("the fireplcae's largest side")
_WORD = re.compile(r"(?<![\w'-])[a-z]+(?=(?:'s)?(?![\w'-]))")


def correct(text: str, names: Iterable[str] = ()) -> tuple[str, list[str], list[str]]:
    """(`text` with each unknown word read as its one close known word; notes "read 'x' as 'y'"; the words that
    are as close to several words the parser uses, "'bside' (beside or side?)": such a question is refused, never
    read one way at random). `names`: object names beyond the vocabulary (a map's categories): words of them are
    known and corrected to."""
    extra = frozenset(w for w in _object_words(names) if w.isalpha())
    notes: list[str] = []
    unclear: list[str] = []

    def fix(m: re.Match) -> str:
        w = m.group(0)
        top = _cached(w) if not extra else tuple(candidates(w, extra))
        if len(top) > 1 and not _before_a_noun(m.string[m.end():]):  # "how many are thre?": not a number or an
            top = tuple(c for c in top if c not in NUMBERS and c not in DET) or top  # article, nothing follows
        if len(top) > 1 and "there" in top and _after_copula(m.string[:m.start()]):  # "are ther", "is thre":
            top = ("there",)                                                          # "there" asks
        if len(top) > 1:
            unclear.append(f"'{w}' ({' or '.join(top)}?)")
        if len(top) != 1:
            return w
        notes.append(f"read '{w}' as '{top[0]}'")
        return top[0]

    return _WORD.sub(fix, text), list(dict.fromkeys(notes)), list(dict.fromkeys(unclear))


def _before_a_noun(after: str) -> bool:
    """Whether a word that could be what a number or an article counts follows ("thre chairs"), not the end, a
    break or a function word ("are thre in this room", "how many are thre?")."""
    m = re.match(r"\s*([a-z']+)", after)
    return m is not None and m.group(1) not in STOP and m.group(1) not in LOCATION and m.group(1) not in DET


def _after_copula(before: str) -> bool:
    return re.search(r"\b(?:is|are|was|were)\s*$", before) is not None


def second_reading(text: str) -> tuple[str, list[str]]:
    """`text` with each word that is a real word but also two swapped letters of a cue word or an object name
    read as that word ("whichever is closets to the tv": "closest"); for a question refused as typed only."""
    meaning, _ = _static()
    notes: list[str] = []

    def fix(m: re.Match) -> str:
        w = m.group(0)
        if w in meaning or len(w) < 4:
            return w
        hits = [c for c in meaning if len(c) == len(w) and _swapped(w, c)]
        if len(hits) != 1:
            return w
        notes.append(f"read '{w}' as '{hits[0]}'")
        return hits[0]

    return _WORD.sub(fix, text), notes


def cue_reading(text: str, read_as: list[str]) -> tuple[str, list[str]]:
    """For a question refused as typed: each typo that was read as an object name or a plain word ("cloest" as
    "closet") read instead as the one cue word also within the bound ("closest"), if there is exactly one."""
    meaning, _ = _static()
    objects = {w for n in NAME_SYNONYMS for w in (n, plural(n)) if " " not in n}
    notes: list[str] = []
    for note in read_as:
        m = re.fullmatch(r"read '([a-z]+)' as '([a-z]+)'", note)
        if m is None or (m.group(2) in meaning and m.group(2) not in objects):  # it was read as a cue word
            continue
        typed, lim = m.group(1), bound(m.group(1))
        cues = [w for w in meaning - objects if abs(len(w) - len(typed)) <= lim and distance(typed, w, lim) <= lim]
        if len(cues) == 1:
            text = re.sub(rf"(?<![\w'-]){m.group(2)}(?![\w'-])", cues[0], text, count=1)
            notes.append(f"read '{typed}' as '{cues[0]}' (not '{m.group(2)}': the question means nothing with it)")
    return text, notes


@functools.lru_cache(maxsize=4096)
def _cached(word: str) -> tuple[str, ...]:
    return tuple(candidates(word))
