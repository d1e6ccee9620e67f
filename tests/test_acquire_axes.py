"""A 3-axis unit on the acquisition path (issue 15): frames of 3 interleaved axes through a
real pty into the ADC reader, and `acquire --bench sim --axis-model` recording the same
per-axis physics as `simulate --axis-model`."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from gyrolab.cli import main
from gyrolab.instruments.drivers.gyroadc import GyroAdcReader
from gyrolab.instruments.roles import AdcRead
from gyrolab.record.reader import read_recording
from gyrolab.sim.bench import ByteFaults, FaultPlan, SimBench
from gyrolab.sim.model import nominal_model
from gyrolab.sim.simulate import axis_physics

N = 10


def test_three_axis_frames_through_the_pty_match_the_physics_per_axis() -> None:
    """1 kHz, 3 axes, 0.1 % of bytes corrupted (~10 % of the 108-byte frames): every
    delivered sample is the source's, in (n, 3) sample-major order, and the axes are three
    gyros."""
    model = nominal_model()
    extras = axis_physics(model, [model, model], 1000.0, 3, 25.0)
    bench = SimBench(
        model=model,
        seed=3,
        rate_hz=1000.0,
        samples_per_frame=N,
        speed=20.0,
        faults=FaultPlan(adc=ByteFaults(corrupt_prob=0.001, seed=1)),
        keep_truth=True,
        tcp=False,
        axis_physics=extras,
    )
    reader = GyroAdcReader(bench.adc_port, samples_per_frame=N, rate_hz=1000.0, axes=3)
    out = AdcRead()
    with bench:
        reader.open()
        deadline = time.monotonic() + 60.0
        while bench.clock.now() < 10.0 and time.monotonic() < deadline:
            r = reader.read(0.05)
            out.blocks += r.blocks
            out.gaps += r.gaps
    reader.close()
    seq, counts, status = bench.truth.arrays()
    assert counts.shape[1:] == (N, 3)
    assert all(b.counts.shape[1:] == (3,) for b in out.blocks)
    got_seq = np.concatenate(
        [np.arange(b.first_seq, b.first_seq + len(b.counts) // N) for b in out.blocks]
    )
    got = np.concatenate([b.counts for b in out.blocks]).reshape(-1, N, 3)
    assert got_seq.size > 800 and np.all(np.diff(got_seq) > 0)
    np.testing.assert_array_equal(got, counts[np.searchsorted(seq, got_seq)])
    assert (status == "damaged").sum() > 0  # the faults did bite, and never passed
    # The three columns are three gyros (own noise), not one copied.
    flat = got.reshape(-1, 3).astype(float)
    assert np.corrcoef(flat[:, 1], flat[:, 2])[0, 1] < 0.5


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    d = tmp_path_factory.mktemp("axes")
    base = nominal_model().to_toml()
    y = d / "y.toml"
    y.write_text(base.replace("c1 = 0.000384", "c1 = -0.0005"))  # opposite tempco
    z = d / "z.toml"
    z.write_text(base.replace("c0 = 0.02", "c0 = -0.05"))
    prof = d / "p.toml"
    prof.write_text(
        'name = "two"\n[[step]]\nsetpoint_c = 45.0\nduration_s = 600.0\n'
        "[[step]]\nsetpoint_c = 5.0\nduration_s = 600.0\n"
    )
    axes = ["--axis-model", str(y), "--axis-model", str(z)]
    acq, sim = d / "acq.mcap", d / "sim.mcap"
    common = ["--profile", str(prof), "--seed", "0", *axes]
    assert main(["acquire", "--bench", "sim", "--speed", "200", *common, "--out", str(acq)]) == 0
    assert main(["simulate", *common, "--out", str(sim)]) == 0
    return acq, sim, prof


def test_acquire_records_three_axes_as_simulate_does(runs) -> None:
    acq, sim, _ = runs
    a, s = read_recording(acq), read_recording(sim)
    assert a.rate.values.ndim == 2 and a.rate.values.shape[1] == 3
    assert a.run["axes"] == 3 == s.run["axes"]
    assert a.bench["adc"]["axes"] == 3
    assert a.adc.values.shape == a.rate.values.shape  # counts and rates block for block
    with open(acq, "rb") as fh:  # the other axes' models, read back by the mcap library
        meta = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
    assert json.loads(meta["sim_provenance_axes"]["axes"]) == 3
    step = a.rate.t[1] - a.rate.t[0]
    assert np.all(np.abs(np.diff(a.rate.t) - step) < 1e-6)  # no gap, whole run
    for k in range(2):  # per step: each axis' mean over its second half, acquire vs simulate
        lo, hi = k * 600.0 + 300.0, (k + 1) * 600.0 - 5.0

        def mean(t: np.ndarray, v: np.ndarray, lo: float = lo, hi: float = hi) -> np.ndarray:
            return v[(t >= lo) & (t < hi)].mean(axis=0)

        ma, ms = mean(a.rate.t, a.rate.values), mean(s.rate.t, s.rate.values)
        # ARW of a 295 s mean is ~1e-4 °/s; the axes differ by 1e-2…7e-2 °/s.
        np.testing.assert_allclose(ma, ms, atol=4e-4)
        assert abs(ma[2] - ma[0]) > 0.05


def test_axis_model_is_refused_on_a_bench_file(runs, tmp_path: Path) -> None:
    _, _, prof = runs
    lab = Path(__file__).resolve().parents[1] / "examples" / "lab.toml"
    out = tmp_path / "o.mcap"
    rc = main(["acquire", "--bench", str(lab), "--axis-model", str(prof), "--out", str(out)])
    assert rc == 2 and not out.exists()


def test_convert_writes_one_rate_and_adc_column_per_axis(runs, tmp_path: Path) -> None:
    """The 3-axis acquisition as Parquet, read back with pyarrow: every axis' rate and code."""
    import pyarrow.parquet as pq

    acq = runs[0]
    out = tmp_path / "a.parquet"
    assert main(["convert", str(acq), "--to", "parquet", "--out", str(out)]) == 0
    t = pq.read_table(out)
    rec = read_recording(acq)
    assert t.column_names[:8] == [
        "index", "t_s", "rate_x_dps", "rate_y_dps", "rate_z_dps",
        "adc_counts_x", "adc_counts_y", "adc_counts_z",
    ]  # fmt: skip
    for j, a in enumerate("xyz"):
        np.testing.assert_array_equal(t[f"rate_{a}_dps"].to_numpy(), rec.rate.values[:, j])
        np.testing.assert_array_equal(t[f"adc_counts_{a}"].to_numpy(), rec.adc.values[:, j])
