"""`gyrolab acquire --bench sim --units N`: several units in one chamber through the real
drivers over real pseudo-terminals and the scanner's TCP socket (docs/fleet.md)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from simruns import run_on_sim, three_step_profile

from gyrolab.cli import main
from gyrolab.record.format import TOPIC_EVENT, TOPIC_LOG, TOPIC_OVEN, TOPIC_PT100, TOPIC_RATE
from gyrolab.record.reader import list_units, read_recording

SERIALS = [f"SIM4-{k:02d}" for k in range(1, 9)]
PROFILE = three_step_profile("units")


@pytest.fixture(scope="module")
def eight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("units")
    (d / "p.toml").write_text(PROFILE)
    out = d / "eight.mcap"
    args = ["acquire", "--bench", "sim", "--units", "8", "--seed", "4", "--speed", "100"]
    assert main([*args, "--profile", str(d / "p.toml"), "--out", str(out)]) == 0
    return out


def test_eight_units_each_recorded_whole_and_read_back_per_unit(eight: Path) -> None:
    assert list_units(eight) == SERIALS
    topics = [TOPIC_RATE, TOPIC_PT100, TOPIC_OVEN, TOPIC_EVENT, TOPIC_LOG]
    recs = [read_recording(eight, topics=topics, unit=s) for s in SERIALS]
    # the profile's end: 960 s, later by any time the run was held (a loaded machine
    # starving the simulated bench: docs/reliability.md, "Suspenders")
    (end,) = [e["t"] for e in recs[0].events if e["event"] == "run_ended"]
    assert end >= 960.0
    means = []
    for s, rec in zip(SERIALS, recs, strict=True):
        rate = rec.require_rate()
        assert rec.unit == s and rec.run["units"] == SERIALS
        # Every unit's stream from run sample 0 to the profile's end, without a gap.
        assert rate.gaps() == [] and rate.index[0] == 0
        # to the profile's end (and what arrived while the safe state was commanded)
        assert end <= rate.t[-1] + rate.period < end + 8.0
        assert rec.pt100_t.size >= 300  # a sweep every 2 s, every unit's own PT100
        assert rec.bench["units"][s]["temperature_channel"] == 101 + SERIALS.index(s)
        means.append(float(np.mean(rate.values)))
    assert len(set(means)) == 8  # a dispersed family: every unit its own
    # One chamber: the shared oven record, the same for every unit.
    np.testing.assert_array_equal(recs[0].oven_pv_c, recs[7].oven_pv_c)
    assert recs[0].bench["scanner"]["channels"] == list(range(101, 109))
    events = [e["event"] for e in recs[0].events]
    resoaked = sum("re-soaks" in e["detail"] for e in recs[0].events if e["event"] == "resumed")
    assert events.count("step_started") == 3 + resoaked
    assert events[-2:] == ["run_ended", "safe_state"]
    assert not [m for m in recs[0].logs if m.get("kind") in ("gap", "unit_dropped")]


def test_the_recording_compensates_one_unit_with_unit(
    eight: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from test_pipeline import SMALL

    fast = replace(SMALL, causal_families=("poly",), ga_generations=2, bp_max_iter=50)
    # the pipeline runs end to end; its quality is not the point here
    monkeypatch.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", fast)
    out = tmp_path / "m"
    assert main(["compensate", str(eight), "--unit", "SIM4-05", "--out", str(out)]) == 0
    assert (out / "model.json").is_file()


def test_a_unit_unplugged_mid_run_is_dropped_and_the_others_complete(tmp_path: Path) -> None:
    from gyrolab.app.acquire import sim_bench_config, start_sim_bench
    from gyrolab.profiles.profile import load_profile
    from gyrolab.sim.bench import FaultEvent, FaultPlan

    (tmp_path / "p.toml").write_text(PROFILE.replace("320", "60"))
    prof = load_profile(tmp_path / "p.toml")
    # Unit 2's ADC cable pulled 40 s into the simulated bench (some 20-35 s into the run),
    # for good; it is given up after comm_timeout_s of silence.
    faults = FaultPlan(events=[FaultEvent("disconnect", t_s=40.0, duration_s=1e6, unit=1)])
    sim, cfg = start_sim_bench(sim_bench_config(0, 3), prof, seed=0, speed=40.0, faults=faults)
    cfg = replace(cfg, limits=replace(cfg.limits, comm_timeout_s=10.0))
    out = tmp_path / "run.mcap"
    res = run_on_sim(cfg, prof, out, sim)
    assert res.outcome == "completed" and res.units_dropped == ["SIM0-02"]
    rec = read_recording(out, topics=[TOPIC_LOG, TOPIC_EVENT], unit="SIM0-01")
    (drop,) = [m for m in rec.logs if m.get("kind") == "unit_dropped"]
    assert drop["source"] == "unit/SIM0-02" and drop["data"]["units_left"] == 2
    assert any(m.get("kind") == "fault" and m["source"] == "unit/SIM0-02" for m in rec.logs)
    # Its silence held the run (a stream stall: docs/reliability.md, "Suspenders") until
    # it was given up; the profile then went on, as much later.
    stall = [m for m in rec.logs if m.get("kind") == "suspend" and m["source"] == "unit/SIM0-02"]
    assert stall and stall[0]["t"] < drop["t"]
    (end,) = [e["t"] for e in rec.events if e["event"] == "run_ended"]
    assert end >= 180.0
    for s in ("SIM0-01", "SIM0-03"):  # the others: whole, to the end of the profile
        rate = read_recording(out, unit=s).require_rate()
        assert rate.gaps() == [] and end <= rate.t[-1] + rate.period < end + 2.0
    lost = read_recording(out, unit="SIM0-02")
    tail = [m for m in lost.logs if m.get("kind") == "gap" and m["source"] == "unit/SIM0-02"]
    assert tail and lost.require_rate().t[-1] < 60.0  # recorded up to the unplug, gap after
