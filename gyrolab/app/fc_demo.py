"""``gyrolab demo --fc px4|ardupilot``: a flight controller through the whole loop.

On one simulated bench (the F4 chamber and a simulated PX4 or ArduPilot controller with
three IMUs, :mod:`gyrolab.app.fc_bench`) that keeps running — so the controller keeps its
parameters from one step to the next, as a vehicle on a bench does:

1. **calibration run** — the ``mavlink`` driver in calibration mode (thermal compensation,
   gyro offsets and board rotation off for the run, the user's values put back after):
   ``calibration.mcap``, one unit per IMU, three axes each, the IMU's own temperature;
2. **compensate** — one model per IMU (``model/<serial>/axis_{x,y,z}``), fitted with the
   demo's reduced search (:data:`FC_DEMO_CONFIG`);
3. **export** — each IMU's firmware file (``export/imu<k>.params`` for PX4 with the IMU's
   device id, ``export/imu<k>.parm`` for ArduPilot), what a user would load by hand;
4. **flash** — the same parameters written into the controller over MAVLink as one
   transaction, each read back (:func:`gyrolab.app.flash.flash_models`): ``flash.json``,
   and per IMU the catalogue's flash record ``flash/<serial>.json``;
5. **verification run** — a held-out profile with the firmware's compensation ON
   (``verification.mcap``), and per IMU and axis the device's drift p-p of 100 s averages
   beside what gyrolab predicted for that run (:mod:`gyrolab.compensation.verification`):
   ``verification.json``, ``verification.md``, and per IMU the catalogue's verification
   record ``verification/<serial>.json`` (PASS: every axis within 10 %).

``DIR`` is then registered in the catalogue as ``gyrolab demo`` registers its directory
(``DIR/catalogue.sqlite`` unless ``--catalogue`` or ``$GYROLAB_CATALOGUE`` says another):
units, runs, models, exports, flashes, verifications — ``gyrolab runs trace PX4-IMU1``.

``DIR`` appears atomically; a failed step fails the demo with one line, exit 2, nothing
left.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

from gyrolab.acquisition import interrupts
from gyrolab.app.options import DemoOptions
from gyrolab.compensation.config import PipelineConfig
from gyrolab.errors import GyrolabError
from gyrolab.outputs import atomic_dir, check_output
from gyrolab.profiles.profile import Profile, Step
from gyrolab.progress import progress

# The demo's fit: the same pipeline with a reduced parameter search (the FC loop, not the
# paper's VMD search, is what this demo shows); the chosen model is the causal one.
FC_DEMO_CONFIG = PipelineConfig(
    vmd_K=5,
    vmd_alpha=2000.0,
    ga_population=12,
    ga_generations=6,
    bp_max_iter=150,
    hidden=6,
    gpso_population=4,
    gpso_generations=1,
    causal_families=("poly", "structured"),
)
CALIBRATION_PROFILE = Profile(
    name="fc-calibration",
    description="flight-controller calibration: 25 -> -10 -> 55 -> 25 degC",
    steps=(
        Step(25.0, 600.0, label="power-on"),
        Step(-10.0, 2400.0),
        Step(55.0, 3600.0),
        Step(25.0, 1200.0),
    ),
)
VERIFICATION_PROFILE = Profile(
    name="fc-verification",
    description="held-out verification: 25 -> 50 -> -5 -> 30 degC",
    steps=(
        Step(25.0, 300.0, label="power-on"),
        Step(50.0, 2100.0),
        Step(-5.0, 2700.0),
        Step(30.0, 1500.0),
    ),
)
TOLERANCE = 0.10  # the acceptance: device p-p within 10 % of the prediction


def _acquire(handle: Any, cfg: Any, profile: Profile, out: Path, seed: int) -> None:
    from gyrolab.app.acquire import run_acquisition
    from gyrolab.app.fc_bench import with_ports

    result = run_acquisition(
        cfg=with_ports(cfg, handle), profile=profile, out=out, force=False, sim=handle, seed=seed
    )
    if result.outcome == "interrupted":
        raise KeyboardInterrupt
    if result.exit_code != 0:
        raise GyrolabError(f"demo --fc: {out.name} ended {result.outcome} ({result.reason})")


def _compensate(run: Path, serial: str, out: Path, seed: int, label: str) -> None:
    from gyrolab.compensation import commands

    print(
        commands.compensate(
            run, out, seed=seed, unit=serial, run_label=label, base_config=FC_DEMO_CONFIG
        )
    )


def _export(model: Path, firmware: str, imu: int, device_id: int, out: Path) -> None:
    """As ``gyrolab export`` writes it (its provenance line names the model by hash)."""
    from gyrolab.export.commands import export

    export(model, firmware, out, instance=imu, device_id=device_id if firmware == "px4" else None)


def _write_records(d: Path, records: dict[str, dict[str, Any]]) -> dict[str, Path]:
    """Catalogue records (serial → record) as ``d/<serial>.json``."""
    d.mkdir()
    paths = {}
    for serial, rec in records.items():
        paths[serial] = d / f"{serial}.json"
        paths[serial].write_text(json.dumps(rec, indent=2) + "\n")
    return paths


def verification_records(
    result: dict[str, Any], flash_paths: dict[str, Path], run: Path
) -> dict[str, dict[str, Any]]:
    """One catalogue verification record per IMU (``"format": "gyrolab.verification"``,
    docs/catalogue.md): PASS when every axis's device drift p-p is within the tolerance of
    the prediction."""
    import datetime as dt

    from gyrolab.app.index_files import VERIFICATION_FORMAT
    from gyrolab.catalogue.digest import file_digest

    when = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")
    run_hash = file_digest(run)
    out = {}
    for serial, imu in result["imus"].items():
        ok = all(abs(a["ratio"] - 1.0) <= result["tolerance"] for a in imu["axes"].values())
        out[serial] = {
            "format": VERIFICATION_FORMAT,
            "unit": serial,
            "time": when,
            "verdict": "PASS" if ok else "FAIL",
            "flash_record_sha256": file_digest(flash_paths[serial]),
            "run_sha256": run_hash,
            "detail": {"firmware": result["firmware"], "tolerance": result["tolerance"], **imu},
        }
    return out


@interrupts.deferring_stop_signals
def run_fc_demo(
    out: str | Path,
    firmware: str,
    seed: int = 1,
    force: bool = False,
    catalogue: str | None = None,
) -> dict[str, Any]:
    """The whole loop into ``out`` (module doc); returns verification.json's content (and
    ``catalogue``: where ``out`` was registered, as :func:`gyrolab.app.demo.run_demo`
    registers, or None). Ctrl-C (SIGTERM, SIGHUP) ends it as it ends ``acquire``: the run
    in progress stops, the controller's parameters are put back, nothing is left."""
    from gyrolab.app.register import demo_catalogue, register_tree

    old = sys.getswitchinterval()
    # the simulated instruments share this process (and its GIL) with the drivers: hand
    # the GIL over sooner, as gyrolab acquire --bench sim does
    sys.setswitchinterval(0.0005)
    try:
        res = _run_fc_demo(out, firmware, seed, force)
    finally:
        sys.setswitchinterval(old)
    url = demo_catalogue(Path(out), catalogue)
    res["catalogue"] = url if url is not None and register_tree(Path(out), url) else None
    return res


def _run_fc_demo(out: str | Path, firmware: str, seed: int, force: bool) -> dict[str, Any]:
    from gyrolab.acquisition.simdir import sim_workdir
    from gyrolab.app.fc_bench import fc_bench_config, fc_serials, start_fc_bench
    from gyrolab.app.flash import compensation_parameters, flash_models, flash_records
    from gyrolab.instruments.mavlink_link import MavlinkLink
    from gyrolab.record.reader import read_metadata

    if firmware not in ("px4", "ardupilot"):
        raise GyrolabError(f"demo --fc: px4 or ardupilot, not {firmware!r}")
    out_p = Path(out)
    check_output(out_p, force, kind="dir")
    serials = fc_serials(firmware)
    timings: dict[str, float] = {}
    bar = progress(total=5, desc=f"demo --fc {firmware}", unit="stage")
    t_all = time.perf_counter()

    def stage(name: str, t0: float) -> float:
        timings[name] = time.perf_counter() - t0
        bar.update(1)
        return time.perf_counter()

    try:
        with atomic_dir(out_p, force, command="demo") as tmp, sim_workdir() as work:
            handle = start_fc_bench(firmware, seed=seed, speed=None, workdir=Path(work))
            try:
                t0 = time.perf_counter()
                cal = tmp / "calibration.mcap"
                _acquire(handle, fc_bench_config(firmware), CALIBRATION_PROFILE, cal, seed)
                t0 = stage("calibration run", t0)
                bench = read_metadata(cal)["bench"]["units"]
                device_ids = {
                    k: int(bench[s]["adc"].get("device_id", 0)) for k, s in enumerate(serials)
                }
                models = {k: tmp / "model" / s for k, s in enumerate(serials)}
                (tmp / "model").mkdir()
                for k, s in enumerate(serials):
                    _compensate(cal, s, models[k], seed, "calibration.mcap")
                t0 = stage("compensate", t0)
                (tmp / "export").mkdir()
                ext = "params" if firmware == "px4" else "parm"
                for k in models:
                    _export(models[k], firmware, k, device_ids[k], tmp / "export" / f"imu{k}.{ext}")
                link = MavlinkLink(
                    handle.addresses[f"unit/{serials[0]}"], timeout_s=handle.timeout(1.0)
                )
                try:
                    link.connect(10.0)
                    flashed = flash_models(link, models, device_ids if firmware == "px4" else None)
                finally:
                    link.close()
                (tmp / "flash.json").write_text(json.dumps(flashed.to_dict(), indent=2) + "\n")
                records = flash_records(
                    flashed,
                    dict(enumerate(serials)),
                    {k: tmp / "export" / f"imu{k}.{ext}" for k in models},
                )
                flash_paths = _write_records(
                    tmp / "flash", {serials[k]: r for k, r in records.items()}
                )
                if not flashed.ok:
                    raise GyrolabError(f"demo --fc: {flashed.summary()}")
                t0 = stage("export and flash", t0)
                ver = tmp / "verification.mcap"
                cfg = fc_bench_config(firmware, calibration=False)
                _acquire(handle, cfg, VERIFICATION_PROFILE, ver, seed + 1)
                link = MavlinkLink(
                    handle.addresses[f"unit/{serials[0]}"], timeout_s=handle.timeout(1.0)
                )
                try:
                    link.connect(10.0)
                    params = compensation_parameters(link, list(models))
                finally:
                    link.close()
                t0 = stage("verification run", t0)
                result = verify(tmp, firmware, models, device_ids, params, seed)
                stage("verify", t0)
                timings["total"] = time.perf_counter() - t_all
                result["timing_s"] = timings
                (tmp / "verification.json").write_text(json.dumps(result, indent=2) + "\n")
                (tmp / "verification.md").write_text(verification_table(result))
                _write_records(
                    tmp / "verification", verification_records(result, flash_paths, ver)
                )
            finally:
                handle.stop()
    finally:
        bar.close()
    return result


def verify(
    d: Path,
    firmware: str,
    models: dict[int, Path],
    device_ids: dict[int, int],
    params: dict[str, float],
    seed: int,
) -> dict[str, Any]:
    """verification.json's content from ``d/calibration.mcap``, ``d/verification.mcap``,
    the models (IMU → model directory) and the parameters read back from the vehicle."""
    from gyrolab.compensation.model_dir import ModelDir
    from gyrolab.compensation.verification import mean_noise_dps, noise_lsb, verify_imu
    from gyrolab.record.reader import read_recording

    serials = {k: m.name for k, m in models.items()}
    result: dict[str, Any] = {
        "firmware": firmware,
        "seed": seed,
        "calibration_profile": CALIBRATION_PROFILE.to_dict(),
        "verification_profile": VERIFICATION_PROFILE.to_dict(),
        "window_s": 100.0,
        "tolerance": TOLERANCE,
        "parameters_on_vehicle": params,
        "imus": {},
    }
    recs = {k: read_recording(d / "verification.mcap", unit=s) for k, s in serials.items()}
    controller = [(device_ids.get(k, 0), r.pt100_t, r.pt100_c) for k, r in recs.items()]
    worst = 0.0
    for k, s in serials.items():
        cal = read_recording(d / "calibration.mcap", unit=s)
        sigma = [noise_lsb(cal.adc.values[:, a]) for a in range(3)]
        fitted = [p.load() for _n, p in ModelDir(models[k]).axes()]
        axes = verify_imu(
            fitted, firmware, params, k, recs[k], sigma, device_ids.get(k, 0), seed,
            mean_noise=mean_noise_dps(fitted, cal), controller=controller,
        )  # fmt: skip
        worst = max([worst, *(abs(a["ratio"] - 1.0) for a in axes.values())])
        result["imus"][s] = {"imu": k, "device_id": device_ids.get(k, 0), "axes": axes}
    result["max_relative_difference"] = worst
    result["within_tolerance"] = bool(worst <= TOLERANCE)
    return result


def verification_table(res: dict[str, Any]) -> str:
    """verification.md: the device's drift p-p beside the prediction, per IMU and axis."""
    lines = [
        f"# On-device verification ({res['firmware']})",
        "",
        "Drift peak-to-peak of 100 s averages on the held-out verification run, with the "
        "firmware's compensation on (the flashed parameters): what the device reported "
        "beside what gyrolab predicted for that run (its model of the IMU, the firmware's "
        "rules on the parameters read back from the vehicle, the MAVLink encoding; "
        "docs/instruments.md).",
        "",
        "| IMU | axis | predicted °/s | device °/s | device / predicted |",
        "| --- | --- | ---: | ---: | ---: |",
    ]
    for serial, imu in res["imus"].items():
        for axis, a in imu["axes"].items():
            lines.append(
                f"| {serial} | {axis} | {a['predicted_drift_pp_100s_deg_per_s']:.5f} | "
                f"{a['device_drift_pp_100s_deg_per_s']:.5f} | {a['ratio']:.3f} |"
            )
    verdict = "within" if res["within_tolerance"] else "NOT within"
    lines += [
        "",
        f"Largest difference {100 * res['max_relative_difference']:.1f} % — {verdict} "
        f"{100 * res['tolerance']:.0f} %.",
    ]
    return "\n".join(lines) + "\n"


def fc_summary(out: Path, res: dict[str, Any]) -> str:
    """The demo's closing lines on stdout."""
    t = res.get("timing_s", {}).get("total", float("nan"))
    verdict = "within" if res["within_tolerance"] else "NOT within"
    line = (
        f"demo --fc {res['firmware']} finished in {t:.0f} s: on-device drift p-p (100 s) "
        f"{verdict} {100 * res['tolerance']:.0f} % of the prediction for every IMU and axis "
        f"(largest difference {100 * res['max_relative_difference']:.1f} %); "
        f"{out / 'verification.md'}"
    )
    if res.get("catalogue"):
        from gyrolab.catalogue.store import shown

        where = shown(res["catalogue"])
        first = next(iter(res["imus"]), "")
        line += f"\ncatalogue: {where} (gyrolab runs trace {first} --catalogue {where})"
    return line


def fc_demo(opts: DemoOptions) -> int:
    """``gyrolab demo --fc px4|ardupilot --out DIR``: :func:`run_fc_demo`, the verification
    table and the closing line."""
    assert opts.fc is not None
    res = run_fc_demo(
        opts.out, opts.fc, seed=opts.seed, force=opts.force, catalogue=opts.catalogue
    )
    print(verification_table(res), end="")
    print(fc_summary(Path(opts.out), res))
    return 0
