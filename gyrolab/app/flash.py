"""Flash fitted models into a flight controller: one transaction, read back, never half done.

:func:`flash_models` is the call (the catalogue registers its :class:`FlashResult`):
the firmware cubic of each IMU's model directory (its ``axis_x``/``axis_y``/``axis_z``
``firmware.json``) becomes that firmware's parameter set
(:func:`gyrolab.compensation.firmware.px4_parameter_set` /
:func:`~gyrolab.compensation.firmware.ardupilot_parameter_set`: the same values
``gyrolab export`` writes to a file), and all IMUs' sets are written as one transaction
(:func:`gyrolab.instruments.mavlink_link.write_parameters`): every previous value read
first, each PARAM_SET read back (the PARAM_VALUE that answers it must hold the value), and
on any failure every value already written put back and read back, so that the vehicle
keeps its previous calibration. The order keeps a partly written set from ever being in
use: the enable parameters are written 0 first, the coefficients next, the enables last.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gyrolab.instruments.mavlink_link import MavlinkLink, WriteReport, write_parameters


@dataclass
class FlashResult:
    """What was flashed where: ``firmware``, ``port``, the IMUs (instance → model
    directory), the planned writes in order, and the transaction's report."""

    firmware: str
    port: str
    models: dict[int, str]
    plan: list[tuple[str, float, int]]
    report: WriteReport
    device_ids: dict[int, int] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.report.ok

    def summary(self) -> str:
        r = self.report
        if r.ok:
            return f"flashed {len(r.written)} parameters into {self.firmware} at {self.port}"
        name, why = r.failed or ("?", "?")
        kept = "the previous calibration is in place" if not r.restore_failed else (
            "NOT restored: " + ", ".join(r.restore_failed)
        )  # fmt: skip
        return f"flash failed at {name} ({why}); {len(r.restored)} value(s) put back: {kept}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "firmware": self.firmware,
            "port": self.port,
            "models": {str(k): v for k, v in self.models.items()},
            "device_ids": {str(k): v for k, v in self.device_ids.items()},
            "plan": [{"name": n, "value": v, "type": t} for n, v, t in self.plan],
            **self.report.to_dict(),
            "summary": self.summary(),
        }


def parameter_plan(
    firmware: str, polys: dict[int, list[Any]], device_ids: dict[int, int]
) -> list[tuple[str, float, int]]:
    """The writes of a flash, in order (module doc): ``(name, value, MAV_PARAM_TYPE)``."""
    from gyrolab.compensation.firmware import ardupilot_parameter_set, px4_parameter_set

    enables: list[tuple[str, float, int]] = []
    body: list[tuple[str, float, int]] = []
    for imu in sorted(polys):
        if firmware == "px4":
            vals = px4_parameter_set(polys[imu], imu, device_ids.get(imu, 0))
        else:
            vals = ardupilot_parameter_set(polys[imu], imu)
        for name, (value, ptype) in vals.items():
            if name.endswith("_ENABLE"):
                if name not in {n for n, _v, _t in enables}:
                    enables.append((name, value, ptype))
            else:
                body.append((name, value, ptype))
    off = [(n, 0.0, t) for n, _v, t in enables]
    return off + body + enables


def flash_models(
    link: MavlinkLink, models: dict[int, str | Path], device_ids: dict[int, int] | None = None
) -> FlashResult:
    """Flash each IMU's model (IMU instance → model directory of that unit) into the
    controller on ``link`` (connected: its firmware known). PX4 needs each IMU's device id
    (``TC_Gi_ID``; default: read from ``CAL_GYROi_ID``)."""
    from gyrolab.compensation.model_dir import ModelDir

    polys = {
        imu: [d.require_firmware() for _n, d in ModelDir(m).axes()] for imu, m in models.items()
    }
    res = flash_polys(link, polys, device_ids)
    res.models = {k: str(v) for k, v in models.items()}
    return res


def flash_polys(
    link: MavlinkLink, polys: dict[int, list[Any]], device_ids: dict[int, int] | None = None
) -> FlashResult:
    """:func:`flash_models` for firmware cubics already loaded (IMU → its axes' Poly3)."""
    from gyrolab.autopilot import px4

    fw = link.firmware
    ids = dict(device_ids or {})
    if fw == "px4":
        for imu in polys:
            if imu not in ids:
                ids[imu] = int(link.param_read(px4.cal_id_name(imu))[0])
    plan = parameter_plan(fw, polys, ids)
    report = write_parameters(link, plan)
    return FlashResult(fw, link.address, {}, plan, report, ids)


def compensation_parameters(link: MavlinkLink, imus: list[int]) -> dict[str, float]:
    """The parameters the firmware corrects the IMUs with, read from the vehicle now (what
    :mod:`gyrolab.compensation.verification` runs the firmware's rules on)."""
    from gyrolab.autopilot import ardupilot as ap
    from gyrolab.autopilot import px4

    names: list[str] = []
    if link.firmware == "px4":
        names += ["TC_G_ENABLE", px4.BOARD_ROTATION]
        for s in range(px4.TC_SLOTS):
            names += px4.tc_names(s)[1:] + [px4.cal_id_name(s), *px4.cal_offset_names(s)]
    else:
        names.append(ap.BOARD_ORIENTATION)
        for k in imus:
            names += ap.tcal_names(k) + ap.gyro_offset_names(k) + [ap.caltemp_name(k)]
    out = {}
    for n in dict.fromkeys(names):
        out[n] = link.param_read(n)[0]
    return out


def imu_parameter_names(firmware: str, imu: int) -> set[str]:
    """The parameters of a flash that belong to IMU ``imu`` (PX4's ``TC_G_ENABLE`` is every
    IMU's)."""
    from gyrolab.autopilot import ardupilot as ap
    from gyrolab.autopilot import px4

    if firmware == "px4":
        return set(px4.tc_names(imu))
    return {*ap.tcal_names(imu), *ap.gyro_offset_names(imu), ap.caltemp_name(imu)}


def flash_records(
    result: FlashResult,
    serials: dict[int, str],
    params_files: dict[int, str | Path] | None = None,
    when: str | None = None,
) -> dict[int, dict[str, Any]]:
    """One catalogue record per IMU of ``result`` (``"format": "gyrolab.flash"``, the keys of
    docs/catalogue.md): its unit (``serials``: IMU → serial), the device, what was written
    (``params_sha256``: the export file of the same parameter set where one was written,
    ``params_files``; else the hash of the values), the model's hash, and ``result``:
    ``written``, ``restored`` (a failed flash whose previous values were put back) or
    ``failed`` (not all put back). Write each to a file and register it
    (``gyrolab.app.register.register_record``)."""
    import datetime as dt
    import hashlib
    import json

    from gyrolab.app.index_files import FLASH_FORMAT
    from gyrolab.catalogue.digest import PREFIX, file_digest
    from gyrolab.compensation.model_dir import ModelDir

    rep = result.report
    outcome = "written" if rep.ok else ("failed" if rep.restore_failed else "restored")
    when = when or dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")
    out = {}
    for imu, serial in serials.items():
        names = imu_parameter_names(result.firmware, imu)
        values = {n: v for n, v, _t in result.plan if n in names}
        pf = (params_files or {}).get(imu)
        if pf is not None:
            params_hash = file_digest(pf)
        else:
            blob = json.dumps(values, sort_keys=True).encode()
            params_hash = PREFIX + hashlib.sha256(blob).hexdigest()
        model = result.models.get(imu)
        device = f"{result.firmware} flight controller at {result.port}, IMU {imu}"
        if result.device_ids.get(imu):
            device += f" (device id {result.device_ids[imu]})"
        out[imu] = {
            "format": FLASH_FORMAT,
            "unit": serial,
            "time": when,
            "device": device,
            "params_sha256": params_hash,
            "model_sha256": ModelDir(model).digest() if model else None,
            "result": outcome,
            "detail": {
                "firmware": result.firmware,
                "imu": imu,
                "parameters": values,
                "written": {n: v for n, v in rep.written.items() if n in names},
                "failed": list(rep.failed) if rep.failed else None,
                "restored": {n: v for n, v in rep.restored.items() if n in names},
                "summary": result.summary(),
            },
        }
    return out
