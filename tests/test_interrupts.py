"""SIGTERM and SIGHUP end every command as SIGINT does (gyrolab/cli.py): exit 130 and the
atomic output's hidden ``.NAME.*.part`` removed. Before, SIGTERM during ``simulate``,
``report`` or a multi-unit ``compensate`` killed the process and left it behind.

Each case runs the command in a subprocess and signals it once its temporary output exists
(``acquire``'s own handling: tests/test_report_outcome.py).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import pytest

from gyrolab.cli import _stop_signals_like_sigint, main
from gyrolab.outputs import atomic_dir, atomic_file

ENV = {**os.environ, "GYROLAB_NO_PROGRESS": "1", "MPLBACKEND": "Agg"}
PROFILE = 'name = "p"\n' + "".join(
    f"[[step]]\nsetpoint_c = {c}\nduration_s = 320\n" for c in (25, 60, 0)
)


def _parts(d: Path) -> list[Path]:
    return sorted(d.glob(".*.part"))


def _size(p: Path) -> int:
    """Bytes in ``p`` (a file, or the files inside a directory); 0 for what went meanwhile
    (the output check's probe file lives for microseconds)."""
    total = 0
    with contextlib.suppress(FileNotFoundError, NotADirectoryError):
        for f in [p] if not p.is_dir() else list(p.rglob("*")):
            with contextlib.suppress(FileNotFoundError):
                total += f.stat().st_size if f.is_file() else 0
    return total


def _work_under_way(d: Path, min_bytes: int) -> bool:
    """The command's own temporary output exists in ``d``: a ``.part`` directory, or a
    ``.part`` file with ``min_bytes`` (> 0) written — never the output check's empty probe
    file (``outputs._probe``), which a poll catches only when the command stalls inside it."""
    return any((p.is_dir() or min_bytes > 0) and _size(p) >= min_bytes for p in _parts(d))


def _start_as_from_a_terminal(argv: list[str]) -> subprocess.Popen[str]:
    """``python -m gyrolab argv`` with SIGTERM and SIGHUP at their default action, as a
    shell starts it: a test runner started under ``nohup`` passed its ignored SIGHUP on,
    and the command keeps an ignored SIGHUP ignored by design (the report then ran to the
    end: exit 0). Only the runner's own main thread sets handlers (briefly, around the
    fork), so this holds however the suite is started."""
    stops = [getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n)]
    ignored = [s for s in stops if signal.getsignal(s) == signal.SIG_IGN]
    for s in ignored:
        signal.signal(s, signal.SIG_DFL)
    try:
        return subprocess.Popen(
            [sys.executable, "-m", "gyrolab", *argv], env=ENV, stderr=subprocess.PIPE, text=True
        )
    finally:
        for s in ignored:
            signal.signal(s, signal.SIG_IGN)


def _signal_once_writing(
    argv: list[str], where: Path, sig: signal.Signals, min_bytes: int = 0
) -> tuple[int, str]:
    """Run ``gyrolab argv``; send ``sig`` as soon as its temporary output is under way in
    ``where`` (``min_bytes`` written in a ``.part`` file: the work itself under way, past
    its libraries' start-up — a KeyboardInterrupt raised inside an import's ``exec`` ends
    the process by SIGINT whatever catches it, docs/reliability.md "Known limits").

    No wall-clock bound: each command ends by itself, so the wait ends when the output
    appears or the command ends (under load a report reached its output after 20-60 s)."""
    p = _start_as_from_a_terminal(argv)
    while not _work_under_way(where, min_bytes):
        assert p.poll() is None, f"ended before it wrote: {p.communicate()[1]}"
        time.sleep(0.005)
    p.send_signal(sig)
    _, err = p.communicate(timeout=900)  # a guard against a hang, not a bound on time
    return p.returncode, err


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("interrupts")
    (d / "p.toml").write_text(PROFILE)
    for name, units in (("one", "1"), ("two", "2")):
        argv = ["simulate", "--profile", str(d / "p.toml"), "--rate", "10", "--units", units]
        assert main([*argv, "--out", str(d / f"{name}.mcap")]) == 0
    return {"dir": d, "one": d / "one.mcap", "two": d / "two.mcap"}


@pytest.mark.parametrize(
    "argv, sig, min_bytes",
    [
        (["simulate", "--profile", "paper", "--out", "{out}/x.mcap"], signal.SIGTERM, 4096),
        (["report", "{one}", "--out", "{out}/rep"], signal.SIGHUP, 0),
        # at once: the Dask cluster is starting (the signal waits for it, then closes it)
        (["compensate", "{two}", "--workers", "2", "--out", "{out}/models"], signal.SIGTERM, 0),
    ],
    ids=["simulate SIGTERM", "report SIGHUP", "multi-unit compensate SIGTERM"],
)
def test_a_stop_signal_cleans_up_like_sigint(
    argv: list[str], sig: signal.Signals, min_bytes: int, runs: dict[str, Path], tmp_path: Path
) -> None:
    out = tmp_path / "out"
    out.mkdir()
    args = [a.format(out=out, one=runs["one"], two=runs["two"]) for a in argv]
    rc, err = _signal_once_writing(args, out, sig, min_bytes)
    assert rc == 130, err
    assert f"gyrolab: interrupted by {sig.name}" in err
    assert "Traceback" not in err, err
    assert list(out.iterdir()) == [], "left behind: " + ", ".join(p.name for p in out.iterdir())


def test_an_interrupt_inside_a_libraries_exec_still_exits_130(tmp_path: Path) -> None:
    """A stop signal that lands while a library runs ``exec(source)`` at import (scipy,
    dask) made ``python -m gyrolab`` end by SIGINT (status -2) after ``main`` returned 130:
    CPython remembered the interrupt as unhandled (gyrolab/cli.py
    ``_forget_interrupt_in_exec``). The command here raises it from such an ``exec``."""
    pkg = tmp_path / "execstop"
    pkg.mkdir()
    (pkg / "__main__.py").write_text(
        "from gyrolab import cli\n"
        "def _stopped_in_exec(opts):\n"
        "    exec(\"raise KeyboardInterrupt('SIGTERM')\")\n"
        "cli._handler = lambda command: _stopped_in_exec\n"
        "raise SystemExit(cli.main(['runs', 'list']))\n"
    )
    path = os.pathsep.join(p for p in (str(tmp_path), os.environ.get("PYTHONPATH")) if p)
    p = subprocess.run(
        [sys.executable, "-m", "execstop"],
        env={**ENV, "PYTHONPATH": path},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 130, p.stderr
    assert "gyrolab: interrupted by SIGTERM" in p.stderr


@pytest.mark.parametrize(
    "output, make, nth",
    [(atomic_file, "mkstemp", 1), (atomic_file, "mkstemp", 2), (atomic_dir, "mkdtemp", 1)],
    ids=["the output check's probe", "a file's temporary", "a directory's temporary"],
)
def test_a_stop_signal_while_the_temporary_is_made_leaves_nothing(
    output: Any, make: str, nth: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The signal lands just after the file system made the ``.part``, before its name is
    back with the code that removes it (a signalled ``report`` left its probe file or its
    ``.part`` directory behind under load: stalled there, it met the signal there)."""
    real, calls = getattr(tempfile, make), []

    def made_then_signalled(*args: Any, **kw: Any) -> Any:
        made = real(*args, **kw)
        calls.append(made)
        if len(calls) == nth:
            signal.raise_signal(signal.SIGTERM)
        return made

    monkeypatch.setattr(tempfile, make, made_then_signalled)
    with _stop_signals_like_sigint(), pytest.raises(KeyboardInterrupt, match="SIGTERM"):
        with output(tmp_path / "out"):
            pass
    assert len(calls) == nth  # the signal came where meant, and ended the output there
    assert list(tmp_path.iterdir()) == []
