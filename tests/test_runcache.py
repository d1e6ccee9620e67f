"""benchmarks/runcache.py: cached benchmark runs as deterministic gzip-compressed JSON, and
runs cached before as plain JSON still read."""

from __future__ import annotations

import gzip
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from runcache import load, path_of, save  # noqa: E402

RUN = {"meta": {"date": "2026-11-27", "machine": "τ"}, "units": [{"x": 0.1 + 0.2, "n": 3}]}


def test_save_is_compact_deterministic_and_loads_equal(tmp_path: Path) -> None:
    stem = tmp_path / "staircase-x"
    out = save(stem, RUN)
    assert out.name == "staircase-x.json.gz"
    first = out.read_bytes()
    assert b" " not in gzip.decompress(first)  # no indent, compact separators
    assert load(stem) == RUN
    save(stem, RUN)  # the same run again: the same bytes (gzip mtime 0)
    assert out.read_bytes() == first
    assert not list(tmp_path.glob("*.part"))  # atomic: no temporary left behind
    # numpy scalars are written as floats, as the suites produce them
    save(stem, {"v": np.float64(1.5)})
    assert load(stem) == {"v": 1.5}


def test_plain_json_of_older_runs_still_reads(tmp_path: Path) -> None:
    stem = tmp_path / "random-old"
    (tmp_path / "random-old.json").write_text(json.dumps(RUN, indent=1))
    assert path_of(stem).name == "random-old.json"
    assert load(stem) == RUN
    # once rewritten compressed, the .json.gz is the one read; the plain file stays
    save(stem, {"new": 1})
    assert load(stem) == {"new": 1}
    assert (tmp_path / "random-old.json").exists()
