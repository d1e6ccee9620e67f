"""The run engine with several units and a scanner, without threads or ports
(``Acquisition(threaded=False)``, as tests/test_run_core.py): a scripted scanner — silent,
a channel open (overload), a channel hot, SCPI error-queue entries — and what the run, the
recording and the status snapshots make of it (docs/fleet.md, "Acquisition")."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from test_run_core import Chamber, FakeClock, Stream

from gyrolab.acquisition.bench_config import Limits, SafeState
from gyrolab.acquisition.runner import Acquisition, RunResult, Status, UnitDevices
from gyrolab.instruments.drivers.gyroadc import GyroAdcConfig
from gyrolab.instruments.roles import InstrumentReport, InstrumentTimeout, ThermometerReading
from gyrolab.instruments.scpi import scpi_reports
from gyrolab.profiles.profile import Profile, Step
from gyrolab.pt100 import cvd_resistance
from gyrolab.record.reader import Recording, read_recording
from gyrolab.record.writer import RecordingWriter

SERIALS = ["U1", "U2", "U3"]
CHANNELS = [101, 102, 103]


class Scanner:
    """Every unit's PT100 on its channel: the chamber air, +0.01 °C per unit. ``script``:
    ``(start, end, kind, channel)`` in run seconds — ``timeout`` (no sweep at all), ``open``
    (the channel overloads: NaN, as the driver returns it) or ``hot`` (90 °C); ``errors``:
    ``(t, code, text)`` entries of the error queue, reported after the first sweep at or
    after ``t`` (classified by the drivers' own SCPI rule)."""

    name = "scanner"
    channels = tuple(CHANNELS)

    def __init__(self, clock: FakeClock, chamber: Chamber, script=(), errors=()) -> None:
        self.clock, self.chamber, self.script = clock, chamber, list(script)
        self.errors = sorted(errors)
        self._reports: list[InstrumentReport] = []

    def read(self) -> dict[int, ThermometerReading]:
        t = self.clock.now() - 1000.0
        active = [(kind, ch) for a, b, kind, ch in self.script if a <= t < b]
        if any(kind == "timeout" for kind, _ in active):
            raise InstrumentTimeout("34970A", "no reply to READ?")
        out = {}
        for k, ch in enumerate(self.channels):
            kinds = {kind for kind, c in active if c == ch}
            c = 90.0 if "hot" in kinds else self.chamber.air + 0.01 * k
            if "open" in kinds:
                out[ch] = ThermometerReading(math.nan, math.nan)
            else:
                out[ch] = ThermometerReading(float(cvd_resistance(c)), c)
        due = [(code, text) for te, code, text in self.errors if te <= t]
        self.errors = [e for e in self.errors if e[0] > t]
        self._reports += scpi_reports(due, "after READ?")
        return out

    def reports(self) -> list[InstrumentReport]:
        out, self._reports = self._reports, []
        return out


def _run(
    tmp_path: Path, *, script=(), errors=(), comm_timeout_s: float = 20.0
) -> tuple[RunResult, dict[str, Recording], Chamber, list[Status]]:
    clock = FakeClock()
    chamber = Chamber(clock)
    units = []
    for serial, ch in zip(SERIALS, CHANNELS, strict=True):
        stream = Stream(clock)
        stream.name = f"unit/{serial}"
        units.append(UnitDevices(serial, stream, GyroAdcConfig(sample_rate_hz=100.0), ch))
    out = tmp_path / "run.mcap"
    w = RecordingWriter(out, start_time_ns=0, run={}, bench={}, units=SERIALS)
    snapshots: list[Status] = []

    def keep(st: Status) -> None:
        snapshots.append(Status(**{**vars(st), "units": list(st.units)}))

    acq = Acquisition(
        profile=Profile("t", (Step(25.0, 60.0, "soak"), Step(40.0, 120.0))),
        writer=w,
        clock=clock,
        thermometer=Scanner(clock, chamber, script, errors),
        chamber=chamber,
        units=units,
        limits=Limits(comm_timeout_s=comm_timeout_s, pt100_max_c=75.0, watchdog_samples=3),
        safe_state=SafeState(setpoint_c=25.0),
        pt100_period_s=2.0,
        chamber_period_s=2.0,
        on_status=keep,
        status_every_s=0.0,
        threaded=False,
        turn_s=0.125,  # exact in binary: the scripted times are hit exactly
    )
    res = acq.run()
    w.close()
    return res, {s: read_recording(out, unit=s) for s in SERIALS}, chamber, snapshots


def _aborted_at(rec: Recording) -> float:
    (ab,) = [e for e in rec.events if e["event"] == "aborted"]
    return float(ab["t"])


def test_a_silent_scanner_ends_the_run_in_the_safe_state(tmp_path: Path) -> None:
    res, recs, chamber, _ = _run(tmp_path, script=[(50.0, 1e9, "timeout", 0)])
    assert res.outcome == "fault" and "lost communication with scanner" in res.reason
    assert res.safe_state_ok and chamber.commands[-1][1] == 25.0
    # last sweep at 48 s; lost 20 s later, at the next 0.125 s turn
    assert _aborted_at(recs["U1"]) == pytest.approx(68.125, abs=1e-9)
    logs = recs["U1"].logs
    (first,) = [m for m in logs if m["source"] == "scanner" and m.get("kind") == "fault"]
    assert first["t"] == pytest.approx(50.0) and "InstrumentTimeout" in first["message"]
    assert any(m["level"] == "fault" and m["source"] == "watchdog" for m in logs)
    for s in SERIALS:  # every unit recorded up to the end, readable, no gap
        rate = recs[s].require_rate()
        assert rate.gaps() == [] and 67.0 < rate.t[-1] + rate.period <= 68.7
        assert recs[s].pt100_t.max() == pytest.approx(48.0)
    assert [e["event"] for e in recs["U2"].events][-2:] == ["aborted", "safe_state"]


def test_an_open_channel_loses_that_unit_s_readings_only(tmp_path: Path) -> None:
    res, recs, _, snaps = _run(tmp_path, script=[(30.0, 90.0, "open", 102)])
    assert res.outcome == "completed" and res.units_dropped == [] and res.faults == 1
    n1 = recs["U1"].pt100_t.size
    assert n1 >= 89 and recs["U3"].pt100_t.size == n1  # the others: every sweep
    t2 = recs["U2"].pt100_t
    assert t2.size == n1 - 30  # the sweeps at 30, 32 … 88 s: a gap, nothing invented
    assert not ((t2 >= 30.0) & (t2 < 90.0)).any() and t2.max() > 170.0
    logs = [m for m in recs["U2"].logs if m.get("data", {}).get("unit") == "U2"]
    lost, back = logs
    assert (lost["kind"], lost["t"], lost["data"]["channel"]) == ("fault", 30.0, 102)
    assert lost["source"] == "scanner" and "still recorded" in lost["message"]
    assert back["kind"] == "recovery" and back["t"] == 90.0
    assert back["data"]["outage_s"] == 60.0 and back["data"]["sweeps_lost"] == 30
    rate = recs["U2"].require_rate()  # kept: its rate is whole, to the end
    assert rate.gaps() == [] and rate.t[-1] + rate.period == pytest.approx(180.0, abs=0.2)
    # the status: U2 shows its lost PT100 while it lasts, the others keep their readings
    during = [s for s in snaps if 31.0 < s.t < 89.0]
    assert during and all(
        [u.state for u in s.units] == ["recording", "pt100_lost", "recording"]
        and math.isnan(s.units[1].temperature_c)
        and math.isfinite(s.units[0].temperature_c)
        for s in during
    )
    assert [u.state for u in snaps[-1].units] == ["recording"] * 3
    assert [u.serial for u in snaps[-1].units] == SERIALS
    assert snaps[-1].samples == sum(u.samples for u in snaps[-1].units) > 3 * 17_000


def test_a_lost_reading_neither_clears_nor_trips_the_temperature_watchdog(
    tmp_path: Path,
) -> None:
    """U3 reads hot at 100 and 102 s, its channel is open at 104 and 106 s, hot again at
    108 s: the third hot reading in a row trips the watchdog (an open channel says nothing
    about the temperature). U2's channel, open from 50 s, does not stop anyone else's."""
    script = [
        (50.0, 1e9, "open", 102),
        (100.0, 104.0, "hot", 103),
        (104.0, 108.0, "open", 103),
        (108.0, 1e9, "hot", 103),
    ]
    res, recs, chamber, _ = _run(tmp_path, script=script)
    assert res.outcome == "fault" and "unit U3 PT100 over-temperature" in res.reason
    assert _aborted_at(recs["U1"]) == pytest.approx(108.0, abs=1e-9)
    assert res.safe_state_ok and chamber.commands[-1][1] == 25.0


def test_every_channel_open_is_a_blind_watchdog_and_ends_the_run(tmp_path: Path) -> None:
    script = [(40.0, 1e9, "open", ch) for ch in CHANNELS]
    res, recs, _, _ = _run(tmp_path, script=script)
    assert res.outcome == "fault" and "no unit's temperature reading" in res.reason
    # the last sweep with a reading at 38 s; blind for more than 20 s at the 58.125 s turn
    assert _aborted_at(recs["U1"]) == pytest.approx(58.125, abs=1e-9)
    assert res.safe_state_ok
    lost = [m for m in recs["U1"].logs if m.get("kind") == "fault" and m["source"] == "scanner"]
    assert sorted(m["data"]["unit"] for m in lost) == SERIALS  # each logged once


def test_scanner_error_queue_entries_are_faults_and_a_device_error_ends_the_run(
    tmp_path: Path,
) -> None:
    errors = [(20.0, -222, "Data out of range"), (100.0, -310, "System error")]
    res, recs, chamber, _ = _run(tmp_path, errors=errors)
    scpi = [m for m in recs["U1"].logs if m.get("data", {}).get("protocol") == "SCPI"]
    e222, e310 = scpi
    assert e222["source"] == "scanner" and e222["level"] == "fault" and e222["t"] == 20.0
    assert e222["data"]["code"] == -222 and e222["data"]["fatal"] is False
    assert e310["data"]["code"] == -310 and e310["data"]["fatal"] is True
    assert res.outcome == "fault" and 'scanner reported SCPI error -310 "System error"' in (
        res.reason
    )
    assert _aborted_at(recs["U1"]) == pytest.approx(100.0, abs=1e-9)
    assert res.safe_state_ok and chamber.commands[-1][1] == 25.0
    for s in SERIALS:  # readings went on after the -222 at 20 s, up to the -310
        assert recs[s].pt100_t.max() == pytest.approx(100.0)
