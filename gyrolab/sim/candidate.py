"""How the discrepancy workflow looks for an effect: the declaration every effect of the
vocabulary carries beside its physics (``effects.py``; docs/discrepancy.md, "The candidate
catalogue").

An effect declares

- :class:`Candidate`: the channel it is scored on (``sample``, ``temperature``, ``gyro``,
  ``noise``), the gap metric that must shrink when it is added, and the parameter (and
  reference shape) its detection limit is stated in;
- for a deterministic gyro term, :class:`GyroTerms`: its regressors on the workflow's
  bins (linear in the effect's amplitudes), its one nonlinear shape parameter and the
  grid it is scanned on, and its wider form within the name, if any.

A new gyro term is therefore one class in ``effects.py``: the workflow's fit, score,
detection limit and ``model.toml`` are generic over these declarations. An effect on
another channel also needs that channel's scorer (``sim/discrepancy/channels/``).
Plain data and numpy only: nothing here imports the workflow.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

CHANNELS = ("sample", "temperature", "gyro", "noise")
"""The channels, in the order the workflow looks at them (docs/discrepancy.md)."""

GAP_LF = "lf_residual_rms_dps"
GAP_ALLAN = "allan_log_distance"
GAP_TEMPERATURE = "temperature_rms_c"
GAP_SPIKES = "spike_log_ratio"
GAP_LATTICE = "lattice_tv_distance"


@dataclass(frozen=True)
class Candidate:
    """How an effect is looked for (module docstring)."""

    channel: str
    gap: str
    """The gap metric that belongs to the effect: it must shrink when the effect is added."""
    limit: str | None = None
    """The parameter its detection limit is stated in (None: no limit is stated)."""
    limit_at: Mapping[str, float] = field(default_factory=dict)
    """Shape parameters the limit is stated at (the simulator's defaults)."""


@dataclass(frozen=True)
class Bins:
    """What a gyro term's regressors are evaluated on: the workflow's bin centres and the
    bias-setting temperature (the case, or the die with ``thermal_lag``)."""

    t: np.ndarray
    """Bin centres, s since power-on."""
    temp_c: np.ndarray
    """Bias-setting temperature at the bin centres, °C."""
    dtemp_c_per_s: np.ndarray
    """Its rate of change at the bin centres, °C/s."""
    grid_t: np.ndarray
    """The 1 s thermal grid, s (history-dependent terms run on it)."""
    grid_temp_c: np.ndarray
    """The bias-setting temperature on that grid, °C."""
    grid_dtemp_c_per_s: np.ndarray
    """Its rate of change on that grid, °C/s."""
    poly_order: int
    """Order of the temperature polynomial ``bias_poly`` (2, or 3–4 from a starting model)."""


Columns = Callable[[Bins, Mapping[str, float]], list[tuple[str, np.ndarray]]]
"""(bins, shape values) → [(coefficient name, regressor)]."""
TemperatureChange = Callable[[np.ndarray, Mapping[str, float]], tuple[np.ndarray, np.ndarray]]
"""(case temperature on the 1 s grid, shape values) → (bias-setting temperature, its rate)."""


@dataclass(frozen=True)
class WiderForm:
    """A wider form within an effect's name, tried when the plain form is the candidate
    (the lower BIC, its extra parameter counted, wins)."""

    kind: str
    """``"second"``: a second component of the same shape, its shape parameter scanned on
    the effect's grid; ``"slope"``: the shape parameter linear in ``T − 25 °C``, the
    slopes ``tries`` × the shape value tried."""
    param: str
    """The simulator parameter that holds the form's shape value (e.g. ``tau2_s``)."""
    present: str
    """The parameter that is non-zero when a model uses the form (e.g. ``A2``)."""
    label: str
    neutral: float | None = None
    """The shape value of the plain form (``slope``: 0), or None (``second``: absent)."""
    tries: tuple[float, ...] = ()


@dataclass(frozen=True)
class GyroTerms:
    """A deterministic gyro term's fit terms (module docstring)."""

    columns: Columns | None = None
    shape: str | None = None
    """Its nonlinear simulator parameter (scanned), or None."""
    grid: Callable[[float, float], np.ndarray] | None = None
    """(run duration s, bin s) → the scan grid of ``shape``."""
    scan: str = "grid"
    """``"grid"``: a grid scan then a bounded 1-D refinement within ×/÷1.5; ``"frequency"``:
    the columns are the sine and cosine at the period ``shape``, scanned all at once and
    refined within one frequency-resolution cell (the likelihood is multimodal in it)."""
    wider: WiderForm | None = None
    fixed: Mapping[str, float] = field(default_factory=dict)
    """Parameters the fit holds (e.g. ``t_ref_c``), reported with the fitted ones."""
    derive: Callable[[dict[str, float]], dict[str, float]] | None = None
    """Fitted values (coefficients and shape) → simulator parameters, where they differ."""
    temperature: TemperatureChange | None = None
    """A term that changes the temperature every other term sees instead of adding columns
    (``thermal_lag``): (case temperature on the 1 s grid, shape) → (temperature, rate)."""
