"""One name and one default per concept (issue 28 point 6; docs/architecture.md, "Names")."""

from __future__ import annotations

import ast
import inspect
from dataclasses import fields
from pathlib import Path

from gyrolab.acquisition.bench_config import BenchConfig, UnitConfig
from gyrolab.acquisition.runner import Acquisition, UnitDevices
from gyrolab.app.demo import run_demo
from gyrolab.app.options import SimulateOptions
from gyrolab.cli import build_parser
from gyrolab.instruments.drivers.gyroadc import GyroAdcConfig, GyroAdcReader
from gyrolab.sampling import DEFAULT_RATE_HZ
from gyrolab.sim.bench.simbench import SimBench
from gyrolab.sim.commands import simulate_file
from gyrolab.sim.physics import Physics
from gyrolab.sim.simulate import simulate_run

ROOT = Path(__file__).resolve().parents[1] / "gyrolab"
#: Names the sample rate no longer goes by in code (the files keep ``sample_rate_hz``).
RETIRED = {"fs_hz", "adc_rate_hz", "sample_rate", "fs"}


def _default(f: object, name: str) -> object:
    return inspect.signature(f).parameters[name].default  # type: ignore[arg-type]


def test_the_sample_rate_has_one_default() -> None:
    assert GyroAdcConfig().sample_rate_hz == DEFAULT_RATE_HZ
    assert _default(GyroAdcReader, "rate_hz") == DEFAULT_RATE_HZ
    assert _default(Physics, "rate_hz") == DEFAULT_RATE_HZ
    assert _default(SimBench, "rate_hz") == DEFAULT_RATE_HZ
    for f in (simulate_run, simulate_file, run_demo):
        assert _default(f, "rate_hz") == DEFAULT_RATE_HZ
    assert SimulateOptions(out="x.mcap").rate_hz == DEFAULT_RATE_HZ
    args = build_parser().parse_args(["simulate", "--out", "x.mcap"])
    assert args.rate_hz == DEFAULT_RATE_HZ


def test_no_parameter_uses_a_retired_name_for_the_sample_rate() -> None:
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.arg) and node.arg in RETIRED:
                bad.append(f"{path.relative_to(ROOT.parent)}:{node.lineno} {node.arg}")
    assert not bad, bad


def test_each_role_goes_by_its_role_name_in_code() -> None:
    """The bench's fields and the run engine's keywords are the roles' names (the BENCH.toml
    tables ``[thermometer]``, ``[chamber]``, ``[rate_stream]``); ``multimeter``, ``oven`` and
    ``adc`` remain only what the recording calls the instruments, and older BENCH.toml
    tables (tests/test_registry)."""
    bench = {f.name for f in fields(BenchConfig)}
    assert {"thermometer", "chamber", "rate_stream", "scanner"} <= bench
    assert not {"multimeter", "oven", "adc"} & bench
    assert "rate_stream" in {f.name for f in fields(UnitConfig)}
    assert "rate_stream" in {f.name for f in fields(UnitDevices)}
    params = inspect.signature(Acquisition).parameters
    assert {"thermometer", "chamber", "chamber_period_s", "rate_stream"} <= set(params)
    assert not {"oven", "multimeter", "oven_period_s", "adc"} & set(params)
