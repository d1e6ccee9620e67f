"""Wire-level simulated instruments (34401A SCPI, Watlow F4 Modbus RTU, framed gyro ADC)
on pseudo-terminals and TCP, driven by one Physics and one simulated clock."""

from gyrolab.sim.bench.clock import SimClock
from gyrolab.sim.bench.faults import ByteFaults, FaultEvent, FaultPlan, ModbusFaults
from gyrolab.sim.bench.simbench import SimBench

__all__ = [
    "ByteFaults",
    "FaultEvent",
    "FaultPlan",
    "ModbusFaults",
    "SimBench",
    "SimClock",
]
