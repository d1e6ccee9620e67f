"""Simulated Agilent 34970A with a 34901A multiplexer in slot 1: a SCPI responder that
reads one 4-wire PT100 per channel, each from its own callback (a unit's physics).

The subset the ``keysight34970a`` driver uses (docs/instruments.md): ``*IDN?``, ``*RST``,
``*CLS``, ``SYST:ERR?``, ``CONF:FRES <range>,(@list)`` (configures the channels and makes
them the scan list), ``[SENS:]FRES:NPLC <n>,(@list)``, ``ROUT:SCAN (@list)``,
``ROUT:SCAN?`` (definite-length block, ``#214(@101,102,103)``), ``ROUT:SCAN:SIZE?`` and
``READ?`` (one sweep, readings comma separated in scan order). A channel with no sensor
wired reads overload (+9.9E+37), as an open 4-wire input does; 4-wire channels are 101-110
(each paired with its sense channel n+10). A sweep takes each channel's integration time
(NPLC / 50 Hz, ×2 for autozero) in simulated time. Errors are pushed with the SCPI codes
of the 34401A responder it extends. Faults: the 34401A responder's outage (no replies) and
error-queue entries, and :meth:`Scpi34970A.open_channel` (a PT100 lead broken: the channel
reads overload for a while; as on the instrument, an overload puts nothing in the error
queue — 34970A User's Guide ch. 5, "The Questionable Data Register").
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

from gyrolab.sim.bench.clock import SimClock
from gyrolab.sim.bench.dmm_scpi import (
    E_PARAM,
    E_SYNTAX,
    OVERLOAD,
    RANGES,
    Scpi34401A,
    scpi_re,
)

IDN = "Agilent Technologies,34970A,MY44000001,13-2-2"
NPLCS = (0.02, 0.2, 1.0, 2.0, 10.0, 20.0, 100.0, 200.0)
SLOT = 1  # the 34901A's slot
FOUR_WIRE = range(101, 111)  # 4-wire source channels of a 34901A in slot 1
E_CHANNEL = '-221,"Settings conflict"'  # a channel the card cannot measure 4-wire
_LIST = re.compile(r"\(@([0-9:,\s]*)\)")


@dataclass
class ChannelConf:
    range_ohm: float = 1e3
    nplc: float = 1.0


def parse_channel_list(text: str) -> list[int] | None:
    """``(@101:103,105)`` → ``[101, 102, 103, 105]``; None when malformed."""
    m = _LIST.search(text)
    if m is None:
        return None
    out: list[int] = []
    for part in filter(None, (p.strip() for p in m.group(1).split(","))):
        a, _, b = part.partition(":")
        try:
            lo, hi = int(a), int(b or a)
        except ValueError:
            return None
        if hi < lo:
            return None
        out.extend(range(lo, hi + 1))
    return out


class Scpi34970A(Scpi34401A):
    """The scanner's command interpreter. ``read_ohm(channel)`` returns the 4-wire
    resistance on ``channel`` now (Ω), or None when nothing is wired there."""

    IDN = IDN

    def __init__(
        self, read_ohm: Callable[[int], float | None], clock: SimClock | None = None
    ) -> None:
        super().__init__(lambda: 0.0, clock)
        self.read_channel = read_ohm
        self.conf: dict[int, ChannelConf] = {}
        self.scan: list[int] = []
        self.sweeps = 0
        self.open_until: dict[int, float] = {}  # channel -> simulated time it reads again
        self._table = self.system_commands() + [
            (scpi_re("CONFigure:FRESistance"), self._conf_fres),
            (scpi_re("[SENSe:]FRESistance:NPLCycles"), self._nplc),
            (scpi_re("ROUTe:SCAN"), self._route_scan),
            (scpi_re("ROUTe:SCAN?"), self._scan_q),
            (scpi_re("ROUTe:SCAN:SIZE?"), lambda a: str(len(self.scan))),
            (scpi_re("READ?"), self._read),
        ]

    def open_channel(self, channel: int, until_t_sim: float) -> None:
        """The sensor on ``channel`` is open (a lead broken) until simulated time
        ``until_t_sim``: the channel reads overload meanwhile. Called from the bench's tick
        thread: no lock (a sweep holds the responder's lock while it waits for that thread
        to advance the clock)."""
        self.open_until[channel] = until_t_sim

    def _rst(self, arg: str) -> None:
        super()._rst(arg)
        self.conf.clear()
        self.scan = []

    def _channels(self, arg: str, four_wire: bool) -> list[int] | None:
        chans = parse_channel_list(arg)
        if chans is None:
            self._push(E_SYNTAX)
            return None
        if four_wire and any(c not in FOUR_WIRE for c in chans):
            self._push(E_CHANNEL)
            return None
        return chans

    def _conf_fres(self, arg: str) -> None:
        chans = self._channels(arg, True)
        if chans is None:
            return
        head = arg.split("(@")[0].strip().rstrip(",")
        v = self._number(head.split(",")[0], RANGES, 1e3)
        if v is None:
            self._push(E_SYNTAX)
            return
        fit = [r for r in RANGES if r >= v]
        if not fit:
            self._push(E_PARAM)
            return
        for c in chans:
            self.conf[c] = ChannelConf(range_ohm=fit[0])
        self.scan = chans  # CONFigure redefines the scan list (User's Guide ch. 5)

    def _nplc(self, arg: str) -> None:
        chans = self._channels(arg, False) if "(@" in arg else list(self.scan)
        if chans is None:
            return
        v = self._number(arg.split(",")[0], NPLCS, 1.0)
        if v is None:
            self._push(E_SYNTAX)
        elif v not in NPLCS or any(c not in self.conf for c in chans):
            self._push(E_PARAM)
        else:
            for c in chans:
                self.conf[c].nplc = v

    def _route_scan(self, arg: str) -> None:
        chans = self._channels(arg, False)
        if chans is None:
            return
        if any(c not in self.conf for c in chans):
            self._push(E_CHANNEL)  # a channel with no measurement configured
            return
        self.scan = chans

    def _scan_q(self, arg: str) -> str:
        body = "(@" + ",".join(str(c) for c in self.scan) + ")"
        n = str(len(body))
        return f"#{len(n)}{n}{body}"

    def sweep_s(self) -> float:
        """Simulated time one sweep takes: each channel's integration (×2, autozero)."""
        return sum(2.0 * self.conf[c].nplc / self.line_frequency_hz for c in self.scan)

    def _read(self, arg: str) -> str | None:  # type: ignore[override]
        if not self.scan:  # nothing to sweep: no reply, an error queued
            self._push('-230,"Data stale"')
            return None
        if self.clock is not None:
            self.clock.sleep(self.sweep_s(), timeout_wall_s=10.0)
        self.sweeps += 1
        now = self.clock.now() if self.clock is not None else 0.0
        out = []
        for c in self.scan:
            r = None if now < self.open_until.get(c, -1.0) else self.read_channel(c)
            if r is None or not r < 1.2 * self.conf[c].range_ohm:
                out.append(OVERLOAD)
            else:
                out.append(f"{float(r):+.8E}")
        return ",".join(out)
