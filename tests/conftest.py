"""Shared test settings: no progress bars, headless matplotlib, ../shared located, and
every command's catalogue registration going to the session's own catalogue file."""

from __future__ import annotations

import os
from collections.abc import Iterator
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


@pytest.fixture(scope="session", autouse=True)
def session_catalogue(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Every command a test runs (in process or as a subprocess) registers in this
    session's own SQLite catalogue, never in the user's (docs/catalogue.md)."""
    path = tmp_path_factory.mktemp("catalogue") / "catalogue.sqlite"
    saved = os.environ.get("GYROLAB_CATALOGUE")
    os.environ["GYROLAB_CATALOGUE"] = str(path)
    yield path
    if saved is None:
        os.environ.pop("GYROLAB_CATALOGUE", None)
    else:
        os.environ["GYROLAB_CATALOGUE"] = saved
