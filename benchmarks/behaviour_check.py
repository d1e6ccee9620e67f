"""Behaviour unchanged, measured: the same inputs through two commits of gyrolab.

Issue 28 restructured the code (a drift-model interface, the model directory's one owner,
the run engine in parts, the discrepancy catalogue, every command through ``app/``, one
name per concept) and asks that behaviour stay as it was: ``simulate`` byte-identical
on the paper profile, and ``model.json``, the results and ``discrepancy.json`` identical on
the demo's runs. This script runs both commits on the same inputs, each in its own
process from its own tree, and says what differs, record by record and key by key::

    python benchmarks/behaviour_check.py --old 9edcf5c [--new REV] --work /tmp/bc
        [--profile paper] [--cal CAL.mcap] [--held HELD.mcap] [--skip compensate,discrepancy]
    python benchmarks/validation_suite.py --units 2 --workers 1 --json /tmp/vs.json --out ''
    python benchmarks/behaviour_check.py --old X --work W --suite-json /tmp/vs.json

1. ``simulate --profile P --seed 1`` with each tree: the two files' bytes, and where they
   differ, which MCAP records differ and in which fields;
2. the demo's held-out run: ``acquire --bench sim --seed 2 --speed 600`` with the new
   tree (the run engine's holds depend on the machine's load, so both trees read this one
   file), or ``--held FILE``;
3. ``compensate CAL --validate HELD --seed 1`` with each tree on the same two files: every
   file of the model directories (JSON key by key; ``.npz`` array by array);
4. ``discrepancy CAL`` with each tree: ``discrepancy.json`` key by key, ``model.toml``.

Wall times (``timing_s``, ``timing_breakdown_s``, ``elapsed_s``) and the output marker are left
out of the comparison; everything else is compared
exactly. The old tree is a ``git worktree add --detach`` of ``--old`` under ``--work``
(kept for the next call; ``git worktree remove`` it when done).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
# wall times: never equal between two runs
IGNORED_KEYS = {"timing_s", "timing_breakdown_s", "elapsed_s"}
IGNORED_FILES = {".gyrolab-output"}  # the output marker: the command and when it ran


def run(tree: Path, args: list[str], log: Path) -> float:
    """``python -m gyrolab ARGS`` on ``tree``'s code (its own PYTHONPATH), output to
    ``log``; returns the wall seconds. Fails loudly: a failed command is no comparison."""
    env = dict(os.environ, PYTHONPATH=str(tree), GYROLAB_NO_PROGRESS="1", MPLBACKEND="Agg")
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        rc = subprocess.call(
            [sys.executable, "-m", "gyrolab", *args], cwd=tree, env=env, stdout=fh, stderr=fh
        )
    if rc != 0:
        raise SystemExit(f"{tree}: gyrolab {' '.join(args)} exit {rc} (see {log})")
    return time.perf_counter() - t0


def old_tree(rev: str, work: Path) -> Path:
    """A detached worktree of ``rev`` under ``work`` (made once)."""
    sha = subprocess.check_output(["git", "-C", str(REPO), "rev-parse", rev], text=True).strip()
    tree = work / f"tree-{sha[:10]}"
    if not tree.exists():
        subprocess.check_call(
            ["git", "-C", str(REPO), "worktree", "add", "--detach", str(tree), sha],
            stdout=subprocess.DEVNULL,
        )
    return tree


def mcap_records(path: Path) -> list[Any]:
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as fh:
        return list(StreamReader(fh, skip_magic=False, validate_crcs=False).records)


def diff_mcap(a: Path, b: Path) -> list[str]:
    """Empty when the bytes are equal; else each record (by position) whose fields differ."""
    if a.read_bytes() == b.read_bytes():
        return []
    ra, rb = mcap_records(a), mcap_records(b)
    out = [
        f"{a.name}: {a.stat().st_size} B vs {b.stat().st_size} B, {len(ra)} vs {len(rb)} records"
    ]
    for i, (x, y) in enumerate(zip(ra, rb, strict=False)):
        if x == y:
            continue
        name = type(x).__name__
        if type(x) is not type(y):
            out.append(f"  record {i}: {name} vs {type(y).__name__}")
            continue
        fields = [k for k in vars(x) if getattr(x, k) != getattr(y, k)]
        shown = {k: (getattr(x, k), getattr(y, k)) for k in fields}
        text = str(shown)
        out.append(f"  record {i} {name}: {text[:300]}")
        if len(out) > 20:
            out.append("  …")
            break
    return out


def diff_json(x: Any, y: Any, path: str = "") -> list[str]:
    """Every key path whose value differs (old → new), keys only one side has."""
    if isinstance(x, dict) and isinstance(y, dict):
        out: list[str] = []
        for k in sorted(set(x) | set(y), key=str):
            if k in IGNORED_KEYS:
                continue
            p = f"{path}.{k}" if path else str(k)
            if k not in y:
                out.append(f"{p}: only in old")
            elif k not in x:
                out.append(f"{p}: only in new")
            else:
                out += diff_json(x[k], y[k], p)
        return out
    if isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
        return [
            d
            for i, (u, v) in enumerate(zip(x, y, strict=True))
            for d in diff_json(u, v, f"{path}[{i}]")
        ]
    if x != y:
        sx, sy = json.dumps(x)[:80], json.dumps(y)[:80]
        return [f"{path}: {sx} -> {sy}"]
    return []


def diff_npz(a: Path, b: Path) -> list[str]:
    with np.load(a, allow_pickle=False) as za, np.load(b, allow_pickle=False) as zb:
        out = [f"{k}: only in old" for k in sorted(set(za.files) - set(zb.files))]
        out += [f"{k}: only in new" for k in sorted(set(zb.files) - set(za.files))]
        for k in sorted(set(za.files) & set(zb.files)):
            u, v = za[k], zb[k]
            if u.shape != v.shape or u.dtype != v.dtype:
                out.append(f"{k}: {u.dtype}{u.shape} -> {v.dtype}{v.shape}")
            elif not np.array_equal(u, v, equal_nan=u.dtype.kind == "f"):
                d = np.nanmax(np.abs(u.astype(float) - v.astype(float))) if u.size else 0.0
                out.append(f"{k}: values differ (max |diff| {d:.3g})")
        return out


def diff_tree(a: Path, b: Path) -> dict[str, list[str]]:
    """Per file of two output directories: [] when equal, else what differs."""
    names = sorted(
        {p.relative_to(a) for p in a.rglob("*") if p.is_file()}
        | {p.relative_to(b) for p in b.rglob("*") if p.is_file()}
    )
    res: dict[str, list[str]] = {}
    for rel in names:
        if rel.name in IGNORED_FILES:
            continue
        pa, pb = a / rel, b / rel
        if not pa.exists() or not pb.exists():
            res[str(rel)] = ["only in " + ("new" if not pa.exists() else "old")]
        elif pa.read_bytes() == pb.read_bytes():
            res[str(rel)] = []
        elif rel.suffix == ".json":
            d = diff_json(json.loads(pa.read_text()), json.loads(pb.read_text()))
            res[str(rel)] = d or ["bytes differ, values equal (formatting, or only timing_s)"]
        elif rel.suffix == ".npz" and zipfile.is_zipfile(pa):
            res[str(rel)] = diff_npz(pa, pb) or ["bytes differ, arrays equal (zip metadata)"]
        else:
            res[str(rel)] = [
                f"bytes differ ({hashlib.sha256(pa.read_bytes()).hexdigest()[:12]} "
                f"-> {hashlib.sha256(pb.read_bytes()).hexdigest()[:12]})"
            ]
    return res


def show(title: str, res: dict[str, list[str]]) -> None:
    same = [k for k, v in res.items() if not v]
    print(f"{title}: {len(same)} of {len(res)} files identical ({', '.join(same) or 'none'})")
    for k, v in res.items():
        for line in v:
            print(f"  {k}: {line}")


def each_tree(trees: dict[str, Path], work: Path, name: str, argv: list[str]) -> None:
    """``gyrolab ARGV WORK/<tag>/NAME`` with each tree (kept: a later call reuses it)."""
    for tag, tree in trees.items():
        out = work / tag / name
        if not out.exists():
            s = run(tree, [*argv, str(out)], work / tag / f"{argv[0]}.log")
            print(f"{argv[0]} ({tag}): {s:.1f} s")


def diff_suite(new: Path, ref: Path) -> list[str]:
    """A ``validation_suite.py --units N --json NEW`` run against the committed suite
    (``REF``, more units): its units (unit ``u`` is drawn from its own seed, so the first
    N are the same units) and the rotation check, key by key (``meta`` left out)."""
    a, b = json.loads(ref.read_text()), json.loads(new.read_text())
    out = diff_json(a["units"][: len(b["units"])], b["units"], "units")
    return out + diff_json(a["rotation"], b["rotation"], "rotation")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--old", help="the commit to compare against (e.g. 9edcf5c)")
    ap.add_argument("--new", default=None, help="the new commit (default: this tree as it is)")
    ap.add_argument(
        "--cal",
        type=Path,
        help="the calibration run for compensate/discrepancy "
        "(default: the new tree's simulate output)",
    )
    ap.add_argument("--work", type=Path, help="scratch directory")
    ap.add_argument("--profile", default="paper")
    ap.add_argument("--held", type=Path, help="the held-out run (default: acquire one)")
    ap.add_argument("--skip", default="", help="comma list of: compensate, discrepancy")
    ap.add_argument(
        "--suite-json",
        type=Path,
        help="only compare this validation_suite.py --json output with the committed one",
    )
    a = ap.parse_args(argv)
    if a.suite_json is not None:
        ref = REPO / "benchmarks/results/validation_suite.json"
        d = diff_suite(a.suite_json, ref)
        print(f"validation suite: {'identical' if not d else 'DIFFERS'} ({a.suite_json} vs {ref})")
        for line in d:
            print(f"  {line}")
        return 0
    if a.old is None or a.work is None:
        ap.error("--old and --work are required (but with --suite-json)")
    work = a.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    new = REPO if a.new is None else old_tree(a.new, work)
    trees = {"old": old_tree(a.old, work), "new": new}
    skip = set(filter(None, a.skip.split(",")))
    for tag in trees:
        (work / tag).mkdir(exist_ok=True)

    sims = {}
    for tag, tree in trees.items() if a.cal is None else ():
        sims[tag] = work / tag / "cal.mcap"
        if not sims[tag].exists():
            s = run(
                tree,
                ["simulate", "--out", str(sims[tag]), "--profile", a.profile, "--seed", "1"],
                work / tag / "simulate.log",
            )
            print(f"simulate ({tag}): {s:.1f} s")
    if a.cal is None:
        d = diff_mcap(sims["old"], sims["new"])
        print(
            f"simulate --profile {a.profile} --seed 1: "
            + ("byte-identical" if not d else "DIFFERS")
        )
        for line in d:
            print(line)
    cal = sims["new"] if a.cal is None else a.cal.resolve()
    held = a.held
    if held is None and not skip >= {"compensate"}:
        held = work / "held.mcap"
        if not held.exists():
            s = run(
                trees["new"],
                [
                    "acquire",
                    "--bench",
                    "sim",
                    "--out",
                    str(held),
                    "--profile",
                    a.profile,
                    "--seed",
                    "2",
                    "--speed",
                    "600",
                ],
                work / "acquire.log",
            )
            print(f"acquire held-out ({a.profile}, new tree): {s:.1f} s")
    if "compensate" not in skip:
        argv = ["compensate", str(cal), "--validate", str(held), "--seed", "1", "--out"]
        each_tree(trees, work, "model", argv)
        show(
            "compensate model directory", diff_tree(work / "old" / "model", work / "new" / "model")
        )
    if "discrepancy" not in skip:
        each_tree(trees, work, "disc", ["discrepancy", str(cal), "--out"])
        res = diff_tree(work / "old" / "disc", work / "new" / "disc")
        # index.html embeds the figures' PNG bytes (matplotlib's own metadata): not compared
        show("discrepancy directory", {k: v for k, v in res.items() if k != "index.html"})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
