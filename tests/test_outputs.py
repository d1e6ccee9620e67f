"""Data safety of every command that writes (gyrolab/outputs.py; docs/cli.md, "Outputs").

An output is never one of the command's inputs (same path, same inode, or a directory that
contains an input); ``--force`` replaces a directory only if gyrolab wrote it (it holds
``.gyrolab-output``); files and directories honour the umask.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

from gyrolab.cli import main
from gyrolab.errors import InputError
from gyrolab.outputs import MARKER, atomic_dir, atomic_file

PROFILE = 'name = "p"\n[[step]]\nsetpoint_c = 25\nduration_s = 20\n'


@contextlib.contextmanager
def _umask(mask: int) -> Iterator[None]:
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def _mode(p: Path) -> int:
    return stat.S_IMODE(p.stat().st_mode)


@pytest.fixture(scope="module")
def run_mcap(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small recording (the 20 s profile at 10 Hz) to use as an input."""
    d = tmp_path_factory.mktemp("run")
    prof = d / "p.toml"
    prof.write_text(PROFILE)
    out = d / "run.mcap"
    assert main(["simulate", "--profile", str(prof), "--rate", "10", "--out", str(out)]) == 0
    return out


def _snapshot(*paths: Path) -> list[tuple[str, bytes, int]]:
    return [(str(p), p.read_bytes(), p.stat().st_mtime_ns) for p in paths]


def _refused(capsys, argv: list[str], *keep: Path, says: str = "inputs") -> str:
    before = _snapshot(*keep)
    assert main(argv) == 2, argv
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert _snapshot(*keep) == before  # nothing written, nothing touched
    return err[0]


def test_apply_refuses_to_write_over_the_raw_recording(run_mcap: Path, tmp_path, capsys) -> None:
    """The issue's case: `gyrolab apply M run.mcap --out run.mcap --force`."""
    model = tmp_path / "M"
    model.mkdir()
    err = _refused(
        capsys, ["apply", str(model), str(run_mcap), "--out", str(run_mcap), "--force"], run_mcap
    )
    assert "is one of this command's inputs" in err
    # The same file through a hard link (same inode) and through a symlink.
    hard = tmp_path / "hard.mcap"
    os.link(run_mcap, hard)
    soft = tmp_path / "soft.mcap"
    soft.symlink_to(run_mcap)
    for out in (hard, soft):
        argv = ["apply", str(model), str(run_mcap), "--out", str(out), "--force"]
        _refused(capsys, argv, run_mcap)
    # ... and over the model directory it reads.
    argv = ["apply", str(model), str(run_mcap), "--out", str(model), "--force"]
    _refused(capsys, argv, run_mcap)
    assert model.is_dir()


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "--profile", "{prof}", "--out", "{prof}"],
        ["acquire", "--bench", "sim", "--profile", "{prof}", "--out", "{prof}"],
        ["compensate", "{run}", "--out", "{run}"],
        ["compensate", "{run}", "--validate", "{copy}", "--out", "{copy}"],
        ["report", "{run}", "--out", "{run}"],
        ["discrepancy", "{run}", "--out", "{run}"],
        ["recover", "{run}", "--out", "{run}"],
        ["demo", "--profile", "{prof}", "--out", "{prof}"],
        ["convert", "{run}", "--to", "csv", "--out", "{run}"],
    ],
    ids=lambda a: a[0],
)
def test_no_command_writes_over_its_input(argv, run_mcap: Path, tmp_path, capsys) -> None:
    prof = tmp_path / "p.toml"
    prof.write_text(PROFILE)
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(run_mcap.read_bytes())
    args = [a.format(prof=prof, run=run_mcap, copy=copy) for a in argv]
    says = "must differ" if argv[0] == "recover" else "inputs"
    _refused(capsys, [*args, "--force"], prof, run_mcap, copy, says=says)


@pytest.mark.parametrize("command", ["report", "discrepancy", "compensate"])
def test_a_directory_output_may_not_contain_an_input(
    command: str, run_mcap: Path, tmp_path, capsys
) -> None:
    d = tmp_path / "out"
    d.mkdir()
    (d / MARKER).write_text("{}")  # even one gyrolab wrote
    inside = d / "run.mcap"
    inside.write_bytes(run_mcap.read_bytes())
    err = _refused(capsys, [command, str(inside), "--out", str(d), "--force"], inside)
    assert "contains one of this command's inputs" in err


def test_force_replaces_only_directories_gyrolab_wrote(tmp_path: Path) -> None:
    """`--force` on someone's directory refuses and deletes nothing; on gyrolab's own it
    replaces the whole directory."""
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "thesis.tex").write_text("years of work")
    with pytest.raises(InputError, match="did not write"), atomic_dir(theirs, force=True) as t:
        (t / "x").write_text("x")
    assert (theirs / "thesis.tex").read_text() == "years of work"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["theirs"]  # no temp left behind
    # A file where a directory output goes, and a directory where a file output goes.
    afile = tmp_path / "afile"
    afile.write_text("keep")
    with pytest.raises(InputError, match="not a directory"), atomic_dir(afile, force=True):
        pass
    with pytest.raises(InputError, match="is a directory"), atomic_file(theirs, force=True):
        pass
    assert afile.read_text() == "keep"
    ours = tmp_path / "ours"
    with atomic_dir(ours, command="report") as t:
        (t / "old.txt").write_text("1")
    marker = json.loads((ours / MARKER).read_text())
    assert marker["command"] == "report" and marker["written_by"].startswith("gyrolab ")
    with atomic_dir(ours, force=True, command="report") as t:
        (t / "new.txt").write_text("2")
    assert sorted(p.name for p in ours.iterdir()) == [MARKER, "new.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "ours", "theirs"]


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_outputs_honour_the_umask(mask: int, tmp_path: Path) -> None:
    with _umask(mask):
        with atomic_file(tmp_path / "f.bin") as t:
            t.write_bytes(b"x")
        with atomic_dir(tmp_path / "d") as t:
            (t / "inner.txt").write_text("x")
    assert _mode(tmp_path / "f.bin") == 0o666 & ~mask
    assert _mode(tmp_path / "d") == 0o777 & ~mask
    assert _mode(tmp_path / "d" / "inner.txt") == 0o666 & ~mask
    assert _mode(tmp_path / "d" / MARKER) == 0o666 & ~mask


def test_report_directory_has_the_marker_and_umask_modes(run_mcap: Path, tmp_path, capsys) -> None:
    """One real command end to end: a report directory, then `--force` over it."""
    out = tmp_path / "rep"
    with _umask(0o027):
        assert main(["report", str(run_mcap), "--out", str(out)]) == 0
        assert main(["report", str(run_mcap), "--out", str(out)]) == 2
        assert "already exists" in capsys.readouterr().err
        assert main(["report", str(run_mcap), "--out", str(out), "--force"]) == 0
    assert _mode(out) == 0o750
    assert all(_mode(p) == 0o640 for p in out.iterdir())
    assert json.loads((out / MARKER).read_text())["command"] == "report"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]  # no .old/.part left


def test_command_line_inputs_are_a_safety_net_for_every_command(tmp_path: Path) -> None:
    """Every existing path on the command line (but --out) is an input: a command that
    forgets to name its inputs to gyrolab.outputs still cannot write over them."""
    from gyrolab.cli import _input_paths, build_parser
    from gyrolab.outputs import command_inputs

    run = tmp_path / "run.mcap"
    run.write_bytes(b"raw")
    model = tmp_path / "M"
    model.mkdir()
    args = build_parser().parse_args(["apply", str(model), str(run), "--out", str(run)])
    assert sorted(_input_paths(args)) == sorted([str(model), str(run)])
    with command_inputs(_input_paths(args)):
        with pytest.raises(InputError, match="inputs"), atomic_file(run, force=True):
            pass
        with pytest.raises(InputError, match="inputs"), atomic_dir(tmp_path, force=True):
            pass
    assert run.read_bytes() == b"raw"
    with atomic_file(run, force=True) as t:  # outside the command: an ordinary --force
        t.write_bytes(b"new")
    assert run.read_bytes() == b"new"


def _model_dir(tmp_path: Path) -> Path:
    """A directory holding what a model directory holds (the commands below refuse their
    output before they read it)."""
    m = tmp_path / "m"
    m.mkdir()
    for name in ("model.json", "arrays.npz", "metrics.json"):
        (m / name).write_bytes(b"the model's own bytes")
    return m


@pytest.mark.parametrize(
    "argv",
    [
        ["export", "{m}", "--format", "json", "--out", "{m}/model.json"],
        ["export", "{m}", "--format", "c", "--out", "{m}/model.c"],
        ["apply", "{m}", "{run}", "--out", "{m}/results.npz"],
        ["apply", "{m}", "{run}", "--out", "{m}/sub/x.mcap"],
        ["report", "{run}", "--model", "{m}", "--out", "{m}/report"],
        ["fleet", "{m}", "--out", "{m}/fleet"],
    ],
    ids=lambda a: " ".join(a[:1] + a[-1:]),
)
def test_no_output_inside_an_input_directory(argv, run_mcap: Path, tmp_path, capsys) -> None:
    """The issue's probe: `export m --format json --out m/model.json --force` and `apply m
    run.mcap --out m/results.npz --force` overwrote the model's own files."""
    m = _model_dir(tmp_path)
    (m / "sub").mkdir()
    args = [a.format(m=m, run=run_mcap) for a in argv]
    err = _refused(capsys, [*args, "--force"], run_mcap, *sorted(m.glob("*.*")))
    assert "is inside one of this command's inputs" in err
    assert sorted(p.name for p in m.iterdir()) == [
        "arrays.npz",
        "metrics.json",
        "model.json",
        "sub",
    ]


@pytest.mark.parametrize("where", ["/proc/x.csv", "/sys/r"])
@pytest.mark.parametrize(
    "argv",
    [
        ["convert", "{run}", "--to", "csv", "--out", "{out}"],
        ["report", "{run}", "--out", "{out}"],
        ["simulate", "--profile", "{prof}", "--rate", "10", "--out", "{out}"],
        ["acquire", "--bench", "sim", "--profile", "{prof}", "--out", "{out}"],
    ],
    ids=lambda a: a[0],
)
def test_an_unwritable_output_is_one_line_before_any_work(
    argv, where: str, run_mcap: Path, tmp_path, capsys
) -> None:
    """`--out /proc/x.csv` or `/sys/r` (directories that look writable to root and refuse
    every file) was a traceback at the end of the work; now one line before it."""
    if not Path(where).parent.is_dir():
        pytest.skip(f"no {Path(where).parent} here")
    prof = tmp_path / "p.toml"
    prof.write_text(PROFILE)
    args = [a.format(run=run_mcap, prof=prof, out=where) for a in argv]
    err = _refused(capsys, args, run_mcap, says=where)
    assert "cannot be written" in err or "not writable" in err


def test_acquire_force_replaces_a_symlink_not_its_target(tmp_path: Path, capsys) -> None:
    """`acquire --force` onto a symbolic link wrote the recording into the link's target."""
    prof = tmp_path / "p.toml"
    prof.write_text(PROFILE)
    target = tmp_path / "elsewhere.txt"
    target.write_text("someone's file")
    link = tmp_path / "run.mcap"
    link.symlink_to(target)
    argv = ["acquire", "--bench", "sim", "--profile", str(prof), "--out", str(link), "--force"]
    assert main(argv) == 0, capsys.readouterr().err
    assert target.read_text() == "someone's file"
    assert not link.is_symlink() and link.read_bytes()[:8] == b"\x89MCAP0\r\n"
