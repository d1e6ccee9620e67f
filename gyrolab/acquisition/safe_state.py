"""The safe state every run ends in: the chamber commanded to ``[safe_state] setpoint_c``
(and, with ``mode = "off"``, switched off), verified by reading it back, and recorded.

The engine's shutdown (``Acquisition._shutdown``) calls :func:`command_safe_state` first,
before anything is written (a failing recorder must not keep the oven hot), and
:func:`record_safe_state` once the rest of the run is on disk (docs/reliability.md,
"Ending: always in the safe state").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from gyrolab.acquisition.bench_config import SafeState
from gyrolab.acquisition.journal import Journal
from gyrolab.clock import Clock
from gyrolab.instruments.roles import Chamber

# One attempt: (run time, error or "", (setpoint, process value) read back or None).
Attempt = tuple[float, str, Any]

ATTEMPTS = 3
RETRY_S = 0.2  # clock seconds between attempts
READBACK_TOLERANCE_C = 0.05


def command_safe_state(
    chamber: Chamber, safe: SafeState, clock: Clock, t: Callable[[], float]
) -> tuple[bool, list[Attempt]]:
    """Command the safe setpoint and verify it by reading it back (``ATTEMPTS`` tries,
    ``RETRY_S`` apart); with ``mode = "off"`` then switch the chamber off (the driver
    verifies it). Returns ``(ok, attempts)``; ``t()`` is the run clock."""
    attempts: list[Attempt] = []
    for _ in range(ATTEMPTS):
        t0 = t()
        try:
            chamber.set_setpoint(safe.setpoint_c)
            sp, pv = chamber.read()[:2]
            if abs(sp - safe.setpoint_c) > READBACK_TOLERANCE_C:
                raise RuntimeError(f"setpoint read back {sp:g} °C")
            if safe.mode == "off":
                chamber.switch_off()  # type: ignore[attr-defined]  # verifies by read-back
        except Exception as e:
            attempts.append((t0, f"{type(e).__name__}: {e}", None))
            clock.sleep(RETRY_S)
            continue
        attempts.append((t(), "", (sp, pv)))
        return True, attempts
    return False, attempts


def record_safe_state(
    writer: Any, journal: Journal, chamber: str, safe: SafeState, ok: bool, attempts: list[Attempt]
) -> None:
    """Each failed attempt in ``/log``; then the oven's read-back state (mode ``safe``) and
    the ``safe_state`` event, ``setpoint … verified`` or ``FAILED: …``."""
    for k, (t, err, _res) in enumerate(attempts, start=1):
        if err:
            journal.log("error", chamber, f"safe-state attempt {k} failed: {err}", "fault", None, t)
    t, err, res = attempts[-1]
    if ok:
        sp, pv = res
        detail = f"setpoint {safe.setpoint_c:g} °C verified"
        if safe.mode == "off":
            detail += ", chamber off verified"
        writer.write_oven(t, sp, pv, "safe")
        writer.write_event(t, "safe_state", -1, sp, detail)
        journal.log(
            "info",
            chamber,
            f"oven in safe state: {detail}",
            "safe_state",
            {"setpoint_c": sp, "process_value_c": pv},
            t,
        )
    else:
        writer.write_event(t, "safe_state", -1, None, f"FAILED: {err}")
        journal.log(
            "fault", chamber, f"could not put the oven in the safe state: {err}", "fault", None, t
        )
