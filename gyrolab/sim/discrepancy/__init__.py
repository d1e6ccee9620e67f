"""The sim-vs-measured discrepancy workflow (``gyrolab discrepancy``; docs/discrepancy.md).

Fit the current simulator model to a recording, compare channel by channel, localize the
disagreement, name the missing vocabulary effect, add it, and show the gap shrink.
"""

from gyrolab.sim.discrepancy.data import BenchData, from_arrays, load_recording
from gyrolab.sim.discrepancy.workflow import Result, run_discrepancy

__all__ = ["BenchData", "Result", "from_arrays", "load_recording", "run_discrepancy"]
