"""End-to-end checks of the discrepancy workflow on short simulated oven runs.

A 3.2 h staircase (25 → 60 → 20 → −20 → −40 °C) at 2 Hz keeps each run to seconds while
still moving the case temperature over most of the paper's range. The full battery (13 h
paper profile, every effect, ≥ 5 seeds) is benchmarks/discrepancy_battery.py.
"""

from __future__ import annotations

import json
import os

import pytest
import tomllib

from gyrolab.cli import main
from gyrolab.profiles.profile import Profile, Step
from gyrolab.sim.discrepancy.synth import simulate_bench
from gyrolab.sim.discrepancy.workflow import run_discrepancy
from gyrolab.sim.model import load_sim_model, nominal_model

STEPS = [(25.0, 1800.0), (60.0, 2400.0), (20.0, 2400.0), (-20.0, 2400.0), (-40.0, 2400.0)]
PROFILE = Profile("stairs", tuple(Step(sp, d) for sp, d in STEPS))
RATE = 2.0


def _run(seed: int, **effects: dict[str, float]):
    model = nominal_model()
    for name, params in effects.items():
        model = model.with_effect(name, **params)
    return run_discrepancy(simulate_bench(model, PROFILE, RATE, seed))


def test_nominal_data_names_nothing():
    res = _run(11)
    assert res.effects_found == []
    assert res.ambiguous == []
    assert res.gap_after == res.gap_before
    # the fitted nominal model reproduces the truth's parameters
    bp = res.model.get("bias_poly").params
    truth = nominal_model().get("bias_poly").params
    assert bp["c1"] == pytest.approx(truth["c1"], rel=0.05)
    assert res.model.get("arw").params["N"] == pytest.approx(0.0523, rel=0.1)


def test_hidden_thermal_rate_is_named_and_gap_shrinks():
    res = _run(12, thermal_rate={"k": 5e-3})
    assert res.effects_found[0] == "thermal_rate" or any("thermal_rate" in s for s in res.ambiguous)
    assert len(res.effects_found) == 1
    b, a = res.gap_before["lf_residual_rms_dps"], res.gap_after["lf_residual_rms_dps"]
    assert a < 0.5 * b
    if res.effects_found == ["thermal_rate"]:
        assert res.model.get("thermal_rate").params["k"] == pytest.approx(5e-3, rel=0.3)
    step = res.steps[0]
    assert step["added"] == res.effects_found[0]
    assert step["localize"]["worst_steps"], "localization names the worst steps"


def test_temperature_channel_effect_is_named():
    res = _run(13, rtd_self_heating={"offset_c": 0.3})
    assert res.effects_found == ["rtd_self_heating"]
    assert res.model.get("rtd_self_heating").params["offset_c"] == pytest.approx(0.3, abs=0.03)
    assert res.gap_after["temperature_rms_c"] < 0.5 * res.gap_before["temperature_rms_c"]


def test_sample_level_effects_are_named():
    res = _run(14, quantization={"q": 5e-3}, outliers={"rate_per_h": 60.0, "amplitude": 0.3})
    assert set(res.effects_found) == {"quantization", "outliers"}
    assert res.model.get("quantization").params["q"] == pytest.approx(5e-3, rel=0.02)
    assert res.model.get("outliers").params["amplitude"] == pytest.approx(0.3, rel=0.2)
    assert res.gap_after["lattice_tv_distance"] < 0.5 * res.gap_before["lattice_tv_distance"]
    assert res.gap_after["spike_log_ratio"] < 0.5 * res.gap_before["spike_log_ratio"]


def _profile_toml(path) -> str:
    lines = ['name = "stairs"']
    for sp, d in STEPS:
        lines += ["[[step]]", f"setpoint_c = {sp}", f"duration_s = {d}"]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def test_cli_reads_only_bench_channels_and_writes_contract(tmp_path, monkeypatch):
    prof = _profile_toml(tmp_path / "stairs.toml")
    run = tmp_path / "run.mcap"
    rc = main(
        [
            "simulate",
            "--out",
            str(run),
            "--profile",
            prof,
            "--rate",
            str(RATE),
            "--seed",
            "5",
            "--effect",
            "warmup:A=0.008,tau_s=600",
        ]
    )
    assert rc == 0

    # The workflow reads the bench record (the multimeter, for its PT100 test current) and
    # must never decode another metadata record (the simulator's provenance lives there).
    import mcap.reader

    import gyrolab.record.reader

    def forbidden(*a, **k):
        raise AssertionError("discrepancy read all of the recording's metadata")

    class Sealed:
        def __init__(self, m):
            self.name, self._m = m.name, m

        @property
        def metadata(self):
            if self.name != "bench":
                raise AssertionError(f"discrepancy decoded the {self.name!r} metadata record")
            return self._m.metadata

    monkeypatch.setattr(gyrolab.record.reader, "read_metadata", forbidden)
    for cls in (mcap.reader.SeekingReader, mcap.reader.NonSeekingReader):
        orig = cls.iter_metadata
        monkeypatch.setattr(
            cls, "iter_metadata", lambda self, orig=orig: (Sealed(m) for m in orig(self))
        )

    out = tmp_path / "dsc"
    assert main(["discrepancy", str(run), "--out", str(out)]) == 0
    doc = json.loads((out / "discrepancy.json").read_text())
    assert set(doc) >= {"effects_found", "ambiguous", "gap_before", "gap_after", "steps"}
    # the simulated 34401A's test current came from the bench record (1 mA, 1 kΩ range)
    rtd = next(c for c in doc["steps"][0]["candidates"] if c["effect"] == "rtd_self_heating")
    assert rtd["evidence"]["excitation_current_a"] == pytest.approx(1e-3)
    assert "warmup" in doc["effects_found"] or any("warmup" in s for s in doc["ambiguous"])
    for key in ("lf_residual_rms_dps", "allan_log_distance", "temperature_rms_c"):
        assert key in doc["gap_before"] and key in doc["gap_after"]
    assert doc["gap_after"]["lf_residual_rms_dps"] < 0.5 * doc["gap_before"]["lf_residual_rms_dps"]
    html = (out / "index.html").read_text()
    assert html.count("data:image/png;base64,") >= 4 and "<script" not in html
    m = load_sim_model(out / "model.toml")
    assert m.has("warmup")
    assert tomllib.loads((out / "model.toml").read_text())["format"] == "gyrolab-sim-model/1"
    monkeypatch.undo()

    # the updated model drives the simulator
    again = tmp_path / "again.mcap"
    rc = main(
        ["simulate", "--out", str(again), "--profile", "short", "--rate", "1"]
        + ["--model", str(out / "model.toml")]
    )
    assert rc == 0 and os.path.getsize(again) > 0

    # contract: no clobbering without --force; bad input is one line, exit 2
    assert main(["discrepancy", str(run), "--out", str(out)]) == 2
    assert main(["discrepancy", str(tmp_path / "nope.mcap"), "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_short_thermal_lag_is_reported_ambiguous_with_thermal_rate():
    """A die lag of 100 s is, on a step profile, a rate sensitivity k ≈ −τ·bias′(T)/60:
    the workflow adds the better of the two and reports both (docs/discrepancy.md)."""
    from gyrolab.profiles.profile import load_profile

    model = nominal_model().with_effect("thermal_lag", tau_s=100.0)
    res = run_discrepancy(simulate_bench(model, load_profile("paper"), 2.0, 7))
    assert res.effects_found == ["thermal_lag"]
    assert res.ambiguous == [["thermal_lag", "thermal_rate"]]
    assert res.steps[0]["ambiguous_with"] == ["thermal_rate"]


@pytest.mark.slow
def test_starting_model_without_noise_terms_gets_them_named():
    """White and flicker noise are vocabulary effects too (the 13 h run is needed to see
    the flicker floor clearly)."""
    from gyrolab.profiles.profile import load_profile
    from gyrolab.sim.model import SimModel, make_effect_spec

    bare = SimModel(effects=(make_effect_spec("bias_poly"),))
    data = simulate_bench(nominal_model(), load_profile("paper"), RATE, 15)
    res = run_discrepancy(data, bare)
    assert set(res.effects_found) == {"arw", "bias_instability"}
    assert res.model.get("arw").params["N"] == pytest.approx(0.0523, rel=0.1)
    assert res.gap_after["allan_log_distance"] < 0.5 * res.gap_before["allan_log_distance"]
