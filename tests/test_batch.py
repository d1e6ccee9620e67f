"""`gyrolab batch` on dask.distributed: same bytes as a serial loop, failures isolated,
reruns skip complete items."""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import pytest
import torch
from test_pipeline import SMALL, write_run

from gyrolab import batch as B
from gyrolab.cli import main
from gyrolab.errors import InputError
from gyrolab.outputs import MARKER

torch.set_num_threads(1)

CLI_CONFIG = replace(SMALL, vmd_K=None, vmd_alpha=None, gpso_population=4, gpso_generations=1)
GOOD = ("a", "b", "c")


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("batch")
    for k, name in enumerate(GOOD):
        write_run(d / f"{name}.mcap", 20 + k, hours=0.5, heating=k == 1)
    (d / "bad.mcap").write_bytes(b"\x89MCAP0\r\n this is not a recording")
    return d


@pytest.fixture(scope="module")
def serial(runs: Path) -> Path:
    """The reference: `gyrolab compensate` once per run, in this process."""
    out = runs / "serial"
    out.mkdir()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("gyrolab.compensation.commands.DEFAULT_CONFIG", CLI_CONFIG)
        B.bound_threads(1)
        for name in GOOD:
            assert main(["compensate", str(runs / f"{name}.mcap"), "--out", str(out / name)]) == 0
    return out


PROGRESS: list[tuple[int, float]] = []  # what the workers reported of their items' stages


@pytest.fixture(scope="module")
def batched(runs: Path) -> tuple[Path, list[B.ItemResult]]:
    """The batch on a LocalCluster of 2 worker processes, the bad recording among them."""
    out = runs / "batched"
    keys = [*B.THREAD_ENV, "OMP_NUM_THREADS", "MALLOC_TRIM_THRESHOLD_", "PYTHONHASHSEED"]
    env = {k: os.environ.get(k) for k in keys}
    res = B.run_batch(
        "compensate",
        [str(runs / "*.mcap")],
        out,
        options=B.BatchOptions(config=CLI_CONFIG),
        workers=2,
        on_progress=lambda i, f: PROGRESS.append((i, f)),
    )
    # the cluster's worker settings stay in the workers
    assert {k: os.environ.get(k) for k in keys} == env
    return out, res


def test_progress_moves_with_each_items_stages(
    batched: tuple[Path, list[B.ItemResult]], runs: Path
) -> None:
    """Issue 27: the bar moved while items ran, not only when one ended: the workers
    reported each item's stages (read, fit, write), in order, as fractions below 1."""
    assert PROGRESS, "no stage reported by the workers"
    for i in {i for i, _ in PROGRESS}:
        got = [f for j, f in PROGRESS if j == i]
        assert got == sorted(got) and all(0 < f < 1 for f in got)
    # in one process (one worker) the same stages, read then fit then write
    seen: list[float] = []
    item = B.Item(runs / "a.mcap", runs / "inproc")
    r = B.run_item("compensate", item, B.BatchOptions(config=CLI_CONFIG), seen.append)
    assert r.status == "done" and seen == [0.25, 0.5, 0.75]


def test_batch_gives_the_serial_bytes_and_isolates_a_failure(
    runs: Path, serial: Path, batched: tuple[Path, list[B.ItemResult]]
) -> None:
    out, res = batched
    status = {Path(r.run).stem: r for r in res}
    assert [Path(r.run).stem for r in res] == ["a", "b", "bad", "c"]  # input order
    assert status["bad"].status == "failed"
    assert status["bad"].error.startswith(str(runs / "bad.mcap"))
    assert "\n" not in status["bad"].error
    assert not (out / "bad").exists()
    for name in GOOD:
        assert status[name].status == "done", status[name].error
        assert status[name].worker not in ("", "local")  # ran on a Dask worker
        assert (out / name / "model.json").read_bytes() == (
            serial / name / "model.json"
        ).read_bytes()
        assert json.loads((out / name / MARKER).read_text())["command"] == "compensate"
    # two workers really shared the work
    assert len({status[n].worker for n in (*GOOD, "bad")}) == 2


def test_rerun_does_no_work(
    runs: Path,
    batched: tuple[Path, list[B.ItemResult]],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out, _ = batched
    before = {n: (out / n / "model.json").stat().st_mtime_ns for n in GOOD}

    def no_cluster(*a: object, **k: object) -> None:
        raise AssertionError("a rerun of complete items must not start a cluster")

    monkeypatch.setattr(B, "_client", no_cluster)
    rc = main(["batch", "compensate", str(runs / "[abc].mcap"), "--out", str(out)])
    assert rc == 0
    assert capsys.readouterr().out.splitlines()[-1] == "0 done, 3 skipped, 0 failed"
    assert before == {n: (out / n / "model.json").stat().st_mtime_ns for n in GOOD}


def test_cli_exit_code_and_one_line_per_failure(
    runs: Path, batched: tuple[Path, list[B.ItemResult]], capsys: pytest.CaptureFixture[str]
) -> None:
    out, _ = batched
    rc = main(["batch", "compensate", str(runs / "*.mcap"), "--out", str(out), "--workers", "1"])
    cap = capsys.readouterr()
    assert rc == 1  # the bad recording failed again; the complete ones were skipped
    assert cap.out.splitlines()[-1] == "0 done, 3 skipped, 1 failed"
    fails = [ln for ln in cap.err.splitlines() if "failed:" in ln]
    assert len(fails) == 1 and str(runs / "bad.mcap") in fails[0]


def test_completeness_is_the_marker_of_the_same_command(tmp_path: Path) -> None:
    d = tmp_path / "x"
    d.mkdir()
    assert not B.is_complete(d, "compensate")  # no marker: e.g. someone else's directory
    (d / MARKER).write_text(json.dumps({"command": "report"}))
    assert not B.is_complete(d, "compensate") and B.is_complete(d, "report")


def test_bad_batch_arguments_are_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "a").mkdir()
    for sub in ("a", "b"):
        (tmp_path / sub).mkdir(exist_ok=True)
        (tmp_path / sub / "run.mcap").write_bytes(b"")
    with pytest.raises(InputError, match="same name"):
        B.plan(B.expand_inputs([str(tmp_path / "*" / "run.mcap")]), tmp_path / "out")
    assert (
        main(["batch", "report", str(tmp_path / "none*.mcap"), "--out", str(tmp_path / "o")]) == 2
    )
    assert "matches no file" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


_MMAPPED = """
import ctypes, sys
import numpy as np
from gyrolab.batch import tune_malloc

class MallInfo2(ctypes.Structure):  # glibc >= 2.33, mallinfo2(3)
    _fields_ = [(n, ctypes.c_size_t) for n in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
        "fordblks", "keepcost")]

libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = MallInfo2
if sys.argv[1] == "tuned":
    assert tune_malloc()
for _ in range(3):  # a pipeline's temporaries: allocated, used, freed, again
    a = np.ones(1 << 21)  # 16 MiB
    a.sum()
    print(libc.mallinfo2().hblkhd)  # bytes in mmap-ed blocks while it lives
    del a
"""


def test_tune_malloc_keeps_large_temporaries_off_mmap() -> None:
    """Under a Dask nanny's ``MALLOC_TRIM_THRESHOLD_=65536`` glibc's dynamic mmap threshold
    is off: every temporary above 128 KiB is a fresh mmap, zeroed by the kernel and unmapped
    when freed (the 2.3x per-item cost in docs/performance.md). After
    :func:`gyrolab.batch.tune_malloc` a 16 MiB temporary comes from the heap and is reused."""
    import subprocess
    import sys

    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "65536"}
    mapped = {}
    for how in ("nanny", "tuned"):
        out = subprocess.run(
            [sys.executable, "-c", _MMAPPED, how], env=env, capture_output=True, text=True
        )
        if out.returncode and "mallinfo2" in out.stderr:
            pytest.skip("not glibc >= 2.33")
        assert out.returncode == 0, out.stderr
        mapped[how] = [int(v) for v in out.stdout.split()]
    assert all(v >= 16 << 20 for v in mapped["nanny"])  # each one mmap-ed
    assert all(v < 16 << 20 for v in mapped["tuned"])  # none of them
