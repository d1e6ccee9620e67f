"""``gyrolab batch compensate|report|discrepancy 'runs/*.mcap' --out DIR`` on Dask.

One item per input recording, each written to its own output directory ``DIR/<stem>``
by the same code as the single-run command (``gyrolab compensate RUN --out DIR/<stem>``
and so on), executed on :mod:`dask.distributed`:

* by default a :class:`~distributed.LocalCluster` of ``--workers`` processes (default: the
  number of CPUs, at most one per item), one thread each — no set-up;
* with ``--scheduler ADDRESS`` any running Dask scheduler (a cluster); its workers need
  gyrolab installed and must see the input and output paths (a shared file system).

Each item runs with its numerical libraries bounded to ``threads`` threads (torch, numba,
OpenMP/BLAS; default 1), so a worker's memory and CPU are those of one single-run command,
and results do not depend on how many workers there are: the same inputs and seeds give
the same bytes in ``model.json``.

Resumable and idempotent: an item whose output directory exists and holds the
:data:`gyrolab.outputs.MARKER` of the same command is complete (outputs are atomic, so a
directory with the marker is whole) and is skipped — unless ``--force``. A failed item is
reported as one line naming the file and the problem; the others go on. Exit code: 0 when
every item is done or skipped, 1 when any item failed, 2 for bad arguments (nothing run).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import glob
import io
import json
import os
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gyrolab.errors import GyrolabError, InputError
from gyrolab.outputs import MARKER
from gyrolab.progress import progress

TASKS = ("compensate", "report", "discrepancy")
#: The most local worker processes (and threads per item) a batch or a multi-unit
#: compensate may be asked for: beyond it a value is a typo that would start a process per
#: unit of it.
MAX_WORKERS = 256
#: How long ``--scheduler`` has to answer before the batch is refused (s).
SCHEDULER_TIMEOUT_S = 10.0
THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")


@dataclass
class ItemResult:
    """What became of one input: ``status`` is ``done``, ``skipped`` or ``failed``."""

    run: str
    out: str
    status: str
    unit: str | None = None
    seconds: float = 0.0
    error: str = ""
    peak_rss_mib: float = 0.0  # the worker process's peak resident set so far
    worker: str = ""


@dataclass
class BatchOptions:
    """Per-item settings shared by every item of a batch (picklable: sent to workers)."""

    seed: int | None = None  # compensate (None: CONFIG.toml's seed, else 0)
    models: str | None = None  # report: MODELS/<stem> is the model of each run
    sim_model: str | None = None  # discrepancy: starting SIM_MODEL.toml
    validate: str | None = None  # compensate: held-out run (the same unit's topics)
    also: tuple[str, ...] = ()  # compensate: further calibration runs (--also)
    force: bool = False
    threads: int = 1
    config: Any = None  # compensate: a PipelineConfig (None: the command's default)
    config_file: str | None = None  # compensate: CONFIG.toml (`gyrolab compensate --config`)
    extra: dict[str, Any] = field(default_factory=dict)


def expand_inputs(patterns: Iterable[str]) -> list[Path]:
    """Glob each pattern (sorted); a pattern that matches nothing is an error."""
    runs: list[Path] = []
    for pat in patterns:
        hits = sorted(glob.glob(pat)) if glob.has_magic(pat) else [pat]
        hits = [h for h in hits if Path(h).is_file()]
        if not hits:
            raise InputError(
                pat, "no such recording" if not glob.has_magic(pat) else "pattern matches no file"
            )
        runs.extend(Path(h) for h in hits)
    seen: set[Path] = set()
    unique = []
    for r in runs:
        if r.resolve() not in seen:
            seen.add(r.resolve())
            unique.append(r)
    return unique


@dataclass(frozen=True)
class Item:
    """One unit of work: a recording (and the unit of a multi-unit one) → an output dir."""

    run: Path
    out: Path
    unit: str | None = None


def plan(runs: Sequence[Path], out_dir: Path) -> list[Item]:
    """``out_dir/<stem>`` per single-unit run, ``out_dir/<stem>/<serial>`` per unit of a
    multi-unit run; two runs with one stem are an error."""
    from gyrolab.record.reader import list_units

    by_stem: dict[str, Path] = {}
    items = []
    for r in runs:
        if r.stem in by_stem:
            raise InputError(
                r,
                f"has the same name as {by_stem[r.stem]}: both would write "
                f"{out_dir / r.stem}; batch them separately",
            )
        by_stem[r.stem] = r
        try:
            units = list_units(r)
        except GyrolabError:
            units = []  # a damaged file: its item fails on a worker and is reported there
        if units:
            items.extend(Item(r, out_dir / r.stem / u, u) for u in units)
        else:
            items.append(Item(r, out_dir / r.stem))
    return items


def is_complete(out: Path, task: str) -> bool:
    """True when ``out`` is a whole output of ``gyrolab <task>`` (its marker says so)."""
    try:
        info = json.loads((out / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(info, dict) and info.get("command") == task


def bound_threads(n: int) -> None:
    """Limit this process's numerical libraries to ``n`` threads (BLAS/OpenMP pools through
    threadpoolctl, torch, numba). Also what makes results independent of the worker count:
    a BLAS on two threads sums in another order than on one (measured: a 13 h run's
    ``model.json`` differed between the in-process and the cluster run before this)."""
    import torch
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=n)  # stays in force for the process
    torch.set_num_threads(n)
    try:
        import numba

        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    except ImportError:  # pragma: no cover - numba is a dependency
        pass


# glibc mallopt(3) parameters; see tune_malloc
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


@functools.cache
def _glibc() -> Any:
    """glibc's ``libc.so.6`` (``None`` elsewhere: musl, macOS, Windows)."""
    try:
        lib = ctypes.CDLL("libc.so.6")
    except OSError:
        return None
    return lib if hasattr(lib, "mallopt") and hasattr(lib, "malloc_trim") else None


def tune_malloc() -> bool:
    """Let glibc keep this process's freed large blocks for reuse (True: done; False: not glibc).

    A Dask nanny starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (its
    ``distributed.nanny.pre-spawn-environ``). Setting any malloc threshold turns off glibc's
    dynamic mmap threshold (mallopt(3)), so every array above 128 KiB is a fresh ``mmap``,
    page-faulted in and zeroed by the kernel, and ``munmap``-ed when freed. The pipeline
    makes thousands of multi-MiB temporaries per unit: measured, one unit of a 13 h run took
    10.6 s of system time that way against 1.3 s (27.9 s against 17.3 s wall), and two such
    workers contend for memory bandwidth on top. Set back to what the dynamic threshold
    reaches on its own (mmap above 32 MiB, its ceiling on 64-bit), and trim only above
    256 MiB; :func:`release_memory` gives the memory back after each item instead, as the
    nanny's setting intends.
    """
    libc = _glibc()
    if libc is None:  # nothing to tune
        return False
    return bool(
        libc.mallopt(_M_MMAP_THRESHOLD, 32 << 20) and libc.mallopt(_M_TRIM_THRESHOLD, 256 << 20)
    )


def release_memory() -> None:
    """Return the freed heap to the system between items (glibc ``malloc_trim(0)``)."""
    libc = _glibc()
    if libc is not None:
        libc.malloc_trim(0)


def _peak_rss_mib() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _run_task(task: str, item: Item, opt: BatchOptions, progress: Progress | None) -> None:
    """The single-run command's work for one item (imported in the worker that runs it),
    called as the command calls it; ``progress(fraction)`` follows its stages."""
    run, out, common = str(item.run), str(item.out), {"force": opt.force, "unit": item.unit}
    model = _item_model(item, opt)
    if task == "compensate":
        from gyrolab.compensation.commands import STAGES, compensate

        stages = len(STAGES)
    elif task == "report":
        from gyrolab.record.reader import select_unit
        from gyrolab.report.commands import report_stages, write_report

        stages = len(report_stages(model is not None))
    else:
        from gyrolab.sim.discrepancy.commands import STAGES, discrepancy

        stages = len(STAGES)
    reached = [0]

    def on_stage(_name: str) -> None:
        reached[0] += 1
        if progress is not None:  # the last share is the item's end (run_items)
            progress(reached[0] / (stages + 1))

    if task == "compensate":
        compensate(
            run,
            out,
            validate=opt.validate,
            also=opt.also,
            config=opt.config_file,
            seed=opt.seed,
            base_config=opt.config,
            on_stage=on_stage,
            **common,
        )
    elif task == "report":
        unit = select_unit(run, item.unit)
        write_report(run, out, model, opt.force, unit=unit, on_stage=on_stage)
    else:
        discrepancy(run, out, model=opt.sim_model, on_stage=on_stage, **common)


#: How far one item is, a fraction (0 … 1) of its stages.
Progress = Callable[[float], None]
PROGRESS_TOPIC = "gyrolab-batch-progress"


@dataclass(frozen=True)
class WorkerProgress:
    """An item's progress sent from the Dask worker running it to the client, as events
    of :data:`PROGRESS_TOPIC` (``(batch, index, fraction)``; picklable)."""

    batch: str
    index: int

    def __call__(self, fraction: float) -> None:
        from distributed import get_worker

        with contextlib.suppress(ValueError):  # not on a worker: nobody to tell
            get_worker().log_event(PROGRESS_TOPIC, (self.batch, self.index, fraction))


def _item_model(item: Item, opt: BatchOptions) -> str | None:
    """``report``: the item's model, ``MODELS/<stem>`` (``/<serial>`` for a unit)."""
    if not opt.models:
        return None
    model = Path(opt.models) / item.run.stem
    return str(model / item.unit if item.unit else model)


def item_inputs(task: str, item: Item, opt: BatchOptions) -> list[str]:
    """The item's inputs, which its output may never replace: the run, and the held-out
    and ``--also`` runs (compensate) or the model (report, discrepancy)."""
    other = {
        "compensate": opt.validate,
        "report": _item_model(item, opt),
        "discrepancy": opt.sim_model,
    }[task]
    also = opt.also if task == "compensate" else ()
    return [v for v in (str(item.run), other, *also) if v]


def run_item(
    task: str, item: Item, opt: BatchOptions, progress: Progress | None = None
) -> ItemResult:
    """Run one item (in a worker): the single-run command's work, output silenced;
    ``progress(fraction)`` is told as it goes through its stages.

    Never raises for a problem with the item: it comes back as ``status="failed"`` with
    one line naming the file and the problem."""
    from gyrolab.outputs import command_inputs

    run, out = item.run, item.out
    t0 = time.perf_counter()
    res = ItemResult(str(run), str(out), "done", unit=item.unit)
    try:
        from distributed import get_worker

        res.worker = get_worker().address
    except (ImportError, ValueError):
        res.worker = "local"
    if not opt.force and is_complete(out, task):
        res.status = "skipped"
        return res
    bound_threads(opt.threads)
    tune_malloc()
    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            with command_inputs(item_inputs(task, item, opt)):
                _run_task(task, item, opt, progress)
    except GyrolabError as e:
        res.status, res.error = "failed", str(e)
    except Exception as e:  # a bug or a numerical failure: still one line, the rest go on
        first = (str(e).strip().splitlines() or [""])[0]
        res.status, res.error = "failed", f"{run}: {type(e).__name__}: {first}"
    if res.error and item.unit:
        res.error += f" (unit {item.unit})"
    res.seconds = time.perf_counter() - t0
    res.peak_rss_mib = _peak_rss_mib()
    release_memory()
    return res


@contextlib.contextmanager
def _client(scheduler: str | None, workers: int, threads: int):  # type: ignore[no-untyped-def]
    """A Dask client: of ``scheduler`` if given, else of a fresh LocalCluster."""
    import logging

    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler) as client:
            yield client
        return
    from gyrolab.acquisition.interrupts import deferred_stop_signals

    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
    env.update({k: threads for k in THREAD_ENV})
    env["GYROLAB_NO_PROGRESS"] = "1"
    saved = {k: os.environ.get(k) for k in [*env, "PYTHONHASHSEED"]}
    cluster = None
    try:
        try:
            # A stop signal while the cluster starts is raised once it exists (on leaving
            # the deferral), so that it is closed below: interrupted inside its start, it
            # was left to distributed's atexit close, which failed on its half-started
            # workers (a traceback, or exit -2: tests/test_interrupts.py).
            with (
                dask.config.set({"distributed.nanny.pre-spawn-environ": env}),
                deferred_stop_signals(),
            ):
                cluster = LocalCluster(
                    n_workers=workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    silence_logs=logging.ERROR,
                )
        finally:
            # the nanny sets these in *this* process's environment before spawning (by
            # design); put them back: a caller's numba refuses a changed NUMBA_NUM_THREADS
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        with Client(cluster) as client:
            yield client
    finally:
        if cluster is not None:
            cluster.close()


def check_scheduler(address: str, timeout_s: float | None = None) -> None:
    """A one-line error (exit 2) for a ``--scheduler`` that is not an address or does not
    answer within ``timeout_s`` (default :data:`SCHEDULER_TIMEOUT_S`), found before anything
    is written (a Dask handshake: the address parsed, a connection opened and closed)."""
    import asyncio

    from distributed.comm import connect

    async def probe() -> None:
        comm = await connect(address, timeout=timeout_s or SCHEDULER_TIMEOUT_S)
        await comm.close()

    try:
        asyncio.run(probe())
    except Exception as e:  # ValueError (not an address), OSError (no answer), and worse
        first = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise GyrolabError(f"gyrolab batch: --scheduler {address!r}: {first}") from None


def check_counts(workers: int | None, threads: int) -> None:
    """``--workers`` (None: as many as CPUs) and ``--threads`` within 1..:data:`MAX_WORKERS`."""
    if workers is not None and not 1 <= workers <= MAX_WORKERS:
        raise GyrolabError(f"--workers must be 1..{MAX_WORKERS}, not {workers}")
    if not 1 <= threads <= MAX_WORKERS:
        raise GyrolabError(f"--threads must be 1..{MAX_WORKERS}, not {threads}")


def check_options(task: str, opt: BatchOptions) -> None:
    """The options every item shares, checked once, before anything is written: a bad
    ``--config``, ``--sim-model`` or ``--models`` is one error, not one per item."""
    if opt.config_file:
        from gyrolab.compensation.config import load_config

        load_config(opt.config_file)
    if opt.sim_model:
        from gyrolab.sim.model import load_sim_model

        load_sim_model(opt.sim_model)
    if opt.models and not Path(opt.models).is_dir():
        what = "is not a directory" if Path(opt.models).exists() else "directory not found"
        raise InputError(opt.models, f"{what} (--models: MODELS_DIR/<stem> per run)")


def run_batch(
    task: str,
    patterns: Iterable[str],
    out_dir: str | os.PathLike[str],
    *,
    options: BatchOptions | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    on_progress: Callable[[int, float], None] | None = None,
) -> list[ItemResult]:
    """Run ``task`` on every recording matched by ``patterns`` (every unit of a multi-unit
    one); results in input order (``on_progress``: :func:`run_items`)."""
    if task not in TASKS:
        raise GyrolabError(f"gyrolab batch: unknown task {task!r} (one of {', '.join(TASKS)})")
    out_root = Path(out_dir)
    runs = expand_inputs(patterns)
    for run in runs:
        if out_root.resolve() == run.resolve() or out_root.resolve() in run.resolve().parents:
            raise InputError(out_root, f"contains one of the inputs ({run}); choose another --out")
    if out_root.exists() and not out_root.is_dir():
        raise InputError(out_root, "is not a directory")
    if not out_root.parent.is_dir():
        raise InputError(out_root, f"directory {out_root.parent} does not exist")
    items = plan(runs, out_root)
    check_options(task, options or BatchOptions())
    check_counts(workers, (options or BatchOptions()).threads)
    if scheduler:
        check_scheduler(scheduler)
    try:
        out_root.mkdir(exist_ok=True)  # mode 0777 & ~umask
        for it in items:
            it.out.parent.mkdir(exist_ok=True)  # DIR/<stem> of a multi-unit run
    except OSError as e:
        raise InputError(out_root, f"cannot be written ({e.strerror})") from None
    return run_items(
        task, items, options, scheduler=scheduler, workers=workers, on_progress=on_progress
    )


def run_items(
    task: str,
    items: Sequence[Item],
    options: BatchOptions | None = None,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    on_progress: Callable[[int, float], None] | None = None,
) -> list[ItemResult]:
    """Run ``task`` on ``items`` (complete ones skipped) on Dask; results in item order.

    ``workers=1`` without a scheduler runs the items one after the other in this process
    (no cluster to start: what a one-core machine or a one-unit run wants). The progress
    bar moves as each item goes through its stages (the workers report them as Dask
    events); ``on_progress(index, fraction)`` is told the same."""
    opt = options or BatchOptions()
    check_counts(workers, opt.threads)
    results: dict[int, ItemResult] = {}
    todo = []
    for i, it in enumerate(items):
        if not opt.force and is_complete(it.out, task):
            results[i] = ItemResult(str(it.run), str(it.out), "skipped", unit=it.unit)
        else:
            todo.append(i)
    # the bar moves by the items' stages: an item is 1, shared among its stages
    bar = progress(
        total=len(items),
        desc=f"{task}",
        unit="item",
        bar_format="{l_bar}{bar}| {n:.1f}/{total_fmt} items [{elapsed}<{remaining}{postfix}]",
    )
    bar.update(len(items) - len(todo))
    shown: dict[int, float] = {}
    lock = threading.Lock()

    def advance(i: int, fraction: float) -> None:
        with lock:
            if i in results or fraction <= shown.get(i, 0.0):
                return  # a late report of an item already done
            bar.update(fraction - shown.get(i, 0.0))
            shown[i] = fraction
        if on_progress is not None:
            on_progress(i, fraction)

    def done(i: int, r: ItemResult) -> None:
        with lock:
            results[i] = r
            if r.status == "failed":
                bar.write(f"gyrolab: {task}: failed: {r.error}", file=sys.stderr)
            bar.update(1.0 - shown.get(i, 0.0))

    try:
        n = max(1, workers or min(os.cpu_count() or 1, len(todo)))
        if todo and n == 1 and not scheduler:
            for i in todo:
                done(i, run_item(task, items[i], opt, functools.partial(advance, i)))
        elif todo:
            from distributed import as_completed

            with _client(scheduler, n, opt.threads) as client:
                batch_id = uuid.uuid4().hex

                def on_event(event: tuple[float, Any]) -> None:
                    bid, i, fraction = event[1]
                    if bid == batch_id:
                        advance(i, fraction)

                client.subscribe_topic(PROGRESS_TOPIC, on_event)
                futs = {
                    client.submit(
                        run_item, task, items[i], opt, WorkerProgress(batch_id, i), pure=False
                    ): i
                    for i in todo
                }
                for fut in as_completed(list(futs)):
                    i = futs[fut]
                    try:
                        r = fut.result()
                    except Exception as e:  # the worker died (memory, signal): item failed
                        it = items[i]
                        r = ItemResult(
                            str(it.run),
                            str(it.out),
                            "failed",
                            unit=it.unit,
                            error=f"{it.run}: worker lost ({type(e).__name__}: {e})",
                        )
                    done(i, r)
    finally:
        bar.close()
    return [results[i] for i in range(len(items))]


def summary(results: Sequence[ItemResult]) -> str:
    """One line per item and a total (what ``gyrolab batch`` prints on stdout)."""
    lines = []
    for r in results:
        extra = f"{r.seconds:7.1f} s  {r.peak_rss_mib:6.0f} MiB" if r.status == "done" else ""
        name = f"{r.run} [{r.unit}]" if r.unit else r.run
        lines.append(f"{r.status:<8} {name} -> {r.out}  {extra}".rstrip())
    counts = {s: sum(r.status == s for r in results) for s in ("done", "skipped", "failed")}
    lines.append(", ".join(f"{v} {k}" for k, v in counts.items()))
    return "\n".join(lines)
