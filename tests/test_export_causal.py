"""C and JSON export of the causal drift model (issue 11's feature state machine: die lag,
rate, hysteresis, warm-up) on a 3-axis unit with a die lag and hysteresis: the generated
C, compiled with the system compiler and run reading by reading over a whole held-out
profile (115 200 samples × 3 axes), matches the Python causal output; the JSON's own
evaluator (gyrolab.export.model_json.causal_readings) matches the fitted model exactly."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from test_export import CC, KEYS, run_c
from test_pipeline import SMALL

from gyrolab.cli import main
from gyrolab.compensation.apply import StreamingCompensator
from gyrolab.compensation.causal_models import evaluate_causal
from gyrolab.compensation.evaluate import series_metrics
from gyrolab.compensation.model_dir import ModelDir
from gyrolab.export.model_json import export_spec
from gyrolab.numerics.averaging import BlockAverager
from gyrolab.profiles.profile import load_profile
from gyrolab.record.reader import read_recording
from gyrolab.sim.model import nominal_model
from gyrolab.sim.simulate import simulate_run

torch.set_num_threads(1)


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_causal_model_exported_to_c_and_json(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    m = nominal_model().with_effect("thermal_lag", tau_s=300.0).with_effect("hysteresis", h=3e-3)
    others = [m.with_effect("bias_poly", c1=-2e-4), m.with_effect("bias_poly", c1=1e-4)]
    for name, seed in (("cal", 3), ("val", 4)):
        simulate_run(
            tmp_path / f"{name}.mcap",
            load_profile("short"),
            m,
            rate_hz=40.0,
            seed=seed,
            axis_models=others,
            show_progress=False,
        )
    # the structured family (the one with the lag/rate/hysteresis terms) and GA-BP on the
    # causal features: both inner forms of the causal model
    monkeypatch.setattr(
        "gyrolab.compensation.commands.DEFAULT_CONFIG",
        replace(SMALL, causal_families=("structured",)),
    )
    model = tmp_path / "m"
    assert (
        main(
            [
                "compensate",
                str(tmp_path / "cal.mcap"),
                "--validate",
                str(tmp_path / "val.mcap"),
                "--out",
                str(model),
            ]
        )
        == 0
    )
    metrics = json.loads((model / "metrics.json").read_text())
    spec = export_spec(model)  # kind "chosen" = the causal model
    assert [a["model"]["kind"] for a in spec["axes"]] == ["causal"] * 3
    assert all(a["model"]["model"]["kind"] == "structured" for a in spec["axes"])
    out = tmp_path / "g.c"
    assert main(["export", str(model), "--format", "c", "--out", str(out)]) == 0
    assert "Causal axes: a state machine" in out.with_suffix(".h").read_text()
    rec = read_recording(tmp_path / "val.mcap")
    (tmp_path / "b").mkdir()
    ok, drift_c = run_c(tmp_path / "b", out, rec, 3)
    assert ok.all() and drift_c.shape[0] >= 100_000
    for a, (name, d) in enumerate(ModelDir(model).axes()):
        cm = d.load()
        assert abs(cm.causal.params.tau_s - 300.0) < 60.0  # the die lag is found
        ref = cm.causal.reading_drift(rec.pt100_t, rec.pt100_c)
        np.testing.assert_allclose(
            evaluate_causal(spec["axes"][a]["model"], rec.pt100_t, rec.pt100_c),
            ref,
            rtol=0,
            atol=1e-15,
        )
        py = StreamingCompensator(cm.causal, rec.pt100_t, rec.pt100_c).drift(rec.rate.t)
        err = np.abs(drift_c[:, a] - py)
        scale = np.abs(py).max()
        assert err.max() <= 1e-5 * scale
        big = np.abs(py) >= 0.1 * scale
        assert np.all(err[big] <= 1e-5 * np.abs(py[big]))
        s = rec.axis(a).rate
        acc = BlockAverager(SMALL.block_s)
        acc.add(s.t, s.values.astype(np.float32) - drift_c[:, a], s.period)
        got = series_metrics(acc.result()[1], SMALL.block_s)
        for k in KEYS:
            assert got[k] == pytest.approx(metrics["axes"][name]["causal"][k], rel=1e-4)
    # issue 23's terms (heating-only rate, R|R|, hysteresis amplitude across T), the
    # play's branch at power-on, its self-heating shift, its width's temperature
    # coefficient and the die's own self-heating, added to the fitted models:
    # the JSON evaluator equals the Python model, and the compiled C follows it to
    # float32 precision
    from gyrolab.compensation.causal_models import StructuredCausalModel
    from gyrolab.export.c_code import generate

    extra = {"kp": 2.0e-1, "k2": -40.0, "hT": 1.5e-3}
    for a, (_, d) in enumerate(ModelDir(model).axes()):
        cm = d.load().causal
        inner = replace(cm.model, **extra)
        shift = (0.0, 0.6, 1.2)[a]  # the play's self-heating shift δ (axis 0: none)
        kappa = (0.0, 0.0, 0.01)[a]  # its width's temperature coefficient (axis 2)
        die = (2.5, 0.0, 1.5)[a]  # the die's own self-heating δ_d (axes 0 and 2)
        params = replace(
            cm.params,
            start_branch=(1.0, -1.0, 0.5)[a],
            self_heating_c=shift,
            width_temp_per_c=kappa,
            die_heating_c=die,
        )
        sm = StructuredCausalModel(cm.family, params, inner)
        py = sm.reading_drift(rec.pt100_t, rec.pt100_c)
        assert sm.spec()["features"]["start_branch"] == params.start_branch
        assert sm.spec()["features"].get("self_heating_c", 0.0) == shift
        assert sm.spec()["features"].get("width_temp_per_c", 0.0) == kappa
        assert sm.spec()["features"].get("die_heating_c", 0.0) == die
        spec["axes"][a]["model"]["model"].update(extra)
        spec["axes"][a]["model"]["features"]["start_branch"] = params.start_branch
        if shift:
            spec["axes"][a]["model"]["features"]["self_heating_c"] = shift
        if kappa:
            spec["axes"][a]["model"]["features"]["width_temp_per_c"] = kappa
        if die:
            spec["axes"][a]["model"]["features"]["die_heating_c"] = die
        np.testing.assert_allclose(
            evaluate_causal(spec["axes"][a]["model"], rec.pt100_t, rec.pt100_c),
            py,
            rtol=0,
            atol=1e-15,
        )
    header, source = generate(spec, "g2.h")
    (tmp_path / "g2.h").write_text(header)
    (tmp_path / "g2.c").write_text(source)
    (tmp_path / "c").mkdir()
    ok, drift_c2 = run_c(tmp_path / "c", tmp_path / "g2.c", rec, 3)
    assert ok.all()
    for a in range(3):
        ref = evaluate_causal(spec["axes"][a]["model"], rec.pt100_t, rec.pt100_c)
        i = np.clip(np.searchsorted(rec.pt100_t, rec.rate.t, side="right") - 1, 0, None)
        py = ref[i]
        assert np.abs(drift_c2[:, a] - py).max() <= 1e-5 * np.abs(py).max()
