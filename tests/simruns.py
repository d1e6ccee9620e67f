"""Shared pieces of the tests that run acquisitions against the simulated bench in process."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

# Three steps of 320 s (compensate needs 922 s), about 10 s of wall time at 100x; tests
# shorten it with ``.replace("320", "60")``.
THREE_STEPS = (
    "[[step]]\nsetpoint_c = 25\nduration_s = 320\n"
    "[[step]]\nsetpoint_c = 60\nduration_s = 320\n"
    "[[step]]\nsetpoint_c = 0\nduration_s = 320\n"
)


def three_step_profile(name: str) -> str:
    """The three-step profile as PROFILE.toml text, named ``name``."""
    return f'name = "{name}"\n' + THREE_STEPS


def run_on_sim(cfg: Any, profile: Any, out: Path, sim: Any) -> Any:
    """``run_acquisition`` against a started SimBench, stopping it afterwards. A short GIL
    switch interval keeps the bench's pty writers from starving behind the engine's thread
    on a busy machine (the drivers' reads are paced in wall time)."""
    from gyrolab.app.acquire import run_acquisition

    old = sys.getswitchinterval()
    sys.setswitchinterval(0.0005)
    try:
        return run_acquisition(cfg=cfg, profile=profile, out=out, force=False, sim=sim)
    finally:
        sys.setswitchinterval(old)
        sim.stop()
