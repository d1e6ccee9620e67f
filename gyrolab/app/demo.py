"""``gyrolab demo --out DIR``: simulated bench → recording → compensation → report.

The README quick start in one command, using only the real pieces (nothing is faked):

1. record two runs of the same profile (default ``paper``: 13 h at 100 Hz): the
   calibration run with ``gyrolab simulate`` (the forward model, ``--seed``), the held-out
   run with ``gyrolab acquire --bench sim`` (``--seed + 1``): the lab path — drivers,
   profile runner and recorder talking to the simulated instruments over their wire
   protocols — so the report's run log and bench identity are those of a real
   acquisition. Should that path fail, the held-out run is simulated instead (a warning
   says so) so the quick start still shows the whole chain;
2. ``gyrolab compensate`` the calibration run with ``--validate`` on the held-out one;
3. ``gyrolab report`` the held-out run with the model, so the report's metrics are
   held out (``"held_out": true``), plus the raw record of the calibration run.

``DIR`` ends up holding ``calibration.mcap``, ``heldout.mcap``, ``model/``, ``report/``
(the compensated report: ``index.html``, ``metrics.json``, ``report.pdf``) and
``calibration-report/`` (raw). It appears atomically: the work happens in a temporary
sibling directory, entered so that every path recorded inside the outputs is relative
to ``DIR`` and stays valid after the rename.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from gyrolab.errors import GyrolabError
from gyrolab.outputs import atomic_dir, check_output
from gyrolab.profiles.profile import load_profile
from gyrolab.progress import progress


@contextlib.contextmanager
def _cwd(path: Path) -> Iterator[None]:
    old = Path.cwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


def _run(argv: list[str]) -> None:
    """One gyrolab subcommand, in process; a failure stops the demo with its message."""
    from gyrolab.cli import main

    rc = main(argv)
    if rc != 0:
        raise GyrolabError(f"demo: `gyrolab {' '.join(argv)}` failed (exit {rc})")


# The held-out run is paced: unpaced, the simulated bench runs as fast as the ADC reader
# drains it (~1 800x) and the multimeter poller gets a PT100 reading only every ~26 s of
# run time; at 600x it reads every 1 s (max 3 s) and the paper run takes ~80 s wall.
DEMO_ACQUIRE_SPEED = 600.0


def run_demo(
    out: str | os.PathLike[str],
    profile: str = "paper",
    seed: int = 1,
    force: bool = False,
    rate_hz: float = 100.0,
) -> dict[str, Any]:
    """Run the whole chain into ``out``; returns the report's metrics and stage timings."""
    out_p = Path(out)
    check_output(out_p, force, inputs=(profile,), kind="dir")
    # A bad --profile fails here, before minutes of work (load_profile raises InputError).
    prof_arg = str(Path(profile).resolve()) if Path(profile).is_file() else profile
    load_profile(prof_arg)
    timings: dict[str, float] = {}
    bar = progress(total=5, desc="demo", unit="stage")
    t_all = time.perf_counter()
    sim = ["--profile", prof_arg, "--rate", f"{rate_hz:g}"]
    held_source = "acquire --bench sim"
    try:
        with atomic_dir(out_p, force, command="demo", inputs=(profile,)) as tmp, _cwd(tmp):
            bar.set_postfix_str("simulate calibration run")
            t0 = time.perf_counter()
            _run(["simulate", "--out", "calibration.mcap", *sim, "--seed", str(seed)])
            timings["simulate calibration run"] = time.perf_counter() - t0
            bar.update(1)
            bar.set_postfix_str("acquire held-out run (simulated bench)")
            t0 = time.perf_counter()
            try:
                _run(
                    [
                        "acquire",
                        "--bench",
                        "sim",
                        "--out",
                        "heldout.mcap",
                        "--profile",
                        prof_arg,
                        "--seed",
                        str(seed + 1),
                        "--speed",
                        f"{DEMO_ACQUIRE_SPEED:g}",
                    ]
                )
            except GyrolabError as e:
                print(
                    f"gyrolab demo: warning: {e}; simulating the held-out run instead",
                    file=sys.stderr,
                )
                Path("heldout.mcap").unlink(missing_ok=True)
                held_source = "simulate"
                _run(["simulate", "--out", "heldout.mcap", *sim, "--seed", str(seed + 1)])
            timings["record held-out run"] = time.perf_counter() - t0
            bar.update(1)
            bar.set_postfix_str("compensate (GPSO-VMD, MPE, FLP, GA-BP)")
            t0 = time.perf_counter()
            _run(
                [
                    "compensate",
                    "calibration.mcap",
                    "--out",
                    "model",
                    "--validate",
                    "heldout.mcap",
                    "--seed",
                    str(seed),
                ]
            )
            timings["compensate"] = time.perf_counter() - t0
            bar.update(1)
            bar.set_postfix_str("report (held-out run, with model)")
            t0 = time.perf_counter()
            _run(["report", "heldout.mcap", "--model", "model", "--out", "report"])
            timings["report"] = time.perf_counter() - t0
            bar.update(1)
            bar.set_postfix_str("report (calibration run, raw)")
            t0 = time.perf_counter()
            _run(["report", "calibration.mcap", "--out", "calibration-report"])
            timings["raw report"] = time.perf_counter() - t0
            bar.update(1)
            metrics = json.loads(Path("report/metrics.json").read_text())
            timings["total"] = time.perf_counter() - t_all
            Path("demo.json").write_text(
                json.dumps(
                    {
                        "profile": profile,
                        "seed": seed,
                        "rate_hz": rate_hz,
                        "heldout_source": held_source,
                        "timing_s": timings,
                    },
                    indent=2,
                )
                + "\n"
            )
    finally:
        bar.close()
    return {"metrics": metrics, "timing_s": timings, "heldout_source": held_source}


def _summary(out: Path, res: dict[str, Any]) -> str:
    """The causal headline first, the baselines, the paper's offline method and (where the
    truth is known) the oracle beside it, on the same averages."""
    m = res["metrics"]
    pp = m.get("drift_pp_100s_deg_per_s", {})
    cols = [("raw", "raw"), ("causal", "CAUSAL")]
    if "oracle" in m:
        cols.append(("oracle", "oracle"))
    cols += [(f"baselines.{k}", f"{k}(T)") for k in m.get("baselines", {})]
    cols.append(("compensated", "paper offl."))

    def get(key: str) -> dict[str, Any]:
        d: Any = m
        for part in key.split("."):
            d = d.get(part, {}) if isinstance(d, dict) else {}
        return d if isinstance(d, dict) else {}

    def f(x: Any) -> str:
        return f"{x:.4g}" if isinstance(x, (int, float)) else "—"

    def row(label: str, values: list[Any], unit: str) -> str:
        return f"  {label:<22}" + "".join(f"{f(v):>12}" for v in values) + f"  {unit}"

    held = "held out" if m.get("held_out") else "in sample"
    lines = [
        f"demo finished in {res['timing_s']['total']:.0f} s; metrics on the {held} run "
        "(CAUSAL = the real-time, full-bandwidth headline; paper offl. = the paper's offline, "
        "low-passed reconstruction):",
        "  " + " " * 22 + "".join(f"{c:>12}" for _, c in cols),
        row("drift p-p (100 s)", [pp.get(k) for k, _ in cols], "deg/s"),
        row("bias stability", [get(k).get("bias_stability_deg_per_h") for k, _ in cols], "deg/h"),
        row("drift p-p (3.6 s)", [get(k).get("drift_pp_deg_per_s") for k, _ in cols], "deg/s"),
        row("ARW", [get(k).get("arw_deg_per_sqrt_h") for k, _ in cols], "deg/rt(h)"),
    ]
    if "oracle" not in m:
        lines.append("  (no oracle: the true drift of an acquired run is not known)")
    lines.append(f"report: {out / 'report' / 'index.html'} (PDF: report.pdf beside it)")
    return "\n".join(lines)


def demo(args: argparse.Namespace) -> int:
    """The ``gyrolab demo`` handler."""
    res = run_demo(args.out, args.profile, args.seed, args.force)
    print(_summary(Path(args.out), res))
    return 0
