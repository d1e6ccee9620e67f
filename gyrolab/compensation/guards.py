"""Guards around a fitted compensation model: what it was fitted on, where it may be used.

* :class:`RunHasher` / :func:`content_hash` — a content hash of a run's data (the
  ``/gyro/rate`` values and the ``/temperature/pt100`` readings, not the file name or the
  metadata), stored in ``model.json`` as ``calibration.content_hash``. ``gyrolab
  compensate RUN --validate RUN`` (or a renamed copy of RUN) is refused with it: metrics
  of the calibration data are not held-out metrics.
* :func:`calibration_ranges` / :func:`range_check` — the calibrated range of the drift
  model's inputs (case temperature, °C, and its rate dT/dt, °C/min, as a backward
  difference over ``dtdt_window_s``) and the fraction of a run's 3.6 s points outside it.
  Outside, the model is extrapolated (linearly for the networks, by its own curve for the
  polynomial), so ``compensate --validate`` and ``apply`` warn on stderr and
  ``metrics.json`` carries the flag and the fractions.
* :func:`source_check` / :func:`source_warning` — the temperature source the model was
  fitted on (``calibration.temperature_source``: the unit's PT100, or its internal die
  sensor) against the run's. A mismatch is not refused (the die–case offset and lag may be
  acceptable) but flagged the same way: a stderr line and ``temperature_source_mismatch``.
* :func:`unit_check` / :func:`unit_warning` — the unit the model was fitted on
  (``calibration.unit_serial``, the serial its calibration recording names) against the
  run's: a model applied to another unit's run is flagged (stderr line, ``unit_mismatch``),
  not refused (a fleet prior is applied to other units on purpose).
"""

from __future__ import annotations

import hashlib
import sys
from typing import Any

import numpy as np

from gyrolab.compensation.causal_features import hold
from gyrolab.errors import InputError

HASH_NAME = "blake2b-160"
#: Margin (°C, and fraction of the calibrated span) within which a point still counts as
#: inside the calibrated temperature range: the range is itself measured by the PT100
#: (class B: ±0.3 °C at 0 °C) at the ends of soaks, so a held-out run of the same profile
#: grazes it by noise alone.
TEMP_MARGIN_C = 0.5
SPAN_MARGIN = 0.01


class RunHasher:
    """Incremental content hash of a run: feed the rate samples in time order with
    :meth:`add_rate` (any batching gives the same digest), then :meth:`hexdigest` with the
    PT100 readings. Rate values are hashed as float64, so a file read whole or streamed in
    batches gives the same digest."""

    def __init__(self) -> None:
        self._h = hashlib.blake2b(digest_size=20)
        self.n_rate = 0

    def add_rate(self, x: np.ndarray) -> None:
        a = np.ascontiguousarray(x, dtype=np.float64)
        self._h.update(a.data)
        self.n_rate += a.size

    def hexdigest(self, pt_t: np.ndarray, pt_c: np.ndarray) -> str:
        h = self._h.copy()
        h.update(b"|pt100|")
        h.update(np.ascontiguousarray(pt_t, dtype=np.float64).data)
        h.update(np.ascontiguousarray(pt_c, dtype=np.float64).data)
        return f"{HASH_NAME}:{h.hexdigest()}"


def content_hash(rate: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray) -> str:
    """:class:`RunHasher` digest of whole arrays."""
    h = RunHasher()
    h.add_rate(rate)
    return h.hexdigest(pt_t, pt_c)


def check_also_prior(also: Any, prior: Any) -> None:
    """Refuse ``--also`` with ``--prior``: the one lengthens the calibration, the other is
    for a short one (a MAP fit of one run towards the fleet)."""
    if also and prior is not None:
        raise InputError(
            str(also[0]),
            "--also lengthens the calibration and --prior shortens it: fit with one of them",
        )


def check_not_calibration(validate_path: str, val_hash: str, cal_hash: str) -> None:
    """Refuse a validation run whose data are the calibration run's (same content hash)."""
    if val_hash and val_hash == cal_hash:
        raise InputError(
            validate_path,
            "has the same rate and temperature data as the calibration run (content hash "
            f"{val_hash.split(':')[-1][:12]}…): held-out metrics need a run the model was "
            "not fitted on",
        )


def temperature_rate(t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray, w: float) -> np.ndarray:
    """dT/dt (°C/min) at times ``t``: causal backward difference (T(t) − T(t − w)) / w of the
    zero-order-held PT100 temperature — the rate input of
    :func:`gyrolab.compensation.prepare.features`."""
    T = hold(t, pt_t, pt_c)
    Tp = hold(t - w, pt_t, pt_c)
    return 60.0 * (T - Tp) / w


def calibration_ranges(run: Any, window_s: float) -> dict[str, float]:
    """The calibrated input ranges of a prepared run (``calibration`` entries of
    model.json): temperature (°C) and its rate over ``window_s`` (°C/min)."""
    r = temperature_rate(run.t, run.pt_t, run.pt_c, window_s)
    return {
        "temp_min_c": float(run.temp.min()),
        "temp_max_c": float(run.temp.max()),
        "temp_rate_min_c_per_min": float(r.min()),
        "temp_rate_max_c_per_min": float(r.max()),
        "temp_rate_window_s": float(window_s),
    }


def outside_fraction(
    x: np.ndarray, lo: float, hi: float, min_margin: float = TEMP_MARGIN_C
) -> tuple[float, float]:
    """The fraction of ``x`` beyond the calibrated ``[lo, hi]`` by more than the margin
    ``max(min_margin, SPAN_MARGIN (hi − lo))`` (what sets ``outside_calibration_range``),
    and that margin."""
    margin = max(min_margin, SPAN_MARGIN * (hi - lo))
    out = (x < lo - margin) | (x > hi + margin)
    return float(out.mean()), margin


def source_check(calibration: dict[str, Any], run: Any) -> dict[str, Any]:
    """The model's temperature source (``calibration.temperature_source``, absent =
    ``"pt100"``: models fitted before internal sensors existed) against the run's
    (``PreparedRun.temperature_source``), and whether they differ."""
    fitted = str(calibration.get("temperature_source", "pt100"))
    used = str(run.temperature_source)
    return {
        "temperature_source": used,
        "calibration_temperature_source": fitted,
        "temperature_source_mismatch": used != fitted,
    }


def unit_check(calibration: dict[str, Any], run: Any) -> dict[str, Any]:
    """The serial of the unit the model was fitted on (``calibration.unit_serial``, else
    the multi-unit ``calibration.unit``) against the run's (``PreparedRun.serial``), and
    whether they differ — only where both are known (a model or a recording without a
    serial is not flagged)."""
    fitted = str(calibration.get("unit_serial") or calibration.get("unit") or "")
    used = str(getattr(run, "serial", "") or "")
    return {
        "unit_serial": used or None,
        "calibration_unit_serial": fitted or None,
        "unit_mismatch": bool(fitted and used and fitted != used),
    }


def unit_warning(path: str, t: dict[str, Any]) -> str | None:
    """One stderr line for a run of another unit than the model's (``None`` otherwise)."""
    if not t.get("unit_mismatch"):
        return None
    return (
        f"warning: {path}: the model was fitted on unit {t['calibration_unit_serial']}, "
        f"this run is unit {t['unit_serial']}: its drift is not this unit's"
    )


SOURCE_NAMES = {"pt100": "PT100 (case)", "internal": "internal (die) sensor"}


def source_warning(path: str, t: dict[str, Any]) -> str | None:
    """One stderr line for a run whose temperature source is not the model's (``None``
    when they agree): a die sensor reads the die, offset from and lagging the case PT100."""
    if not t.get("temperature_source_mismatch"):
        return None
    fitted, used = t["calibration_temperature_source"], t["temperature_source"]
    return (
        f"warning: {path}: the model was fitted on the {SOURCE_NAMES.get(fitted, fitted)} "
        f"temperature, this run's is its {SOURCE_NAMES.get(used, used)}: the offset and lag "
        "between die and case enter the drift model's input"
    )


def range_check(calibration: dict[str, Any], run: Any) -> dict[str, Any]:
    """The ``temperature`` block of metrics.json: the run's temperature (and dT/dt) range
    against the calibrated one, the fraction of 3.6 s points outside (strictly, key
    ``fraction_outside_calibration``; and beyond the margin, which sets the flag), and
    ``outside_calibration_range``; with :func:`source_check`'s keys. Models written before
    dT/dt ranges were stored get the temperature check only; with no range, the source
    keys only."""
    lo, hi = calibration.get("temp_min_c"), calibration.get("temp_max_c")
    if lo is None or hi is None:
        return {**source_check(calibration, run), **unit_check(calibration, run)}
    strict = (run.temp < lo) | (run.temp > hi)
    frac_t, margin_t = outside_fraction(run.temp, lo, hi, TEMP_MARGIN_C)
    out: dict[str, Any] = {
        "min_c": float(run.temp.min()),
        "max_c": float(run.temp.max()),
        "calibration_min_c": lo,
        "calibration_max_c": hi,
        "fraction_outside_calibration": float(strict.mean()),
        "margin_c": margin_t,
        "fraction_outside_calibration_beyond_margin": frac_t,
    }
    flag = frac_t > 0
    rlo, rhi = (
        calibration.get("temp_rate_min_c_per_min"),
        calibration.get("temp_rate_max_c_per_min"),
    )
    if rlo is not None and rhi is not None:
        w = float(calibration.get("temp_rate_window_s", 300.0))
        r = temperature_rate(run.t, run.pt_t, run.pt_c, w)
        frac_r, margin_r = outside_fraction(r, rlo, rhi, 0.0)
        out.update(
            rate_min_c_per_min=float(r.min()),
            rate_max_c_per_min=float(r.max()),
            calibration_rate_min_c_per_min=rlo,
            calibration_rate_max_c_per_min=rhi,
            rate_margin_c_per_min=margin_r,
            fraction_rate_outside_calibration=frac_r,
        )
        flag = flag or frac_r > 0
    out["outside_calibration_range"] = bool(flag)
    out.update(source_check(calibration, run))
    out.update(unit_check(calibration, run))
    return out


def range_warning(path: str, t: dict[str, Any]) -> str | None:
    """One stderr line for a run outside the calibrated range (``None`` when inside)."""
    if not t.get("outside_calibration_range"):
        return None
    parts = []
    if t.get("fraction_outside_calibration_beyond_margin", 0) > 0:
        parts.append(
            f"{100 * t['fraction_outside_calibration_beyond_margin']:.1f} % of the points "
            f"outside the calibrated temperature range {t['calibration_min_c']:.1f} … "
            f"{t['calibration_max_c']:.1f} °C (this run {t['min_c']:.1f} … {t['max_c']:.1f} °C)"
        )
    if t.get("fraction_rate_outside_calibration", 0) > 0:
        parts.append(
            f"{100 * t['fraction_rate_outside_calibration']:.1f} % outside the calibrated "
            f"dT/dt range {t['calibration_rate_min_c_per_min']:.2f} … "
            f"{t['calibration_rate_max_c_per_min']:.2f} °C/min (this run "
            f"{t['rate_min_c_per_min']:.2f} … {t['rate_max_c_per_min']:.2f} °C/min)"
        )
    ee = t.get("expected_error")
    grade = (
        f"; expected error {ee['grade']} (the causal model's 90 % band at the 90th "
        f"percentile is {ee['ratio_p90']:.2f}× its in-range width)"
        if ee
        else ""
    )
    return (
        f"warning: {path}: " + "; ".join(parts) + ": the drift model is extrapolated there" + grade
    )


def warn_outside(path: str, t: dict[str, Any]) -> None:
    """The stderr lines of a ``temperature`` block: outside the range, another source,
    another unit."""
    for msg in (range_warning(path, t), source_warning(path, t), unit_warning(path, t)):
        if msg:
            print(msg, file=sys.stderr)
