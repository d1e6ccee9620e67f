"""The sample rate: one name and one default (docs/architecture.md, "Names").

In code the gyro's sample rate is ``rate_hz`` (samples per second on each axis, Hz); the
files name it ``sample_rate_hz`` (BENCH.toml's ``[rate_stream]`` and the recording's bench
metadata: docs/bench-config.md, docs/recording-format.md). Its inverse is ``period`` (s);
an Allan deviation's sampling interval is ``tau0`` (s), the name of its literature.
Here, on the floor and free of numerical imports, so that the command line can give the
same default without slowing its start-up (docs/cli.md).
"""

#: The ADC's sample rate where neither a BENCH.toml, a recording nor an option gives one:
#: the one default of the ADC driver and its configuration, the simulator and the command
#: line.
DEFAULT_RATE_HZ = 100.0
