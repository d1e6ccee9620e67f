"""The flight-controller firmwares' own rules, written once for every layer that needs them.

PX4 and ArduPilot correct each IMU with a cubic in its own temperature; they differ in the
parameters, the reference temperature, when the correction is recomputed and in which frame
it is applied. These modules state those rules as the firmware sources do, so that the
simulated flight controller (``gyrolab.sim.bench``), the driver that talks to a real one
(``gyrolab.instruments``), the ``firmware_*`` scores (``gyrolab.compensation``), the
readers of users' logs (``gyrolab.logs``) and the exporters (``gyrolab.export``) share one
owner:

* :mod:`.px4` — ``TC_G*`` thermal compensation (``calc_thermal_offsets_3D``, the 1 Hz
  module and its 1 °C republish rule), ``CAL_GYRO*`` offsets, ``SENS_BOARD_ROT``;
* :mod:`.ardupilot` — ``INS_TCALn_*`` (35 °C reference, ×1e6 scale, ``CALTEMP``),
  ``INS_GYROFFS``, ``AHRS_ORIENTATION`` and the order ``_rotate_and_correct_gyro`` applies
  them in;
* :mod:`.rotation` — the rotation enum both firmwares number their board orientations by;
* :mod:`.mavlink` — which MAVLink message carries which IMU, its units and rate limits.

Sources are cited in each module and in docs/export.md / docs/instruments.md.
"""

# Gyro calibration slots of each firmware (the exporters' --instance range, checked by the
# command line before anything numerical is imported): PX4 TC_G0..3 (GYRO_COUNT_MAX,
# TemperatureCompensation.h), ArduPilot INS_TCAL1..3 (AP_InertialSensor.cpp)
GYRO_CAL_SLOTS = {"px4": 4, "ardupilot": 3}
