"""What the numbers of a model directory may be (:class:`~.model_dir.ModelDir` applies
these checks to what it reads; docs/compensation.md, "Guards").

* :func:`bad_number` — the first non-finite number of a parsed JSON value, with its field
  path (``NaN``/``Infinity`` literals come in as :class:`NonFinite`, ``1e999`` as inf);
* :func:`check_model_meta` — a single-axis model.json's calibration range inside
  −273.15…1000 °C and in order, positive rates, windows, durations, counts, VMD K and α,
  the seed, and the drift models' and FLPs' numbers present where the model needs them
  (JSON stores a NaN as null).

Each returns the problem as ``"field …"`` (``None``: none); the owner names the file.
"""

from __future__ import annotations

import math
from typing import Any

#: Physically possible temperatures (°C): a calibration range beyond is a damaged file.
TEMP_BOUNDS_C = (-273.15, 1000.0)


class NonFinite:
    """A ``NaN``/``Infinity`` literal met while parsing JSON (refused by the walk)."""

    def __init__(self, text: str) -> None:
        self.text = text


def bad_number(x: Any, where: str = "") -> tuple[str, str] | None:
    """The first non-finite number in a parsed JSON value: ``(field path, literal)``."""
    if isinstance(x, NonFinite):
        return where, x.text
    if isinstance(x, float) and not math.isfinite(x):
        return where, repr(x)
    if isinstance(x, dict):
        for k, v in x.items():
            bad = bad_number(v, f"{where}.{k}" if where else str(k))
            if bad:
                return bad
    elif isinstance(x, list):
        for i, v in enumerate(x):
            bad = bad_number(v, f"{where}[{i}]")
            if bad:
                return bad
    return None


def _positive(where: str, v: Any, *, integer: bool = False, zero: bool = False) -> str | None:
    ok = isinstance(v, (int, float)) and not isinstance(v, bool)
    ok = ok and (v >= 0 if zero else v > 0) and (not integer or float(v).is_integer())
    kind = "a non-negative" if zero else "a positive"
    return None if ok else f"{where} = {v!r} is not {kind} {'integer' if integer else 'number'}"


def check_model_meta(meta: dict[str, Any]) -> str | None:
    """The first value of a single-axis model.json outside its range (module docstring)."""
    cal = meta.get("calibration") or {}
    lo, hi = cal.get("temp_min_c"), cal.get("temp_max_c")
    for key, v in (("temp_min_c", lo), ("temp_max_c", hi)):
        if v is not None and not (
            isinstance(v, (int, float)) and TEMP_BOUNDS_C[0] <= v <= TEMP_BOUNDS_C[1]
        ):
            return (
                f"calibration.{key} = {v!r} °C is outside {TEMP_BOUNDS_C[0]} … "
                f"{TEMP_BOUNDS_C[1]} °C"
            )
    if lo is not None and hi is not None and lo > hi:
        return f"calibration.temp_min_c = {lo!r} exceeds calibration.temp_max_c = {hi!r}"
    rlo, rhi = cal.get("temp_rate_min_c_per_min"), cal.get("temp_rate_max_c_per_min")
    if isinstance(rlo, (int, float)) and isinstance(rhi, (int, float)) and rlo > rhi:
        return f"calibration.temp_rate_min_c_per_min = {rlo!r} exceeds the maximum {rhi!r}"
    checks = [
        ("calibration.temp_rate_window_s", cal.get("temp_rate_window_s"), False, False),
        ("calibration.raw_rate_hz", cal.get("raw_rate_hz"), False, False),
        ("calibration.duration_s", cal.get("duration_s"), False, False),
        ("calibration.n_points", cal.get("n_points"), True, False),
        ("calibration.filled_blocks", cal.get("filled_blocks"), True, True),
        ("vmd.K", (meta.get("vmd") or {}).get("K"), True, False),
        ("vmd.alpha", (meta.get("vmd") or {}).get("alpha"), False, False),
    ]
    for where, v, integer, zero in checks:
        if v is not None or where.startswith("vmd."):
            bad = _positive(where, v, integer=integer, zero=zero)
            if bad:
                return bad
    seed = meta.get("seed")
    if seed is not None and _positive("seed", seed, integer=True, zero=True):
        return _positive("seed", seed, integer=True, zero=True)
    return check_parameters(meta)


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def check_parameters(meta: dict[str, Any]) -> str | None:
    """The drift models' and the FLPs' numbers in model.json: present where the model
    needs them (a NaN is written as null: JSON has none), scales positive, ranges in
    order."""
    cm = meta.get("causal_model") or {}
    scalers = [("drift_model", meta.get("drift_model") or {})]
    scalers += [(f"baselines.{n}", b) for n, b in (meta.get("baselines") or {}).items()]
    scalers += [("causal_model.mlp", cm["mlp"])] if isinstance(cm.get("mlp"), dict) else []
    for where, d in scalers:
        for key in ("y_mean", "y_std", "t_lo", "t_hi"):
            if key in d and not _number(d[key]):
                return f"{where}.{key} is not finite ({d[key]!r})"
        if "y_std" in d and not d["y_std"] > 0:
            return f"{where}.y_std = {d['y_std']!r} is not positive"
        if "t_lo" in d and not d["t_lo"] < d["t_hi"]:
            return f"{where}.t_lo = {d['t_lo']!r} is not below t_hi = {d['t_hi']!r}"
    st = cm.get("structured")
    if isinstance(st, dict):
        for key in ("lo", "hi", "k", "h", "A"):
            if not _number(st.get(key)):
                return f"causal_model.structured.{key} is not finite ({st.get(key)!r})"
        if not all(_number(c) for c in st.get("coef") or [None]):
            return "causal_model.structured.coef is not finite"
        if not st["lo"] < st["hi"]:
            return f"causal_model.structured.lo = {st['lo']!r} is not below hi = {st['hi']!r}"
    for name, f in (meta.get("flp") or {}).items():
        if isinstance(f, dict):
            for i, c in enumerate(f.get("coef") or []):
                if not _number(c):
                    return f"flp.{name}.coef[{i}] is not finite ({c!r})"
            if not _number(f.get("mean", 0.0)):
                return f"flp.{name}.mean is not finite ({f.get('mean')!r})"
    return None


__all__ = ["TEMP_BOUNDS_C", "NonFinite", "bad_number", "check_model_meta", "check_parameters"]
