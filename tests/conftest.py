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
