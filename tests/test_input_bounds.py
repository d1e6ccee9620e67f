"""Bounds on what a command is asked to do (docs/cli.md "Bounds") and messages that name
the right file: each is one line, exit 2, before anything is written.

Before: ``duration_s = 1e300`` simulated until killed, ``--units 0`` and ``--workers 0/-2``
ran and wrote, ``export --instance -1/99`` was a traceback, 500 °C setpoints and
``ambient_c = 500`` were simulated; a model directory given as the run said "file not
found", a multi-unit run given to ``apply`` said "no /temperature/pt100", and
``block_s = inf`` in ``--config`` was blamed on the run.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gyrolab.cli import main

STEP = "[[step]]\nsetpoint_c = {sp}\nduration_s = {dur}\n"


def _refused(capsys: pytest.CaptureFixture[str], argv: list[str], says: str, out: Path) -> str:
    assert main(argv) == 2, argv
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("gyrolab: error: ") and says in err[0], err
    assert not out.exists() and not list(out.parent.glob(f".{out.name}*")), "written"
    return err[0]


@pytest.mark.parametrize(
    "profile, says",
    [
        (STEP.format(sp=25, dur=1e300), "duration_s = 1e+300 must be"),
        (STEP.format(sp=25, dur=5e5) * 2, "more than 604800 s (7 days)"),
        (STEP.format(sp=500, dur=60), "setpoint_c = 500 °C is outside [-100, 200]"),
        ("ambient_c = 500\n" + STEP.format(sp=25, dur=60), "ambient_c = 500 °C is outside"),
        (STEP.format(sp=25, dur=60) + "max_extra_s = 1e300\n", "max_extra_s in [0, 604800]"),
    ],
    ids=["duration 1e300", "a fortnight", "500 °C setpoint", "ambient 500 °C", "extra 1e300"],
)
def test_a_profile_beyond_the_bounds_is_refused(
    profile: str, says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    prof = tmp_path / "p.toml"
    prof.write_text(profile)
    out = tmp_path / "x.mcap"
    for cmd in (["simulate"], ["acquire", "--bench", "sim"]):
        err = _refused(capsys, [*cmd, "--profile", str(prof), "--out", str(out)], says, out)
        assert str(prof) in err


@pytest.mark.parametrize(
    "argv, says",
    [
        (["simulate", "--units", "0"], "--units: must be at least 1"),
        (["simulate", "--units", "300"], "--units: must be 1..256"),
        (["acquire", "--bench", "sim", "--units", "0"], "--units: must be at least 1"),
        (["acquire", "--bench", "sim", "--units", "11"], "1 to 10 units"),
        (["compensate", "{run}", "--workers", "0"], "--workers: must be at least 1"),
        (["compensate", "{run}", "--workers", "-2"], "--workers: must be at least 1"),
        (["batch", "report", "{run}", "--workers", "0"], "--workers: must be at least 1"),
        (["batch", "report", "{run}", "--workers", "1000"], "--workers must be 1..256"),
        (["simulate", "--seed", "-1"], "--seed: must be in [0, 2**63)"),
        (["simulate", "--rate", "inf"], "--rate: must be a finite number > 0"),
        (["acquire", "--bench", "sim", "--speed", "0"], "--speed: must be a finite number > 0"),
        (["export", "{run}", "--format", "json", "--instance", "-1"], "--instance: must be at"),
        (["export", "{run}", "--format", "px4", "--device-id", "1", "--instance", "4"],
         "--instance: px4 has gyro calibration instances 0..3, not 4"),
        (["export", "{run}", "--format", "ardupilot", "--instance", "99"],
         "--instance: ardupilot has gyro calibration instances 0..2, not 99"),
    ],
    ids=lambda a: " ".join(a) if isinstance(a, list) else None,
)
def test_counts_and_rates_out_of_bounds(
    argv: list[str], says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run.mcap"
    run.write_bytes(b"")
    out = tmp_path / "out"
    _refused(capsys, [*(a.format(run=run) for a in argv), "--out", str(out)], says, out)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("msgs")
    (d / "p.toml").write_text(STEP.format(sp=25, dur=20))
    for name, units in (("one", "1"), ("two", "2")):
        argv = ["simulate", "--profile", str(d / "p.toml"), "--rate", "10", "--units", units]
        assert main([*argv, "--out", str(d / f"{name}.mcap")]) == 0
    model = d / "model"
    model.mkdir()
    (model / "model.json").write_text("{}")
    return {"one": d / "one.mcap", "two": d / "two.mcap", "model": model}


@pytest.mark.parametrize(
    "argv, blamed, says",
    [
        (["report", "{model}"], "{model}", "is a directory, not a recording file"),
        (["compensate", "{model}"], "{model}", "is a directory, not a recording file"),
        (["convert", "{model}", "--to", "csv"], "{model}", "is a directory, not a recording"),
        (["apply", "{model}", "{two}"], "{two}", "holds 2 units; choose one with --unit SERIAL"),
        (["compensate", "{one}", "--config", "{cfg}"], "{cfg}", "block_s must be a finite"),
    ],
    ids=["model dir as report's run", "… as compensate's", "… as convert's",
         "multi-unit run to apply", "block_s = inf"],
)  # fmt: skip
def test_the_message_names_the_file_at_fault(
    argv: list[str],
    blamed: str,
    says: str,
    runs: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    cfg = tmp_path / "cfg.toml"
    cfg.write_text("block_s = inf\n")
    fill = {**runs, "cfg": cfg}
    out = tmp_path / "out"
    args = [a.format(**fill) for a in argv]
    err = _refused(capsys, [*args, "--out", str(out)], says, out)
    assert err.startswith(f"gyrolab: error: {blamed.format(**fill)}: "), err
