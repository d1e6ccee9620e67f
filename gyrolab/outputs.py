"""Atomic outputs: write to a temporary sibling, then rename into place.

The one owner of output paths (docs/cli.md, "Outputs"). A reader never sees a
half-written file, an interrupted command leaves nothing behind, and:

* an output is never one of the command's inputs: not the same file (same inode, or the
  same resolved path through links), a directory output never contains an input, and no
  output lies inside an input directory (a model directory's files, say);
* an existing output is replaced only with ``force``; an existing *directory* is replaced
  only if gyrolab wrote it (it holds the marker file :data:`MARKER`, naming the command
  that wrote it) — ``--force`` never deletes a directory of someone else's files;
* files get mode ``0666 & ~umask`` and directories ``0777 & ~umask``, as if the user had
  created them (``mkstemp``/``mkdtemp`` make them 0600/0700).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import math
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from gyrolab.errors import InputError

# Written into every output directory; ``--force`` replaces only a directory holding it.
MARKER = ".gyrolab-output"

PathLike = str | os.PathLike[str]


def umask() -> int:
    """The process umask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


# The inputs named on the command line of the running command (set by gyrolab.cli.main
# through :func:`command_inputs`): a safety net under every command's own ``inputs``, so
# that a command that forgets to pass them still cannot write over what it was given.
_COMMAND_INPUTS: list[str] = []


@contextlib.contextmanager
def command_inputs(paths: Iterable[PathLike]) -> Iterator[None]:
    """Within this context every output check also refuses ``paths`` (nestable)."""
    saved = list(_COMMAND_INPUTS)
    _COMMAND_INPUTS[:] = [str(x) for x in paths]
    try:
        yield
    finally:
        _COMMAND_INPUTS[:] = saved


def _input_clash(out: Path, inputs: Iterable[PathLike | None]) -> tuple[str, str] | None:
    """``(input, how)`` for the first input that ``out`` is (same inode or resolved path:
    ``"is"``), contains (``"contains"``) or lies inside (an input directory: ``"is inside"``);
    None when it touches none. Paths are compared resolved, so no link leads around it."""
    out_r = out.resolve()
    for inp in inputs:
        if inp is None:
            continue
        ip = Path(inp)
        if not ip.exists():
            continue
        ip_r = ip.resolve()
        if ip_r == out_r or (out.exists() and os.path.samefile(out, ip)):
            return str(inp), "is"
        if out_r in ip_r.parents:
            return str(inp), "contains"
        if ip.is_dir() and ip_r in out_r.parents:
            return str(inp), "is inside"
    return None


def check_output(
    path: PathLike,
    force: bool = False,
    *,
    inputs: Iterable[PathLike | None] = (),
    kind: str | None = None,
) -> Path:
    """Check that ``path`` may be written; raise :class:`InputError` (exit 2) if not.

    ``inputs``: the command's input files and directories; the output may be none of them
    and, as a directory, contain none. ``kind``: ``"file"`` or ``"dir"`` when the caller
    knows what it will write (``None``: either). Existing outputs need ``force``; an
    existing directory is replaced only if it holds :data:`MARKER`.
    """
    p = Path(path)
    clash = _input_clash(p, [*inputs, *_COMMAND_INPUTS])
    if clash is not None:
        inp, how = clash
        raise InputError(p, f"{how} one of this command's inputs ({inp}); choose another --out")
    if p.exists() or p.is_symlink():
        if not force:
            raise InputError(p, "already exists (use --force to overwrite)")
        if p.is_dir() and not p.is_symlink():
            if kind == "file":
                raise InputError(p, "is a directory; --force replaces files only with files")
            if not (p / MARKER).is_file():
                raise InputError(
                    p,
                    f"is a directory gyrolab did not write (no {MARKER}); --force replaces "
                    "only gyrolab's own output directories: remove it yourself or choose "
                    "another --out",
                )
        elif kind == "dir":
            raise InputError(p, "is not a directory; --force replaces a directory only")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(p, f"directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise InputError(p, f"directory {parent} is not writable")
    _probe(p)
    return p


def _probe(p: Path) -> None:
    """Create and remove a file where the output will be built (its temporary sibling):
    a place that refuses files although it looks writable (``/proc``, ``/sys``, a read-only
    mount, root's view of either) is found before any work starts, not at its end."""
    with _temporary(p, tempfile.mkstemp) as tmp:
        tmp.unlink()


class _StopSignalsHeld:
    """SIGINT, SIGTERM and SIGHUP held from now until :meth:`release`: one that comes
    meanwhile is noted, then handed to the handler it was meant for (``KeyboardInterrupt``
    under gyrolab/cli.py) by ``release``. A temporary is made and its clean-up armed in
    between: raised inside ``mkstemp``, after the file system made the ``.part`` but before
    its name came back, the interrupt left the ``.part`` behind. Only handlers set from
    Python, in the main thread (where Python runs them); an ignored or default signal is
    left as it is."""

    def __init__(self) -> None:
        self._noted: list[tuple[int, Any]] = []
        self._handlers: dict[int, Any] = {}
        if threading.current_thread() is threading.main_thread():
            for name in ("SIGINT", "SIGTERM", "SIGHUP"):
                sig = getattr(signal, name, None)
                if sig is not None and callable(signal.getsignal(sig)):
                    self._handlers[sig] = signal.signal(sig, self._note)
        self._held = dict(self._handlers)

    def __enter__(self) -> _StopSignalsHeld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def _note(self, signum: int, frame: Any) -> None:
        self._noted.append((signum, frame))

    def release(self) -> None:
        """Put the handlers back, then hand them the first signal noted (if any). May be
        called again (a signal during the first call raised there): no-op after."""
        while self._held:
            sig, handler = self._held.popitem()
            signal.signal(sig, handler)
        if self._noted:
            signum, frame = self._noted[0]
            self._noted.clear()
            self._handlers[signum](signum, frame)


@contextlib.contextmanager
def _temporary(final: Path, make: Any, mode: int | None = None) -> Iterator[Path]:
    """``make(prefix=…, suffix=".part", dir=…)`` (mkstemp or mkdtemp) beside ``final``, with
    ``mode & ~umask`` (``None``: as made, for the output check's probe); removed if
    anything is raised before the caller renamed it — a stop signal that came while it was
    being made included. A refusal of the file system is the output's one-line error."""
    held = _StopSignalsHeld()
    tmp: Path | None = None
    try:
        try:
            made = make(prefix=f".{final.name}.", suffix=".part", dir=final.parent)
        except OSError as e:
            raise InputError(final, f"cannot be written in {final.parent} ({e.strerror})") from None
        if isinstance(made, tuple):  # mkstemp: (fd, path)
            os.close(made[0])
            made = made[1]
        tmp = Path(made)
        held.release()  # a signal noted above is raised here, where the clean-up is armed
        if mode is not None:  # mkstemp/mkdtemp make it 0600/0700; an output gets the umask's
            os.chmod(tmp, mode & ~umask())
        yield tmp
    except BaseException:
        if tmp is not None:
            if tmp.is_dir() and not tmp.is_symlink():
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                with contextlib.suppress(FileNotFoundError):
                    tmp.unlink()
        held.release()
        raise


@contextlib.contextmanager
def atomic_file(
    path: PathLike, force: bool = False, *, inputs: Iterable[PathLike | None] = ()
) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success fsync and rename it into place."""
    final = check_output(path, force, inputs=inputs, kind="file")
    with _temporary(final, tempfile.mkstemp, 0o666) as tmp_path:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp_path, final)


def write_marker(directory: PathLike, command: str) -> None:
    """Write :data:`MARKER` into ``directory``: who wrote it, when, with which command."""
    from gyrolab import __version__

    info = {
        "written_by": f"gyrolab {__version__}",
        "command": command,
        "time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
    (Path(directory) / MARKER).write_text(json.dumps(info) + "\n", encoding="utf-8")


@contextlib.contextmanager
def atomic_dir(
    path: PathLike,
    force: bool = False,
    *,
    command: str = "gyrolab",
    inputs: Iterable[PathLike | None] = (),
) -> Iterator[Path]:
    """Yield a temporary directory beside ``path``; on success swap it into place.

    The directory gets :data:`MARKER` (naming ``command``) and mode ``0777 & ~umask``.
    An existing ``path`` is replaced only under the rules of :func:`check_output`.
    """
    final = check_output(path, force, inputs=inputs, kind="dir")
    with _temporary(final, tempfile.mkdtemp, 0o777) as tmp:
        yield tmp
        write_marker(tmp, command)
        if final.exists():
            # Checked again now (the work may have taken minutes): still ours to replace.
            check_output(final, force, inputs=inputs, kind="dir")
            with _StopSignalsHeld():  # the swap is one step: no .old left, no final missing
                # A fresh, unique name: never a path that might hold someone else's files.
                old = tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".old", dir=final.parent)
                os.replace(final, old)
                os.replace(tmp, final)
                shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, final)


def json_safe(x: Any) -> Any:
    """A JSON-safe copy of ``x``: numpy arrays and scalars become Python lists and numbers,
    NaN and ±inf become ``None`` (JSON has neither), keys become strings. Every JSON
    output of gyrolab (model directories, reports, fleet tables) goes through it."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if hasattr(x, "tolist") and not isinstance(x, (str, bytes)):  # numpy array or scalar
        return json_safe(x.tolist())
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    return x
