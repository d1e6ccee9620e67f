"""The lost-communication watchdog: who last answered when, outages logged once with
their recovery, and who has been silent for too long.

When a silent instrument counts as lost is a :class:`SilencePolicy`: the lab's rule is
:class:`RunTimeSilence` (more than ``comm_timeout_s`` run seconds); a simulated bench
supplies its own (``gyrolab.app.sim_bench.SimSilence``). What a lost instrument means for
the run (the run ends, a unit is dropped, the run is suspended) is the engine's decision.
"""

from __future__ import annotations

from typing import Protocol

from gyrolab.acquisition.journal import Journal
from gyrolab.clock import Clock

# The silence policy's name for "some unit's temperature (PT100 or internal sensor) gave a
# reading" (multi-unit runs).
UNIT_TEMPERATURES = "unit temperatures"


class SilencePolicy(Protocol):
    """When an instrument that has said nothing for a while counts as lost (the watchdog).

    :class:`RunTimeSilence` is the lab's rule; a simulated bench supplies its own
    (``gyrolab.app.sim_bench``)."""

    def heard(self, source: str) -> None:
        """``source`` just answered."""

    def lost(self, source: str, silent_s: float, timeout_s: float) -> bool:
        """Is ``source``, silent for ``silent_s`` run seconds, lost (limit ``timeout_s``)?"""
        ...


class RunTimeSilence:
    """The lab's rule: lost after more than ``comm_timeout_s`` seconds of run time."""

    def heard(self, source: str) -> None:
        pass

    def lost(self, source: str, silent_s: float, timeout_s: float) -> bool:
        return silent_s > timeout_s


class CommWatch:
    """Each watched source's last good exchange (clock time) and its outage: the first
    failure of an outage is a fault in ``/log``, the first success after it a recovery
    with the outage's length and failed attempts."""

    def __init__(
        self, journal: Journal, clock: Clock, silence: SilencePolicy, timeout_s: float
    ) -> None:
        self.journal = journal
        self.clock = clock
        self.silence = silence
        self.timeout_s = timeout_s
        self.last_ok: dict[str, float] = {}
        self.last_error: dict[str, str] = {}  # each source's latest failure
        # Sources whose silence another part judges (the temperature suspender).
        self.unjudged: set[str] = set()
        self._down_since: dict[str, float] = {}
        self._down_errors: dict[str, int] = {}

    def start(self, sources: list[str], now: float) -> None:
        """Watch ``sources``, each heard at clock time ``now`` (the run's start)."""
        for name in sources:
            self.last_ok[name] = now
            self.silence.heard(name)

    def ok(self, source: str, t: float, t_clock: float) -> None:
        """``source`` answered at run time ``t`` (clock time ``t_clock``)."""
        self.last_ok[source] = t_clock
        self.silence.heard(source)
        if source in self._down_since:
            since = self._down_since.pop(source)
            n = self._down_errors.pop(source, 0)
            self.journal.log(
                "info",
                source,
                f"{source} recovered after {t - since:.1f} s ({n} failed attempts)",
                "recovery",
                {"outage_s": round(t - since, 3), "failed_attempts": n},
                t,
            )

    def failed(self, source: str, t: float, message: str) -> None:
        """An exchange with ``source`` failed at run time ``t`` (to be retried)."""
        self.last_error[source] = message
        if source not in self._down_since:
            self._down_since[source] = t
            self._down_errors[source] = 1
            self.journal.fault("warning", source, f"{source}: {message}", t=t)
        else:
            self._down_errors[source] += 1

    def down(self, source: str) -> bool:
        """Whether ``source``'s last exchange failed (an outage is going on)."""
        return source in self._down_since

    def forget(self, source: str) -> None:
        """Stop watching ``source`` (a dropped unit)."""
        for d in (self.last_ok, self._down_since, self._down_errors):
            d.pop(source, None)

    def silent(
        self, timeout_s: float | None = None, policy: SilencePolicy | None = None
    ) -> list[tuple[str, float]]:
        """``(source, silent seconds)`` of every source the silence ``policy`` (default:
        the watchdog's) calls lost after ``timeout_s`` (default: the watchdog's, and then
        ``unjudged`` sources left out)."""
        now = self.clock.now()
        limit = self.timeout_s if timeout_s is None else timeout_s
        rule = policy or self.silence
        return [
            (source, now - last)
            for source, last in list(self.last_ok.items())
            if (timeout_s is not None or source not in self.unjudged)
            and rule.lost(source, now - last, limit)
        ]
