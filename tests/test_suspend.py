"""Suspenders (gyrolab/acquisition/suspend.py): conditions that hold a run instead of
ending it, driven as tests/test_run_core.py drives the engine — a fake clock, scripted
instruments, no threads. A chamber alarm, a lost PT100, a stalled stream and an operator
pause each hold the profile (the setpoint stays, the step's clock stops), resume it when
they clear (re-soaking when the temperature left its band) and end the run in the verified
safe state when they outlast their limit."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from test_run_core import Chamber, FakeClock, Stream, Thermometer

from gyrolab.acquisition.bench_config import Limits, SafeState, Suspend
from gyrolab.acquisition.runner import Acquisition, RunResult
from gyrolab.instruments.drivers.gyroadc import GyroAdcConfig
from gyrolab.instruments.roles import AdcRead, ChamberReading
from gyrolab.profiles.profile import Profile, Step
from gyrolab.record.reader import Recording, read_recording
from gyrolab.record.writer import RecordingWriter

AMBIENT_C = 25.0


class AlarmChamber(Chamber):
    """A chamber in alarm during ``alarms`` ``(start, end)`` run seconds: it reports it
    and its heater and refrigerator stop (the air relaxes to ambient, 30 s constant)."""

    def __init__(self, clock: FakeClock, alarms=()) -> None:
        super().__init__(clock)
        self.alarms = list(alarms)

    def _alarm(self) -> str:
        t = self.clock.now() - 1000.0
        return "limit alarm" if any(a <= t < b for a, b in self.alarms) else ""

    def _advance(self) -> None:
        dt = self.clock.now() - self.t_last
        target = AMBIENT_C if self._alarm() else self.sp
        self.air += (target - self.air) * (1.0 - math.exp(-dt / 30.0))
        self.t_last = self.clock.now()

    def read(self) -> ChamberReading:
        self._advance()
        return ChamberReading(self.sp, self.air, self._alarm())


class StallingStream(Stream):
    """The 100 Hz stream, silent during ``stalls`` ``(start, end)`` run seconds (its
    samples then come in a burst, as a device FIFO gives them)."""

    def __init__(self, clock: FakeClock, stalls=()) -> None:
        super().__init__(clock)
        self.stalls = list(stalls)

    def read(self, timeout_s: float) -> AdcRead:
        t = self.clock.now() - 1000.0
        return AdcRead() if any(a <= t < b for a, b in self.stalls) else super().read(timeout_s)


PROFILE = Profile("t", (Step(25.0, 60.0, "soak"), Step(40.0, 120.0), Step(30.0, 60.0)))


def _run(
    tmp_path: Path,
    suspend: Suspend | None,
    *,
    alarms=(),
    therm_faults=(),
    stalls=(),
    pause=None,
    comm_timeout_s: float = 60.0,
) -> tuple[RunResult, Recording, Chamber]:
    clock = FakeClock()
    chamber = AlarmChamber(clock, alarms)
    out = tmp_path / "run.mcap"
    w = RecordingWriter(out, start_time_ns=0, run={}, bench={})
    acq = Acquisition(
        profile=PROFILE,
        writer=w,
        clock=clock,
        thermometer=Thermometer(clock, chamber, therm_faults),
        chamber=chamber,
        gyro=StallingStream(clock, stalls),
        rate_stream=GyroAdcConfig(sample_rate_hz=100.0),
        limits=Limits(comm_timeout_s=comm_timeout_s, pt100_max_c=75.0, watchdog_samples=3),
        safe_state=SafeState(setpoint_c=25.0),
        pt100_period_s=1.0,
        chamber_period_s=2.0,
        threaded=False,
        turn_s=0.125,
        suspend=suspend,
    )
    if pause is not None:  # the operator: pause at a, resume at b (run seconds)
        a, b = pause
        sleep = clock.sleep

        def operator(dt: float) -> None:
            sleep(dt)
            t = clock.now() - 1000.0
            if a <= t < b:
                acq.request_pause("paused by the test")
            elif t >= b:
                acq.request_resume()

        clock.sleep = operator  # type: ignore[method-assign]
    res = acq.run()
    w.close()
    return res, read_recording(out), chamber


def _events(rec: Recording, name: str) -> list[dict]:
    return [e for e in rec.events if e["event"] == name]


def _starts(rec: Recording) -> list[tuple[int, float]]:
    return [(e["step"], round(e["t"], 3)) for e in _events(rec, "step_started")]


def test_a_chamber_alarm_of_two_minutes_holds_the_step_and_it_re_soaks(tmp_path: Path) -> None:
    """The alarm at 100 s (step 2, 40 °C) stops the chamber for 120 s: the air falls
    towards 25 °C, out of the band, so step 2 starts again when the alarm clears."""
    res, rec, chamber = _run(tmp_path, Suspend(), alarms=[(100.0, 220.0)])
    assert res.outcome == "completed" and res.safe_state_ok and res.suspensions == 1
    (sus,) = _events(rec, "suspended")
    (back,) = _events(rec, "resumed")
    # seen at the first oven poll in the alarm (2 s polls), cleared at the first after it
    assert sus["t"] == pytest.approx(100.0, abs=0.2) and "chamber alarm" in sus["detail"]
    assert back["t"] == pytest.approx(220.0, abs=0.2) and "re-soaks" in back["detail"]
    assert sus["step"] == back["step"] == 1
    b = back["t"]
    assert _starts(rec) == [(0, 0.0), (1, 60.0), (1, round(b, 3)), (2, round(b + 120.0, 3))]
    assert rec.events[-2]["event"] == "run_ended"
    assert res.t_end == pytest.approx(back["t"] + 180.0, abs=1e-6)
    # while held the setpoint stayed at 40 °C; the resume commanded it again
    assert [c for t, c in chamber.commands if 100.0 < t < b] == []
    assert [c for t, c in chamber.commands if b <= t < b + 1.0] == [40.0]
    # the oven record says "hold" while the run was held
    held = (rec.oven_t > sus["t"] + 1) & (rec.oven_t < back["t"] - 1)
    assert set(np.asarray(rec.oven_mode)[held]) == {"hold"}
    (start,) = [m for m in rec.logs if m.get("kind") == "suspend"]
    (clear,) = [m for m in rec.logs if m.get("kind") == "suspend_cleared"]
    assert start["data"]["condition"] == "chamber alarm" and start["source"] == "oven"
    assert clear["data"]["held_s"] == pytest.approx(120.0, abs=2.1)
    assert rec.require_rate().gaps() == []  # the data went on being recorded


def test_a_chamber_alarm_past_its_limit_ends_in_the_verified_safe_state(tmp_path: Path) -> None:
    res, rec, chamber = _run(tmp_path, Suspend(chamber_alarm_s=90.0), alarms=[(100.0, 1e9)])
    assert res.outcome == "fault" and "chamber alarm for" in res.reason
    assert "chamber_alarm_s 90 s" in res.reason
    (ab,) = _events(rec, "aborted")
    assert ab["t"] == pytest.approx(190.0, abs=0.3)
    assert res.safe_state_ok and chamber.commands[-1][1] == 25.0
    (ss,) = _events(rec, "safe_state")
    assert "verified" in ss["detail"]


def test_without_the_suspender_a_chamber_alarm_ends_the_run_at_once(tmp_path: Path) -> None:
    res, rec, chamber = _run(tmp_path, Suspend(chamber_alarm_s=0.0), alarms=[(100.0, 1e9)])
    assert res.outcome == "fault" and "chamber alarm: limit alarm" in res.reason
    assert _events(rec, "aborted")[0]["t"] == pytest.approx(100.0, abs=0.2)
    assert res.suspensions == 0 and res.safe_state_ok


def test_a_lost_pt100_holds_the_step_without_a_re_soak(tmp_path: Path) -> None:
    """No reading 70-80 s (step 2 ramping to 40 °C): held from 5 s after the last
    reading (69 s) to the next (80 s), then step 2 goes on for what it had left (its clock
    stopped): it ends that much later than it would have."""
    res, rec, _ = _run(tmp_path, Suspend(resoak_band_c=5.0), therm_faults=[(70.0, 80.0, "timeout")])
    assert res.outcome == "completed" and res.suspensions == 1
    (sus,) = _events(rec, "suspended")
    (back,) = _events(rec, "resumed")
    assert "temperature lost" in sus["detail"] and "goes on" in back["detail"]
    held = back["t"] - sus["t"]
    assert sus["t"] == pytest.approx(74.125) and back["t"] == pytest.approx(80.0)
    assert _starts(rec) == [(0, 0.0), (1, 60.0), (2, round(180.0 + held, 3))]


def test_a_pt100_lost_past_its_limit_ends_the_run(tmp_path: Path) -> None:
    """Limit 30 s < comm_timeout_s 60 s: the suspender, not the watchdog, ends it (held
    from 74.125 s: 5 s without a reading)."""
    res, rec, chamber = _run(
        tmp_path, Suspend(temperature_lost_s=30.0), therm_faults=[(70.0, 1e9, "timeout")]
    )
    assert res.outcome == "fault" and "temperature lost for" in res.reason
    assert _events(rec, "aborted")[0]["t"] == pytest.approx(104.25, abs=0.2)
    assert res.safe_state_ok


def test_a_stalled_stream_holds_the_run_and_its_gap_is_whole(tmp_path: Path) -> None:
    """No samples 100-120 s: held from 5 s into the stall, resumed when the samples come
    back (in a burst: nothing is lost), and step 2 ends that much later."""
    res, rec, _ = _run(tmp_path, Suspend(), stalls=[(100.0, 120.0)])
    assert res.outcome == "completed" and res.suspensions == 1
    (sus,) = _events(rec, "suspended")
    (back,) = _events(rec, "resumed")
    assert "stream stall" in sus["detail"] and sus["t"] == pytest.approx(105.0, abs=0.2)
    assert back["t"] == pytest.approx(120.0, abs=0.2)
    assert rec.require_rate().gaps() == []


def test_an_operator_pause_holds_the_run_until_resumed(tmp_path: Path) -> None:
    res, rec, _ = _run(tmp_path, Suspend(), pause=(30.0, 90.0))
    assert res.outcome == "completed" and res.suspensions == 1
    (sus,) = _events(rec, "suspended")
    (back,) = _events(rec, "resumed")
    assert "operator pause" in sus["detail"] and sus["step"] == 0
    assert back["t"] - sus["t"] == pytest.approx(60.0, abs=0.3)
    # the soak (25 °C, the temperature never left its band) goes on: 60 s + 60 s held
    assert _starts(rec)[1] == (1, pytest.approx(back["t"] + 30.0, abs=0.3))


def test_an_operator_pause_is_refused_when_switched_off(tmp_path: Path) -> None:
    res, rec, _ = _run(tmp_path, Suspend(operator_pause_s=0.0), pause=(30.0, 40.0))
    assert res.outcome == "completed" and res.suspensions == 0
    (refused,) = [m for m in rec.logs if m.get("data", {}).get("refused")]
    assert refused["kind"] == "suspend" and "operator_pause_s = 0" in refused["message"]
    assert res.t_end == pytest.approx(240.0, abs=1e-6)


# ---------------------------------------------------------------- on the simulated bench

PROFILE_TOML = """name = "alarm"
[[step]]
setpoint_c = 25
duration_s = 30
[[step]]
setpoint_c = 40
duration_s = 100
"""


def _acquire_with_alarm(tmp_path: Path, capsys, duration_s: float) -> tuple[int, str, Path]:
    from gyrolab.cli import main

    prof = tmp_path / "p.toml"
    prof.write_text(PROFILE_TOML, encoding="utf-8")
    faults = tmp_path / "faults.toml"
    faults.write_text(
        f'[[event]]\nkind = "chamber_alarm"\nt_s = 60\nduration_s = {duration_s}\n',
        encoding="utf-8",
    )
    out = tmp_path / "run.mcap"
    argv = ["acquire", "--bench", "sim", "--profile", str(prof), "--faults", str(faults)]
    rc = main([*argv, "--speed", "100", "--out", str(out)])
    return rc, capsys.readouterr().err, out


def test_faults_file_chamber_alarm_of_two_minutes_suspends_and_resumes(
    tmp_path: Path, capsys
) -> None:
    """FAULTS.toml: the simulated F4's limit controller trips for 120 s in step 2: the run
    is held (heater and refrigerator off), resumes when it clears and completes; the
    gyro case moved well under the 1 °C band meanwhile (the simulated chamber ramps about
    1 °C/min and had not left 26 °C), so step 2 goes on, ending as much later as it was
    held."""
    from gyrolab.report.record_sections import suspension_rows

    rc, err, out = _acquire_with_alarm(tmp_path, capsys, 120.0)
    assert rc == 0, err
    assert "1 suspension(s)" in err and "safe state verified" in err
    rec = read_recording(out)
    (sus,) = _events(rec, "suspended")
    (back,) = _events(rec, "resumed")
    assert sus["step"] == 1 and "chamber alarm" in sus["detail"]
    assert "digital input 1 active" in sus["detail"]
    assert back["t"] - sus["t"] == pytest.approx(120.0, abs=6.0)  # 2 s polls, the bench's tick
    assert "goes on" in back["detail"]
    (ended,) = [e for e in _events(rec, "step_ended") if e["step"] == 1]
    assert ended["t"] == pytest.approx(30.0 + 100.0 + (back["t"] - sus["t"]), abs=1e-6)
    assert rec.events[-2]["event"] == "run_ended"
    (row,) = suspension_rows(rec)  # what the report's run log shows
    assert row[2] == "2" and row[4] == "the step goes on"


def test_faults_file_chamber_alarm_past_its_limit_ends_in_the_verified_safe_state(
    tmp_path: Path, capsys
) -> None:
    rc, err, out = _acquire_with_alarm(tmp_path, capsys, 1000.0)
    assert rc == 1, err
    assert "chamber_alarm_s 300 s" in err and "safe state verified" in err
    rec = read_recording(out)
    (sus,) = _events(rec, "suspended")
    (ab,) = _events(rec, "aborted")
    # 300 s, and the engine's reaction time: a turn or two, seconds at 100x when loaded
    assert 300.0 <= ab["t"] - sus["t"] <= 315.0
    assert _events(rec, "safe_state")[0]["detail"].startswith("setpoint 25")


def test_sigusr1_pauses_and_sigusr2_resumes_even_before_the_run() -> None:
    """The operator's signals (gyrolab/acquisition/interrupts.py): during the run SIGUSR1
    pauses and SIGUSR2 resumes; one sent while ``acquire`` starts up is kept for the run
    (its default action would kill the process); the handlers are restored after."""
    import os
    import signal

    from gyrolab.acquisition import interrupts

    got: list[str] = []
    with interrupts.deferred_stop_signals():
        os.kill(os.getpid(), signal.SIGUSR1)  # while starting up
        with interrupts.pause_requests(got.append, lambda: got.append("resumed")):
            os.kill(os.getpid(), signal.SIGUSR2)
            os.kill(os.getpid(), signal.SIGUSR1)
    assert got == ["paused by SIGUSR1", "resumed", "paused by SIGUSR1"]
    assert signal.getsignal(signal.SIGUSR1) is signal.SIG_DFL


def test_the_simulated_benchs_hold_rule_hears_what_its_watchdog_hears() -> None:
    """The hold rule's wall floor counts from the last time the watchdog heard a source
    (one record): a rule of its own, never told, would pass its floor at once and hold the
    run on every simulated-time silence (a quiet machine's 600x demo held 214 times)."""
    from gyrolab.app.sim_bench import SIM_HOLD_MIN_WALL_S, SimHandle, SimSilence

    watchdog = SimSilence(1.0)
    hold = watchdog.sharing(SIM_HOLD_MIN_WALL_S)
    watchdog.heard("multimeter")
    assert not hold.lost("multimeter", 100.0, 5.0)  # heard a moment ago: not silent in wall time
    assert hold.lost("oven", 100.0, 5.0)  # never heard at all
    handle = SimHandle({}, None, watchdog, float, 300.0, None, lambda: None)  # type: ignore[arg-type]
    assert handle.hold_silence is not None and not handle.hold_silence.lost(
        "multimeter", 100.0, 5.0
    )


def test_the_flight_controller_bench_holds_before_it_gives_a_source_up(monkeypatch) -> None:
    """The FC bench's two wall floors, like the ADC bench's: a source silent for 5-15 s of
    wall time (and past its simulated limits) holds the run but is not lost; from 15 s it
    is; both rules count from what the watchdog heard (one record)."""
    import gyrolab.app.sim_bench as sim_bench
    from gyrolab.app.fc_bench import FC_COMM_MIN_WALL_S, FC_HOLD_MIN_WALL_S, fc_silence

    assert FC_HOLD_MIN_WALL_S < FC_COMM_MIN_WALL_S
    now = [1000.0]

    class WallClock:
        @staticmethod
        def monotonic() -> float:
            return now[0]

    monkeypatch.setattr(sim_bench, "time", WallClock)
    watchdog, hold = fc_silence()
    watchdog.heard("chamber")
    for wall, held, lost in [(1.0, False, False), (6.0, True, False), (16.0, True, True)]:
        now[0] = 1000.0 + wall
        assert hold.lost("chamber", 500.0, 5.0) is held, wall
        assert watchdog.lost("chamber", 500.0, 60.0) is lost, wall
    assert not hold.lost("chamber", 4.0, 5.0)  # within its simulated limit: never held
