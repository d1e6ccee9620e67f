"""Sample-level candidates, read off the full-rate stream independently of every fit:
``outliers`` (the tail of the centred second difference) and ``quantization`` (the output's
lattice). Reported on the ``noise`` channel of ``discrepancy.json``.
"""

from __future__ import annotations

from typing import Any

from gyrolab.sim.discrepancy import noise_fit as nf
from gyrolab.sim.discrepancy.catalogue import limit_entry
from gyrolab.sim.discrepancy.fitting import Fitted, Fitter
from gyrolab.sim.discrepancy.scored import Scored

REPORTED_AS = "noise"


def _outliers(fx: Fitter) -> Scored:
    d = fx.d
    o = nf.fit_outliers(d, fx.coarse_lattice())
    obs, gauss = nf.spike_counts(d)
    return Scored(
        "outliers",
        REPORTED_AS,
        float(o.lr),
        bool(o.lr > nf.OUTLIER_LR and o.amplitude > 4.0 * o.sigma),
        {
            "likelihood_ratio": o.lr,
            "exceedances_5sigma": obs,
            "gaussian_expectation_5sigma": gauss,
            **o.sim_params(d.hr.dt),
        },
    )


def _quantization(fx: Fitter) -> Scored:
    hr = fx.d.hr
    sig = fx.lattice_significant()
    return Scored(
        "quantization",
        REPORTED_AS,
        float(1e3 * hr.lattice_fraction if sig else 0.0),
        bool(sig),
        {
            "lattice_step_dps": hr.lattice_step,
            "adc_lsb_dps": fx.lsb,
            "white_sigma_dps": hr.white_sigma,
            "fraction_on_lattice": hr.lattice_fraction,
        },
    )


SCORERS = {"outliers": _outliers, "quantization": _quantization}


def score(fx: Fitter, cur: Fitted) -> list[Scored]:
    """Every sample-level candidate the model lacks."""
    return [s(fx) for name, s in SCORERS.items() if not cur.structure.has(name)]


def limits(fx: Fitter, cur: Fitted) -> dict[str, dict[str, Any]]:
    """The lattice rule for ``quantization`` (max of 3 ADC LSB and 0.1 σ of the sample
    noise) and the amplitude rule for ``outliers`` (4 σ of the second difference: the
    binding rule at any rate the tail test sees — a few spikes beyond 4 σ_e already give
    a likelihood ratio ≫ 40 on a clean tail)."""
    hr = fx.d.hr
    out: dict[str, dict[str, Any]] = {}
    if not cur.structure.has("quantization"):
        q = max(nf.LATTICE_RATIO * fx.lsb, nf.LATTICE_NOISE_RATIO * hr.white_sigma)
        out["quantization"] = limit_entry("quantization", q, "lattice rule (ADC LSB, sample noise)")
    if not cur.structure.has("outliers"):
        out["outliers"] = limit_entry(
            "outliers", 4.0 * hr.e_sigma, "amplitude rule (4 σ of the second difference)"
        )
    return out


def params(fx: Fitter, f: Fitted) -> dict[str, dict[str, float]]:
    """Fitted simulator parameters of the sample-level effects ``f`` has."""
    out: dict[str, dict[str, float]] = {}
    if f.outliers is not None:
        out["outliers"] = f.outliers.sim_params(fx.d.hr.dt)
    if f.structure.has("quantization") and fx.d.hr.lattice_step > 0:
        out["quantization"] = {"q": fx.d.hr.lattice_step}
    return out
