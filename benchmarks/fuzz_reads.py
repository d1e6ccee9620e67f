"""Fuzz the checked reads: random bit flips and truncations of a recording through
``report``, ``convert``, ``compensate``, ``apply`` and ``discrepancy``, in one process.

    python benchmarks/fuzz_reads.py [--flips 1000] [--cuts 200] [--per-region 20] [--seed 0]
                                    [--profile short] [--older-format] [--work DIR]
                                    [--json OUT.json]

A recording is simulated (``--profile``, default ``short``), each command is run on it once
(the baseline), then every damaged copy — one bit flipped at a uniformly random byte (and
``--per-region`` more in each kind of part of the file: header, metadata, message index,
summary, footer, …), or the file cut at a uniformly random length — goes through every
command (``gyrolab.cli.main``, in this process: no process launch per case). A case passes
when the command

* exits 2 with one line on stderr, ``gyrolab: error: <file>: <problem>``, no traceback,
  and leaves nothing where its output would go; or
* exits 0 with outputs whose data equal the baseline's (what a flip that changes no data
  must give: in the current format there is none, every byte being under a CRC; in the
  ``--older-format`` a flip in a message index, which no reader uses).

Anything else — an exception escaping the command (a traceback), another exit code,
different data with exit 0, an output (or a hidden ``.NAME.*.part``) left after an error —
is a failure and is listed. The result is tallied by where the damage landed (the MCAP record
type at the flipped byte). docs/reliability.md "Checked reads" has the measured result.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import os
import random
import shutil
import struct
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# argv of each command on RUN (relative: the outputs name the run as given) into OUT
COMMANDS: dict[str, Callable[[str, str, str], list[str]]] = {
    "convert": lambda run, out, model: ["convert", run, "--to", "csv", "--out", f"{out}/x.csv"],
    "report": lambda run, out, model: ["report", run, "--out", f"{out}/rep"],
    "compensate": lambda run, out, model: ["compensate", run, "--out", f"{out}/model"],
    "apply": lambda run, out, model: ["apply", model, run, "--out", f"{out}/ap.mcap"],
    "discrepancy": lambda run, out, model: ["discrepancy", run, "--out", f"{out}/dsc"],
}
# Outputs that are renderings of the data with the time they were made (the data they show
# are compared through the JSON/CSV/NPZ beside them) and the output marker (its time).
SKIP_SUFFIXES = (".html", ".pdf")
SKIP_NAMES = (".gyrolab-output",)
# JSON keys whose values are wall-clock measurements, not data
VOLATILE_KEYS = {
    "timing_s",
    "timing_breakdown_s",
    "elapsed_s",
    "time",
    "recovered_at",
    "fit_time_s",
    "seconds",
}

_NAMES = {
    0x01: "header",
    0x02: "footer",
    0x03: "schema",
    0x04: "channel",
    0x05: "message",
    0x06: "chunk",
    0x07: "message index",
    0x08: "chunk index",
    0x09: "attachment",
    0x0A: "attachment index",
    0x0B: "statistics",
    0x0C: "metadata",
    0x0D: "metadata index",
    0x0E: "summary offset",
    0x0F: "data end",
}


def regions(data: bytes) -> list[tuple[int, int, str]]:
    """``(start, end, name)`` of every part of an MCAP file: the magics and each record
    (by record type), from the records' length prefixes."""
    out = [(0, 8, "magic")]
    pos = 8
    while pos + 9 <= len(data) - 8:
        op, length = struct.unpack_from("<BQ", data, pos)
        end = min(pos + 9 + length, len(data))
        out.append((pos, end, _NAMES.get(op, f"op 0x{op:02x}")))
        pos = end
    out.append((pos, len(data), "magic"))
    return out


def region_of(regs: list[tuple[int, int, str]], offset: int) -> str:
    for a, b, name in regs:
        if a <= offset < b:
            return name
    return "?"


def _norm(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _norm(v) for k, v in x.items() if k not in VOLATILE_KEYS}
    if isinstance(x, list):
        return [_norm(v) for v in x]
    return x


def _mcap_digest(path: Path) -> str:
    """Digest of a recording's content: its metadata and every message (the header's
    library string and the layout of chunks are not data)."""
    from gyrolab.record.source import opened

    h = hashlib.blake2b(digest_size=16)
    with opened(path) as src:
        for rec in sorted(src.metadata(), key=lambda r: r.name):
            h.update(json.dumps([rec.name, _norm(_jsonish(rec.metadata))]).encode())
        for topic, log_time, data, _cid, seq, pub in src.messages():
            h.update(f"{topic}|{log_time}|{seq}|{pub}|".encode())
            h.update(data)
    return h.hexdigest()


def _jsonish(values: dict[str, str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in values.items():
        try:
            out[k] = json.loads(v)
        except ValueError:
            out[k] = v
    return out


def fingerprint(out_dir: Path) -> dict[str, str]:
    """Relative path → digest of every output under ``out_dir`` (the data, see module
    docstring): JSON without its wall-clock keys, recordings by content, the rest by bytes."""
    fp: dict[str, str] = {}
    for p in sorted(out_dir.rglob("*")):
        if not p.is_file() or p.name in SKIP_NAMES or p.suffix in SKIP_SUFFIXES:
            continue
        rel = str(p.relative_to(out_dir))
        if p.suffix == ".json":
            doc = _norm(json.loads(p.read_text()))
            fp[rel] = hashlib.blake2b(json.dumps(doc, sort_keys=True).encode()).hexdigest()
        elif p.suffix == ".mcap":
            fp[rel] = _mcap_digest(p)
        else:
            fp[rel] = hashlib.blake2b(p.read_bytes()).hexdigest()
    return fp


@dataclass
class Outcome:
    """One command on one damaged copy."""

    command: str
    kind: str  # "flip" | "cut"
    offset: int
    region: str
    verdict: str  # "refused" | "identical" | failure: "traceback" | "exit N" | ...
    detail: str = ""

    @property
    def ok(self) -> bool:
        return self.verdict in ("refused", "identical")


def run_command(argv: list[str]) -> tuple[int | None, str, str]:
    """``(exit code or None for an exception, stderr, traceback text)`` of
    ``gyrolab.cli.main(argv)`` in this process."""
    import traceback

    from gyrolab.cli import main

    err, out = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            rc = main(argv)
    except BaseException:  # noqa: BLE001 - anything escaping main is the failure we count
        return None, err.getvalue(), traceback.format_exc()
    return rc, err.getvalue(), ""


def judge(
    command: str,
    argv: list[str],
    out_dir: Path,
    baseline: dict[str, str] | None,
    blame: str = "run.mcap",
) -> tuple[str, str]:
    """Run one command; ``(verdict, detail)`` as the module docstring defines them. A
    refusal must name the damaged file, ``blame``; with ``baseline`` None an exit 0 is
    "unchecked" (a caller that expects every case refused)."""
    rc, err, tb = run_command(argv)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    left = (
        sorted(str(p.relative_to(out_dir)) for p in out_dir.rglob("*")) if out_dir.exists() else []
    )
    if rc is None:
        return "traceback", tb.strip().splitlines()[-1] if tb else ""
    if rc == 2:
        errors = [ln for ln in lines if ln.startswith("gyrolab: error: ")]
        if len(errors) != 1 or "Traceback" in err:
            return "bad message", err.strip()[-300:]
        if left:
            return "left output", ", ".join(left[:5])
        if not errors[0].startswith(f"gyrolab: error: {blame}: "):
            return "blames another file", errors[0]
        return "refused", errors[0]
    if rc == 0:
        if baseline is None:
            return "unchecked", ""
        fp = fingerprint(out_dir)
        if fp != baseline:
            diff = sorted(k for k in set(fp) | set(baseline) if fp.get(k) != baseline.get(k))
            return "different data", ", ".join(diff[:5])
        return "identical", ""
    return f"exit {rc}", (lines[-1] if lines else "")[:300]


@contextlib.contextmanager
def chdir(path: Path) -> Iterator[None]:
    old = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


@dataclass
class Fuzz:
    """A fuzz campaign over one intact recording (``work/intact/run.mcap``)."""

    work: Path
    commands: tuple[str, ...] = tuple(COMMANDS)
    baselines: dict[str, dict[str, str]] = field(default_factory=dict)
    outcomes: list[Outcome] = field(default_factory=list)

    @property
    def intact(self) -> Path:
        return self.work / "intact" / "run.mcap"

    @property
    def model(self) -> Path:
        return self.work / "intact" / "compensate" / "model"

    def baseline(self) -> None:
        """Every command on the intact file, outputs kept under ``intact/<command>/``
        (compensate first: apply uses its model)."""
        case = self.intact.parent
        for name in sorted(self.commands, key=lambda c: c != "compensate"):
            out = case / name
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir()
            with chdir(case):
                rc, err, tb = run_command(COMMANDS[name]("run.mcap", name, str(self.model)))
            if rc != 0:
                raise RuntimeError(f"baseline {name} failed (rc {rc}): {err}{tb}")
            self.baselines[name] = fingerprint(out)

    def case(self, kind: str, offset: int, data: bytes, regs: list[tuple[int, int, str]]) -> None:
        """One damaged copy through every command."""
        case = self.work / "case"
        shutil.rmtree(case, ignore_errors=True)
        case.mkdir()
        (case / "run.mcap").write_bytes(data)
        region = region_of(regs, offset) if kind == "flip" else f"cut in {region_of(regs, offset)}"
        for name in self.commands:
            out = case / name
            out.mkdir()
            with chdir(case):
                argv = COMMANDS[name]("run.mcap", name, str(self.model))
                verdict, detail = judge(name, argv, out, self.baselines.get(name))
            self.outcomes.append(Outcome(name, kind, offset, region, verdict, detail))
            shutil.rmtree(out, ignore_errors=True)

    def flips(self, n: int, rng: random.Random) -> None:
        intact = self.intact.read_bytes()
        regs = regions(intact)
        for _ in range(n):
            off = rng.randrange(len(intact))
            d = bytearray(intact)
            d[off] ^= 1 << rng.randrange(8)
            self.case("flip", off, bytes(d), regs)

    def flips_per_region(self, n: int, rng: random.Random) -> None:
        """``n`` flips in each kind of region the file has (magics, header, metadata, chunks,
        message indexes, DataEnd, summary records, footer): uniform flips land almost all
        in chunks, and these show every other part is covered too."""
        intact = self.intact.read_bytes()
        regs = regions(intact)
        for name in sorted({r[2] for r in regs}):
            spans = [(a, b) for a, b, k in regs if k == name]
            for _ in range(n):
                a, b = rng.choice(spans)
                off = rng.randrange(a, b)
                d = bytearray(intact)
                d[off] ^= 1 << rng.randrange(8)
                self.case("flip", off, bytes(d), regs)

    def cuts(self, n: int, rng: random.Random) -> None:
        intact = self.intact.read_bytes()
        regs = regions(intact)
        for _ in range(n):
            off = rng.randrange(len(intact))
            self.case("cut", off, intact[:off], regs)

    def table(self) -> dict[str, Any]:
        """Counts per (kind, region, command, verdict) and the failures."""
        tally: dict[str, dict[str, int]] = {}
        for o in self.outcomes:
            key = f"{o.kind} | {o.region}"
            row = tally.setdefault(key, {})
            row[o.verdict] = row.get(o.verdict, 0) + 1
        failures = [vars(o) for o in self.outcomes if not o.ok]
        return {"tally": tally, "failures": failures, "runs": len(self.outcomes)}


def without_data_crc(data: bytes) -> bytes:
    """``data`` as gyrolab wrote it before the data section's CRC: the DataEnd record's
    CRC 0 ("not computed", which the MCAP specification allows; no other byte differs)."""
    footer = len(data) - 8 - 29
    (summary_start,) = struct.unpack_from("<Q", data, footer + 9)
    d = bytearray(data)
    d[summary_start - 4 : summary_start] = b"\0\0\0\0"
    return bytes(d)


def make_recording(path: Path, profile: str, seed: int) -> None:
    from gyrolab.cli import main

    path.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(["simulate", "--profile", profile, "--seed", str(seed), "--out", str(path)])
    if rc != 0:
        raise RuntimeError("simulate failed")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flips", type=int, default=1000)
    ap.add_argument("--cuts", type=int, default=200)
    ap.add_argument(
        "--per-region", type=int, default=20, help="flips more in each kind of region (20)"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--profile", default="short")
    ap.add_argument("--work", type=Path, help="scratch directory (default: a temporary one)")
    ap.add_argument("--json", type=Path, help="write the tally and failures here")
    ap.add_argument(
        "--older-format",
        action="store_true",
        help="fuzz the recording as gyrolab wrote it before the data section's CRC (its "
        "DataEnd CRC set to 0): chunks and summary checked by their own CRCs, metadata not",
    )
    args = ap.parse_args()
    os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
    os.environ.setdefault("MPLBACKEND", "Agg")
    work = args.work or Path(tempfile.mkdtemp(prefix="gyrolab-fuzz-"))
    work.mkdir(parents=True, exist_ok=True)
    fz = Fuzz(work)
    t0 = time.perf_counter()
    make_recording(fz.intact, args.profile, args.seed)
    if args.older_format:
        fz.intact.write_bytes(without_data_crc(fz.intact.read_bytes()))
    fz.baseline()
    t_base = time.perf_counter() - t0
    rng = random.Random(args.seed)
    fz.flips(args.flips, rng)
    fz.flips_per_region(args.per_region, rng)
    fz.cuts(args.cuts, rng)
    res = fz.table()
    res.update(
        older_format=args.older_format,
        flips=args.flips,
        flips_per_region=args.per_region,
        cuts=args.cuts,
        seed=args.seed,
        profile=args.profile,
        file_bytes=fz.intact.stat().st_size,
        baseline_s=round(t_base, 1),
        fuzz_s=round(time.perf_counter() - t0 - t_base, 1),
        load_average=os.getloadavg()[0],
    )
    print(
        f"{fz.intact.stat().st_size} bytes, {args.flips} flips, {args.cuts} cuts, "
        f"{len(fz.commands)} commands: {res['runs']} runs in {res['fuzz_s']} s "
        f"(baseline {res['baseline_s']} s, load {res['load_average']:.1f})"
    )
    for key in sorted(res["tally"]):
        print(f"  {key:<28} {res['tally'][key]}")
    print(f"failures: {len(res['failures'])}")
    for f in res["failures"][:40]:
        print(
            f"  {f['command']} {f['kind']} at {f['offset']} ({f['region']}): "
            f"{f['verdict']} {f['detail']}"
        )
    if args.json:
        args.json.write_text(json.dumps(res, indent=1) + "\n")
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)
    return 1 if res["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
