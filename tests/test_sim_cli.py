"""``gyrolab simulate``: recording contents, reproducibility, model files, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gyrolab.cli import main
from gyrolab.errors import InputError
from gyrolab.record.reader import read_recording
from gyrolab.sim.model import load_sim_model, nominal_model

PROFILE = """
name = "tiny"
ambient_c = 25.0
[[step]]
setpoint_c = 25.0
duration_s = 20.5
[[step]]
setpoint_c = 30.0
duration_s = 40.0
[[step]]
setpoint_c = 30.0
duration_s = 10.0
stable_slope_c_per_min = 5.0
stable_window_s = 20.0
max_extra_s = 30.0
"""


@pytest.fixture()
def tiny(tmp_path: Path) -> Path:
    p = tmp_path / "tiny.toml"
    p.write_text(PROFILE)
    return p


def sim(*args: str) -> int:
    return main(["simulate", *args])


def test_recording_has_every_topic_and_consistent_rate(tiny: Path, tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    assert sim("--out", str(out), "--profile", str(tiny), "--rate", "50", "--seed", "2") == 0
    rec = read_recording(out)
    rate, adc = rec.require_rate(), rec.adc
    assert adc is not None and rate.rate_hz == pytest.approx(50.0)
    # /gyro/rate is the ADC codes converted as a bench converts them
    conv = rec.bench["adc"]
    lsb = conv["vref_v"] / 2 ** (conv["bits"] - 1)
    expect = (adc.values * lsb - conv["offset_v"]) / conv["gain_v_per_dps"]
    np.testing.assert_allclose(rate.values, expect.astype(np.float32), rtol=0, atol=0)
    assert rate.gaps() == [] and rate.index[0] == 0
    n_s = rate.t.size / 50.0
    assert 70.5 <= n_s <= 70.5 + 30  # time steps + stability hold (at most max_extra)
    assert rec.topic_counts["/gyro/rate"] == int(np.ceil(n_s))  # 1 s blocks
    assert np.allclose(np.diff(rec.pt100_t), 1.0) and np.allclose(np.diff(rec.oven_t)[:-1], 1.0)
    assert np.all(np.abs(rec.pt100_c - 27) < 6)
    ev = [(e["event"], e["step"]) for e in rec.events]
    assert ev[0] == ("run_started", -1) and ev[-1] == ("run_ended", -1)
    assert [s for e, s in ev if e == "step_started"] == [0, 1, 2]
    starts = [e["t"] for e in rec.events if e["event"] == "step_started"]
    assert starts[:2] == [0.0, 20.5]  # a step boundary inside a block is kept exact
    assert rec.run["seed"] == 2 and rec.bench["adc"]["sample_rate_hz"] == 50.0
    assert rec.run["profile"]["name"] == "tiny" and rec.run["source"] == "simulate"
    assert rec.run["start_time"] == "2021-04-20T00:00:00Z"
    assert "34401A" in rec.bench["multimeter"]["idn"]
    prov = rec.metadata["sim_provenance"]
    assert prov["effects"] == ["bias_poly", "arw", "bias_instability"]
    assert "bias_poly" in prov["model_toml"]


def test_same_seed_same_bytes_other_seed_other_bytes(tiny: Path, tmp_path: Path) -> None:
    paths = [tmp_path / f"{k}.mcap" for k in "abc"]
    for p, seed in zip(paths, ("5", "5", "6"), strict=True):
        assert sim("--out", str(p), "--profile", str(tiny), "--rate", "20", "--seed", seed) == 0
    a, b, c = (p.read_bytes() for p in paths)
    assert a == b
    assert a != c


def test_effect_option_and_model_file(tiny: Path, tmp_path: Path) -> None:
    m = nominal_model().with_effect("warmup", A=0.5, tau_s=10.0)
    mf = tmp_path / "m.toml"
    mf.write_text(m.to_toml())
    assert load_sim_model(mf) == m  # TOML round trip
    out = tmp_path / "w.mcap"
    args = ["--out", str(out), "--profile", str(tiny), "--rate", "10", "--model", str(mf)]
    assert sim(*args, "--effect", "periodic:A=0.01,period_s=30") == 0
    rec = read_recording(out)
    assert rec.metadata["sim_provenance"]["effects"][-2:] == ["warmup", "periodic"]
    r = rec.require_rate().values
    assert r[:5].mean() > 0.3  # warm-up of 0.5 °/s at power-on is in the data
    assert abs(r[-50:].mean()) < 0.1


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--effect", "wobble"], "unknown effect 'wobble'"),
        (["--effect", "arw:N=-1"], "arw.N must be >= 0"),
        (["--effect", "arw:M=1"], "unknown parameter"),
        (["--effect", "arw:N=abc"], "is not a number"),
        (["--profile", "nosuch"], "unknown profile"),
        (["--rate", "0"], "--rate"),
    ],
)
def test_bad_input_is_one_line_exit_2_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], needle: str
) -> None:
    out = tmp_path / "bad.mcap"
    assert sim("--out", str(out), "--profile", "short", *extra) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1 and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_unwritable_or_existing_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert sim("--out", str(tmp_path / "no" / "dir" / "x.mcap")) == 2
    assert "does not exist" in capsys.readouterr().err
    existing = tmp_path / "x.mcap"
    existing.write_bytes(b"keep")
    assert sim("--out", str(existing), "--profile", "short") == 2
    assert "already exists" in capsys.readouterr().err
    assert existing.read_bytes() == b"keep"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.mcap"]


def test_bad_model_file_names_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "m.toml"
    bad.write_text('[[effect]]\nname = "bias_poly"\nc9 = 1.0\n')
    with pytest.raises(InputError, match=r"m\.toml: effect bias_poly: unknown parameter"):
        load_sim_model(bad)
    bad.write_text('[[effect]]\nname = "flux_capacitor"\n')
    with pytest.raises(InputError, match="unknown effect"):
        load_sim_model(bad)
    bad.write_text("[thermal]\nair_tau_s = -3\n")
    with pytest.raises(InputError, match="air_tau_s must be > 0"):
        load_sim_model(bad)
    with pytest.raises(InputError, match="not found"):
        load_sim_model(tmp_path / "missing.toml")
