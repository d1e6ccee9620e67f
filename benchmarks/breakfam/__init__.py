"""The break-the-model validation family (issue 23): its own physics, trajectories, real
noise and scorer, sharing no code with gyrolab's simulator, features or metrics.

* :mod:`.physics` — chamber, two-node thermal network with self-heating, quartic bias,
  temperature-dependent hysteresis width, asymmetric rate sensitivity, gradient, aging,
  temperature-dependent noise;
* :mod:`.trajectories` — staircase, heating staircase, random steps, fast ramps, cold
  start, slow ramp;
* :mod:`.realnoise` — noise cut from real static ADIS16405 records (benchmarks/data);
* :mod:`.score` — block means, bias stability, 100 s peak-to-peak, residual mean bias and
  band coverage, written here (not gyrolab's metrics);
* :mod:`.family` — units and runs: ``simulate_run(unit, trajectory)``.
"""
