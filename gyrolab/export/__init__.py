"""``gyrolab export``: a fitted model in the forms firmware and other tools load
(PX4 ``.params``, ArduPilot ``.parm``, C99, versioned JSON, kalibr ``imu.yaml``);
docs/export.md is the user's page."""
