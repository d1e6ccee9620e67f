"""Three axes end to end and `gyrolab export`: simulate a 3-axis unit -> compensate ->
export px4/ardupilot/c/json/kalibr -> read each back by its own rules (PX4 .params parsed,
ArduPilot .parm parsed, the C compiled with the system compiler) -> apply it in Python to
the held-out run -> the residual metrics.json states for that form."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from test_pipeline import SMALL

from gyrolab.cli import main
from gyrolab.compensation.apply import StreamingCompensator, streaming_compensate
from gyrolab.compensation.evaluate import series_metrics
from gyrolab.compensation.firmware import DEG2RAD
from gyrolab.compensation.model_dir import ModelDir, load_model
from gyrolab.compensation.prepare import causal_temperature
from gyrolab.compensation.regressors import evaluate_inputs
from gyrolab.export.model_json import export_spec
from gyrolab.export.params import (
    ardupilot_correction,
    px4_correction,
    read_ardupilot_parm,
    read_px4_params,
)
from gyrolab.numerics.averaging import BlockAverager
from gyrolab.profiles.profile import load_profile
from gyrolab.record.reader import read_recording
from gyrolab.sim.model import nominal_model
from gyrolab.sim.simulate import simulate_run

torch.set_num_threads(1)
RATE_HZ = 40.0  # 2880 s short profile -> 115 200 samples per axis (>= 100 000 for the C)
CC = shutil.which("cc") or shutil.which("gcc")


def axis_models():
    m = nominal_model()
    return m, [
        m.with_effect("bias_poly", c0=-0.01, c1=-2e-4, c2=5e-6, c3=2e-8),
        m.with_effect("bias_poly", c0=0.005, c1=1e-4, c2=-3e-6),
    ]


@pytest.fixture(scope="module")
def unit(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("unit3")
    mx, others = axis_models()
    prof = load_profile("short")
    for name, seed in (("cal", 3), ("val", 4)):
        simulate_run(
            d / f"{name}.mcap",
            prof,
            mx,
            rate_hz=RATE_HZ,
            seed=seed,
            axis_models=others,
            show_progress=False,
        )
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", SMALL)
        rc = main(
            [
                "compensate",
                str(d / "cal.mcap"),
                "--validate",
                str(d / "val.mcap"),
                "--out",
                str(d / "model"),
            ]
        )
    assert rc == 0
    return {"dir": d, "cal": d / "cal.mcap", "val": d / "val.mcap", "model": d / "model"}


def held_out(unit: dict[str, Path]):
    rec = read_recording(unit["val"])
    return rec, json.loads((unit["model"] / "metrics.json").read_text())


def residual_metrics(rec, k: int, offset_dps) -> dict[str, float]:
    """Causal raw - offset(T(t-)) on axis k, averaged like the pipeline, scored by it."""
    s = rec.axis(k).rate
    T = causal_temperature(s.t, rec.pt100_t, rec.pt100_c)
    acc = BlockAverager(SMALL.block_s)
    acc.add(s.t, s.values - offset_dps(T), s.period)
    return series_metrics(acc.result()[1], SMALL.block_s)


KEYS = ("rms_deg_per_s", "drift_pp_deg_per_s", "bias_stability_deg_per_h")


# ------------------------------------------------------------------ three axes


def test_three_axis_recording_and_model_dir(unit: dict[str, Path]) -> None:
    rec = read_recording(unit["val"])
    assert rec.axes == 3 and rec.rate.values.shape == (115200, 3)
    assert rec.adc.values.shape == (115200, 3)
    assert rec.run["axes"] == 3 and rec.bench["adc"]["axes"] == 3
    # axis x is exactly the single-axis unit of the same seed; y, z are other units
    assert not np.allclose(rec.rate.values[:, 0], rec.rate.values[:, 1])
    head = json.loads((unit["model"] / "model.json").read_text())
    assert head["axes"] == ["x", "y", "z"]
    assert [p.path.name for _a, p in ModelDir(unit["model"]).axes()] == [
        "axis_x",
        "axis_y",
        "axis_z",
    ]
    m = json.loads((unit["model"] / "metrics.json").read_text())
    assert m["held_out"] is True and set(m["axes"]) == {"x", "y", "z"}
    for a in "xyz":
        am = m["axes"][a]
        assert am["held_out"] is True and am["calibration"]["held_out"] is False
        fw = am["firmware_poly3"]
        # the chosen causal output: issue 11's causal model where fitted, else GA-BP on T
        chosen = "causal" if "causal" in am else "compensated_streaming"
        assert fw["vs_chosen"]["chosen"] == chosen
        for k in KEYS:
            assert fw["vs_chosen"][f"{k}_ratio"] == pytest.approx(
                fw[k] / am[fw["vs_chosen"]["chosen"]][k]
            )
    # a multi-axis directory is refused by the single-axis loader with one clear line
    from gyrolab.errors import InputError

    with pytest.raises(InputError, match="3-axis model: give one axis's directory"):
        load_model(str(unit["model"]))


def test_apply_three_axes(unit: dict[str, Path]) -> None:
    out = unit["dir"] / "applied.mcap"
    assert main(["apply", str(unit["model"]), str(unit["val"]), "--out", str(out)]) == 0
    got = read_recording(out)
    rec = read_recording(unit["val"])
    assert got.rate.values.shape == rec.rate.values.shape == (115200, 3)
    assert got.metadata["compensation"]["axes"] == 3
    for a, (_n, d) in enumerate(ModelDir(unit["model"]).axes()):
        # the headline: the causal model, as on one axis and in the C export (issue 24)
        want = streaming_compensate(
            d.load(), rec.rate.t, rec.rate.values[:, a], rec.pt100_t, rec.pt100_c, "chosen"
        )
        np.testing.assert_array_equal(got.rate.values[:, a], want.astype(np.float32))


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_apply_three_axes_runs_the_model_the_c_export_runs(unit: dict[str, Path]) -> None:
    """Issue 24: on three axes as on one (test_model_dir), /gyro/rate of `apply` is raw −
    the drift the C export (default kind) computes, within float32."""
    out = unit["dir"] / "applied_c.mcap"
    assert main(["apply", str(unit["model"]), str(unit["val"]), "--out", str(out)]) == 0
    c = unit["dir"] / "chosen.c"
    assert main(["export", str(unit["model"]), "--format", "c", "--out", str(c)]) == 0
    rec = read_recording(unit["val"])
    tmp = unit["dir"] / "cbuild_apply"
    tmp.mkdir()
    ok, drift_c = run_c(tmp, c, rec, 3)
    assert ok.all()
    raw = rec.rate.values.astype(float)
    d_apply = raw - read_recording(out).rate.values.astype(float)
    ulp = 2 * np.spacing(np.float32(np.abs(raw).max()))
    for a in range(3):
        err = np.abs(d_apply[:, a] - drift_c[:, a])
        assert err.max() <= 1e-5 * np.abs(d_apply[:, a]).max() + ulp, a


def test_three_axis_report_shows_every_axis(unit: dict[str, Path]) -> None:
    from gyrolab.report.axes_report import build_axes_report

    doc, metrics = build_axes_report(unit["val"], unit["model"], 3, lambda _s: None)
    assert set(metrics["axes"]) == {"x", "y", "z"}
    titles = [s.title for s in doc.sections]
    for a in "xyz":
        assert any(t.startswith(f"Axis {a} — ") for t in titles)
        assert "firmware_poly3" in metrics["axes"][a]
    assert len({s.key for s in doc.sections}) == len(doc.sections)
    # the up/down hysteresis width of every axis's causal model (issue 30): its own table
    # in the axis's headline, and one overview row per axis after the run section
    with_causal = [a for a in "xyz" if "causal" in metrics["axes"][a]]
    assert with_causal
    assert doc.sections[1].key == "hysteresis-axes"
    overview = doc.sections[1].blocks[0]
    assert [r[0] for r in overview.rows] == with_causal
    keys = {t.key for t in doc.tables()}
    for a, row in zip(with_causal, overview.rows, strict=True):
        am = metrics["axes"][a]
        w = am["causal_hysteresis_width"]
        assert f"{a}-causal-hysteresis" in keys
        assert row[3] == f"{w['at_mid_deg_per_h']:+.3g}"
        st = am["causal_model"].get("structured")
        if st is not None:  # heating - cooling = 2 h (+ 2 hT v) on the structured model
            assert w["at_mid_deg_per_h"] == pytest.approx(7200.0 * st["h"], abs=1e-9)
            assert w["at_high_deg_per_h"] == pytest.approx(
                7200.0 * (st["h"] + st.get("hT", 0.0)), abs=1e-9
            )


# ------------------------------------------------------------------------ PX4


def test_px4_params_golden_and_round_trip(unit: dict[str, Path]) -> None:
    out = unit["dir"] / "tc.params"
    assert (
        main(
            [
                "export",
                str(unit["model"]),
                "--format",
                "px4",
                "--out",
                str(out),
                "--instance",
                "1",
                "--device-id",
                "2490378",
            ]
        )
        == 0
    )
    text = out.read_text()
    lines = text.splitlines()
    assert lines[0] == "# Sensor thermal compensation parameters"
    assert "# Vehicle-Id Component-Id Name Value Type" in lines
    body = [ln for ln in lines if not ln.startswith("#")]
    assert all(len(ln.split("\t")) == 5 for ln in body)
    p = read_px4_params(text)
    names = {"TC_G_ENABLE", "TC_G1_ID", "TC_G1_TMIN", "TC_G1_TMAX", "TC_G1_TREF"} | {
        f"TC_G1_X{k}_{a}" for k in range(4) for a in range(3)
    }
    assert set(p) == names and [ln.split("\t")[2] for ln in body] == sorted(names)
    assert all(v[0] == 1 and v[1] == 1 for v in p.values())
    assert p["TC_G1_ID"][2:] == (2490378, 6) and p["TC_G_ENABLE"][2:] == (1, 6)
    assert {p[n][3] for n in names - {"TC_G1_ID", "TC_G_ENABLE"}} == {9}
    polys = [d.require_firmware() for _a, d in ModelDir(unit["model"]).axes()]
    lo, hi = min(q.t_min for q in polys), max(q.t_max for q in polys)
    assert p["TC_G1_TMIN"][2] == np.float32(lo) and p["TC_G1_TMAX"][2] == np.float32(hi)
    assert p["TC_G1_TREF"][2] == np.float32(0.5 * (lo + hi))
    for a, q in enumerate(polys):  # rad/s about TREF, order k = X{k}
        c = q.recentred(0.5 * (lo + hi))
        for k in range(4):
            assert p[f"TC_G1_X{k}_{a}"][2] == np.float32(c[k] * DEG2RAD)
    # the firmware's own arithmetic on the held-out run -> the residual metrics.json states
    rec, m = held_out(unit)
    corr = px4_correction(text, 1)
    for a, name in enumerate("xyz"):
        got = residual_metrics(rec, a, lambda T, a=a: corr.offset_dps(a, T))
        want = m["axes"][name]["firmware_poly3"]
        for k in KEYS:
            assert got[k] == pytest.approx(want[k], rel=1e-4)


# ------------------------------------------------------------------- ArduPilot


def test_ardupilot_parm_golden_and_round_trip(unit: dict[str, Path]) -> None:
    out = unit["dir"] / "tcal.parm"
    assert (
        main(
            [
                "export",
                str(unit["model"]),
                "--format",
                "ardupilot",
                "--out",
                str(out),
                "--instance",
                "0",
            ]
        )
        == 0
    )
    text = out.read_text()
    body = [ln for ln in text.splitlines() if not ln.startswith("#")]
    assert all(len(ln.split(" ")) == 2 for ln in body)
    p = read_ardupilot_parm(text)
    names = {"INS_TCAL1_ENABLE", "INS_TCAL1_TMIN", "INS_TCAL1_TMAX", "INS_GYR1_CALTEMP"}
    names |= {f"INS_TCAL1_GYR{k}_{a}" for k in (1, 2, 3) for a in "XYZ"}
    names |= {f"INS_GYROFFS_{a}" for a in "XYZ"}
    assert set(p) == names and p["INS_TCAL1_ENABLE"] == 1
    polys = [d.require_firmware() for _a, d in ModelDir(unit["model"]).axes()]
    lo, hi = min(q.t_min for q in polys), max(q.t_max for q in polys)
    assert p["INS_GYR1_CALTEMP"] == np.float32(min(max(35.0, lo), hi))
    for a, q in zip("XYZ", polys, strict=True):  # x = T - 35, no constant, x 1e6, rad/s
        c = q.recentred(35.0)
        for k in (1, 2, 3):
            assert p[f"INS_TCAL1_GYR{k}_{a}"] == np.float32(c[k] * DEG2RAD * 1e6)
    rec, m = held_out(unit)
    corr = ardupilot_correction(text, 0)
    for a, name in enumerate("xyz"):
        got = residual_metrics(rec, a, lambda T, a=a: corr.offset_dps(a, T))
        want = m["axes"][name]["firmware_poly3"]
        for k in KEYS:
            assert got[k] == pytest.approx(want[k], rel=1e-4)


# ------------------------------------------------------------------------- JSON


def test_json_schema_is_the_fitted_model(unit: dict[str, Path]) -> None:
    out = unit["dir"] / "model.export.json"
    # the GA-BP network (the chosen default is the causal model: test_export_causal.py)
    argv = ["export", str(unit["model"]), "--format", "json", "--kind", "gabp", "--out", str(out)]
    assert main(argv) == 0
    doc = json.loads(out.read_text())
    assert doc["format"] == "gyrolab.export" and doc["format_version"] == 1
    assert doc["units"] == {"rate": "deg/s", "temperature": "degC", "time": "s"}
    assert [a["axis"] for a in doc["axes"]] == ["x", "y", "z"]
    T = np.linspace(0.0, 60.0, 241)[:, None]  # inside and far outside the calibrated range
    for ax, (_a, d) in zip(doc["axes"], ModelDir(unit["model"]).axes(), strict=True):
        mdl = ax["model"]
        assert mdl["kind"] == "mlp" and mdl["inputs"] == ["T"]
        assert np.asarray(mdl["W"]).shape == (1, mdl["hidden"])
        want = d.load().drift.predict(T)
        np.testing.assert_allclose(evaluate_inputs(mdl, T), want, rtol=1e-12, atol=1e-15)
    for kind in ("poly", "poly3"):
        for ax, (_a, d) in zip(
            export_spec(unit["model"], kind)["axes"], ModelDir(unit["model"]).axes(), strict=True
        ):
            m = d.load()
            want = (
                m.baselines["poly"].predict(T)
                if kind == "poly"
                else d.require_firmware().predict(T[:, 0])
            )
            np.testing.assert_allclose(evaluate_inputs(ax["model"], T), want, rtol=1e-12)


# ---------------------------------------------------------------------------- C

DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "comp.h"
/* in: nr, ns; nr x (double t, float T); ns x (double t, float raw[AXES]) -> out: ns x
   (int ok, float drift[AXES]). Readings are pushed before the samples at or after them. */
int main(int argc, char **argv)
{
    if (argc < 3) return 2;
    FILE *f = fopen(argv[1], "rb"), *g = fopen(argv[2], "wb");
    long nr, ns;
    if (!f || !g || fread(&nr, 8, 1, f) != 1 || fread(&ns, 8, 1, f) != 1) return 1;
    double *rt = malloc(nr * sizeof(double)); float *rT = malloc(nr * sizeof(float));
    if (fread(rt, 8, nr, f) != (size_t)nr || fread(rT, 4, nr, f) != (size_t)nr) return 1;
    gyrolab_comp_state st;
    gyrolab_comp_init(&st);
    long r = 0;
    for (long i = 0; i < ns; ++i) {
        double t; float raw[GYROLAB_COMP_AXES], out[GYROLAB_COMP_AXES];
        if (fread(&t, 8, 1, f) != 1 || fread(raw, 4, GYROLAB_COMP_AXES, f) != GYROLAB_COMP_AXES)
            return 1;
        while (r < nr && rt[r] <= t) { gyrolab_comp_temperature(&st, rt[r], rT[r]); ++r; }
        int ok = gyrolab_comp_apply(&st, t, raw, out);
        fwrite(&ok, 4, 1, g);
        for (int a = 0; a < GYROLAB_COMP_AXES; ++a) out[a] = raw[a] - out[a];  /* drift */
        fwrite(out, 4, GYROLAB_COMP_AXES, g);
    }
    fclose(f); fclose(g);
    return 0;
}
"""


def run_c(tmp: Path, c_file: Path, rec, axes: int) -> tuple[np.ndarray, np.ndarray]:
    """Compile ``c_file`` with the driver (-std=c99 -Wall -Wextra -pedantic -Werror) and run
    it over ``rec``'s PT100 readings and gyro samples; returns (ok, drift (n, axes))."""
    (tmp / "comp.h").write_text(c_file.with_suffix(".h").read_text())
    (tmp / "comp.c").write_text(c_file.read_text().replace(f'"{c_file.stem}.h"', '"comp.h"'))
    (tmp / "driver.c").write_text(DRIVER)
    exe = tmp / "comp"
    subprocess.run(
        [
            CC,
            "-std=c99",
            "-O2",
            "-Wall",
            "-Wextra",
            "-pedantic",
            "-Werror",
            "-o",
            str(exe),
            str(tmp / "driver.c"),
            str(tmp / "comp.c"),
            "-lm",
        ],
        check=True,
    )
    s = rec.rate
    vals = s.values.reshape(s.t.size, -1)[:, :axes]
    rows = np.zeros(s.t.size, dtype=[("t", "<f8"), ("raw", "<f4", (axes,))])
    rows["t"], rows["raw"] = s.t, vals
    with open(tmp / "in.bin", "wb") as fh:
        np.array([rec.pt100_t.size, s.t.size], dtype="<i8").tofile(fh)
        rec.pt100_t.astype("<f8").tofile(fh)
        rec.pt100_c.astype("<f4").tofile(fh)
        rows.tofile(fh)
    subprocess.run([str(exe), str(tmp / "in.bin"), str(tmp / "out.bin")], check=True)
    out = np.fromfile(tmp / "out.bin", dtype=[("ok", "<i4"), ("d", "<f4", (axes,))])
    return out["ok"], out["d"].astype(float)


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_c_export_matches_python_over_a_whole_profile(unit: dict[str, Path]) -> None:
    out = unit["dir"] / "gyro_comp.c"
    argv = ["export", str(unit["model"]), "--format", "c", "--kind", "gabp", "--out", str(out)]
    assert main(argv) == 0
    header = out.with_suffix(".h").read_text()
    assert "#define GYROLAB_COMP_AXES 3" in header and "clipped to the calibrated range" in header
    rec, m = held_out(unit)
    tmp = unit["dir"] / "cbuild"
    tmp.mkdir()
    ok, drift_c = run_c(tmp, out, rec, 3)
    assert ok.all() and drift_c.shape[0] >= 100_000
    for a, (name, d) in enumerate(ModelDir(unit["model"]).axes()):
        model = d.load()
        py = StreamingCompensator(model.drift, rec.pt100_t, rec.pt100_c).drift(rec.rate.t)
        err = np.abs(drift_c[:, a] - py)
        scale = np.abs(py).max()
        assert err.max() <= 1e-5 * scale  # relative to the drift's full scale
        # and sample by sample away from zero crossings, where float32's y_std*y + y_mean
        # cancels (on the 13 h paper run: 4.9e-5 at 1 % of full scale, 6.3e-6 at 10 %)
        big = np.abs(py) >= 0.1 * scale
        assert np.all(err[big] <= 1e-5 * np.abs(py[big]))
        # the C output averaged as the pipeline does: the causal metrics of metrics.json
        got = residual_metrics(rec, a, lambda T, a=a: 0.0)  # raw, for the raw check below
        assert got["rms_deg_per_s"] == pytest.approx(
            m["axes"][name]["raw"]["rms_deg_per_s"], rel=1e-9
        )
        s = rec.axis(a).rate
        acc = BlockAverager(SMALL.block_s)
        acc.add(s.t, s.values.astype(np.float32) - drift_c[:, a], s.period)
        comp = series_metrics(acc.result()[1], SMALL.block_s)
        for k in KEYS:
            assert comp[k] == pytest.approx(m["axes"][name]["compensated_streaming"][k], rel=1e-4)


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
@pytest.mark.parametrize("kind", ["poly", "poly3"])
def test_c_export_other_kinds(unit: dict[str, Path], kind: str) -> None:
    out = unit["dir"] / f"k_{kind}.c"
    assert (
        main(["export", str(unit["model"]), "--format", "c", "--kind", kind, "--out", str(out)])
        == 0
    )
    rec = read_recording(unit["val"])
    tmp = unit["dir"] / f"cbuild_{kind}"
    tmp.mkdir()
    ok, drift_c = run_c(tmp, out, rec, 3)
    spec = export_spec(unit["model"], kind)
    T = causal_temperature(rec.rate.t, rec.pt100_t, rec.pt100_c)
    for a, ax in enumerate(spec["axes"]):
        py = evaluate_inputs(ax["model"], T[:, None])
        assert np.abs(drift_c[:, a] - py).max() <= 1e-5 * np.abs(py).max()


# ----------------------------------------------------------------------- kalibr


def test_kalibr_imu_yaml_from_allan(unit: dict[str, Path]) -> None:
    from gyrolab.numerics.allan import allan_deviation
    from gyrolab.numerics.noise_terms import noise_terms

    out = unit["dir"] / "imu.yaml"
    assert (
        main(
            [
                "export",
                str(unit["model"]),
                "--format",
                "kalibr",
                "--run",
                str(unit["val"]),
                "--out",
                str(out),
                "--rostopic",
                "/imu0",
            ]
        )
        == 0
    )
    y = yaml.safe_load(out.read_text())
    assert set(y) == {"gyroscope_noise_density", "gyroscope_random_walk", "update_rate", "rostopic"}
    assert y["update_rate"] == RATE_HZ and y["rostopic"] == "/imu0"
    rec = read_recording(unit["val"])
    nds = []
    for a, (_n, d) in enumerate(ModelDir(unit["model"]).axes()):
        s = rec.axis(a).rate
        comp = streaming_compensate(d.load(), s.t, s.values, rec.pt100_t, rec.pt100_c, "chosen")
        nds.append(noise_terms(allan_deviation(comp, RATE_HZ, confidence=None)).N)
    # continuous-time density = Allan N (deg/s * sqrt(s)) in rad/s/sqrt(Hz), largest axis
    assert y["gyroscope_noise_density"] == pytest.approx(max(nds) * math.pi / 180, rel=1e-6)
    # the simulated ARW is 0.0523 deg/sqrt(h): N = 0.0523/60 deg/sqrt(s)
    assert y["gyroscope_noise_density"] == pytest.approx(0.0523 / 60 * math.pi / 180, rel=0.5)
    assert y["gyroscope_random_walk"] > 0


def test_export_bad_input_writes_nothing(unit: dict[str, Path]) -> None:
    out = unit["dir"] / "nothing.params"
    assert main(["export", str(unit["model"]), "--format", "px4", "--out", str(out)]) == 2
    assert main(["export", str(unit["dir"]), "--format", "json", "--out", str(out)]) == 2
    assert main(["export", str(unit["model"]), "--format", "kalibr", "--out", str(out)]) == 2
    assert not out.exists()


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_c_export_with_dtdt_state(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A model on (T, dT/dt): the C keeps the readings of the dT/dt window in its ring
    buffer; over 100 800 samples it matches the Python streaming compensator."""
    from dataclasses import replace

    from test_pipeline import write_run

    cal = write_run(tmp_path / "cal.mcap", 1, fs=28.0, hours=1.0)
    monkeypatch.setattr(
        "gyrolab.compensation.commands.DEFAULT_CONFIG", replace(SMALL, use_dtdt=True)
    )
    assert main(["compensate", str(cal), "--out", str(tmp_path / "m")]) == 0
    out = tmp_path / "g.c"
    argv = ["export", str(tmp_path / "m"), "--format", "c", "--kind", "gabp", "--out", str(out)]
    assert main(argv) == 0
    assert "dT/dt = (T(t) - T(t - 300)) / 300" in out.with_suffix(".h").read_text()
    rec = read_recording(cal)
    (tmp_path / "b").mkdir()
    ok, drift_c = run_c(tmp_path / "b", out, rec, 1)
    assert ok.all() and drift_c.shape[0] >= 100_000
    model = load_model(str(tmp_path / "m"))
    assert model.config.use_dtdt and model.drift.regressor.n_in == 2
    py = StreamingCompensator(model.drift, rec.pt100_t, rec.pt100_c).drift(rec.rate.t)
    err = np.abs(drift_c[:, 0] - py)
    scale = np.abs(py).max()
    assert err.max() <= 1e-5 * scale
    big = np.abs(py) >= 0.1 * scale  # away from zero crossings (see the test above)
    assert np.all(err[big] <= 1e-5 * np.abs(py[big]))


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_c_export_names_that_are_not_identifiers(unit: dict[str, Path]) -> None:
    """`--out '1bad-name;x.c'` wrote `#define 1BAD_NAME_X_H` (a macro name may not start
    with a digit: the header did not compile); a name an #include line cannot carry is
    refused before anything is written."""
    model = str(unit["model"])
    out = unit["dir"] / "1bad-name;x.c"
    assert main(["export", model, "--format", "c", "--kind", "poly", "--out", str(out)]) == 0
    header = out.with_suffix(".h")
    assert "#define GYROLAB_1BAD_NAME_X_H" in header.read_text()
    cc = subprocess.run(  # the header alone: its guard is what the name could break
        [str(CC), "-fsyntax-only", "-x", "c", str(header)], capture_output=True, text=True
    )
    assert cc.returncode == 0, cc.stderr
    bad = unit["dir"] / 'q"uote.c'
    assert main(["export", model, "--format", "c", "--kind", "poly", "--out", str(bad)]) == 2
    assert not bad.exists() and not bad.with_suffix(".h").exists()


def test_kalibr_on_a_short_real_log_has_no_nan_and_accelerometer_fields(
    unit: dict[str, Path],
) -> None:
    """pymavlink's tests/test.BIN is a 0.9 s log: N (defined at 1 s) and K (at 3 s) lie
    beyond it, so both are the documented upper bounds, never nan and never labelled as
    read at a tau the record does not reach; the log has accelerometers, so kalibr's
    accelerometer fields are written from them."""
    log = Path(__file__).parent / "data" / "pymavlink_test.BIN"
    out = unit["dir"] / "short.yaml"
    assert main(["export", str(unit["model"]), "--format", "kalibr", "--run", str(log),
                 "--out", str(out)]) == 0  # fmt: skip
    text = out.read_text()
    y = yaml.safe_load(text)
    assert set(y) == {
        "gyroscope_noise_density", "gyroscope_random_walk", "accelerometer_noise_density",
        "accelerometer_random_walk", "update_rate", "rostopic",
    }  # fmt: skip
    for k, v in y.items():
        if k != "rostopic":
            assert isinstance(v, float) and math.isfinite(v) and v > 0, k
    assert "nan" not in text.lower()
    assert "read at tau" not in text  # nothing labelled at a tau beyond the record
    assert text.count("upper bound") >= 12 and "beyond the 0.901 s record" in text


def test_export_instance_out_of_range_is_one_line(unit: dict[str, Path], capsys) -> None:
    out = unit["dir"] / "bad.params"
    dev = ["--device-id", "1"]
    cases = [("px4", "4", dev), ("ardupilot", "3", []), ("px4", "-1", dev), ("ardupilot", "-1", [])]
    for fmt, inst, extra in cases:
        rc = main(["export", str(unit["model"]), "--format", fmt, "--instance", inst,
                   "--out", str(out), *extra])  # fmt: skip
        err = capsys.readouterr().err.strip()
        assert rc == 2 and not out.exists(), (fmt, inst)
        assert err.count("\n") == 0 and "--instance" in err and f"not {inst}" in err, err
