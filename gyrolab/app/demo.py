"""The demo: simulated bench → recording → compensation → report, in one call.

The README quick start in one command, using only the real pieces (nothing is faked):

1. record two runs of the same profile (default ``paper``: 13 h at 100 Hz): the
   calibration run simulated by the forward model (``seed``), the held-out run acquired
   on the simulated bench (``seed + 1``, :func:`gyrolab.app.acquire.acquire`): the lab
   path — drivers, run engine and recorder talking to the simulated instruments over
   their wire protocols — so the report's run log and bench identity are those of a real
   acquisition. Should that acquisition fail (or end without completing the profile),
   the demo fails with one line (exit 2) and leaves nothing behind;
2. fit the compensation model on the calibration run, validated on the held-out one;
3. report the held-out run with the model, so the report's metrics are held out
   (``"held_out": true``), judged against the example spec (:data:`DEMO_SPEC`,
   ``examples/spec.toml``: the causal output's metrics and the run's limits), plus the
   raw report of the calibration run.

``DIR`` ends up holding ``calibration.mcap``, ``heldout.mcap``, ``model/``, ``firmware/``
(the model exported: ``gyro_comp.c``/``.h``, ``ardupilot.parm``), ``report/`` (the
compensated report: ``index.html``, ``metrics.json``, ``report.pdf``),
``calibration-report/`` (raw), ``demo.json`` and ``catalogue.sqlite`` (where the demo
registered its units, runs, model, exports and reports, unless told another catalogue:
:func:`run_demo`). It appears atomically: the work happens
in a temporary sibling directory renamed into place at the end, and any failure removes
it. Each stage is a library call (no command line, no change of directory) on the files
in the temporary directory; the runs recorded inside the outputs (model.json's
``calibration.path``, ``run`` and ``calibration_run`` in the metrics, results.json, the
report's software table) are named relative to ``DIR`` (``calibration.mcap``,
``heldout.mcap``), never by the temporary directory, which no longer exists afterwards.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from gyrolab.app.acquire import acquire
from gyrolab.app.options import AcquireOptions, CompensateOptions, DemoOptions
from gyrolab.app.register import demo_catalogue, register_tree
from gyrolab.errors import GyrolabError
from gyrolab.outputs import atomic_dir, check_output
from gyrolab.profiles.profile import load_profile
from gyrolab.progress import progress
from gyrolab.report.spec_limits import Line
from gyrolab.sampling import DEFAULT_RATE_HZ

# The held-out run is paced: unpaced, the simulated bench runs as fast as the ADC reader
# drains it (~1 800x) and the multimeter poller gets a PT100 reading only every ~26 s of
# run time; at 600x it reads every 1 s (max 3 s) and the paper run takes ~80 s wall.
DEMO_ACQUIRE_SPEED = 600.0

HELDOUT_SOURCE = "acquire --bench sim"
# The spec the held-out report is judged against: the example spec (examples/spec.toml
# links to it), shipped with the package so that an installed gyrolab has it too.
DEMO_SPEC = Path(__file__).resolve().parents[1] / "report" / "example_spec.toml"


def run_demo(
    out: str | os.PathLike[str],
    profile: str = "paper",
    seed: int = 1,
    force: bool = False,
    rate_hz: float = DEFAULT_RATE_HZ,
    catalogue: str | None = None,
) -> dict[str, Any]:
    """Run the whole chain into ``out``; returns the report's metrics and stage timings.

    Then ``out`` is registered (:func:`gyrolab.app.register.register_tree`, once it is in
    place: the paths are final) in ``catalogue``, else in ``$GYROLAB_CATALOGUE`` where the
    user set it, else in ``out/catalogue.sqlite``: a demo's simulated units stay out of a
    lab's catalogue unless asked, and nothing is written outside ``out`` unless asked."""
    from gyrolab.app.compensate import compensate
    from gyrolab.report.commands import write_report
    from gyrolab.sim.commands import simulate_file

    out_p = Path(out)
    check_output(out_p, force, inputs=(profile,), kind="dir")
    # A bad profile fails here, before minutes of work (load_profile raises InputError).
    prof_arg = str(Path(profile).resolve()) if Path(profile).is_file() else profile
    load_profile(prof_arg)
    timings: dict[str, float] = {}
    bar = progress(total=6, desc="demo", unit="stage")
    t_all = time.perf_counter()

    def stage(name: str) -> float:
        bar.set_postfix_str(name)
        return time.perf_counter()

    def done(name: str, t0: float) -> None:
        timings[name] = time.perf_counter() - t0
        bar.update(1)

    try:
        with atomic_dir(out_p, force, command="demo", inputs=(profile,)) as tmp:
            # the outputs name each run by its path relative to DIR, which stays true after
            # the rename (tmp, where the stages read it, is gone by then)
            cal_label, held_label = "calibration.mcap", "heldout.mcap"
            cal, held = tmp / cal_label, tmp / held_label
            model, report = tmp / "model", tmp / "report"
            t0 = stage("simulate calibration run")
            line = simulate_file(cal, prof_arg, rate_hz=rate_hz, seed=seed)
            print(line, file=sys.stdout)
            done("simulate calibration run", t0)

            t0 = stage("acquire held-out run (simulated bench)")
            opts = AcquireOptions(
                bench="sim", out=held, profile=prof_arg, seed=seed + 1, speed=DEMO_ACQUIRE_SPEED
            )
            result = acquire(opts)
            if result.outcome == "interrupted":
                raise KeyboardInterrupt  # the demo ends as an interrupted command (130)
            if result.exit_code != 0:
                raise GyrolabError(
                    f"demo: the held-out acquisition ended {result.outcome} ({result.reason})"
                )
            done("record held-out run", t0)

            t0 = stage("compensate (GPSO-VMD, MPE, FLP, GA-BP)")
            compensate(
                CompensateOptions(
                    run=str(cal),
                    out=str(model),
                    validate=str(held),
                    seed=seed,
                    run_label=cal_label,
                    validate_label=held_label,
                )
            )
            done("compensate", t0)

            t0 = stage("export (C source, ArduPilot parameters)")
            export_firmware(model, tmp / "firmware")
            done("export", t0)

            t0 = stage("report (held-out run, with model)")
            metrics = write_report(held, report, model, label=held_label, spec=DEMO_SPEC)
            done("report", t0)

            t0 = stage("report (calibration run, raw)")
            write_report(cal, tmp / "calibration-report", label=cal_label)
            done("raw report", t0)
            timings["total"] = time.perf_counter() - t_all
            info = {
                "profile": profile,
                "seed": seed,
                "rate_hz": rate_hz,
                "heldout_source": HELDOUT_SOURCE,
                "spec": "examples/spec.toml",
                "timing_s": timings,
            }
            (tmp / "demo.json").write_text(json.dumps(info, indent=2) + "\n")
    finally:
        bar.close()
    url = demo_catalogue(out_p, catalogue)
    registered = url is not None and register_tree(out_p, url)
    return {
        "metrics": metrics,
        "timing_s": timings,
        "heldout_source": HELDOUT_SOURCE,
        "catalogue": url if registered else None,
    }


def export_firmware(model: Path, out: Path) -> None:
    """The model as firmware takes it: ``gyro_comp.c``/``.h`` (the chosen causal model,
    float32 C99) and ``ardupilot.parm`` (the firmware cubic), as ``gyrolab export`` writes
    them (each names its model by hash: the catalogue's trace goes model → export)."""
    from gyrolab.export.commands import export

    out.mkdir()
    export(model, "c", out / "gyro_comp.c")
    export(model, "ardupilot", out / "ardupilot.parm")


def summary(out: Path, res: dict[str, Any]) -> str:
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
    v = m.get("verdict")
    if v:
        lines.append(
            f"verdict: {v['verdict']} against {v['spec']} (examples/spec.toml; metric limits "
            f"on the {v['series']} output)"
        )
        lines += [f"  {Line(**d).text()}" for d in v["lines"] if not d["passed"]]
    lines.append(f"report: {out / 'report' / 'index.html'} (PDF: report.pdf beside it)")
    if res.get("catalogue"):
        from gyrolab.catalogue.store import shown

        where = shown(res["catalogue"])
        lines.append(f"catalogue: {where} (gyrolab runs list --catalogue {where})")
    return "\n".join(lines)


def demo(opts: DemoOptions) -> int:
    """The ``gyrolab demo`` command: :func:`run_demo`, then its :func:`summary`; with
    ``--fc``, the flight-controller loop (:mod:`gyrolab.app.fc_demo`)."""
    if opts.fc is not None:
        from gyrolab.app.fc_demo import fc_demo

        return fc_demo(opts)
    res = run_demo(opts.out, opts.profile, opts.seed, opts.force, catalogue=opts.catalogue)
    print(summary(Path(opts.out), res))
    return 0
