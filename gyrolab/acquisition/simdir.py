"""The simulated bench's scratch directory (``/tmp/gyrolab-sim-*``, or under
``$GYROLAB_SIM_SCRATCH``), removed on every exit.

``gyrolab acquire --bench sim`` keeps the simulated instruments' pseudo-terminal links in a
temporary directory. It is removed

* on a normal end and on any exception (``finally``);
* on SIGINT, SIGTERM and SIGHUP at any moment of ``acquire``: they end the command through
  the same ``finally`` (gyrolab/acquisition/interrupts.py says how and why they are
  deferred to safe points instead of raised where they land);
* at interpreter exit (``atexit``), should anything bypass the above;
* after a ``kill -9``, which runs no code at all: the directory holds an ``owner.pid``
  marker, and the next ``acquire --bench sim`` removes every ``gyrolab-sim-*`` directory
  whose marker names a process that no longer exists. Directories without the marker are
  not gyrolab's and are never touched.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

PREFIX = "gyrolab-sim-"
MARKER = "owner.pid"
#: Where the scratch directories are made (and swept): this variable's directory, else the
#: system's temporary directory. Tests point it at their own, so that no other gyrolab
#: run on the machine sweeps what they are looking at.
SCRATCH_ENV = "GYROLAB_SIM_SCRATCH"


def scratch_root() -> Path:
    """The directory the ``gyrolab-sim-*`` scratch directories go in (:data:`SCRATCH_ENV`)."""
    return Path(os.environ.get(SCRATCH_ENV) or tempfile.gettempdir())


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def sweep_stale(tmp: str | os.PathLike[str] | None = None) -> list[Path]:
    """Remove ``gyrolab-sim-*`` directories left by processes that died (kill -9)."""
    removed = []
    for d in Path(tmp or scratch_root()).glob(PREFIX + "*"):
        try:
            pid = int((d / MARKER).read_text().strip())
        except (OSError, ValueError):
            continue  # not ours (no marker) or not readable: leave it
        if pid != os.getpid() and not _alive(pid):
            shutil.rmtree(d, ignore_errors=True)
            removed.append(d)
    return removed


@contextlib.contextmanager
def sim_workdir() -> Iterator[Path]:
    """A fresh ``gyrolab-sim-*`` directory with its owner marker; removed on every exit."""
    root = scratch_root()
    sweep_stale(root)
    work = Path(tempfile.mkdtemp(prefix=PREFIX, dir=root))
    (work / MARKER).write_text(f"{os.getpid()}\n")

    def remove() -> None:
        shutil.rmtree(work, ignore_errors=True)

    atexit.register(remove)
    try:
        yield work
    finally:
        remove()
        atexit.unregister(remove)
