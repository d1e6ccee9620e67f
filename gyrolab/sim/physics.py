"""The simulated world — oven air, gyro case and die, PT100, gyro output — on one clock.

:class:`Physics` is the stepping API shared by ``gyrolab simulate`` (a loop over
:meth:`Physics.advance` with the profile's setpoints) and the wire-level simulated bench
(which changes the setpoint whenever a Modbus write arrives). The state after ``advance``
depends only on the number of samples elapsed and the setpoints commanded between calls —
never on how the calls cut the run — so both paths give the same physics.

Sample ``i`` is at ``t = i / rate_hz`` s since power-on. A setpoint set with
:meth:`set_setpoint` acts from the next sample advanced.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gyrolab.sampling import DEFAULT_RATE_HZ
from gyrolab.sim.effects import EFFECTS, BlockContext, Effect, self_heating_c
from gyrolab.sim.model import SimModel
from gyrolab.sim.noise import FlickerStream, effect_rng
from gyrolab.sim.sensors import AdcModel, DieThermometer, cvd_resistance
from gyrolab.sim.thermal import kernel_params, thermal_kernel


@dataclass
class PhysicsBlock:
    """``n`` consecutive ADC samples and the thermal state at the block's end."""

    t0: float
    period: float
    first_index: int
    rate_dps: np.ndarray  # gyro output with every error effect, °/s, before the ADC
    counts: np.ndarray  # int32 ADC codes of rate_dps
    air_c: float
    case_c: float
    die_c: float
    case_trace: np.ndarray | None = None  # case temperature at every sample, °C
    die_trace: np.ndarray | None = None  # die temperature at every sample, °C

    @property
    def n(self) -> int:
        return int(self.counts.size)


class Physics:
    """The simulated world (oven air, gyro case/die, PT100, gyro output), advanced by a clock.

    Parameters
    ----------
    model : SimModel
        Thermal parameters, sensors and effects.
    rate_hz : float
        ADC sample rate (Hz); one :meth:`advance` sample is ``1/rate_hz`` s.
    seed : int
        Seeds every stochastic effect (each its own stream) and the multimeter noise.
    ambient_c : float
        Room temperature: air, case and die at power-on, and the first setpoint.
    block_s : float
        Block length the recorder uses (``block_n`` samples); :meth:`advance` takes any n.
    """

    def __init__(
        self,
        model: SimModel,
        *,
        rate_hz: float = DEFAULT_RATE_HZ,
        seed: int = 0,
        ambient_c: float = 25.0,
        block_s: float = 1.0,
    ) -> None:
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError("rate_hz must be > 0")
        self.model = model
        self.rate_hz = float(rate_hz)
        self.period = 1.0 / self.rate_hz
        self.seed = int(seed)
        self.block_n = max(1, int(round(block_s * self.rate_hz)))
        self.adc: AdcModel = model.sensors.adc
        self.setpoint_c = float(ambient_c)
        self.index = 0

        counts: dict[str, int] = {}
        self.effects: list[Effect] = []
        for spec in model.effects:
            cls = EFFECTS[spec.name]
            k = counts.get(spec.name, 0)
            counts[spec.name] = k + 1
            rng = effect_rng(self.seed, spec.name, k) if cls.stochastic else None
            self.effects.append(cls(spec.params, rng, self.rate_hz))
        self._rate_fx = [e for e in self.effects if e.target == "rate"]
        self._post_fx = [e for e in self.effects if e.target == "post"]
        # Streamed noise sources whose blocks are costly to make (see prefetch).
        self._streams = [
            v for e in self.effects for v in vars(e).values() if isinstance(v, FlickerStream)
        ]

        lag = model.get("thermal_lag")
        self._bias_from_die = lag is not None
        omega = zeta = 0.0
        for e in self.effects:
            if e.name == "oven_overshoot":
                omega, zeta = e.omega_zeta()  # type: ignore[attr-defined]
        self._kp = kernel_params(
            model.thermal,
            die_tau_s=None if lag is None else lag.params["tau_s"],
            omega=omega,
            zeta=zeta,
        )
        self._rtd_offset_c = sum(
            e.params["offset_c"] for e in model.effects if e.name == "rtd_self_heating"
        )
        a = float(ambient_c)
        self._state = np.array([a, 0.0, a, a], dtype=np.float64)  # air, air rate, case, die
        self._dmm_rng = effect_rng(self.seed, "dmm")
        # The internal (die) temperature sensor: its own stream, the unit's offset drawn first
        self.die_sensor = DieThermometer()
        self._die_rng = effect_rng(self.seed, "die_sensor")
        self.die_sensor_offset_c = self.die_sensor.offset_sd_c * float(
            self._die_rng.standard_normal()
        )

    # ------------------------------------------------------------------ clock
    @property
    def t(self) -> float:
        """Simulated time now, s since power-on."""
        return self.index * self.period

    def set_setpoint(self, setpoint_c: float) -> None:
        """Command the oven setpoint (°C); acts from the next sample."""
        if not np.isfinite(setpoint_c):
            raise ValueError("setpoint must be finite")
        self.setpoint_c = float(setpoint_c)

    def prefetch(self, n_samples: int) -> None:
        """Do now the costly work the next ``n_samples`` of :meth:`advance` would do:
        make the flicker-noise chunks they need (0.1–0.3 s each, one per 3.6 h).

        Safe to call from another thread while :meth:`advance` runs, and needs no lock
        around the physics (the simulated bench calls it from a helper thread so that its
        lock is never held for that long). Changes no result: the same numbers are made
        in the same order, only earlier."""
        first = self.index  # one read: advance may move it meanwhile
        for s in self._streams:
            s.prefetch(first, int(n_samples), self.rate_hz)

    def advance(self, n_samples: int) -> PhysicsBlock:
        """Advance the world by ``n_samples`` ADC samples and return them."""
        n = int(n_samples)
        if n < 0:
            raise ValueError("n_samples must be >= 0")
        first = self.index
        air = np.empty(n)
        case = np.empty(n)
        die = np.empty(n)
        dcase = np.empty(n)
        thermal_kernel(
            n, self.period, self.setpoint_c, self._state, self._kp, air, case, die, dcase
        )
        if self._bias_from_die:
            # dTd/dt from the die's own equation (τ_die = thermal_lag.tau_s)
            temp, dtemp = die, (case - die) / self._kp[7]
        else:
            temp, dtemp = case, dcase
        t = (first + np.arange(n)) * self.period
        ctx = BlockContext(first, self.period, t, temp, dtemp)
        out = np.zeros(n)
        for e in self._rate_fx:
            out += e.rate(ctx)
        for e in self._post_fx:
            out = e.post(out, ctx)
        self.index = first + n
        return PhysicsBlock(
            t0=first * self.period,
            period=self.period,
            first_index=first,
            rate_dps=out,
            counts=self.adc.dps_to_counts(out),
            air_c=self.chamber_c(),
            case_c=self.case_c(),
            die_c=self.die_c(),
            case_trace=case,
            die_trace=die,
        )

    # ------------------------------------------------------------ instruments
    def chamber_c(self) -> float:
        """Oven air temperature now (the controller's process value), °C."""
        return float(self._state[0])

    def case_c(self) -> float:
        """Gyro case temperature now, °C."""
        return float(self._state[2])

    def die_c(self) -> float:
        """Gyro die temperature now, °C."""
        return float(self._state[3])

    def pt100_true_ohm(self) -> float:
        """Noise-free PT100 resistance now: CVD(case + its self-heating at the case
        temperature, ``rtd_self_heating``), Ω."""
        case = self.case_c()
        return float(cvd_resistance(case + self_heating_c(self._rtd_offset_c, case)))

    def pt100_ohm(self) -> float:
        """What a 4-wire DMM reads now: CVD(T_case + rtd offset) + DMM noise, Ω."""
        noise = self.model.sensors.dmm_noise_ohm * float(self._dmm_rng.standard_normal())
        return self.pt100_true_ohm() + noise

    def die_sensor_codes(self, die_c: np.ndarray) -> np.ndarray:
        """What the unit's internal temperature sensor reports for die temperatures
        ``die_c`` (°C; e.g. ``PhysicsBlock.die_trace`` at each frame's first sample): register
        codes with the unit's offset, one noise draw per reading (its own stream, in order,
        so the codes do not depend on how the calls are cut) and quantisation."""
        die = np.asarray(die_c, dtype=float)
        w = self._die_rng.standard_normal(die.size)
        return self.die_sensor.codes(die, self.die_sensor_offset_c, w)
