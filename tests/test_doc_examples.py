"""The examples in docs/ run as written (issue 27): every fenced block after a
``<!-- doc-test -->`` line is run in one scratch directory that holds what the examples
name — ``run.mcap`` (a short simulated run), ``static.mcap`` (a copy of it) and ``MODEL``
(the session demo's model, tests/test_demo.py). A shell block runs each ``gyrolab …``
line through the command line (exit 0 expected); a Python block is executed."""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import shutil
from pathlib import Path

import pytest
from test_demo import make_demo

from gyrolab.cli import main

DOCS = Path(__file__).resolve().parents[1] / "docs"
MARK = re.compile(r"^<!-- doc-test[^>]*-->\n```(\w*)\n(.*?)^```", re.M | re.S)


def examples() -> list[tuple[str, str, str]]:
    """(where, language, code) of every marked block, in document order."""
    out = []
    for md in sorted(DOCS.glob("*.md")):
        text = md.read_text(encoding="utf-8")
        for m in MARK.finditer(text):
            line = text[: m.start()].count("\n") + 1
            out.append((f"{md.name}:{line}", m.group(1) or "sh", m.group(2)))
    return out


EXAMPLES = examples()


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("docs")
    argv = ["simulate", "--out", str(d / "run.mcap"), "--profile", "short", "--rate", "10"]
    assert main(argv) == 0
    shutil.copy(d / "run.mcap", d / "static.mcap")
    shutil.copytree(make_demo(tmp_path_factory) / "model", d / "MODEL")
    return d


def test_the_marked_examples_cover_the_docs() -> None:
    where = {w.split(":")[0] for w, _, _ in EXAMPLES}
    assert {"convert.md", "export.md", "profiles.md", "recording-format.md"} <= where
    assert len(EXAMPLES) >= 9


@pytest.mark.parametrize("where, lang, code", EXAMPLES, ids=[w for w, _, _ in EXAMPLES])
def test_doc_example_runs_as_written(workdir: Path, where: str, lang: str, code: str) -> None:
    cwd = os.getcwd()
    os.chdir(workdir)
    try:
        if lang == "python":
            with contextlib.redirect_stdout(io.StringIO()):
                exec(compile(code, where, "exec"), {"__name__": "__doc_example__"})
            return
        commands = [shlex.split(line, comments=True) for line in code.splitlines()]
        commands = [c for c in commands if c and c[0] == "gyrolab"]
        assert commands, f"{where}: no gyrolab command in the block"
        for argv in commands:
            rc = main(argv[1:])
            assert rc == 0, f"{where}: {' '.join(argv)} exited {rc}"
    finally:
        os.chdir(cwd)
