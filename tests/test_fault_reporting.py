"""Faults the instruments report, and a stream that stops, reach /log and the run result.

`gyrolab acquire --bench sim --faults FAULTS.toml` (docs/instruments.md, "Fault
injection"): SCPI error-queue entries and Modbus exception responses are logged as level
``fault`` with their code and text, and end the run or not by their class; an ADC stream
that stops for good is a gap up to the end of the run.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from gyrolab.cli import main
from gyrolab.record.reader import read_recording


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


PROFILE = """name = "faults"
[[step]]
setpoint_c = 25
duration_s = 30
[[step]]
setpoint_c = 35
duration_s = 200
"""


def _acquire(tmp_path: Path, faults: str, capsys) -> tuple[int, str, Path]:
    prof = _write(tmp_path / "p.toml", PROFILE)
    f = _write(tmp_path / "faults.toml", faults)
    out = tmp_path / "run.mcap"
    argv = ["acquire", "--bench", "sim", "--profile", str(prof), "--faults", str(f)]
    rc = main([*argv, "--speed", "20", "--out", str(out)])
    return rc, capsys.readouterr().err, out


def test_scpi_and_modbus_errors_are_logged_as_faults_and_stop_the_run_by_class(
    tmp_path: Path, capsys
) -> None:
    rc, err, out = _acquire(
        tmp_path,
        """
[[event]]
kind = "scpi_error"
t_s = 10
detail = '-222,"Data out of range"'
[[event]]
kind = "modbus_exception"
t_s = 15
count = 2
[[event]]
kind = "scpi_error"
t_s = 40
detail = '-310,"System error"'
""",
        capsys,
    )
    assert rc == 1, err
    assert 'SCPI error -310 "System error"' in err and "safe state verified" in err
    rec = read_recording(out)
    faults = [m for m in rec.logs if m["level"] == "fault" and m.get("data")]
    scpi = [m["data"] for m in faults if m["data"].get("protocol") == "SCPI"]
    modbus = [m for m in faults if m["data"].get("protocol") == "Modbus"]
    # The execution error (-222) is logged and the run goes on ...
    (e222,) = [d for d in scpi if d["code"] == -222]
    assert e222["text"] == "Data out of range" and e222["error_class"] == "execution error"
    assert e222["fatal"] is False
    # ... the device-specific one (-310) is logged and ends the run, safely.
    (e310,) = [m for m in faults if m["data"].get("code") == -310]
    assert e310["data"]["fatal"] is True and "System error" in e310["message"]
    assert e310["source"] == "multimeter" and e310["t"] > 30.0
    assert rec.pt100_t.max() > 30.0  # readings went on after the -222 at ~10 s
    # The Modbus exception responses (06, busy): each one, with its code and name.
    assert len(modbus) == 2 and all(m["source"] == "oven" for m in modbus)
    assert {m["data"]["code"] for m in modbus} == {6}
    assert all("SERVER DEVICE BUSY" in m["message"] for m in modbus)
    ev = [e["event"] for e in rec.events]
    assert ev[-2:] == ["aborted", "safe_state"] and "-310" in rec.events[-2]["detail"]
    assert "verified" in rec.events[-1]["detail"]
    # The injection itself is recorded as the simulator's provenance.
    assert "fault_injection" in rec.metadata["sim_provenance"]


def test_a_stream_that_stops_is_a_gap_up_to_the_end_of_the_run(tmp_path: Path, capsys) -> None:
    rc, err, out = _acquire(
        tmp_path, '[[event]]\nkind = "stall"\nt_s = 20\nduration_s = 1e6\n', capsys
    )
    assert rc == 1 and "lost communication with adc" in err, err
    rec = read_recording(out)
    (gap,) = [m for m in rec.logs if m.get("kind") == "gap"]
    d = gap["data"]
    assert d["cause"] == "stream stopped"
    last = rec.adc.t[-1] + rec.adc.period  # end of the last sample received
    assert d["t_first_missing"] == pytest.approx(last, abs=1e-6)
    assert d["first_missing_index"] == rec.adc.index[-1] + 1
    # From the last sample to the end of the run, the watchdog's 60 s and more (the clock
    # moves in ticks: exactly 60 s can be what "more than 60 s" first reads as).
    assert d["t_end"] - last >= 60.0 - 1e-6
    assert d["n_missing"] == round((d["t_end"] - last) / rec.adc.period)
    assert f"1 gap(s) ({d['n_missing']} samples missing)" in err


def test_scanner_faults_on_the_simulated_multi_unit_bench(tmp_path: Path, capsys) -> None:
    """Three units through the real 34970A driver on the simulated scanner: unit 2's PT100
    channel open for 30 s (only its readings lost, logged, back again), an execution error
    in the scanner's queue (logged, the run goes on), then the scanner silent for good (the
    run ends, oven in the safe state, the recording whole)."""
    prof = _write(tmp_path / "p.toml", PROFILE)
    f = _write(
        tmp_path / "faults.toml",
        """
[[event]]
kind = "open_channel"
unit = 1
t_s = 20
duration_s = 30
[[event]]
kind = "scpi_error"
t_s = 60
detail = '-222,"Data out of range"'
[[event]]
kind = "outage"
t_s = 100
duration_s = 1e6
""",
    )
    out = tmp_path / "run.mcap"
    argv = ["acquire", "--bench", "sim", "--units", "3", "--profile", str(prof)]
    rc = main([*argv, "--faults", str(f), "--speed", "40", "--out", str(out)])
    err = capsys.readouterr().err
    # held while the scanner says nothing (a suspender), ended after temperature_lost_s
    assert rc == 1 and "temperature lost for" in err and "34970A" in err, err
    assert "safe state verified" in err and "(3 units; dropped: none)" in err
    serials = ["SIM0-01", "SIM0-02", "SIM0-03"]
    recs = {s: read_recording(out, unit=s) for s in serials}
    logs = recs["SIM0-01"].logs
    lost, back = [m for m in logs if m.get("data", {}).get("unit") == "SIM0-02"]
    assert lost["kind"] == "fault" and lost["data"]["channel"] == 102
    assert back["kind"] == "recovery" and 25.0 <= back["data"]["outage_s"] <= 35.0
    t2, t1 = recs["SIM0-02"].pt100_t, recs["SIM0-01"].pt100_t
    assert not ((t2 >= lost["t"]) & (t2 < back["t"])).any() and (t2 > back["t"]).any()
    assert ((t1 >= lost["t"]) & (t1 < back["t"])).sum() >= 12  # the others went on
    (e222,) = [m for m in logs if m.get("data", {}).get("code") == -222]
    assert e222["source"] == "scanner" and e222["data"]["fatal"] is False
    assert e222["t"] < t1.max()  # readings went on after it
    ev = [e["event"] for e in recs["SIM0-03"].events]
    assert ev[-2:] == ["aborted", "safe_state"]
    assert "verified" in recs["SIM0-03"].events[-1]["detail"]
    for s in serials:  # every unit's rate, whole, up to the end of the run
        rate = recs[s].require_rate()
        assert rate.gaps() == [] and rate.t[-1] > t1.max() + 30.0


def test_faults_file_keys_are_strict_and_only_for_the_simulated_bench(
    tmp_path: Path, capsys
) -> None:
    out = tmp_path / "run.mcap"
    cases = {
        '[adc]\ncorupt_prob = 0.1\n': "[adc]: unknown key(s) ['corupt_prob']",
        'bogus = 1\n': "unknown key(s) ['bogus']",
        '[[event]]\nkind = "stall"\nt_s = 1\nduration = 5\n': "unknown key(s) ['duration']",
        '[[event]]\nkind = "meltdown"\n': "kind = 'meltdown'",
        '[[event]]\nkind = "stall"\nt_s = 1\n': "stall needs duration_s > 0",
        '[oven]\nexception_prob = 1.5\n': "exception_prob = 1.5",
        '[[event]]\nkind = "scpi_error"\ndetail = "oops"\n': "expected an error-queue entry",
        '[[event]]\nkind = "open_channel"\nt_s = 1\n': "open_channel needs duration_s > 0",
        '[[event]]\nkind = "open_channel"\nt_s = 1\nduration_s = 5\n': "--units N only",
    }
    for i, (text, msg) in enumerate(cases.items()):
        f = _write(tmp_path / f"f{i}.toml", text)
        argv = ["acquire", "--bench", "sim", "--profile", "short", "--faults", str(f)]
        assert main([*argv, "--out", str(out)]) == 2, text
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and f"f{i}.toml" in lines[0] and msg in lines[0], lines
        assert not out.exists()
    lab = Path(__file__).resolve().parents[1] / "examples" / "lab.toml"
    f = _write(tmp_path / "ok.toml", "")
    assert main(["acquire", "--bench", str(lab), "--faults", str(f), "--out", str(out)]) == 2
    assert "--faults applies to --bench sim only" in capsys.readouterr().err
    assert not out.exists()


def test_a_fault_plan_must_fit_the_bench() -> None:
    """Scanner faults name a unit the bench has, whose PT100 the scanner reads."""
    from gyrolab.errors import InputError
    from gyrolab.sim.bench.fault_file import check_plan_for_bench, faults_from_dict

    def plan(kind: str, unit: int) -> object:
        ev = {"kind": kind, "t_s": 1.0, "duration_s": 5.0, "unit": unit}
        return faults_from_dict({"event": [ev]}, "f.toml")

    check_plan_for_bench(plan("open_channel", 1), 3, "f.toml")  # fits
    check_plan_for_bench(plan("outage", 0), 2, "f.toml", (1,))  # unit 2 is on the scanner
    bad = {
        ("open_channel", 1, 3, (2,)): "unit = 1 reads its internal sensor",
        ("open_channel", 0, 0, ()): "--units N only",
        ("open_channel", 3, 3, ()): "unit = 3: the bench has 3 unit(s)",
        ("outage", 0, 2, (1, 2)): "every unit reads its internal sensor, no scanner",
    }
    for (kind, unit, units, internal), msg in bad.items():
        with pytest.raises(InputError, match=re.escape(msg)):
            check_plan_for_bench(plan(kind, unit), units, "f.toml", internal)  # type: ignore[arg-type]


class _LateMeter:
    """A resource whose first READ? is answered after the driver gave up: the late reply
    sits in the input buffer when the next query is sent."""

    timeout = 250
    resource_name = "GPIB0::22::INSTR"

    def __init__(self) -> None:
        self.buffer: list[str] = []
        self.sent: list[str] = []
        self.n_read = 0

    def write(self, command: str) -> None:
        self.sent.append(command)

    def query(self, command: str) -> str:
        self.sent.append(command)
        if command == "READ?":
            self.n_read += 1
            reply = f"+1.0{self.n_read}000000E+02"
            if self.n_read == 1:
                self.buffer.append(reply)  # arrives late
                raise TimeoutError("VI_ERROR_TMO: Timeout expired before operation completed")
        else:
            reply = '+0,"No error"'
        self.buffer.append(reply)
        return self.buffer.pop(0)

    def read(self) -> str:
        if not self.buffer:
            raise TimeoutError("VI_ERROR_TMO: Timeout expired before operation completed")
        return self.buffer.pop(0)

    def close(self) -> None:
        pass


def test_multimeter_stays_in_step_after_a_late_reply() -> None:
    """Without the resync every later answer is the previous query's: READ? gets the
    late reading (stale) and SYST:ERR? gets a reading (unparsable), for good."""
    from gyrolab.instruments.drivers.agilent34401a import Agilent34401A
    from gyrolab.instruments.roles import InstrumentTimeout

    res = _LateMeter()
    dmm = Agilent34401A(res, timeout_s=0.25)
    with pytest.raises(InstrumentTimeout):
        dmm.read()
    assert dmm.read().resistance_ohm == pytest.approx(102.0)  # this READ?'s own reply
    assert dmm.errors == []
    assert dmm.read().resistance_ohm == pytest.approx(103.0)
    assert dmm.late_replies == 1
