"""``gyrolab convert``: every format read back by its own library with equal values."""

from __future__ import annotations

import csv
import json
import tracemalloc
from pathlib import Path

import h5py
import netCDF4
import numpy as np
import pyarrow.parquet as pq
import pytest

from gyrolab import convert as conv
from gyrolab.cli import main
from gyrolab.record.reader import read_recording
from gyrolab.record.writer import RecordingWriter

START_NS = 1_618_876_800_000_000_000
RATE = 50.0  # Hz


def _recording(path: Path, seconds: int = 40, rate: float = RATE, adc_gap: bool = True) -> None:
    rng = np.random.default_rng(9)
    n = int(rate)
    with RecordingWriter(path, start_time_ns=START_NS, run={"operator": "conv"}) as w:
        w.write_event(0.0, "run_started", detail="convert test")
        w.write_event(0.0, "step_started", 0, 25.0)
        first = 0
        for k in range(seconds):
            if k == 17:
                first += 13  # 13 samples lost: a gap
            t0 = first / rate
            counts = rng.integers(-(2**23), 2**23, n, dtype=np.int32)
            if not (adc_gap and k == 5):  # one block without its ADC message
                w.write_adc_block(t0, 1 / rate, first, counts)
            w.write_rate_block(t0, 1 / rate, first, counts * 3e-6)
            # readings taken inside the block, at odd times
            w.write_pt100(t0 + 0.37, 109.7 + 0.01 * k, 25.0 + 0.1 * k)
            if k % 3 == 0:
                w.write_oven(t0 + 0.61, 25.0 + k, 24.0 + k, "run")
            if k == 17:
                w.write_log(t0 + 0.5, "warning", "adc", "gap", "gap", {"n_missing": 13})
            first += n
        w.write_event(float(seconds), "run_ended")


def _expected(path: Path) -> dict[str, np.ndarray]:
    """The sample table computed from the recording directly, without the converter."""
    rec = read_recording(path)
    t = rec.rate.t

    def held(rt: np.ndarray, rv: np.ndarray) -> np.ndarray:
        k = np.searchsorted(rt, t, side="right") - 1
        return np.where(k >= 0, rv[np.maximum(k, 0)], np.nan)

    adc = np.full(t.size, conv.ADC_FILL, dtype=np.int32)
    pos = np.searchsorted(rec.rate.index, rec.adc.index)
    adc[pos] = rec.adc.values
    return {
        "index": rec.rate.index,
        "t_s": t,
        "rate_dps": rec.rate.values.astype(np.float32),
        "adc_counts": adc,
        "pt100_c": held(rec.pt100_t, rec.pt100_c),
        "setpoint_c": held(rec.oven_t, rec.oven_setpoint_c),
    }


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, np.ndarray]]:
    p = tmp_path_factory.mktemp("conv") / "run.mcap"
    _recording(p)
    return p, _expected(p)


def _assert_table(got: dict[str, np.ndarray], want: dict[str, np.ndarray]) -> None:
    assert set(got) == set(want)
    for k, v in want.items():
        np.testing.assert_array_equal(got[k], v, err_msg=k)
    assert np.isnan(want["pt100_c"][0]) and np.isfinite(want["pt100_c"][-1])  # held, not filled


def test_parquet(run, tmp_path: Path) -> None:
    src, want = run
    out = tmp_path / "r.parquet"
    assert main(["convert", str(src), "--to", "parquet", "--out", str(out)]) == 0
    t = pq.read_table(out)
    got = {k: t.column(k).to_numpy(zero_copy_only=False) for k in t.column_names}
    adc = t.column("adc_counts")
    assert adc.null_count == 1 * 50  # the block whose ADC message is missing
    got["adc_counts"] = np.asarray(adc.fill_null(conv.ADC_FILL).to_numpy(), dtype=np.int32)
    _assert_table(got, want)
    assert t.schema.field("rate_dps").metadata[b"unit"] == b"deg/s"
    md = pq.read_metadata(out).metadata
    assert json.loads(md[b"gyrolab_metadata"])["run"]["operator"] == "conv"
    assert md[b"gyrolab_gaps"] == b"1"
    assert json.loads(md[b"gyrolab_log"])[0]["kind"] == "gap"


def test_hdf5(run, tmp_path: Path) -> None:
    src, want = run
    out = tmp_path / "r.h5"
    assert main(["convert", str(src), "--to", "hdf5", "--out", str(out)]) == 0
    with h5py.File(out, "r") as f:
        got = {k: f["samples"][k][()] for k in f["samples"]}
        assert f["samples/t_s"].attrs["units"] == "s"
        assert f["samples/pt100_c"].attrs["units"] == "degC"
        assert json.loads(f.attrs["gyrolab_events"])[0]["event"] == "run_started"
        np.testing.assert_array_equal(f["pt100/temperature_c"][()], 25.0 + 0.1 * np.arange(40))
        assert f["oven/mode"][0] == b"run"
    _assert_table(got, want)


def test_netcdf(run, tmp_path: Path) -> None:
    src, want = run
    out = tmp_path / "r.nc"
    assert main(["convert", str(src), "--to", "netcdf", "--out", str(out)]) == 0
    with netCDF4.Dataset(out) as nc:
        nc.set_auto_mask(False)
        got = {k: nc.variables[k][:] for k in nc.variables}
        assert nc.variables["t_s"].units == "seconds since 2021-04-20T00:00:00Z"
        assert nc.variables["adc_counts"]._FillValue == conv.ADC_FILL
        assert json.loads(nc.gyrolab_metadata)["run"]["operator"] == "conv"
        np.testing.assert_array_equal(
            nc["oven"].variables["setpoint_c"][:], 25.0 + np.arange(0, 40, 3)
        )
    _assert_table(got, want)


def test_csv(run, tmp_path: Path) -> None:
    src, want = run
    out = tmp_path / "r.csv"
    assert main(["convert", str(src), "--to", "csv", "--out", str(out)]) == 0
    with open(out, newline="", encoding="utf-8") as fh:
        lines = [ln for ln in fh if not ln.startswith("#")]
    rows = list(csv.DictReader(lines))
    got = {
        "index": np.array([int(r["index"]) for r in rows]),
        "t_s": np.array([float(r["t_s"]) for r in rows]),
        "rate_dps": np.array([np.float32(r["rate_dps"]) for r in rows]),
        "adc_counts": np.array(
            [int(r["adc_counts"]) if r["adc_counts"] else conv.ADC_FILL for r in rows], np.int32
        ),
        "pt100_c": np.array([float(r["pt100_c"]) for r in rows]),
        "setpoint_c": np.array([float(r["setpoint_c"]) for r in rows]),
    }
    _assert_table(got, want)
    head = out.read_text(encoding="utf-8").splitlines()
    assert "# column rate_dps: deg/s; angular rate" in head


def test_streaming_memory_is_bounded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """1 kHz runs of 2 and 8 min: the peak of what is allocated does not grow with the run
    (a chunk of the MCAP, one block, one row group), far below the sample table's size."""
    monkeypatch.setattr(conv, "ROWS_PER_WRITE", 8192)
    peaks = []
    for seconds in (120, 480):
        src = tmp_path / f"k{seconds}.mcap"
        _recording(src, seconds=seconds, rate=1000.0, adc_gap=False)
        tracemalloc.start()
        conv.convert_recording(src, "parquet", tmp_path / f"k{seconds}.parquet")
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    table_bytes = 480_000 * (8 + 8 + 4 + 4 + 8 + 8)
    # 4x the samples add at most 1 MiB: Parquet's footer keeps ~10 kB of metadata per row
    # group until the file closes (0.6 MB here, the same before the checked reads); a ratio
    # of the peaks would also fail whenever the reader's own baseline shrinks (it did)
    assert peaks[1] < peaks[0] + (1 << 20), peaks
    assert peaks[1] < table_bytes / 4, (peaks, table_bytes)


def test_refuses_to_overwrite_input_and_says_what_is_missing(
    run, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    src, _ = run
    before = src.read_bytes()
    assert main(["convert", str(src), "--to", "csv", "--out", str(src), "--force"]) == 2
    assert "one of this command's inputs" in capsys.readouterr().err
    assert src.read_bytes() == before
    monkeypatch.setitem(conv._LIBS, "parquet", "no_such_module_for_gyrolab")
    out = tmp_path / "x.parquet"
    assert main(["convert", str(src), "--to", "parquet", "--out", str(out)]) == 2
    assert "pip install 'gyrolab[export]'" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".x.parquet*"))
