"""The autopilots' rotation enum (``enum Rotation``): board orientation → rotation matrix.

ArduPilot's ``AHRS_ORIENTATION`` and PX4's ``SENS_BOARD_ROT`` number the same list of
rotations (``libraries/AP_Math/rotations.h``; PX4 ``src/lib/conversion/rotation.h``, which
started as a copy of it): 0 = none, 8 = roll 180°, ... The matrices come from pymavlink's
``rotmat.rotations`` table ("the rotations used in APM", the one ArduPilot's own
``Tools/scripts/tempcal_IMU.py`` rotates log data with), so gyrolab holds no second copy of
the enum. ``v_body = R · v_sensor``; the inverse is ``R.T``.
"""

from __future__ import annotations

import numpy as np


def rotation_count() -> int:
    """How many enum values there are (0 … count − 1)."""
    from pymavlink.rotmat import rotations

    return len(rotations)


def rotation_name(rot_id: int) -> str:
    """``ROTATION_ROLL_180`` … for an enum value; ``ValueError`` outside the enum."""
    from pymavlink.rotmat import rotations

    if not 0 <= int(rot_id) < len(rotations):
        raise ValueError(f"rotation {rot_id} is not in the autopilot rotation enum")
    return str(rotations[int(rot_id)].name)


def rotation_matrix(rot_id: int) -> np.ndarray:
    """The 3×3 matrix of rotation ``rot_id`` (``v_rotated = R @ v``); ``ValueError``
    outside the enum (e.g. ArduPilot's ROTATION_CUSTOM, 100)."""
    from pymavlink.rotmat import rotations

    rotation_name(rot_id)  # checks the range
    r = rotations[int(rot_id)].r
    m = np.array(
        [[r.a.x, r.a.y, r.a.z], [r.b.x, r.b.y, r.b.z], [r.c.x, r.c.y, r.c.z]], dtype=np.float64
    )
    # the table's matrices come from Euler angles in degrees: snap the 1e-16 residue of
    # cos(90°) to the exact 0/±1 of the firmware's hand-written rotations
    m[np.abs(m) < 1e-12] = 0.0
    return m


def rotate(v: np.ndarray, rot_id: int, inverse: bool = False) -> np.ndarray:
    """Rows of ``v`` (``(n, 3)`` or ``(3,)``) rotated by ``rot_id`` (or by its inverse)."""
    m = rotation_matrix(rot_id)
    return np.asarray(v, dtype=np.float64) @ (m if inverse else m.T)
