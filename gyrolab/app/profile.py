"""``gyrolab profile design``: a short calibration profile designed for the chamber
(:mod:`gyrolab.compensation.profile_design`), written as a profile TOML that ``simulate``
and ``acquire`` run (docs/profiles.md)."""

from __future__ import annotations

import tomli_w

from gyrolab.app.options import ProfileDesignOptions
from gyrolab.app.prior import load_prior
from gyrolab.errors import InputError
from gyrolab.outputs import atomic_file


def profile(opts: ProfileDesignOptions) -> int:
    """The ``gyrolab profile design`` command: prints what the design chose."""
    from gyrolab.compensation.profile_design import design_profile
    from gyrolab.sim.model import load_sim_model

    thermal = None if opts.sim_model is None else load_sim_model(opts.sim_model).thermal
    prior = None if opts.prior is None else load_prior(opts.prior)
    try:
        prof, rec = design_profile(
            opts.hours,
            thermal=thermal,
            setpoint_min_c=opts.setpoint_min,
            setpoint_max_c=opts.setpoint_max,
            ambient_c=opts.ambient,
            prior=prior,
            name=opts.name,
        )
    except ValueError as e:
        raise InputError("--hours", str(e)) from None
    text = tomli_w.dumps(prof.to_dict())
    with atomic_file(opts.out, opts.force, inputs=[opts.sim_model]) as tmp:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
    for s in prof.steps:
        print(f"  {s.label:<16} {s.setpoint_c:6.1f} °C  {s.duration_s / 60:5.0f} min")
    lo, hi = rec["case_range_c"]
    print(
        f"profile {prof.name}: {prof.duration_s / 3600:.2f} h, simulated case "
        f"{lo:.1f}..{hi:.1f} °C, "
        f"expected drift sd {rec['drift_sd_deg_per_s']:.2g} deg/s over the range "
        f"({rec['candidates']} candidates) -> {opts.out}"
    )
    return 0
