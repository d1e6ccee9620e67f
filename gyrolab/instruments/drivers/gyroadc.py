"""``gyroadc``: the gyro's framed ADC stream (docs/instruments.md) as the rate stream.

The reader is :class:`gyrolab.instruments.gyro_adc.GyroAdcReader`; this module makes it
fill the :class:`~gyrolab.instruments.roles.RateStream` role and registers it.
"""

from __future__ import annotations

from typing import Any

from gyrolab.acquisition.bench_config import AdcConfig
from gyrolab.instruments.errors import InstrumentReport
from gyrolab.instruments.gyro_adc import GyroAdcReader
from gyrolab.instruments.registry import DriverSpec, OpenContext, register


class GyroAdcStream(GyroAdcReader):
    """The ADC reader in the rate-stream role."""

    name = "adc"

    def __init__(self, port: str, *, config: AdcConfig, **kw: Any) -> None:
        super().__init__(port, **kw)
        self.config = config

    def counters(self) -> dict[str, int]:
        d = self.decoder.stats
        s = self.stats
        return {
            "frames_ok": d.frames_ok,
            # Damaged frames: CRC failures, and CRC-passing frames whose timestamp
            # disagrees with their sequence number. (Length errors are mostly sync-word
            # look-alikes inside payloads, not frames.)
            "frames_bad": d.crc_errors + d.inconsistent_frames,
            "frames_lost": d.frames_lost,
            "frames_stale": d.stale_frames,
            "gaps": d.gaps,
            "disconnects": s.disconnects,
        }

    def reports(self) -> list[InstrumentReport]:
        return []  # the stream reports gaps and port events in its reads instead

    def describe(self) -> dict[str, Any]:
        a = self.config
        return {
            "driver": "gyroadc",
            "port": self.port_name,
            "serial": a.serial,
            "sample_rate_hz": a.sample_rate_hz,
            "samples_per_frame": a.samples_per_frame,
            "bits": a.bits,
            "vref_v": a.vref_v,
            "gain_v_per_dps": a.gain_v_per_dps,
            "offset_v": a.offset_v,
            "dps_per_count": a.dps_per_count(),
            # Only a multi-axis ADC says so: single-axis metadata stays as it always was.
            **({"axes": a.axes} if a.axes > 1 else {}),
        }


def open_adc(c: AdcConfig, ctx: OpenContext) -> GyroAdcStream:
    reader = GyroAdcStream(
        ctx.address,
        config=c,
        samples_per_frame=c.samples_per_frame,
        rate_hz=c.sample_rate_hz,
        axes=c.axes,
        baudrate=c.baud_rate,
        clock=ctx.clock,
    )
    reader.open()
    return reader


SPEC = register(
    DriverSpec(
        name="gyroadc",
        role="rate_stream",
        config=AdcConfig,
        open=open_adc,
        address_key="port",
        sim_backend="ADC",
        sim_address="adc_port",
        description="framed 24-bit ADC stream over a serial port",
    )
)
