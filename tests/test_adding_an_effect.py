"""Adding an effect to the vocabulary touches one code file: the effect's class, with its
physics and its discrepancy candidate side by side, in ``gyrolab/sim/effects.py``
(docs/sim-model.md, "Adding an effect"; docs/discrepancy.md, "The candidate catalogue").

The ``gradient_stress`` effect below exists in this test module alone: it is registered,
simulated by the simulator through ``SIM_MODEL.toml``, and named by ``gyrolab
discrepancy``'s workflow — its fit terms, score, detection limit and ``model.toml`` come
from the class's own declaration; nothing in ``gyrolab/`` knows its name.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

import gyrolab
from gyrolab.profiles.profile import Profile, Step
from gyrolab.sim.candidate import GAP_LF, Candidate, GyroTerms
from gyrolab.sim.discrepancy.synth import simulate_bench
from gyrolab.sim.discrepancy.workflow import run_discrepancy
from gyrolab.sim.effects import EFFECTS, BlockContext, Effect, Param, register
from gyrolab.sim.model import SimModel, nominal_model
from gyrolab.sim.thermal import lowpass

FILES_NEEDED = ("gyrolab/sim/effects.py", "tests/test_adding_an_effect.py")
"""What adding an effect takes: its class in the vocabulary's module, and its test (here
both are this file)."""


# ---------------------------------------------------- the effect (its class, in full)
class GradientStress(Effect):
    """Thermal-gradient stress that relaxes: the package strains with the *magnitude* of
    the temperature rate and creeps back with time constant τ,
    ``τ dσ/dt = |dT/dt| − σ`` (°C/min), ``bias += g·σ`` (°/s)."""

    name = "gradient_stress"
    PARAMS = {
        "g": Param(5e-3, "deg/s per degC/min", "stress sensitivity"),
        "tau_s": Param(600.0, "s", "relaxation time constant", "pos"),
    }
    candidate = Candidate("gyro", GAP_LF, "g", {"tau_s": 600.0})
    terms = GyroTerms(
        columns=lambda b, s: [("g", np.interp(b.t, b.grid_t, _stress(b.grid_dtemp_c_per_s, s)))],
        shape="tau_s",
        grid=lambda duration_s, bin_s: np.geomspace(60.0, max(600.0, duration_s / 4), 24),
    )

    def __init__(self, params, rng, rate_hz) -> None:
        super().__init__(params, rng, rate_hz)
        self._sigma = 0.0

    def rate(self, ctx: BlockContext) -> np.ndarray:
        if not ctx.n:
            return np.zeros(0)
        a = 1.0 - math.exp(-ctx.dt / self.p["tau_s"])
        u = 60.0 * np.abs(ctx.dtemp_c_per_s)
        sigma = lowpass(u, a, self._sigma)
        self._sigma = float(sigma[-1] + a * (u[-1] - sigma[-1]))
        return self.p["g"] * sigma


def _stress(dtemp_grid: np.ndarray, s: dict[str, float]) -> np.ndarray:
    """σ on the 1 s grid (°C/min) at relaxation time ``s["tau_s"]``."""
    return lowpass(60.0 * np.abs(dtemp_grid), 1.0 - math.exp(-1.0 / s["tau_s"]), 0.0)


# ------------------------------------------------------------------------ the test
STEPS = [(25.0, 1800.0), (60.0, 2400.0), (20.0, 2400.0), (-20.0, 2400.0), (-40.0, 2400.0)]
PROFILE = Profile("stairs", tuple(Step(sp, d) for sp, d in STEPS))


@pytest.fixture
def gradient_stress() -> Iterator[type[Effect]]:
    register(GradientStress)
    try:
        yield GradientStress
    finally:
        EFFECTS.pop(GradientStress.name)


def test_an_effect_defined_here_alone_is_simulated_and_named(gradient_stress):
    # nothing in the package knows the effect: this file is all it took
    root = Path(gyrolab.__file__).parent
    assert not [p for p in root.rglob("*.py") if gradient_stress.name in p.read_text()]
    assert [f for f in FILES_NEEDED if f.startswith("gyrolab/")] == ["gyrolab/sim/effects.py"]

    truth = nominal_model().with_effect("gradient_stress", g=8e-3, tau_s=600.0)
    assert SimModel.from_dict(truth.to_dict()) == truth  # SIM_MODEL.toml knows it
    res = run_discrepancy(simulate_bench(truth, PROFILE, 2.0, 7))
    assert res.effects_found == ["gradient_stress"]
    assert res.ambiguous == []
    p = res.model.get("gradient_stress").params
    assert p["g"] == pytest.approx(8e-3, rel=0.2)
    assert p["tau_s"] == pytest.approx(600.0, rel=0.5)
    step = res.steps[0]
    assert step["gap_metric"] == GAP_LF
    b, a = step["gap_metric_before_after"]
    assert a < 0.5 * b

    # and on a nominal run it is a candidate with a detection limit, not a name
    nom = run_discrepancy(simulate_bench(nominal_model(), PROFILE, 2.0, 8))
    assert nom.effects_found == []
    lim = nom.detection_limits["gradient_stress"]
    assert lim["parameter"] == "g" and lim["at"] == {"tau_s": 600.0}
    assert 0 < lim["limit"] < 8e-3
