"""The driver registry, the role tables of BENCH.toml and the one error vocabulary."""

from __future__ import annotations

from pathlib import Path

import pytest

from gyrolab.acquisition.bench_config import bench_from_dict, load_bench
from gyrolab.errors import InputError
from gyrolab.instruments import registry
from gyrolab.instruments.drivers.agilent34401a import Agilent34401AConfig
from gyrolab.instruments.drivers.watlowf4 import WatlowF4Config
from gyrolab.instruments.roles import (
    InstrumentError,
    InstrumentFault,
    InstrumentTimeout,
    LimitError,
    is_transient,
)

REPO = Path(__file__).resolve().parents[1]


def test_builtin_drivers_registered_per_role() -> None:
    assert "gyroadc" in [s.name for s in registry.drivers("rate_stream")]
    for role, name in registry.DEFAULT_DRIVER.items():
        assert registry.get(name, role).role == role
    with pytest.raises(KeyError, match="registered: agilent34401a"):
        registry.get("watlowf4", "thermometer")


def test_every_driver_follows_the_spec_pattern() -> None:
    # What the loader and the runner rely on, for every registered driver (a new driver
    # is checked here without touching this file).
    for spec in registry.drivers():
        c = spec.config()
        assert c.driver == spec.name, spec.name
        assert isinstance(getattr(c, spec.address_key), str), spec.name
        rate = ("block_s", "sample_rate_hz", "axes", "to_dps")
        keys = ("period_s", "timeout_s") if spec.role != "rate_stream" else rate
        for key in ("serial", *keys):
            assert hasattr(c, key), (spec.name, key)
        assert spec.config.__module__ == spec.open.__module__, spec.name  # one module


def test_new_and_old_table_names_give_the_same_bench() -> None:
    old = bench_from_dict(
        {"multimeter": {"nplc": 1.0}, "oven": {"slave_address": 3}, "adc": {"block_s": 0.25}},
        "old",
    )
    new = bench_from_dict(
        {
            "thermometer": {"driver": "agilent34401a", "nplc": 1.0},
            "chamber": {"driver": "watlowf4", "slave_address": 3},
            "rate_stream": {"driver": "gyroadc", "block_s": 0.25},
        },
        "new",
    )
    assert {**old.to_dict(), "name": ""} == {**new.to_dict(), "name": ""}
    assert isinstance(new.thermometer, Agilent34401AConfig) and new.thermometer.nplc == 1.0
    assert isinstance(new.chamber, WatlowF4Config) and new.chamber.slave_address == 3
    assert new.rate_stream.block_s == 0.25 and "adc" not in new.to_dict()


@pytest.mark.parametrize(
    ("d", "match"),
    [
        ({"thermometer": {"driver": "dmm9999"}}, r"\[thermometer\] driver = 'dmm9999'"),
        ({"chamber": {"driver": "agilent34401a"}}, "no chamber driver 'agilent34401a'"),
        ({"thermometer": {"nplcc": 1}}, r"\[thermometer\]: unknown key\(s\) \['nplcc'\]"),
        ({"thermometer": {}, "multimeter": {}}, "same role"),
        ({"rate_stream": {}, "adc": {}}, r"\[rate_stream\] and \[adc\] are the same role: keep"),
        ({"adc": {"bitz": 3}}, r"\[adc\]: unknown key\(s\) \['bitz'\]"),
    ],
)
def test_bad_role_tables_are_one_clear_error(d: dict, match: str) -> None:
    with pytest.raises(InputError, match=match):
        bench_from_dict(d, "b.toml")


def test_example_bench_names_its_drivers() -> None:
    cfg = load_bench(REPO / "examples" / "lab.toml")
    assert (cfg.thermometer.driver, cfg.chamber.driver, cfg.rate_stream.driver) == (
        "agilent34401a",
        "watlowf4",
        "gyroadc",
    )


def test_one_error_vocabulary() -> None:
    # A failed exchange is retried; a refused setting, a fault or a bug never is.
    assert is_transient(InstrumentError("x", "no reply"))
    assert is_transient(InstrumentTimeout("x", "silent"))
    assert is_transient(OSError("EIO"))
    assert not is_transient(LimitError("x", "setpoint 90 °C outside [-45, 70]"))
    assert not is_transient(InstrumentFault("sensor fault"))
    assert not is_transient(TypeError("bug"))


def test_driver_option_errors_are_one_line(tmp_path: Path, capsys) -> None:
    from gyrolab.cli import main

    out = tmp_path / "x.mcap"
    assert main(["acquire", "--bench", "sim", "--driver", "dmm9999", "--out", str(out)]) == 2
    assert "--driver dmm9999: no such driver" in capsys.readouterr().err
    lab = str(REPO / "examples" / "lab.toml")
    assert main(["acquire", "--bench", lab, "--driver", "espec", "--out", str(out)]) == 2
    assert "--driver applies to --bench sim only" in capsys.readouterr().err
    assert not out.exists()


def test_new_drivers_registered_with_simulated_back_ends() -> None:
    names = {s.name for s in registry.drivers("thermometer")}
    assert {"agilent34401a", "keysight34465a"} <= names
    assert {"espec", "watlowf4"} <= {s.name for s in registry.drivers("chamber")}
    for name in ("agilent34401a", "keysight34465a", "espec", "watlowf4", "gyroadc"):
        s = next(s for s in registry.drivers() if s.name == name)
        assert s.sim_backend and s.sim_address, s.name
