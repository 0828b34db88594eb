"""Which of the question's names the bundle's closed-set detector can see: the vocabulary (grounding's) against the
detector's label list (`models.detector`). Above both, so the model adapters import no stage."""
from __future__ import annotations

import difflib
import os
from typing import Any, Sequence

from .grounding import VOCABULARY
from .infra.bundle import load_bundle
from .infra.errors import InputError
from .models.detector import closed_labels, map_names, normalize_name, one_name_per_label


def detectable_names(bundle: Any, preferred: Sequence[str] = ()) -> list[str]:
    """Every vocabulary name the bundle's closed-set detector can detect, one per set of detector labels
    (`one_name_per_label`; `preferred` names first, e.g. the question's): what a map of "everything" holds.
    bundle: a bundle folder or a loaded `Bundle`. InputError when it has no detector or an open-vocabulary one
    (which detects only what it is asked for)."""
    b = load_bundle(bundle) if isinstance(bundle, (str, os.PathLike)) else bundle
    if not b.has_role("detector"):
        raise InputError(f"{b.root}: the bundle has no `detector` role")
    labels = closed_labels(b)
    if not labels:
        raise InputError("the bundle's detector is open-vocabulary: name the objects (`mosaic map --objects "
                         "a,b,c`, or a question that names them)")
    mapping, _ = map_names(sorted(VOCABULARY), labels)
    return sorted(one_name_per_label(mapping, labels, list(preferred)))


def undetectable_names(bundle: Any, names: Sequence[str]) -> tuple[list[str], int, dict[str, str]]:
    """(the `names` the bundle's closed-set detector cannot detect, its number of labels, {such a name: a close
    spelling it can detect} for typos like "chiars"): what a question may name that no frame can show. ([], 0,
    {}) when the bundle has no detector or an open-vocabulary one (it looks for any name)."""

    labels = closed_labels(bundle)
    if not labels:
        return [], 0, {}
    missing = map_names(list(names), labels)[1]
    known = sorted(map_names(sorted(VOCABULARY), labels)[0])
    close = {n: m[0] for n in missing if (m := difflib.get_close_matches(normalize_name(n), known, 1, 0.8))}
    return missing, len({normalize_name(x) for x in labels} - {"n/a"}), close
