"""The question reader's role adapter (arch "minilm-reader"): registered so that a bundle's `reader` role is
checked like any other (`mosaic bundle verify`). Questions are read by `query.reader.ModelReader`, which opens its
own session (`query.reader.load_reader`); this adapter only names the role's arch."""
from __future__ import annotations

from . import RoleModel


class QuestionReader(RoleModel):
    role = "reader"
