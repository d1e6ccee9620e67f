"""Stop signals (SIGINT, SIGTERM, SIGHUP) during ``gyrolab acquire``: noted when they
arrive, acted on where the command can act on them.

Why not raise ``KeyboardInterrupt`` from the signal handler (Python's default SIGINT
handler, and what ``simdir`` used to do for SIGTERM/SIGHUP)? A Python signal handler runs
at whatever bytecode the main thread is at, and during the bench's start-up that is
mostly library code: numba compiling the physics kernels, scipy and numpy imports, enum
and dataclass creation. An exception raised there

* inside ``exec(str)``/``eval(str)`` (scipy's ``array_api_compat.clone_module`` does
  ``exec("from numpy import *")``) sets CPython 3.11's interpreter-wide
  ``_Py_UnhandledKeyboardInterrupt`` flag (pythonrun.c ``run_eval_code_obj``) as it leaves
  the ``exec``. Catching it later does not clear it: ``cli.main`` printed
  "gyrolab: interrupted" and returned 130, and the interpreter then killed itself with
  SIGINT (exit status -2);
* inside a ctypes callback (llvmlite's object-cache notifications while numba compiles)
  is printed as "Exception ignored" and lost: the signal was ignored and the run went on
  to the end (exit 0);
* anywhere else can leave a half-imported module or a half-started bench behind.

So, inside :func:`deferred_stop_signals`, a stop signal is only noted; :func:`check` raises
``KeyboardInterrupt`` at the points the command chooses (between start-up steps), the
runner (``Acquisition.run``) takes a noted signal as its stop request, and the scope raises
it on exit (after the scratch directory is gone). Every stop signal during ``acquire``
therefore ends with exit 130 (``cli.main``) or, during the run, the runner's interrupted
end (safe state, then 130). A second signal while one is pending raises at once, so that a
start-up that hangs (an instrument that never answers) can still be stopped from the
keyboard.
"""

from __future__ import annotations

import contextlib
import functools
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

__all__ = [
    "STOP_SIGNALS",
    "check",
    "deferred_stop_signals",
    "pause_requests",
    "pending",
    "stop_requests",
    "take",
]

# SIGHUP does not exist on Windows.
STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)
)

_pending: str | None = None  # name of the first stop signal not yet acted on
_armed = False  # a second signal may raise (False while the scope restores its handlers)

F = TypeVar("F", bound=Callable[..., Any])


def _note(signum: int, _frame: object) -> None:
    global _pending
    name = signal.Signals(signum).name
    if _pending is None:
        _pending = name
    elif _armed:  # asked twice: stop now, wherever the main thread is
        raise KeyboardInterrupt(name)


_paused: bool | None = None  # the operator's last pause (True) or resume before the run


def _note_pause(signum: int, _frame: object) -> None:
    global _paused
    _paused = signal.Signals(signum).name == "SIGUSR1"


def pending() -> str | None:
    """The name of the stop signal received and not yet acted on, or None."""
    return _pending


def take() -> str | None:
    """:func:`pending`, and forget it (the caller acts on it)."""
    global _pending
    name, _pending = _pending, None
    return name


def check() -> None:
    """Raise ``KeyboardInterrupt`` here if a stop signal is pending (a safe point)."""
    name = take()
    if name is not None:
        raise KeyboardInterrupt(name)


@contextlib.contextmanager
def deferred_stop_signals() -> Iterator[None]:
    """Note SIGINT/SIGTERM/SIGHUP instead of raising; raise ``KeyboardInterrupt`` on exit
    if one is pending. Only in the main thread (elsewhere signals are not ours to set)."""
    global _armed, _pending
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _pending = None
    old = {sig: signal.signal(sig, _note) for sig in STOP_SIGNALS}
    # The operator's pause and resume before the run: noted for it (their default action
    # would kill the process).
    old |= {sig: signal.signal(sig, _note_pause) for sig in PAUSE_SIGNALS}
    _armed = True
    try:
        yield
    finally:
        _armed = False
        for sig, handler in old.items():
            signal.signal(sig, handler)
    # A signal noted at any moment above, the restore included, is acted on here; one that
    # comes after this line meets the process's own handlers (SIGTERM: exit status -15).
    check()


def deferring_stop_signals(fn: F) -> F:
    """Decorator: run ``fn`` inside :func:`deferred_stop_signals`."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with deferred_stop_signals():
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


@contextlib.contextmanager
def stop_requests(stop: Callable[[str], None]) -> Iterator[None]:
    """During a run: each stop signal is ``stop("interrupted by SIGx")`` (the runner's
    clean stop: safe state, never an exception mid-run), and so is one noted just before
    (by :func:`deferred_stop_signals`). Only in the main thread; the previous handlers
    are restored on exit."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_signal(signum: int, _frame: object) -> None:
        stop(f"interrupted by {signal.Signals(signum).name}")

    old = {sig: signal.signal(sig, on_signal) for sig in STOP_SIGNALS}
    name = take()
    if name is not None:
        stop(f"interrupted by {name}")
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


#: The operator's pause (SIGUSR1) and resume (SIGUSR2) during a run (not on Windows).
PAUSE_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, n) for n in ("SIGUSR1", "SIGUSR2") if hasattr(signal, n)
)


@contextlib.contextmanager
def pause_requests(pause: Callable[[str], None], resume: Callable[[], None]) -> Iterator[None]:
    """During a run: SIGUSR1 is ``pause("paused by SIGUSR1")``, SIGUSR2 ``resume()`` (the
    runner's suspenders hold the run meanwhile). Only in the main thread; the previous
    handlers are restored on exit."""
    if threading.current_thread() is not threading.main_thread() or len(PAUSE_SIGNALS) < 2:
        yield
        return
    usr1, usr2 = PAUSE_SIGNALS

    def on_signal(signum: int, _frame: object) -> None:
        if signum == usr1:
            pause(f"paused by {usr1.name}")
        else:
            resume()

    global _paused
    old = {sig: signal.signal(sig, on_signal) for sig in PAUSE_SIGNALS}
    if _paused:  # paused before the run started
        pause(f"paused by {usr1.name}")
    _paused = None
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
