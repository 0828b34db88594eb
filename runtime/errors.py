"""One small exception hierarchy. Messages name the file/field and say what to do."""
from __future__ import annotations


class MosaicError(Exception):
    """Base of every error the project raises on purpose."""


class InputError(MosaicError):
    """Bad user input: unreadable video/image/folder, unknown object name, malformed question."""


class BundleError(MosaicError):
    """Missing, tampered or malformed model bundle (manifest, sha256, escaping paths, schema version)."""


class ProfileError(MosaicError):
    """A device profile (profiles/*.toml) with unknown keys, wrong units or impossible values."""


class BudgetError(MosaicError):
    """Nothing fits the latency/memory budget; the message says which budget fails and by how much."""


class ProviderError(MosaicError):
    """No execution provider could create or run a session."""


class AlignmentError(MosaicError):
    """Alignment could not proceed (e.g. fewer than two frames with depth)."""


class ExportError(MosaicError):
    """Export failed, including a failed parity check."""
