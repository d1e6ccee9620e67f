"""Extract the ADIS16405 static gyro records of the imudata R package into small numpy
files (what benchmarks/data/README.md describes).

    python benchmarks/data/extract_adis16405.py IMUDATA_CHECKOUT

``IMUDATA_CHECKOUT`` is a git checkout (or bare git directory) of the public repository
SMAC-Group/imudata; its ``data/adis_16405_imu{1..6}.rda`` are read at HEAD with the
``rdata`` package (``pip install rdata``). The records are 1 000 000 samples at 100 Hz
(2.78 h) of a static ADIS16405, gyro X, Y, Z in °/s on the sensor's 0.05 °/s lattice
(columns 1–3 of the R matrix), so every value is an integer code × 0.05 °/s:

* ``benchmarks/data/adis16405_static_10hz.npz`` — ``sums`` (records × 100 000 × 3,
  int16): sums of 10 consecutive codes, i.e. the 10 Hz means are ``sums × 0.005`` °/s.
  Record 4 is left out: a shock at t ≈ 4046 s (±17 °/s spikes on X and Y) is not noise.
* ``tests/data/adis16405_static_gyro_x.npz`` — ``codes`` (int8): the first 120 000
  samples (20 min) of record 1, gyro X, at 100 Hz.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
LSB = 0.05  # °/s, the ADIS16405's gyro output step at its ±300 °/s range
RECORDS = (1, 2, 3, 5, 6)


def read_record(checkout: Path, i: int) -> np.ndarray:
    """(1 000 000, 3) gyro codes of record ``i`` (int)."""
    import rdata

    blob = subprocess.run(
        ["git", "-C", str(checkout), "show", f"HEAD:data/adis_16405_imu{i}.rda"],
        check=True,
        capture_output=True,
    ).stdout
    with tempfile.NamedTemporaryFile(suffix=".rda") as f:
        f.write(blob)
        f.flush()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # R class "imu" has no Python constructor
            conv = rdata.conversion.convert(rdata.parser.parse_file(f.name))
    a = np.asarray(conv[f"adis_16405_imu{i}"].values, dtype=float)[:, :3]
    q = np.round(a / LSB)
    if np.max(np.abs(a / LSB - q)) > 1e-3:
        raise ValueError(f"record {i} is not on the {LSB} °/s lattice")
    return q.astype(np.int64)


def main(argv: list[str]) -> int:
    checkout = Path(argv[1])
    sums = []
    for i in RECORDS:
        q = read_record(checkout, i)
        sums.append(q.reshape(-1, 10, 3).sum(axis=1).astype(np.int16))
        if i == 1:
            np.savez_compressed(
                HERE.parents[1] / "tests" / "data" / "adis16405_static_gyro_x.npz",
                codes=q[:120_000, 0].astype(np.int8),
                lsb_deg_per_s=np.float64(LSB),
                rate_hz=np.float64(100.0),
            )
    np.savez_compressed(
        HERE / "adis16405_static_10hz.npz",
        sums=np.stack(sums),
        records=np.array(RECORDS),
        lsb_deg_per_s=np.float64(LSB / 10.0),
        rate_hz=np.float64(10.0),
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
