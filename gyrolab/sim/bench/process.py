"""The simulated bench in a process of its own (``acquire --bench sim``).

One Python process running both the simulated instruments (physics, ADC frames, the
SCPI/Modbus responders) and the run engine (drivers, readers, recorder) is bound to one
core by its GIL: eight units at 300× needed more (docs/performance.md). The instruments
and the drivers already meet only on the wire (pseudo-terminals, TCP), so the bench moves
to a child process, :func:`serve`, and the run engine keeps only the wires and the clock:

* the child builds :class:`~gyrolab.sim.bench.SimBench` from a picklable recipe
  (:class:`BenchRecipe`: the bench's settings, each unit's simulator model and seed),
  starts it, and answers one JSON line: every address and each unit's ADC calibration and
  die-sensor scale (what a lab reads off the calibration sheet);
* its clock is shared through a small memory-mapped file (:class:`SharedTime`): the run
  engine reads the simulated time and waits on it; :attr:`BenchProcess.clock` ``speed``
  (the handle's ``go``) is a command line on the child's stdin, as is ``stop``;
* the child ignores the terminal's signals (its own session): SIGINT/SIGTERM/SIGHUP reach
  the run engine, which ends in the safe state while the instruments still answer, then
  stops the child. A ``kill -9`` of the run engine closes the child's stdin: it stops its
  bench (the pseudo-terminals and their links go) and exits; the next ``acquire --bench
  sim`` sweeps the scratch directory (gyrolab/acquisition/simdir.py).
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import signal
import struct
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gyrolab.sim.bench.clock import SharedTime
from gyrolab.sim.bench.simbench import PREFETCH_LEAD_S

CLOCK_FILE = "clock"
_LEN = struct.Struct("<Q")


@dataclass
class BenchRecipe:
    """What the child builds its bench from: ``settings`` (``SimBench`` keyword arguments
    without the physics), ``model`` / ``axis_models`` (the unit's and its other axes'
    simulator models), or ``units`` (each unit's ``(model, seed)``: a multi-unit bench),
    or ``device`` (a device with its own protocol instead of the ADC, by its back end's
    name: ``"VN100"``, a VectorNav VN-100 whose IMU is :func:`gyrolab.sim.fc_imus.imu_physics`'s
    first — built in the child, as its prefetched noise is too large to send), ``rate_hz``,
    ``seed``, ``ambient_c``."""

    settings: dict[str, Any]
    rate_hz: float
    seed: int
    ambient_c: float
    model: Any = None
    axis_models: list[Any] = field(default_factory=list)
    units: list[tuple[Any, int]] | None = None
    device: str | None = None

    def build(self) -> Any:
        """The :class:`SimBench` (not started)."""
        from gyrolab.sim.bench.simbench import SimBench
        from gyrolab.sim.model import nominal_model
        from gyrolab.sim.physics import Physics
        from gyrolab.sim.simulate import axis_physics

        model = self.model or nominal_model()
        kw = dict(self.settings)
        if self.device is not None:
            kw["device"] = device_spec(self.device, self.seed, self.rate_hz, self.ambient_c)
        elif self.units is not None:
            kw["unit_physics"] = [
                Physics(m, rate_hz=self.rate_hz, seed=s, ambient_c=self.ambient_c)
                for m, s in self.units
            ]
        else:
            kw["model"] = model
            kw["axis_physics"] = axis_physics(
                model, list(self.axis_models), self.rate_hz, self.seed, self.ambient_c
            )
        return SimBench(seed=self.seed, rate_hz=self.rate_hz, ambient_c=self.ambient_c, **kw)


def device_spec(backend: str, seed: int, rate_hz: float, ambient_c: float) -> Any:
    """The ``SimBench(device=...)`` of a device back end (:class:`BenchRecipe` ``device``)."""
    from gyrolab.sim.fc_imus import imu_physics

    if backend == "VN100":
        from gyrolab.sim.bench.vectornav import VnSpec

        return VnSpec(imu_physics(seed, rate_hz, ambient_c, imus=1), seed=seed)
    raise ValueError(f"no simulated device {backend!r}")


def device_axes(backend: str, seed: int) -> list[tuple[Any, int]]:
    """Each axis's simulator model and noise seed of the device :func:`device_spec` builds
    (its provenance), without building it."""
    from gyrolab.sim.fc_imus import imu_axis_model, imu_seed

    if backend != "VN100":
        raise ValueError(f"no simulated device {backend!r}")
    return [(imu_axis_model(seed, 0, a), imu_seed(seed, 0, a)) for a in range(3)]


def describe(bench: Any) -> dict[str, Any]:
    """What the run engine needs of a started bench: its addresses and each unit's ADC
    calibration and die-sensor scale."""

    def adc(p: Any) -> dict[str, float]:
        a = p.adc
        return {
            "bits": int(a.bits),
            "vref_v": float(a.vref_v),
            "gain_v_per_dps": float(a.gain_v_per_dps),
            "offset_v": float(a.offset_v),
        }

    return {
        "resources": bench.resources(),
        "adc": adc(bench.physics),
        "units": [
            {
                "adc": adc(p),
                "c_per_lsb": float(p.die_sensor.c_per_lsb),
                "zero_c": float(p.die_sensor.zero_c),
            }
            for p in bench.unit_physics
        ],
    }


class _RemoteClock(SharedTime):
    """The child's clock as the run engine sees it; setting ``speed`` tells the child."""

    def __init__(self, path: Path, proc: BenchProcess) -> None:
        super().__init__(path)
        self._proc = proc

    @property
    def speed(self) -> float | None:
        return self.read()[1]

    @speed.setter
    def speed(self, speed: float | None) -> None:
        self._proc.command(f"speed {speed if speed is not None else 'max'}")


class BenchProcess:
    """The parent's side of :func:`serve`: starts the child with ``recipe`` in
    ``workdir``, waits for its description (:attr:`info`), and offers its :attr:`clock`,
    :meth:`command` and :meth:`stop` (module doc)."""

    def __init__(self, recipe: BenchRecipe, workdir: Path, start_timeout_s: float = 120.0) -> None:
        self.workdir = Path(workdir)
        recipe.settings["workdir"] = self.workdir
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "gyrolab.sim.bench.process"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            start_new_session=True,  # the terminal's signals go to the run engine only
        )
        assert self._proc.stdin is not None and self._proc.stdout is not None
        blob = pickle.dumps(recipe)
        try:
            self._proc.stdin.write(_LEN.pack(len(blob)) + blob)
            self._proc.stdin.flush()
            line = self._proc.stdout.readline()
        except BaseException:
            self.stop()
            raise
        if not line:
            self.stop()
            raise RuntimeError("the simulated bench's process exited while starting")
        self.info: dict[str, Any] = json.loads(line)
        if "error" in self.info:
            self.stop()
            raise RuntimeError(f"the simulated bench did not start: {self.info['error']}")
        self.clock = _RemoteClock(self.workdir / CLOCK_FILE, self)

    @property
    def pid(self) -> int:
        return self._proc.pid

    def command(self, line: str) -> None:
        """One command line to the child (``speed X|max``, ``stop``)."""
        assert self._proc.stdin is not None
        with contextlib.suppress(BrokenPipeError, ValueError):
            self._proc.stdin.write(line.encode() + b"\n")
            self._proc.stdin.flush()

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop the child's bench and wait for it (killed after ``timeout_s``)."""
        self.command("stop")
        with contextlib.suppress(Exception):
            assert self._proc.stdin is not None
            self._proc.stdin.close()
        try:
            self._proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        if self._proc.stdout is not None:
            self._proc.stdout.close()


def serve() -> None:
    """The child: read the recipe from stdin, run the bench, answer its description on
    stdout, then obey ``speed``/``stop`` lines until stdin closes (module doc)."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    stdin, out = sys.stdin.buffer, sys.stdout
    (n,) = _LEN.unpack(stdin.read(_LEN.size))
    recipe: BenchRecipe = pickle.loads(stdin.read(n))
    try:
        bench = recipe.build()
        # The first hour of flicker noise now, before the drivers connect: made by the
        # prefetch thread, it would hold this process's GIL while they wait for replies.
        lead = round(PREFETCH_LEAD_S * bench.rate_hz)
        for p in (*bench.unit_physics, *bench.axis_physics):
            p.prefetch(lead)
        shared = SharedTime(Path(recipe.settings["workdir"]) / CLOCK_FILE, create=True)
        bench.clock.on_change = shared.publish
        bench.start()
        shared.publish(bench.clock.now(), bench.clock.speed, False)
    except Exception as e:  # told to the parent, which raises it
        out.write(json.dumps({"error": f"{type(e).__name__}: {e}"}) + "\n")
        out.flush()
        return
    # The instruments' threads share this process only: hand the GIL over sooner (a
    # Modbus or SCPI reply waits on the tick thread otherwise).
    sys.setswitchinterval(0.0005)
    out.write(json.dumps(describe(bench)) + "\n")
    out.flush()
    try:
        for raw in stdin:
            cmd = raw.decode().split()
            if not cmd or cmd[0] == "stop":
                break
            if cmd[0] == "speed":
                bench.clock.speed = None if cmd[1] == "max" else float(cmd[1])
    finally:
        bench.stop()
        shared.close()


if __name__ == "__main__":
    os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
    serve()
