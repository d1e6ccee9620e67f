"""Declarative driver settings (gyrolab/instruments/settings.py, docs/instruments.md
"Declaring a setting"): checked before anything is sent, written, read back, held until
sent, on text commands and Modbus registers."""

from __future__ import annotations

from typing import Any

import pytest

from gyrolab.instruments.roles import InstrumentError, LimitError
from gyrolab.instruments.settings import Setting, Settings, finite_within, in_range, one_of


class MyMeter(Settings):
    """The example of docs/instruments.md, on a recorded line."""

    NAME = "MY-100"
    NPLC_VALUES = (0.2, 1.0, 10.0)
    nplc = Setting(
        "VOLT:NPLC {value:g}",
        "integration time, power-line cycles",
        get="VOLT:NPLC?",
        label="NPLC",
        validator=one_of,
        values="NPLC_VALUES",
        cast=float,
    )
    gain = Setting("GAIN {value}", "amplifier gain", validator=in_range, values=(1, 100))

    def __init__(self, replies: dict[str, str] | None = None) -> None:
        self.written: list[str] = []
        self.replies = replies or {}

    def write(self, command: str) -> None:
        self.written.append(command)

    def query(self, command: str) -> str:
        return self.replies[command]


class NarrowMeter(MyMeter):
    NPLC_VALUES = (1.0,)
    nplc = MyMeter.nplc.with_command("VOLT:NPLC {value:g},(@101)")


class Controller:
    """A Modbus slave's setpoint register, the F4 way: °C x 10 on register 300."""

    NAME = "CTRL"
    setpoint_c = Setting(
        300,
        "setpoint, °C",
        get=300,
        label="setpoint",
        unit="°C",
        validator=finite_within,
        values=lambda d: [("bench limits", d.limits)],
        set_process=lambda d, v: round(10 * v),
        get_process=lambda d, raw: raw / 10,
        readback=True,
    )

    def __init__(self, stuck: int | None = None) -> None:
        self.limits = (-40.0, 70.0)
        self.registers: dict[int, int] = {}
        self.log: list[tuple[str, int, int]] = []
        self.stuck = stuck

    def write_register(self, reg: int, raw: int) -> None:
        self.log.append(("write", reg, raw))
        self.registers[reg] = raw if self.stuck is None else self.stuck

    def read_register(self, reg: int) -> int:
        self.log.append(("read", reg, self.registers[reg]))
        return self.registers[reg]


def test_a_text_setting_is_checked_then_written_and_read() -> None:
    m = MyMeter({"VOLT:NPLC?": "+1.00000000E+01"})
    m.nplc = 10
    assert m.written == ["VOLT:NPLC 10"]
    with pytest.raises(LimitError, match=r"MY-100: NPLC 7 is not one of \(0.2, 1.0, 10.0\)"):
        m.nplc = 7
    with pytest.raises(LimitError, match="gain 0 outside the range"):
        m.gain = 0
    assert m.written == ["VOLT:NPLC 10"]  # nothing sent for either refusal
    assert m.nplc == "+1.00000000E+01"  # read through get (no get_process: the reply)
    assert MyMeter.nplc.__doc__ == "integration time, power-line cycles"


def test_held_values_are_sent_later_in_order() -> None:
    m = MyMeter()
    m.hold("gain", 20)
    m.hold("nplc", 1)
    with pytest.raises(LimitError):
        m.hold("gain", float("nan"))
    assert m.written == [] and m.gain == 20  # the refused value is not kept
    m.send("nplc", "gain")
    assert m.written == ["VOLT:NPLC 1", "GAIN 20"]


def test_a_derived_model_narrows_values_and_changes_the_command() -> None:
    n = NarrowMeter()
    with pytest.raises(LimitError, match=r"not one of \(1.0,\)"):
        n.nplc = 10
    n.nplc = 1
    assert n.written == ["VOLT:NPLC 1,(@101)"]
    assert NarrowMeter.nplc.__doc__ == MyMeter.nplc.__doc__


def test_a_register_setting_is_written_and_read_back() -> None:
    c = Controller()
    c.setpoint_c = 42.5
    assert c.log == [("write", 300, 425), ("read", 300, 425)]
    assert c.setpoint_c == 42.5
    for bad in (80.0, float("inf"), "40"):
        with pytest.raises(LimitError, match="setpoint"):
            c.setpoint_c = bad  # type: ignore[assignment]
    assert len(c.log) == 3  # two writes' worth of I/O only: none for the refusals
    stuck = Controller(stuck=250)
    with pytest.raises(InstrumentError, match="setpoint read-back 250 != written 300"):
        stuck.setpoint_c = 30.0


def test_declaration_mistakes_are_caught() -> None:
    with pytest.raises(ValueError, match="readback needs a get"):
        Setting("X {value}", "x", readback=True)
    m: Any = MyMeter()
    with pytest.raises(AttributeError, match="gain has not been set"):
        _ = m.gain
    with pytest.raises(AttributeError, match="not a Setting"):
        m.hold("written", 1)
