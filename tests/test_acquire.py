"""`gyrolab acquire --bench sim`: the real drivers over real pseudo-terminals, end to end.

Timings on a loaded 2-core machine are noisy; the speeds below leave room for that.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from contract import ADC_KEYS, recording_metadata_keys
from simruns import run_on_sim

from gyrolab.cli import main
from gyrolab.instruments.drivers.gyroadc import GyroAdcConfig
from gyrolab.record.format import TOPIC_LOG
from gyrolab.record.metadata import BenchMetadata, RunMetadata
from gyrolab.record.reader import read_recording

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def short_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    """The built-in short profile (48 min) at 200x through the simulated bench."""
    out = tmp_path_factory.mktemp("acq") / "short.mcap"
    rc = main(
        ["acquire", "--bench", "sim", "--profile", "short", "--speed", "200", "--out", str(out)]
    )
    return out, rc


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "short-sim.mcap"
    assert main(["simulate", "--profile", "short", "--seed", "0", "--out", str(out)]) == 0
    return out


def test_short_profile_completes_with_every_transition_recorded(short_run) -> None:
    out, rc = short_run
    assert rc == 0
    rec = read_recording(out)
    names = [e["event"] for e in rec.events]
    assert names[0] == "run_started" and names.count("step_started") == 12
    assert names.count("soaked") == names.count("step_ended") == 12
    assert names[-2:] == ["run_ended", "safe_state"]
    starts = [e["t"] for e in rec.events if e["event"] == "step_started"]
    # Steps start on the run clock, on the 240 s schedule exactly, however late the busy
    # engine noticed the boundary (docs/reliability.md, "Timing") — later only by the
    # time the run was held before them: a simulated bench starved of the CPU for a wall
    # second (a loaded machine) holds the run as a stalled stream would
    # (docs/reliability.md, "Suspenders"); the held step goes on, no re-soak.
    held = [0.0] * 12
    for sus, back in zip(
        [e for e in rec.events if e["event"] == "suspended"],
        [e for e in rec.events if e["event"] == "resumed"],
        strict=True,
    ):
        assert "goes on" in back["detail"]
        held[sus["step"]] += back["t"] - sus["t"]
    schedule = np.cumsum([0.0] + [240.0 + h for h in held])
    assert starts == pytest.approx(list(schedule[:12]), abs=1e-6)
    assert [e["t"] for e in rec.events if e["event"] == "run_ended"] == [
        pytest.approx(schedule[12])
    ]
    assert "verified" in rec.events[-1]["detail"] and rec.oven_mode[-1] == "safe"
    assert rec.oven_setpoint_c[-1] == 25.0
    # Every setpoint of the profile was written and read back by the oven driver at the
    # start of its step: the engine's reaction time (ms wall; tens of ms on a busy
    # machine) is seconds at 200x, up to 18 s seen with two CPU hogs. Each is verified
    # well inside the first quarter of its step, and typically within a few seconds.
    cmds = [m for m in rec.logs if m.get("kind") == "command"]
    # (a held step's setpoint is commanded again when the run resumes)
    cmds = [m for i, m in enumerate(cmds) if i == 0 or m["data"] != cmds[i - 1]["data"]]
    verified = [m["data"]["setpoint_c"] for m in cmds]
    assert verified == [25.0, 60.0, 50.0, 40.0, 30.0, 20.0, 10.0, 0.0, -10.0, -20.0, -30.0, -40.0]
    lag = np.array([m["t"] for m in cmds]) - np.array(starts)
    assert np.all(lag >= 0.0) and np.all(lag < 60.0) and np.median(lag) <= 5.0, lag
    # A loaded test machine can hold a simulated reply past the drivers' 0.25 s wall floor
    # (gyrolab/app/sim_bench.py): that reading times out, is logged as a warning and the run
    # goes on (seen at load 10). Anything else (an error, an abort) fails the run.
    faults = [m for m in rec.logs if m.get("kind") in ("fault", "abort")]
    assert all(
        m["kind"] == "fault" and m["level"] == "warning" and "InstrumentTimeout" in m["message"]
        for m in faults
    ), faults


def test_short_run_adc_stream_is_whole_and_converted_exactly(short_run) -> None:
    rec = read_recording(short_run[0])
    adc, rate = rec.adc, rec.rate
    assert adc.gaps() == [] and adc.index[0] == 0
    assert np.array_equal(adc.index, np.arange(adc.index.size))
    assert adc.period == pytest.approx(0.01)
    # 100 Hz for the whole run. The stream starts with the bench's first 1 s tick after
    # t = 0 (sample 0 is timed by its block's arrival: a few ticks at most at 200x on a
    # busy machine), and a completed run records it up to the profile's end (the engine
    # drains what is in flight, docs/reliability.md). The index being contiguous, that
    # is every sample of the run.
    t_end = rec.events[-2]["t"]
    assert rec.events[-2]["event"] == "run_ended"
    assert adc.t[0] < 3.0
    assert adc.t[-1] + adc.period >= t_end - 1e-6
    assert adc.index.size >= 100 * (t_end - 3.0)
    assert np.array_equal(adc.index, rate.index) and np.allclose(adc.t, rate.t)
    expect = GyroAdcConfig().to_dps(adc.values.astype(np.float64)).astype(np.float32)
    assert np.array_equal(rate.values.astype(np.float32), expect)
    # PT100 read about once a (simulated) second; the oven every ~2 s. At 200x a second is
    # 5 ms of wall time: on a loaded machine a reading can take longer, and the poller then
    # reads at the next period instead of twice at once (median 2 s seen at load 10).
    assert 0.8 <= np.median(np.diff(rec.pt100_t)) <= 2.2
    assert np.median(np.diff(rec.oven_t)) <= 3.0


def test_short_run_metadata(short_run) -> None:
    rec = read_recording(short_run[0])
    run, bench = rec.run, rec.bench
    assert run["source"] == "acquire" and run["operator"] == "simulated"
    assert run["unit_serial"] == "SIM-GYRO-0001" and run["profile"]["name"] == "short"
    assert run["speed"] == 200
    assert "34401A" in bench["multimeter"]["idn"]
    assert bench["multimeter"]["resource"].startswith("ASRL")
    assert bench["oven"]["registers"]["units"] == "C"
    assert bench["adc"]["dps_per_count"] == pytest.approx(2.5 / 2**23 / 0.01)
    assert bench["recorder"]["flush_every_s"] == 1.0
    assert "sim_provenance" in rec.metadata


def test_acquire_and_simulate_show_the_same_physics(short_run, simulated) -> None:
    """Same profile and seed: the wire-level bench and `simulate` agree within noise."""
    a, s = read_recording(short_run[0]), read_recording(simulated)
    assert a.pt100_c.min() == pytest.approx(s.pt100_c.min(), abs=0.3)
    assert a.pt100_c.max() == pytest.approx(s.pt100_c.max(), abs=0.3)
    assert a.oven_pv_c.min() == pytest.approx(s.oven_pv_c.min(), abs=0.5)
    assert a.oven_pv_c.max() == pytest.approx(s.oven_pv_c.max(), abs=0.5)
    # A step the run was held in (a loaded machine starving the simulated bench holds it
    # as a stalled stream would; docs/reliability.md, "Suspenders") lasted longer than
    # simulate's: compared are the steps that were not held, each on its own start.
    starts = [e["t"] for e in a.events if e["event"] == "step_started"]
    held = {e["step"] for e in a.events if e["event"] == "suspended"}
    compared = [k for k in range(12) if k not in held]
    assert len(compared) >= 3, f"held in steps {sorted(held)}: too few left to compare"
    for k in compared:  # per step: PT100 at its end and the gyro drift over its 2nd half

        def mean(t: np.ndarray, v: np.ndarray, t0: float) -> float:
            return float(v[(t >= t0 + 120.0) & (t < t0 + 235.0)].mean())

        assert mean(a.pt100_t, a.pt100_c, starts[k]) == pytest.approx(
            mean(s.pt100_t, s.pt100_c, 240.0 * k), abs=0.15
        )
        # ARW noise of a 115 s mean is ~1e-4 °/s; the step-to-step drift is ~1e-3.
        assert mean(a.rate.t, a.rate.values, starts[k]) == pytest.approx(
            mean(s.rate.t, s.rate.values, 240.0 * k), abs=4e-4
        )


def _profile(tmp_path: Path, steps: list[tuple[float, float]]) -> Path:
    text = 'name = "t"\n' + "".join(
        f"[[step]]\nsetpoint_c = {sp}\nduration_s = {d}\n" for sp, d in steps
    )
    f = tmp_path / "p.toml"
    f.write_text(text)
    return f


def test_simulated_clock_slips_after_a_stall_instead_of_leaping_ahead() -> None:
    """A starved tick thread does not race the simulated world ahead of its observers
    (the cause of steps starting 7 s late at 200x on a busy machine)."""
    from gyrolab.sim.bench.clock import SimClock

    c = SimClock(100.0, max_catch_up_s=2.0)
    assert c.advance_to(1.0)
    time.sleep(0.15)  # the process is starved: 15 simulated seconds of schedule pass
    t0 = time.monotonic()
    for k in range(2, 6):  # the backlog is not raced through: each tick is paced again
        assert c.advance_to(float(k))
    assert time.monotonic() - t0 >= 0.025  # 3 ticks of 10 ms after the slip
    assert 10.0 <= c.slipped_s <= 20.0 and c.now() == 5.0
    racing = SimClock(100.0)  # no bound: the schedule is kept (the backlog is raced through)
    racing.advance_to(1.0)
    time.sleep(0.15)
    for k in range(2, 6):
        racing.advance_to(float(k))
    assert racing.slipped_s == 0.0 and racing.wall_time_for(5.0) < time.monotonic()


def test_refuses_bad_requests_before_touching_anything(tmp_path: Path, capsys) -> None:
    existing = tmp_path / "run.mcap"
    existing.write_bytes(b"precious")
    assert main(["acquire", "--bench", "sim", "--profile", "short", "--out", str(existing)]) == 2
    assert existing.read_bytes() == b"precious"
    assert "already exists" in capsys.readouterr().err
    hot = _profile(tmp_path, [(25, 60), (90, 60)])
    out = tmp_path / "x.mcap"
    assert main(["acquire", "--bench", "sim", "--profile", str(hot), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "step 2 setpoint 90 °C is outside the bench limits" in err[0]
    assert not out.exists()
    lab = REPO / "examples" / "lab.toml"
    assert main(["acquire", "--bench", str(lab), "--speed", "10", "--out", str(out)]) == 2
    assert "--speed applies to --bench sim only" in capsys.readouterr().err
    # The example bench's ports do not exist here: one line naming the file and the port.
    assert main(["acquire", "--bench", str(lab), "--profile", "short", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "lab.toml" in err[0] and "[thermometer]" in err[0]
    assert not out.exists()


def _run_in_process(tmp_path: Path, profile: Path, *, speed: float, faults, limits=None):
    """run_acquisition against a SimBench built here (for faults and ground truth)."""
    from dataclasses import replace

    from gyrolab.app.sim_bench import sim_bench_config, start_sim_bench
    from gyrolab.profiles.profile import load_profile

    prof = load_profile(profile)
    sim, cfg = start_sim_bench(
        sim_bench_config(0), prof, seed=0, speed=speed, keep_truth=True, faults=faults
    )
    if limits is not None:
        cfg = replace(cfg, limits=limits)
    out = tmp_path / "run.mcap"
    res = run_on_sim(cfg, prof, out, sim)
    return res, read_recording(out), sim.bench


def test_fault_run_completes_logs_every_fault_and_never_alters_a_sample(tmp_path: Path) -> None:
    """ADC byte corruption, a 30 s multimeter outage and Modbus error bursts in one run."""
    from gyrolab.sim.bench import ByteFaults, FaultEvent, FaultPlan

    faults = FaultPlan(
        adc=ByteFaults(corrupt_prob=2e-4, seed=5),
        events=[
            FaultEvent("outage", t_s=20.0, duration_s=30.0),
            FaultEvent("modbus_exception", t_s=70.0, count=4),
            FaultEvent("modbus_crc", t_s=85.0, count=4),
            FaultEvent("modbus_no_reply", t_s=100.0, count=2),
        ],
    )
    prof = _profile(tmp_path, [(25, 30), (35, 60), (30, 50)])
    # 10x: the drivers' timeouts do not go below 0.25 s wall on the simulated bench
    # (SIM_TIMEOUT_FLOOR_S: scheduling jitter on a loaded machine), 2.5 simulated seconds
    # here; much faster, a burst of timeouts would add up towards the 60 s communication
    # timeout, as it would with a slow bench.
    res, rec, bench = _run_in_process(tmp_path, prof, speed=10.0, faults=faults)
    assert res.outcome == "completed", res.reason
    fired = {k for _, k, _ in bench.log}
    assert {"outage:start", "modbus_exception:start", "modbus_crc:start"} <= fired
    logs = rec.logs
    by_kind = lambda src, kind: [m for m in logs if m["source"] == src and m.get("kind") == kind]  # noqa: E731
    # The multimeter outage: a fault, then a recovery after about 30 s.
    (dmm_fault,) = [m for m in by_kind("multimeter", "fault") if 15 < m["t"] < 55]
    rec_dmm = [m for m in by_kind("multimeter", "recovery") if m["t"] > dmm_fault["t"]]
    assert rec_dmm and 25.0 <= rec_dmm[0]["data"]["outage_s"] <= 45.0
    pt_gap = np.diff(rec.pt100_t).max()
    assert 25.0 <= pt_gap <= 45.0  # explicit: no PT100 readings invented in the outage
    # The Modbus bursts: the oven driver's retries absorb some; what got through is
    # logged as a fault and a recovery, and the oven's setpoints were still all verified.
    assert by_kind("oven", "fault") and by_kind("oven", "recovery")
    # (each step's setpoint once, and again when a hold — the outage — ended)
    sps = [m["data"]["setpoint_c"] for m in by_kind("oven", "command")]
    assert [c for i, c in enumerate(sps) if i == 0 or c != sps[i - 1]] == [25.0, 35.0, 30.0]
    # ADC corruption: damaged frames rejected and counted; each loss is an explicit gap.
    assert res.gaps > 0 and by_kind("adc", "corruption")
    gap_logs = by_kind("adc", "gap")
    assert len(gap_logs) == res.gaps == len(rec.adc.gaps())
    assert sum(m["data"]["n_missing"] for m in gap_logs) == res.samples_missing
    # Ground truth: every recorded sample is exactly what the source sent for that index,
    # no index appears twice, and every missing index was a frame damaged on the wire.
    seq, counts, status = bench.truth.arrays()
    truth = counts.reshape(-1)
    n = bench.samples_per_frame
    dev_idx = rec.adc.index + res.first_device_index
    assert np.unique(dev_idx).size == dev_idx.size
    assert np.array_equal(rec.adc.values, truth[dev_idx - seq[0] * n])
    present = np.zeros(truth.size, bool)
    present[dev_idx - seq[0] * n] = True
    span = slice(dev_idx[0] - seq[0] * n, dev_idx[-1] - seq[0] * n + 1)
    missing_frames = np.unique(np.flatnonzero(~present[span]) // n + (span.start // n))
    assert set(status[missing_frames]) <= {"damaged"}
    assert (status[span.start // n : span.stop // n] == "damaged").sum() >= missing_frames.size


def test_over_temperature_watchdog_puts_the_oven_in_the_safe_state(tmp_path: Path) -> None:
    from gyrolab.acquisition.bench_config import Limits
    from gyrolab.sim.bench import FaultPlan

    prof = _profile(tmp_path, [(25, 30), (60, 900)])
    res, rec, bench = _run_in_process(
        tmp_path, prof, speed=50.0, faults=FaultPlan(), limits=Limits(pt100_max_c=26.0)
    )
    assert res.outcome == "fault" and "over-temperature" in res.reason and res.exit_code == 1
    assert res.safe_state_ok and bench.physics.setpoint_c == 25.0
    ev = [e["event"] for e in rec.events]
    assert ev[-2:] == ["aborted", "safe_state"]
    assert any(m["level"] == "fault" and "over-temperature" in m["message"] for m in rec.logs)
    assert np.all(rec.pt100_c[-3:] > 26.0) and np.all(rec.pt100_c[:-3] <= 26.05)


def test_lost_multimeter_ends_the_run_safely(tmp_path: Path) -> None:
    from gyrolab.app.sim_bench import SIM_COMM_MIN_WALL_S, SIM_HOLD_MIN_WALL_S
    from gyrolab.sim.bench import FaultEvent, FaultPlan

    prof = _profile(tmp_path, [(25, 30), (40, 600)])
    faults = FaultPlan(events=[FaultEvent("outage", t_s=40.0, duration_s=10_000.0)])
    speed = 50.0
    res, rec, bench = _run_in_process(tmp_path, prof, speed=speed, faults=faults)
    # the run is held while the multimeter says nothing (a suspender) and ends when that
    # has lasted [suspend] temperature_lost_s (docs/reliability.md, "Suspenders")
    assert res.outcome == "fault" and "temperature lost for" in res.reason
    assert "(> temperature_lost_s 60 s)" in res.reason and "34401A" in res.reason
    assert res.safe_state_ok and bench.physics.setpoint_c == 25.0
    assert rec.events[-1]["event"] == "safe_state"
    # When, by the simulated bench's rule: held after hold_after_s (5 s) of silence and
    # SIM_HOLD_MIN_WALL_S of wall time; ended after temperature_lost_s (60 s) held and
    # SIM_COMM_MIN_WALL_S of wall time (a starved process slips the clock: never later).
    # The slack: a reading period and a driver timeout on either side.
    (held,) = [e["t"] for e in rec.events if e["event"] == "suspended"]
    ended = rec.events[-2]["t"]
    last = rec.pt100_t[-1]
    assert last + 5.0 <= held <= last + max(5.0, SIM_HOLD_MIN_WALL_S * speed) + 10.0
    assert held + 60.0 <= ended <= held + max(60.0, SIM_COMM_MIN_WALL_S * speed) + 10.0


def test_sigint_ends_cleanly_with_the_oven_safe_and_exit_130(tmp_path: Path) -> None:
    prof = _profile(tmp_path, [(25, 30), (60, 3600)])
    out = tmp_path / "int.mcap"
    env = {**os.environ, "GYROLAB_NO_PROGRESS": "1"}
    cmd = [sys.executable, "-m", "gyrolab", "acquire", "--bench", "sim", "--profile", str(prof)]
    p = subprocess.Popen(
        [*cmd, "--speed", "50", "--out", str(out)], env=env, stderr=subprocess.PIPE, text=True
    )
    # Interrupt once the 60 °C step is under way (the file grows as chunks are flushed); no
    # wall-clock limit: the step is an hour, so the run gets there or ends (asserted).
    while not out.exists() or out.stat().st_size < 60_000:
        assert p.poll() is None, f"ended before the hot step: {p.communicate()[1]}"
        time.sleep(0.1)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    assert "interrupted" in err
    rec = read_recording(out)  # finalized: readable as is, no recovery needed
    ev = rec.events
    assert ev[-2]["event"] == "aborted" and "SIGINT" in ev[-2]["detail"]
    assert ev[-1]["event"] == "safe_state" and "verified" in ev[-1]["detail"]
    assert rec.oven_mode[-1] == "safe" and rec.oven_setpoint_c[-1] == 25.0
    assert 60.0 in rec.oven_setpoint_c  # it really was at 60 °C before
    assert rec.adc.gaps() == [] and rec.adc.index.size > 1000
    assert any(m.get("kind") == "abort" for m in rec.logs)
    assert rec.topic_counts[TOPIC_LOG] >= 4


@pytest.mark.slow
def test_kill_9_at_random_moments_loses_at_most_2_s(tmp_path: Path) -> None:
    """Ten SIGKILLs of a running acquisition; each file recovers; loss <= 2 s of data."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "bench_acquire", REPO / "benchmarks" / "bench_acquire.py"
    )
    mod = importlib.util.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(mod)
    rows = mod.kill_campaign(
        10, profile="short", speed=100.0, seed=11, max_delay_s=1.5, work=tmp_path
    )
    print(json.dumps(rows))
    assert len(rows) == 10
    for row in rows:
        assert row["messages"] > 0 and row["contiguous"]
        assert -1e-6 <= row["lost_s"] <= 2.0, row


def test_lab_bench_file_path_runs_in_real_time_against_instruments_on_ptys(
    tmp_path: Path,
) -> None:
    """`--bench BENCH.toml` (the lab path: wall clock, ports from the file) against the
    simulated instruments running in real time: what a lab sees, minus the hardware."""
    from gyrolab.sim.bench import SimBench

    prof = _profile(tmp_path, [(25, 2), (30, 2)])
    with SimBench(seed=3, speed=1.0, tcp=False, tick_s=0.1) as bench:
        text = (REPO / "examples" / "lab.toml").read_text()
        text = text.replace('"ASRL/dev/ttyUSB0::INSTR"', f'"{bench.dmm_serial_resource}"')
        text = text.replace('"/dev/ttyUSB1"', f'"{bench.oven_port}"')
        text = text.replace('"/dev/ttyUSB2"', f'"{bench.adc_port}"')
        text = text.replace('profile = "paper"', f'profile = "{prof}"')
        text = text.replace("nplc = 10.0", "nplc = 1.0").replace("period_s = 1.0", "period_s = 0.5")
        cfg = tmp_path / "lab.toml"
        cfg.write_text(text)
        out = tmp_path / "lab.mcap"
        t0 = time.monotonic()
        assert main(["acquire", "--bench", str(cfg), "--out", str(out)]) == 0
        wall = time.monotonic() - t0
        assert bench.physics.setpoint_c == 25.0  # safe state after the 30 °C step
    assert 4.0 <= wall < 15.0  # real time: the profile's 4 s, plus connecting
    rec = read_recording(out)
    assert rec.run["operator"] == "A. Engineer" and rec.run["unit_serial"] == "MG-2021-0042"
    assert rec.bench["name"] == "oven-bench-1" and rec.bench["simulated"] is False
    assert rec.bench["multimeter"]["calibration_due"] == "2027-03-01"
    starts = [e["t"] for e in rec.events if e["event"] == "step_started"]
    assert starts[0] < 0.01 and starts[1] == pytest.approx(2.0, abs=0.3)
    assert rec.adc.gaps() == [] and rec.adc.index.size >= 350
    assert rec.pt100_t.size >= 6 and rec.events[-1]["event"] == "safe_state"


@pytest.mark.hardware
def test_one_minute_on_a_real_bench(tmp_path: Path) -> None:
    """On real instruments: GYROLAB_BENCH_FILE=BENCH.toml pytest -m hardware."""
    bench = os.environ.get("GYROLAB_BENCH_FILE")
    if not bench:
        pytest.skip("set GYROLAB_BENCH_FILE=BENCH.toml to run on real instruments")
    prof = _profile(tmp_path, [(25, 60)])  # one minute at room temperature
    out = tmp_path / "hw.mcap"
    assert main(["acquire", "--bench", bench, "--profile", str(prof), "--out", str(out)]) == 0
    rec = read_recording(out)
    assert rec.adc.index.size > 0 and rec.pt100_t.size >= 30
    assert "verified" in rec.events[-1]["detail"]


def _raw_metadata(path: Path) -> dict[str, dict[str, object]]:
    """The metadata records as the file holds them (no normalisation), JSON decoded."""
    from mcap.reader import make_reader

    out: dict[str, dict[str, object]] = {}
    with open(path, "rb") as fh:
        for m in make_reader(fh).iter_metadata():
            vals: dict[str, object] = {}
            for k, v in m.metadata.items():
                try:
                    vals[k] = json.loads(v)
                except ValueError:
                    vals[k] = v
            out[m.name] = vals
    return out


def test_simulate_and_acquire_write_the_same_documented_metadata(short_run, simulated) -> None:
    """Both producers write the one schema (gyrolab/record/metadata.py): the same `run` and
    `bench` keys, exactly those docs/recording-format.md documents, as written."""
    acq, sim = _raw_metadata(short_run[0]), _raw_metadata(simulated)
    for record in ("run", "bench"):
        keys, layout = recording_metadata_keys(record)
        assert set(sim[record]) == keys - layout, record
        # an acquisition also says what only it knows (its run_id and segment, its bench's
        # suspenders): documented keys absent from other files
        assert keys - layout <= set(acq[record]) <= keys, record
    assert (acq["run"]["source"], sim["run"]["source"]) == ("acquire", "simulate")
    for meta in (acq, sim):
        run, bench = meta["run"], meta["bench"]
        assert isinstance(run["profile"], dict) and run["profile"]["name"] == "short"
        assert len(run["profile"]["step"]) == 12
        assert isinstance(bench["adc"], dict) and ADC_KEYS <= set(bench["adc"])
        assert bench["adc"]["sample_rate_hz"] == 100.0 and bench["simulated"] is True
        assert bench["multimeter"]["driver"] and bench["oven"]["driver"]
        # what was written is already the typed schema's shape: nothing to normalise
        assert RunMetadata.from_dict(run).to_dict() == run
        assert BenchMetadata.from_dict(bench).to_dict() == bench
