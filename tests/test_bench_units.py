"""BENCH.toml for several units: ``[[unit]]`` and ``[scanner]`` (docs/bench-config.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gyrolab.acquisition.bench_config import bench_from_dict, load_bench
from gyrolab.errors import InputError
from gyrolab.instruments.drivers.gyroadc import GyroAdcConfig

TWO = {
    "chamber": {"port": "/dev/ttyUSB1"},
    "rate_stream": {"sample_rate_hz": 200.0, "gain_v_per_dps": 0.01},
    "scanner": {"driver": "keysight34970a", "resource": "TCPIP::10.0.0.9::5025::SOCKET"},
    "unit": [
        {"serial": "G-001", "port": "/dev/ttyUSB3", "temperature_channel": 101},
        {
            "serial": "G-002",
            "port": "/dev/ttyUSB4",
            "temperature_channel": 103,
            "rate_stream": {"gain_v_per_dps": 0.0102},
        },
    ],
}


def test_units_take_the_rate_stream_table_with_their_port_and_overrides() -> None:
    cfg = bench_from_dict(TWO, "b.toml")
    assert [u.serial for u in cfg.units] == ["G-001", "G-002"]
    a, b = (u.rate_stream for u in cfg.units)
    assert isinstance(a, GyroAdcConfig) and (a.port, b.port) == ("/dev/ttyUSB3", "/dev/ttyUSB4")
    assert a.sample_rate_hz == b.sample_rate_hz == 200.0  # from [rate_stream]
    assert (a.gain_v_per_dps, b.gain_v_per_dps) == (0.01, 0.0102)  # the unit's own
    assert cfg.scanner.channels == (101, 103)  # the scan list: the units' channels
    assert bench_from_dict({}, "one.toml").units == ()  # a single-unit bench: none


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"scanner": None}, r"needs \[scanner\]"),
        ({"unit": None}, r"needs the units it reads"),
        ({"thermometer": {}}, r"\[thermometer\]: a multi-unit bench"),
        ({"scanner": {"channels": [101]}}, "set by each"),
        ({"unit": [{"serial": "a/b", "temperature_channel": 101}]}, "serial"),
        ({"unit": [{"serial": "A", "temperature_channel": "101"}]}, "temperature_channel"),
        ({"unit": [{"serial": "A", "temperature_channel": 101, "colour": 1}]}, "colour"),
        ({"unit": [{"serial": "A", "temperature_channel": 101, "adc": {"bitz": 3}}]}, "bitz"),
        (
            {"unit": [{"serial": "A", "temperature_channel": 101, "adc": {}, "rate_stream": {}}]},
            r"\[\[unit\]\] A: rate_stream and adc are the same table: keep one",
        ),
        ({"adc": {}}, r"\[rate_stream\] and \[adc\] are the same role: keep one"),
        (
            {"unit": [{"serial": "A", "temperature_channel": 101}] * 2},
            "serial A is given to more than one unit",
        ),
        (
            {
                "unit": [
                    {"serial": "A", "temperature_channel": 101},
                    {"serial": "B", "temperature_channel": 101},
                ]
            },
            "channel 101 is given to more than one unit",
        ),
    ],
)
def test_bad_unit_tables_are_one_clear_error(change: dict, match: str) -> None:
    d = {**TWO, **{k: v for k, v in change.items() if v is not None}}
    for k in (k for k, v in change.items() if v is None):
        d.pop(k)
    with pytest.raises(InputError, match=match):
        bench_from_dict(d, "b.toml")


def test_a_real_bench_needs_every_units_port(tmp_path: Path) -> None:
    f = tmp_path / "b.toml"
    f.write_text(
        '[chamber]\nport = "/dev/ttyUSB1"\n[scanner]\nresource = "TCPIP::h::5025::SOCKET"\n'
        '[[unit]]\nserial = "G-1"\nport = "/dev/ttyUSB3"\ntemperature_channel = 101\n'
        '[[unit]]\nserial = "G-2"\ntemperature_channel = 102\n'
    )
    with pytest.raises(InputError, match=r"\[\[unit\]\] G-2 port is required"):
        load_bench(f)
    f.write_text(f.read_text() + 'port = "/dev/ttyUSB4"\n')
    cfg = load_bench(f)  # no [thermometer] resource nor [rate_stream] port needed
    assert [u.rate_stream.port for u in cfg.units] == ["/dev/ttyUSB3", "/dev/ttyUSB4"]


def test_example_fixture_bench() -> None:
    cfg = load_bench(Path(__file__).resolve().parents[1] / "examples" / "fixture.toml")
    assert [u.temperature_channel for u in cfg.units] == [101, 102]
    assert cfg.units[1].rate_stream.gain_v_per_dps == 0.01008 and cfg.scanner.card == "34901A"


def test_multi_unit_bench_round_trips() -> None:
    cfg = bench_from_dict(TWO, "b.toml")
    again = bench_from_dict(cfg.to_dict(), "again")
    assert again.units == cfg.units and again.scanner == cfg.scanner


def test_older_adc_tables_read_as_rate_stream() -> None:
    """A BENCH.toml written before the rename (``[adc]``, ``[[unit]] adc``) reads as the
    same bench."""
    old = {k: v for k, v in TWO.items() if k not in ("rate_stream", "unit")}
    old["adc"] = TWO["rate_stream"]
    old["unit"] = [
        {("adc" if k == "rate_stream" else k): v for k, v in u.items()} for u in TWO["unit"]
    ]
    assert bench_from_dict(old, "b.toml").units == bench_from_dict(TWO, "b.toml").units
