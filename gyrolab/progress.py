"""Progress bars (with ETA) for long work, on stderr so that stdout stays clean."""

from __future__ import annotations

import os
import sys
from typing import Any

from tqdm.auto import tqdm


def progress(total: float | None = None, desc: str = "", unit: str = "it", **kw: Any) -> tqdm:
    """A tqdm bar on stderr; silenced by ``GYROLAB_NO_PROGRESS=1`` (tests set it)."""
    disable = os.environ.get("GYROLAB_NO_PROGRESS", "") not in ("", "0")
    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        file=sys.stderr,
        disable=disable,
        mininterval=0.5,
        dynamic_ncols=True,
        **kw,
    )
