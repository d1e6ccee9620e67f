"""``watlowf4``: the Watlow F4 controller (Modbus RTU) as the bench's chamber.

The Modbus driver is :class:`gyrolab.acquisition.oven.WatlowF4`; this module makes it fill
the :class:`~gyrolab.acquisition.roles.Chamber` role and registers it.
"""

from __future__ import annotations

from typing import Any

from gyrolab.acquisition.bench_config import OvenConfig
from gyrolab.acquisition.instrument import InstrumentReport
from gyrolab.acquisition.oven import WatlowF4
from gyrolab.acquisition.registry import DriverSpec, OpenContext, register
from gyrolab.acquisition.roles import ChamberReading, InstrumentFault


class WatlowF4Chamber(WatlowF4):
    """The F4 in the chamber role."""

    name = "oven"

    def __init__(self, port: Any, *, config: OvenConfig, **kw: Any) -> None:
        super().__init__(port, **kw)
        self.config = config
        self.registers: dict[str, Any] = {}

    def connect(self) -> dict[str, Any]:
        self.registers = super().connect()
        return self.registers

    def read(self) -> ChamberReading:
        sp = self.setpoint_c
        pv = self.process_value_c
        st = self.status
        if st.sensor_fault:
            # The controller cannot see the chamber: nothing it does can be trusted.
            raise InstrumentFault(f"oven controller reports a sensor fault (status {st.raw:#x})")
        return ChamberReading(float(sp), float(pv))

    def reports(self) -> list[InstrumentReport]:
        return self.pop_reports()

    def describe(self) -> dict[str, Any]:
        return {
            "driver": "watlowf4",
            "model": "Watlow F4 (Modbus RTU)",
            "port": self.port_name,
            "slave_address": self.config.slave_address,
            "serial": self.config.serial,
            "registers": self.registers,
        }


def open_f4(c: OvenConfig, ctx: OpenContext) -> WatlowF4Chamber:
    timeout_s = ctx.timeout(c.timeout_s)
    oven = WatlowF4Chamber(
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
    try:
        oven.connect()
    except BaseException:
        oven.close()
        raise
    return oven


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
