"""The discrepancy workflow per axis with the temperature channels shared (issue 18,
point 6): effects of the bench reported once, effects of one axis on that axis."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gyrolab.profiles.profile import Profile, Step
from gyrolab.sim.discrepancy.axes_workflow import from_arrays_axes, run_discrepancy_axes
from gyrolab.sim.discrepancy.synth import simulate_bench
from gyrolab.sim.model import nominal_model

STEPS = [(25.0, 1800.0), (60.0, 2400.0), (20.0, 2400.0), (-20.0, 2400.0), (-40.0, 2400.0)]
PROFILE = Profile("stairs", tuple(Step(sp, d) for sp, d in STEPS))


def test_two_axes_share_the_bench_and_keep_their_own_terms():
    bench = nominal_model().with_effect("rtd_self_heating", offset_c=0.3)
    a0 = simulate_bench(bench.with_effect("thermal_rate", k=5e-3), PROFILE, 2.0, 51)
    a1 = simulate_bench(bench, PROFILE, 2.0, 52)
    # one chamber, one PT100: the second axis sees the first's temperature channels
    a1 = replace(a1, pt100_c=a0.pt100_c, oven_pv=a0.oven_pv, oven_sp=a0.oven_sp)
    res = run_discrepancy_axes([a0, a1])
    assert res.shared == ["rtd_self_heating"]
    assert res.by_axis[0] in (["thermal_rate"], ["thermal_lag"]) or "thermal_rate" in {
        e for s in res.axes[0].ambiguous for e in s
    }
    assert res.by_axis[1] == []
    doc = res.to_json()
    assert doc["effects_shared"] == ["rtd_self_heating"] and len(doc["axes"]) == 2
    # the thermal fit is the same object on both axes (done once)
    assert res.axes[0].final.case.offset_c == pytest.approx(res.axes[1].final.case.offset_c)


def test_axes_from_one_array_and_mismatched_channels_refused():
    t = np.arange(400.0)
    rates = np.random.default_rng(0).standard_normal((4000, 3)) * 1e-3
    axes = from_arrays_axes(0.0, 0.1, rates, t, np.full(400, 25.0), t, np.full(400, 25.0), t)
    assert len(axes) == 3
    np.testing.assert_allclose(axes[2].y[:3], rates[:, 2].reshape(-1, 10)[:3].mean(axis=1))
    bad = replace(axes[1], pt100_c=axes[1].pt100_c + 0.1)
    with pytest.raises(ValueError, match="axis 1"):
        run_discrepancy_axes([axes[0], bad])


def test_three_axis_recording_loads_one_bench_per_axis(tmp_path):
    """A recording in issue 15's multi-axis layout (``gyrolab simulate --axis-model``) is
    read as one BenchData per axis with the same temperature channels; the single-axis
    reader still refuses it with one line."""
    from gyrolab.cli import main
    from gyrolab.errors import InputError
    from gyrolab.sim.discrepancy.data import load_recording, load_recording_axes

    base = tmp_path / "x.toml"
    base.write_text('format = "gyrolab-sim-model/1"\n[[effect]]\nname = "bias_poly"\n')
    y = tmp_path / "y.toml"
    y.write_text('format = "gyrolab-sim-model/1"\n[[effect]]\nname = "bias_poly"\nc0 = -0.5\n')
    prof = tmp_path / "p.toml"
    prof.write_text('name = "tiny"\n[[step]]\nsetpoint_c = 30.0\nduration_s = 30.0\n')
    three = tmp_path / "three.mcap"
    args = ["simulate", "--profile", str(prof), "--model", str(base), "--rate", "20"]
    assert main([*args, "--axis-model", str(y), "--axis-model", str(y), "--out", str(three)]) == 0
    axes = load_recording_axes(three)
    assert len(axes) == 3
    for a in axes[1:]:
        np.testing.assert_array_equal(a.pt100_c, axes[0].pt100_c)
        np.testing.assert_array_equal(a.oven_pv, axes[0].oven_pv)
    assert np.mean(axes[1].y) == pytest.approx(np.mean(axes[0].y) - 0.52, abs=0.05)
    with pytest.raises(InputError, match="3-axis"):
        load_recording(three)


def test_cli_on_a_two_axis_recording_writes_the_axes_layout(tmp_path):
    """``gyrolab discrepancy`` on a 2-axis recording: shared effects once in
    discrepancy.json, one model (readable by ``load_sim_model``) and one report per axis."""
    import json

    from gyrolab.cli import main
    from gyrolab.sim.model import load_sim_model

    base = tmp_path / "x.toml"
    y = tmp_path / "y.toml"
    bench = nominal_model().with_effect("rtd_self_heating")
    base.write_text(bench.to_toml())
    y.write_text(bench.with_effect("thermal_rate", k=5e-3).to_toml())
    prof = tmp_path / "p.toml"
    prof.write_text(
        'name = "short"\n'
        + "".join(
            f"[[step]]\nsetpoint_c = {sp}\nduration_s = {d}\n"
            for sp, d in [(25.0, 1200.0), (60.0, 2400.0), (0.0, 2400.0)]
        )
    )
    run = tmp_path / "two.mcap"
    args = ["simulate", "--profile", str(prof), "--model", str(base), "--rate", "2"]
    assert main([*args, "--axis-model", str(y), "--seed", "7", "--out", str(run)]) == 0
    out = tmp_path / "d"
    assert main(["discrepancy", str(run), "--out", str(out)]) == 0
    doc = json.loads((out / "discrepancy.json").read_text())
    assert len(doc["axes"]) == 2 and "rtd_self_heating" in doc["effects_shared"]
    assert "rtd_self_heating" not in doc["effects_by_axis"][1]
    assert doc["axes"][0]["chamber_cooling"]["form"] == "knee"  # the simulator's chamber
    for k in range(2):
        m = load_sim_model(out / f"model_axis{k}.toml")
        assert "rtd_self_heating" in [e.name for e in m.effects]
        assert (out / f"index_axis{k}.html").read_text().startswith("<")
    assert "index_axis1.html" in (out / "index.html").read_text()
