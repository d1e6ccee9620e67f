"""Independent readers in JavaScript (node + npm packages) for the MCAP interop tests.

The packages are installed once into a cache (``GYROLAB_JS_CACHE``, default
``~/.cache/gyrolab-js``), one sub-folder per set, and the script is copied beside its
``node_modules``: ES modules resolve packages beside the script, not through NODE_PATH.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def js_script(name: str, packages: list[str], folder: str = "") -> Path:
    """``tests/js/<name>`` installed beside ``packages`` (skips without node/npm)."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if not node or not npm:
        pytest.skip(f"node/npm not installed: the independent check {name} needs them")
    root = Path(os.environ.get("GYROLAB_JS_CACHE", Path.home() / ".cache" / "gyrolab-js"))
    cache = root / folder if folder else root
    cache.mkdir(parents=True, exist_ok=True)
    mods = cache / "node_modules"
    if not all((mods / p.rsplit("@", 1)[0] / "package.json").is_file() for p in packages):
        (cache / "package.json").write_text('{"name": "gyrolab-js-check", "private": true}\n')
        r = subprocess.run(
            [npm, "install", "--no-audit", "--no-fund", "--silent", *packages],
            cwd=cache,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert r.returncode == 0, f"npm install {packages} failed: {r.stderr[-2000:]}"
    script = cache / name
    shutil.copyfile(HERE / "js" / name, script)
    return script


def run_js(script: Path, mcap: Path) -> dict:
    """Run ``script`` on ``mcap``; its JSON output."""
    r = subprocess.run(
        ["node", str(script), str(mcap)],
        cwd=script.parent,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout)
