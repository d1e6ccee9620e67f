"""The ``mavlink`` driver against the simulated PX4 and ArduPilot controllers over a real
pty: every IMU recorded (three axes, its own temperature) in the sensor frame with the
compensation and offsets off, the user's parameters put back at the end — also after a
fault — and a refused write at set-up leaving the vehicle as it was; flashing as one
transaction, an injected PARAM_SET failure leaving the previous parameters, reported."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from gyrolab.app.acquire import connect_instruments, run_acquisition
from gyrolab.app.fc_bench import fc_bench_config, fc_serials, start_fc_bench, with_ports
from gyrolab.app.flash import flash_polys, flash_records, parameter_plan
from gyrolab.app.register import register_record
from gyrolab.catalogue import Catalogue
from gyrolab.compensation.firmware import Poly3
from gyrolab.errors import InputError
from gyrolab.instruments.mavlink_link import MavlinkLink
from gyrolab.profiles.profile import Profile, Step
from gyrolab.record.reader import list_units, read_metadata, read_recording
from gyrolab.sim.fc_imus import imu_axis_model

RATE = 10.0
SEED = 3


def _handle(fw: str, **kw):
    return start_fc_bench(fw, seed=SEED, speed=None, rate_hz=RATE, **kw)


def _bias_dps(imu: int, axis: int, temp_c: np.ndarray) -> np.ndarray:
    p = next(e for e in imu_axis_model(SEED, imu, axis).effects if e.name == "bias_poly").params
    d = np.asarray(temp_c) - p["t_ref_c"]
    return p["c0"] + d * (p["c1"] + d * (p["c2"] + d * (p["c3"] + d * p["c4"])))


@pytest.mark.parametrize("fw", ["px4", "ardupilot"])
def test_every_imu_recorded_in_the_sensor_frame_and_the_parameters_put_back(
    tmp_path: Path, fw: str
) -> None:
    h = _handle(fw)
    out = tmp_path / "run.mcap"
    # the bench's two wall floors (hold 5 s, loss 15 s) on the watchdog's one record
    assert (h.silence.min_wall_s, h.hold_silence.min_wall_s) == (15.0, 5.0)
    h.silence.heard("probe")
    assert not h.hold_silence.lost("probe", 1e9, 0.0)
    try:
        before = h.bench.device.values()
        cfg = with_ports(fc_bench_config(fw, rate_hz=RATE), h)
        prof = Profile("t", (Step(25.0, 60.0, label="power-on"), Step(40.0, 240.0)))
        res = run_acquisition(cfg=cfg, profile=prof, out=out, force=False, sim=h, seed=SEED)
        after = h.bench.device.values()
    finally:
        h.stop()
    assert res.outcome == "completed", res.reason
    assert after == before  # the user's parameters, every one
    serials = fc_serials(fw)
    assert list_units(out) == serials
    bench = read_metadata(out)["bench"]["units"]
    for k, s in enumerate(serials):
        rec = read_recording(out, unit=s)
        assert rec.rate.values.shape[1] == 3 and rec.temperature_source == "internal"
        assert rec.rate.t.size > 0.9 * 300 * RATE and not rec.rate.gaps()
        adc = bench[s]["adc"]
        assert adc["imu"] == k and adc["firmware"] == fw and adc["calibration_mode"] is True
        changed = adc["parameters_changed"]
        enable = "TC_G_ENABLE" if fw == "px4" else f"INS_TCAL{k + 1}_ENABLE"
        offsets = "CAL_GYRO0_XOFF" if fw == "px4" else "INS_GYROFFS_X"
        assert changed[offsets] == [pytest.approx(before[offsets]), 0.0]
        assert enable in changed
        if fw == "ardupilot":  # the board was mounted upside down: roll 180° taken off
            assert changed["AHRS_ORIENTATION"] == [8.0, 0.0]
        # the sensor's own rate: its bias at its temperature, no offset, no rotation
        # (the user's offsets are 0.2-0.7 °/s; a rotation would flip y and z's sign)
        temp = np.interp(rec.rate.t, rec.pt100_t, rec.pt100_c)
        for a in range(3):
            want = _bias_dps(k, a, temp - h.bench.device.imus[k][0].die_sensor_offset_c)
            assert abs(np.mean(rec.rate.values[:, a] - want)) < 0.06, (s, a)


def test_a_reader_starved_for_less_than_the_hold_floor_loses_no_sample() -> None:
    """Free-running, the controller's stream waits for its reader (back-pressure) as long as
    the run calls a silence a hiccup (the 5 s hold floor): the driver's threads starved for
    a second while the bench's tick thread runs on — a loaded machine — lose no sample.
    (With the 50 ms wait of the connect speed kept for the run, 0.1 s lost a tick.)"""
    h = _handle("px4")
    try:
        link = MavlinkLink(h.addresses["unit/PX4-IMU1"], timeout_s=h.timeout(1.0))
        link.connect(10.0)
        link.set_imu_rate(0, RATE)
        h.go()  # free-running, as a run is once connected

        def drain(wall_s: float) -> None:
            end = time.monotonic() + wall_s
            while time.monotonic() < end:
                link.pump(0.01)

        drain(0.3)
        t_stall = h.bench.clock.now()
        time.sleep(1.0)  # nobody reads: the port fills and the controller waits
        assert h.bench.clock.now() - t_stall < 100.0  # held back, not running free
        drain(0.3)
        link.close()
        idx = np.rint(np.array([s.t for s in link.imu[0]]) * RATE)
        assert idx.size > 200 and np.all(np.diff(idx) == 1)
        assert h.bench.device.stats.write_overruns == 0
    finally:
        h.stop()


def test_a_refused_write_at_set_up_leaves_the_vehicle_as_it_was() -> None:
    h = _handle("px4", fail_param_sets={"CAL_GYRO1_YOFF"})
    try:
        before = h.bench.device.values()
        cfg = with_ports(fc_bench_config("px4", rate_hz=RATE), h)
        with pytest.raises(InputError, match=r"CAL_GYRO1_YOFF.*previous values put back"):
            connect_instruments(cfg, h.addresses, timeout=h.timeout)
        assert h.bench.device.values() == before
    finally:
        h.stop()


def test_a_fault_mid_run_still_puts_the_parameters_back() -> None:
    """What the run engine does on any exception (a fault, Ctrl-C): it closes the
    instruments; the last IMU to close restores the vehicle."""
    h = _handle("ardupilot")
    try:
        before = h.bench.device.values()
        cfg = with_ports(fc_bench_config("ardupilot", rate_hz=RATE), h)
        inst = connect_instruments(cfg, h.addresses, timeout=h.timeout)
        try:
            assert h.bench.device.values()["AHRS_ORIENTATION"] == 0.0  # set up for the run
            _serial, stream = inst.units[1]
            for _ in range(20):
                stream.read(0.05)
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            pass
        finally:
            inst.close()
        assert h.bench.device.values() == before
    finally:
        h.stop()


def test_px4_with_compensation_on_is_rebooted_for_the_calibration() -> None:
    """PX4 keeps published thermal offsets until a reboot (TC_G_ENABLE is
    @reboot_required): a vehicle with TC on is rebooted after TC_G_ENABLE = 0, and again
    once the user's values are back."""
    h = _handle("px4")
    try:
        link = MavlinkLink(h.addresses["unit/PX4-IMU1"], timeout_s=h.timeout(1.0))
        link.connect(10.0)
        assert link.param_set("TC_G_ENABLE", 1, 6) == 1.0
        link.close()
        cfg = with_ports(fc_bench_config("px4", rate_hz=RATE), h)
        inst = connect_instruments(cfg, h.addresses, timeout=h.timeout)
        assert h.bench.device.stats.reboots == 1
        assert h.bench.device.values()["TC_G_ENABLE"] == 0.0
        inst.close()
        assert h.bench.device.values()["TC_G_ENABLE"] == 1.0
        assert h.bench.device.stats.reboots == 2  # the user's compensation in use again
    finally:
        h.stop()


def _polys() -> dict[int, list[Poly3]]:
    return {
        k: [
            Poly3((0.01 * (k + 1) + a * 1e-3, 2e-3, -3e-5, 4e-7), 30.0, 5.0, 60.0) for a in range(3)
        ]
        for k in range(3)
    }


def test_flash_order_keeps_a_partial_set_out_of_use() -> None:
    for fw, enables in (
        ("px4", ["TC_G_ENABLE"]),
        ("ardupilot", [f"INS_TCAL{n}_ENABLE" for n in (1, 2, 3)]),
    ):
        plan = parameter_plan(fw, _polys(), {0: 11, 1: 12, 2: 13})
        names = [n for n, _v, _t in plan]
        assert names[: len(enables)] == enables and names[-len(enables) :] == enables
        assert [v for _n, v, _t in plan[: len(enables)]] == [0.0] * len(enables)
        assert [v for _n, v, _t in plan[-len(enables) :]] == [1.0] * len(enables)


@pytest.mark.parametrize("fw", ["px4", "ardupilot"])
def test_flash_writes_reads_back_and_an_injected_failure_restores(fw: str, tmp_path) -> None:
    bad = "TC_G1_X2_1" if fw == "px4" else "INS_TCAL2_GYR2_Y"
    h = _handle(fw, fail_param_sets={bad})
    try:
        before = h.bench.device.values()
        link = MavlinkLink(h.addresses[f"unit/{fc_serials(fw)[0]}"], timeout_s=h.timeout(1.0))
        link.connect(10.0)
        res = flash_polys(link, _polys())
        assert not res.ok and res.report.failed[0] == bad
        assert not res.report.restore_failed
        assert h.bench.device.values() == before  # the previous calibration, untouched
        assert "the previous calibration is in place" in res.summary()
        assert res.to_dict()["failed"]["name"] == bad
        failed = flash_records(res, {1: "IMU2"})[1]
        h.bench.device.fail_param_sets.clear()
        res = flash_polys(link, _polys())
        link.close()
        assert res.ok and len(res.report.written) == len(set(n for n, _v, _t in res.plan))
        now = h.bench.device.values()
        for name, value in res.report.written.items():
            assert now[name] == pytest.approx(value, rel=1e-6, abs=1e-9), name
        # the catalogue's record of each (docs/catalogue.md): reported, registered, traced
        written = flash_records(res, {1: "IMU2"})[1]
        assert (failed["result"], written["result"]) == ("restored", "written")
        assert set(written["detail"]["parameters"]) <= set(res.report.written)
        url = f"sqlite:///{tmp_path / 'cat.sqlite'}"
        for k, rec in enumerate((failed, written)):
            (tmp_path / f"f{k}.json").write_text(json.dumps(rec))
            assert register_record(tmp_path / f"f{k}.json", url)
        with Catalogue.open(url) as cat:
            flashes = cat.unit("IMU2")["flashes"]
        assert sorted(f["result"] for f in flashes) == ["restored", "written"]
    finally:
        h.stop()
