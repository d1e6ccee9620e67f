"""Shared test settings: no progress bars, headless matplotlib, ../shared located, and
every command's catalogue registration going to the session's own catalogue file."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.skip(
            f"reference data not found at {SHARED}: these tests compare with the Stable32 "
            "results of ../shared/ref/allan/ (an OCXO record and its Stable32 deviations, "
            "from the allantools test suite), which the project keeps beside the checkout, "
            "not in it; CI has it there. To run them, put the project's shared/ directory "
            "beside the repository as ../shared (see ../shared/README.md)"
        )
    return SHARED


_CATALOGUE_DIR: list[str] = []
_SAVED: dict[str, str | None] = {}


def pytest_configure(config: pytest.Config) -> None:
    """Every command a test runs (in process, or as a subprocess with an environment copied
    at import time) registers in this session's own SQLite catalogue, never in the user's
    (docs/catalogue.md): set before the test modules are imported."""
    d = tempfile.mkdtemp(prefix="gyrolab-test-catalogue-")
    _CATALOGUE_DIR.append(d)
    _SAVED["GYROLAB_CATALOGUE"] = os.environ.get("GYROLAB_CATALOGUE")
    os.environ["GYROLAB_CATALOGUE"] = str(Path(d) / "catalogue.sqlite")


def pytest_unconfigure(config: pytest.Config) -> None:
    for d in _CATALOGUE_DIR:
        shutil.rmtree(d, ignore_errors=True)
    if _SAVED.get("GYROLAB_CATALOGUE") is None:
        os.environ.pop("GYROLAB_CATALOGUE", None)
    else:
        os.environ["GYROLAB_CATALOGUE"] = str(_SAVED["GYROLAB_CATALOGUE"])


@pytest.hookimpl(tryfirst=True)  # before xdist's own, which reads the marks into node ids
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Groups for ``pytest -n 2 --dist loadgroup`` (the README's command): each test file
    is its group, as ``--dist loadfile`` makes it, except that the files using the
    session's demo (those importing ``test_demo.make_demo``) are one group, so the demo
    is made once per run instead of once per worker (about 45 s)."""
    if not config.pluginmanager.hasplugin("xdist"):  # the mark is xdist's
        return
    for item in items:
        module = getattr(item, "module", None)
        demo = module is not None and hasattr(module, "make_demo")
        item.add_marker(pytest.mark.xdist_group("demo" if demo else item.path.name))


@pytest.fixture(scope="session")
def session_catalogue() -> Path:
    """The session's catalogue file (pytest_configure)."""
    return Path(os.environ["GYROLAB_CATALOGUE"])
