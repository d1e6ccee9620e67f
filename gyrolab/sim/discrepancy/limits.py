"""Detection limits: the smallest amplitude of each effect not in the model that this run
would have revealed (``discrepancy.json`` → ``detection_limits``).

A run that names nothing does not say "not there"; it says "smaller than this". For an
effect whose signature is linear in its amplitude ``a`` (columns ``x`` of the gyro
design, or a constant on the PT100 channel), the expected score when it is present is the
non-centrality of its whitened signature after projecting out the current model::

    λ(a) = a² ‖P⊥ L⁻¹ x‖² / σ²,     E[ΔBIC] ≈ λ + 1 − k ln n

(``L⁻¹`` the whitener of the noise covariance the candidates are judged with, ``σ²``
the innovation variance, k the candidate's parameters, n the bins). The limit is the
``a`` at which the expected score reaches the significance threshold (the median
detection point: at 2× the limit λ is four times larger, at ½× four times smaller).
Nonlinear shape parameters are held at a stated reference value (``at``);
``thermal_lag`` is linearized for τ ≪ τ_case
(``bias(T_d) ≈ bias(T_c) − τ·bias′(T_c)·dT_c/dt``). Stochastic and sample-level effects
use their own criteria: the Allan Δχ² for ``rate_random_walk`` (found by bisection on
the measured curve plus K²τ/3), the lattice rule for ``quantization``, the amplitude
rule for ``outliers``; ``rtd_self_heating`` its channel's ΔBIC (on the effective number
of readings) and RMS-gain rules. ``oven_overshoot`` has no single amplitude (a second-order
chamber differs from the first-order one in speed as well as in overshoot): its limit is
stated at the reference period without the first-order refit's absorption, an
optimistic bound.

Each channel computes its own effects' limits (:mod:`.channels`); the parameter and the
reference shape are what each effect declares (``candidate.limit``, ``limit_at``).
"""

from __future__ import annotations

from typing import Any

from gyrolab.sim.discrepancy.channels import gyro, noise, sample, temperature
from gyrolab.sim.discrepancy.fitting import Fitted, Fitter


def detection_limits(fx: Fitter, cur: Fitted) -> dict[str, dict[str, Any]]:
    """``detection_limits`` of ``discrepancy.json``: every vocabulary effect not in the
    model that states a limit, in its parameter's units."""
    out: dict[str, dict[str, Any]] = {}
    for channel in (gyro, noise, sample, temperature):
        out.update(channel.limits(fx, cur))
    return out
