"""``watlowf4``: the Watlow F4 controller (Modbus RTU) as the bench's chamber.

The Modbus driver is :class:`gyrolab.instruments.oven.WatlowF4`; this module makes it fill
the :class:`~gyrolab.instruments.roles.Chamber` role and registers it.
"""

from __future__ import annotations

from typing import Any

from gyrolab.acquisition.bench_config import OvenConfig
from gyrolab.instruments.errors import InstrumentError, InstrumentReport
from gyrolab.instruments.oven import NAME, PROFILE_PAUSED, PROFILE_RUNNING, WatlowF4
from gyrolab.instruments.registry import DriverSpec, OpenContext, connected, register
from gyrolab.instruments.roles import ChamberReading, InstrumentFault


class WatlowF4Chamber(WatlowF4):
    """The F4 in the chamber role."""

    name = "oven"

    def __init__(self, port: Any, *, config: OvenConfig, **kw: Any) -> None:
        super().__init__(port, **kw)
        self.config = config
        self.registers: dict[str, Any] = {}

    def connect(self) -> dict[str, Any]:
        self.registers = super().connect()
        mode = self.profile_mode
        self.registers["profile_mode"] = mode
        if mode in (PROFILE_RUNNING, PROFILE_PAUSED):
            # A profile drives the loop, not register 300: our setpoints would do nothing.
            raise InstrumentError(
                NAME, f"a profile is running on the controller (register 200 = {mode}): "
                "end it at the controller first"
            )
        ev = self.config.control_event
        if ev:
            self.registers[f"event_{ev}"] = int(self.event(ev))
        return self.registers

    def read(self) -> ChamberReading:
        sp = self.setpoint_c
        pv = self.process_value_c
        mode = self.profile_mode
        if mode in (PROFILE_RUNNING, PROFILE_PAUSED):
            raise InstrumentFault(
                f"a profile was started on the controller (register 200 = {mode}): "
                "register 300 no longer controls the chamber"
            )
        return ChamberReading(float(sp), float(pv))

    def set_setpoint(self, value_c: float) -> float:
        """Setpoint (limits first, read back), then the chamber on through its control
        event output, if the bench wires one (read back)."""
        sp = super().set_setpoint(value_c)
        ev = self.config.control_event
        if ev and not self.event(ev):
            self.set_event(ev, True)
        return sp

    def switch_off(self) -> None:
        """Chamber off: its control event output to 0, verified by read-back."""
        ev = self.config.control_event
        if not ev:
            raise InstrumentError(NAME, "no control_event configured: cannot switch off")
        self.set_event(ev, False)

    def reports(self) -> list[InstrumentReport]:
        return self.pop_reports()

    def describe(self) -> dict[str, Any]:
        return {
            "driver": "watlowf4",
            "model": "Watlow F4 (Modbus RTU)",
            "port": self.port_name,
            "slave_address": self.config.slave_address,
            "serial": self.config.serial,
            "control_event": self.config.control_event,
            "registers": self.registers,
        }


def open_f4(c: OvenConfig, ctx: OpenContext) -> WatlowF4Chamber:
    timeout_s = ctx.timeout(c.timeout_s)
    return connected(
        WatlowF4Chamber(
            ctx.address,
            config=c,
            address=c.slave_address,
            baudrate=c.baud_rate,
            timeout_s=timeout_s,
            # A reply later than timeout + silence cannot be told from the next one's
            # (oven.py); the simulated slave is late by scheduling jitter at most.
            silence_s=timeout_s,
            setpoint_limits_c=ctx.setpoint_limits_c,
        )
    )


SPEC = register(
    DriverSpec(
        name="watlowf4",
        role="chamber",
        config=OvenConfig,
        open=open_f4,
        address_key="port",
        sim_backend="F4",
        sim_address="oven_port",
        description="Watlow F4 controller, Modbus RTU on RS-232/RS-485",
    )
)
