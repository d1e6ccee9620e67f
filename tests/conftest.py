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
        pytest.skip("../shared is not beside the checkout")
    return SHARED
