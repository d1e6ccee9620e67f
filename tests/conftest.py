"""Shared test settings: no progress bars, headless matplotlib, ../shared located."""

from __future__ import annotations

import os
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
