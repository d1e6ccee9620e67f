"""``FAULTS.toml``: the simulated bench's fault injection as a file
(``gyrolab acquire --bench sim --faults FAULTS.toml``; docs/instruments.md, "Fault
injection").

Layout (every key optional; unknown keys are errors naming the file and the key)::

    [adc]                 # random byte faults on the ADC stream (ByteFaults)
    corrupt_prob = 2e-4   # per byte: XOR with a random non-zero byte
    drop_prob = 0.0       # per byte: dropped
    seed = 5

    [oven]                # random faults on the oven's Modbus replies (ModbusFaults)
    exception_prob = 0.0  # per request: exception response with exception_code
    crc_error_prob = 0.0
    no_reply_prob = 0.0
    exception_code = 6    # 06 slave device busy
    seed = 0

    [[event]]             # scheduled faults (FaultEvent), any number
    kind = "scpi_error"   # disconnect | stall | outage | scpi_error | open_channel |
                          # modbus_exception | modbus_crc | modbus_no_reply | chamber_alarm
    t_s = 30.0            # simulated bench seconds (the run starts a few s later)
    duration_s = 0.0      # disconnect / stall / outage / open_channel / chamber_alarm
    count = 1             # modbus_* : the next `count` replies
    detail = '-310,"System error"'   # scpi_error: the error-queue entry
    unit = 0              # disconnect / stall / open_channel on a multi-unit bench: which
                          # unit (0-based)

``outage`` and ``scpi_error`` hit the bench's thermometer: the multimeter, or on a
multi-unit bench the scanner; ``open_channel`` is for multi-unit benches only;
``chamber_alarm`` needs a chamber whose driver reports its alarm (the F4 with ``[chamber]
alarm_input``, as ``--bench sim`` has it, or the ESPEC).
"""

from __future__ import annotations

import math
import os
import re
from typing import Any

from gyrolab.errors import InputError
from gyrolab.sim.bench.faults import (
    ADC_KINDS,
    CHAMBER_KINDS,
    DMM_KINDS,
    OVEN_KINDS,
    SCANNER_KINDS,
    ByteFaults,
    FaultEvent,
    FaultPlan,
    ModbusFaults,
)
from gyrolab.tomlfile import read_toml

_ADC_KEYS = {"corrupt_prob": float, "drop_prob": float, "seed": int}
_OVEN_KEYS = {
    "exception_prob": float,
    "crc_error_prob": float,
    "no_reply_prob": float,
    "exception_code": int,
    "seed": int,
}
_EVENT_KEYS = {
    "kind": str,
    "t_s": float,
    "duration_s": float,
    "count": int,
    "detail": str,
    "unit": int,
}
_SCPI_ERROR = re.compile(r'^[+-]?\d+,".*"$')


def _table(raw: Any, keys: dict[str, type], where: str, source: str) -> dict[str, Any]:
    if not isinstance(raw, dict):
        raise InputError(source, f"{where} must be a table")
    unknown = sorted(set(raw) - set(keys))
    if unknown:
        raise InputError(source, f"{where}: unknown key(s) {unknown} (known: {', '.join(keys)})")
    out: dict[str, Any] = {}
    for k, v in raw.items():
        typ = keys[k]
        ok = (
            isinstance(v, str)
            if typ is str
            else isinstance(v, (int, float)) and not isinstance(v, bool)
        )
        if typ is int and ok and float(v) != int(v):
            ok = False
        if typ is float and ok and not math.isfinite(float(v)):
            ok = False
        if not ok:
            raise InputError(source, f"{where} {k} = {v!r}: expected {typ.__name__}")
        out[k] = typ(v)
    return out


def _probs(d: dict[str, Any], names: tuple[str, ...], where: str, source: str) -> None:
    for k in names:
        if k in d and not 0.0 <= d[k] < 1.0:
            raise InputError(source, f"{where} {k} = {d[k]:g}: a probability in [0, 1)")
    if sum(d.get(k, 0.0) for k in names) >= 1.0:
        raise InputError(source, f"{where}: the probabilities must add up to less than 1")


def faults_from_dict(d: dict[str, Any], source: str = "<dict>") -> FaultPlan:
    """Build a :class:`FaultPlan` from the FAULTS.toml layout; InputError on any problem."""
    unknown = sorted(set(d) - {"adc", "oven", "event"})
    if unknown:
        raise InputError(source, f"unknown key(s) {unknown} (known: adc, oven, event)")
    adc = _table(d.get("adc", {}), _ADC_KEYS, "[adc]", source)
    _probs(adc, ("corrupt_prob", "drop_prob"), "[adc]", source)
    oven = _table(d.get("oven", {}), _OVEN_KEYS, "[oven]", source)
    _probs(oven, ("exception_prob", "crc_error_prob", "no_reply_prob"), "[oven]", source)
    if not 1 <= oven.get("exception_code", 6) <= 255:
        raise InputError(source, "[oven] exception_code must be 1..255 (Modbus exception code)")
    raw_events = d.get("event", [])
    if not isinstance(raw_events, list):
        raise InputError(source, "event must be an array of tables ([[event]])")
    events = []
    kinds = ADC_KINDS + DMM_KINDS + OVEN_KINDS + SCANNER_KINDS + CHAMBER_KINDS
    for i, raw in enumerate(raw_events, start=1):
        where = f"[[event]] {i}"
        e = _table(raw, _EVENT_KEYS, where, source)
        if "kind" not in e:
            raise InputError(source, f"{where}: kind is required (one of {', '.join(kinds)})")
        if e["kind"] not in kinds:
            raise InputError(source, f"{where}: kind = {e['kind']!r} (one of {', '.join(kinds)})")
        if (
            e.get("t_s", 0.0) < 0
            or e.get("duration_s", 0.0) < 0
            or e.get("count", 1) < 1
            or e.get("unit", 0) < 0
        ):
            raise InputError(
                source, f"{where}: t_s, duration_s, unit must be >= 0 and count >= 1"
            )
        timed = ("disconnect", "stall", "outage", "open_channel", "chamber_alarm")
        if e["kind"] in timed and not e.get("duration_s", 0.0) > 0:
            raise InputError(source, f"{where}: {e['kind']} needs duration_s > 0")
        if e["kind"] == "scpi_error" and "detail" in e and not _SCPI_ERROR.match(e["detail"]):
            raise InputError(
                source,
                f"{where}: detail = {e['detail']!r}: expected an error-queue entry "
                "such as '-310,\"System error\"'",
            )
        # A scheduled fault needs a time: "now" (t_s None) is for SimBench.inject only.
        events.append(FaultEvent(**{"t_s": 0.0, **e}))
    return FaultPlan(adc=ByteFaults(**adc), oven=ModbusFaults(**oven), events=events)


def check_plan_for_bench(
    plan: FaultPlan,
    units: int,
    source: str = "<faults>",
    internal: tuple[int, ...] = (),
    chamber_alarm: bool = True,
) -> None:
    """InputError unless every event fits a bench of ``units`` units (0: single-unit) of
    which ``internal`` (1-based) read their internal sensor: ``unit`` within the bench,
    ``open_channel`` only on a unit whose PT100 the scanner reads, ``outage`` /
    ``scpi_error`` only where a thermometer is read (not when every unit is internal),
    ``chamber_alarm`` only where the chamber's driver reports one (``chamber_alarm``)."""
    n = max(1, units)
    for i, e in enumerate(plan.events, start=1):
        where = f"[[event]] {i}"
        if e.kind == "chamber_alarm" and not chamber_alarm:
            raise InputError(
                source,
                f"{where}: chamber_alarm: the chamber's driver reports no alarm here "
                "(the F4 needs [chamber] alarm_input)",
            )
        if e.unit >= n:
            raise InputError(
                source, f"{where}: unit = {e.unit}: the bench has {n} unit(s) (0-based)"
            )
        if e.kind == "open_channel" and not units:
            raise InputError(source, f"{where}: open_channel is a scanner channel: --units N only")
        if e.kind == "open_channel" and e.unit + 1 in internal:
            raise InputError(
                source, f"{where}: unit = {e.unit} reads its internal sensor: no scanner channel"
            )
        if e.kind in DMM_KINDS and units and set(range(1, units + 1)) <= set(internal):
            raise InputError(
                source, f"{where}: {e.kind}: every unit reads its internal sensor, no scanner"
            )


def load_faults(path: str | os.PathLike[str]) -> FaultPlan:
    """Read and check a FAULTS.toml."""
    return faults_from_dict(read_toml(path, "faults file"), str(path))


def plan_to_dict(plan: FaultPlan) -> dict[str, Any]:
    """The plan in the FAULTS.toml layout (for the recording's provenance)."""
    a, o = plan.adc, plan.oven
    return {
        "adc": {"corrupt_prob": a.corrupt_prob, "drop_prob": a.drop_prob, "seed": a.seed},
        "oven": {
            "exception_prob": o.exception_prob,
            "crc_error_prob": o.crc_error_prob,
            "no_reply_prob": o.no_reply_prob,
            "exception_code": o.exception_code,
            "seed": o.seed,
        },
        "event": [
            {
                "kind": e.kind,
                "t_s": e.t_s,
                "duration_s": e.duration_s,
                "count": e.count,
                "detail": e.detail,
                **({"unit": e.unit} if e.unit else {}),
            }
            for e in plan.events
        ],
    }
