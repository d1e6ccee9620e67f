"""The command line answers ``--help`` and a typing mistake before any numerical library is
imported (issue 27: parse and check the arguments and input paths first). Checked on what
is loaded, not on a clock: one fresh interpreter runs every case and reports, after each,
which heavy packages ``sys.modules`` holds."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from gyrolab.cli import main

HEAVY = ["numpy", "torch", "numba", "matplotlib", "dask", "distributed", "scipy", "mcap"]

PROBE = """
import contextlib, io, json, sys
from gyrolab.cli import main
heavy = set(HEAVY)
out = []
for argv in CASES:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except SystemExit as e:  # --help
            rc = e.code
    loaded = sorted({m.split(".")[0] for m in sys.modules} & heavy)
    out.append([argv, rc, loaded, err.getvalue()])
print(json.dumps(out))
"""


def test_help_and_argument_errors_import_nothing_heavy(tmp_path: Path) -> None:
    out = tmp_path / "x"
    model = tmp_path / "M"
    model.mkdir()
    (tmp_path / "run.mcap").write_bytes(b"")
    cases = [
        ["--help"],
        ["compensate", "--help"],
        ["export", "--help"],
        ["simulate"],  # --out missing
        ["simulate", "--out", str(out), "--profile", str(tmp_path / "nosuch.toml")],
        ["simulate", "--out", str(out), "--profile", "papr"],
        ["simulate", "--out", str(out), *["--axis-model", str(tmp_path / "run.mcap")] * 3],
        ["compensate", str(tmp_path / "missing.mcap"), "--out", str(out)],
        ["export", "M", "--format", "px4", "--out", str(tmp_path / "x.params")],
        ["export", str(model), "--format", "kalibr", "--out", str(tmp_path / "imu.yaml")],
        ["report", str(tmp_path / "run.mcap"), "--model", str(model / "no"), "--out", str(out)],
        ["apply", str(model), str(tmp_path / "missing.mcap"), "--out", str(out)],
        ["fleet", str(tmp_path / "nope"), "--out", str(out)],
        ["batch", "report", str(tmp_path / "run.mcap"), "--out", str(out), "--sim-model", "m"],
        ["convert", str(tmp_path / "missing.mcap"), "--to", "csv", "--out", str(out)],
        ["acquire", "--bench", str(tmp_path / "lab.toml"), "--out", str(out)],
        ["acquire", "--bench", str(tmp_path / "run.mcap"), "--speed", "9", "--out", str(out)],
        ["acquire", "--bench", "sim", "--internal-temperature", "1", "--out", str(out)],
    ]
    code = PROBE.replace("HEAVY", repr(HEAVY)).replace("CASES", repr(cases))
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    for argv, rc, loaded, err in json.loads(res.stdout):
        assert loaded == [], f"{argv}: imported {loaded} before answering"
        if "--help" in argv:
            assert rc == 0
            continue
        assert rc == 2, (argv, err)
        assert len(err.strip().splitlines()) == 1, (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["M", "run.mcap"]  # nothing written


def test_simulate_effect_errors_come_before_the_simulator(tmp_path: Path) -> None:
    """An unknown effect or parameter is answered with the vocabulary's module loaded (it
    needs numba, which loads scipy's base) but not the recording stack (mcap) nor torch or
    matplotlib."""
    cases = [
        ["simulate", "--out", str(tmp_path / "x.mcap"), "--effect", "bogus"],
        ["simulate", "--out", str(tmp_path / "x.mcap"), "--effect", "arw:Q=1"],
    ]
    code = PROBE.replace("HEAVY", repr(HEAVY)).replace("CASES", repr(cases))
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    for argv, rc, loaded, err in json.loads(res.stdout):
        assert rc == 2 and err.startswith("gyrolab: error: --effect:"), (argv, err)
        assert not {"mcap", "torch", "matplotlib", "dask"} & set(loaded), (argv, loaded)
    assert list(tmp_path.iterdir()) == []


def test_export_help_lists_the_options_one_format_requires(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        main(["export", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--device-id ID required with --format px4" in text
    assert "--run RUN required with --format kalibr" in text


def test_a_reader_that_goes_away_ends_the_command_quietly(tmp_path: Path) -> None:
    """``gyrolab ... | head``: the pipe closed before the output was written is exit 141
    (a shell's SIGPIPE code) with nothing on stderr, not a BrokenPipeError traceback."""
    p = subprocess.Popen(
        # unbuffered, so that the listing is written (and meets the pipe) inside main
        [sys.executable, "-u", "-m", "gyrolab", "runs", "list", "--json"],
        env={**os.environ, "GYROLAB_CATALOGUE": str(tmp_path / "c.sqlite")},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert p.stdout is not None and p.stderr is not None
    p.stdout.close()  # before the interpreter has started: every write meets a closed pipe
    err = p.stderr.read().decode()
    assert p.wait(timeout=60) == 141
    assert err == ""
