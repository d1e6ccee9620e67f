"""Noise terms on real static gyro records: gyrolab's ARW and B against the −½-region
reading and against allantools (issue 23, point 4).

    python benchmarks/noise_terms_real.py IMUDATA_CHECKOUT

``IMUDATA_CHECKOUT``: a checkout (or bare git directory) of SMAC-Group/imudata
(benchmarks/data/README.md: source, licence). Its five undisturbed ADIS16405 records
(100 Hz, 2.78 h, gyro X, Y, Z: 15 axes) are read at full rate with
``extract_adis16405.read_record``.

Per axis:

* **the −½-region reading** (the reference, independent of gyrolab's rules): on the
  octave overlapping Allan curve (τ ≤ T/10), the longest run of consecutive τ whose every
  local log-log slope is within 0.1 of −½; the line of slope −½ through the run's points
  (mean of log σ√τ) read at τ = 1 s, × 60 (°/√h). Also σ(1 s)·60 and the same reading on
  allantools' ``oadev`` curve.
* gyrolab: ``filter_corner_tau`` (the sensor's filter corner), ``noise_terms`` (slope
  method, ``tau_min`` = corner, as kalibr's export reads it), the single-point rule above
  the corner (the plateau noise table's reading), ``method="fit"`` above the corner, and
  the old readings through the filtered τ (no ``tau_min``).
* B: the slope method's floor (or its upper bound when there is none), the fit's B
  against its own bound σ_min/0.664 (withheld above it).

Prints one markdown table and the summary line (worst |ARW ÷ reading − 1|).
"""

from __future__ import annotations

import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent / "data"))

from extract_adis16405 import LSB, RECORDS, read_record  # noqa: E402

from gyrolab.numerics.allan import allan_deviation  # noqa: E402
from gyrolab.numerics.noise_terms import (  # noqa: E402
    DOMINANCE_TOL,
    FLICKER_FLOOR,
    filter_corner_tau,
    noise_terms,
)

RATE_HZ = 100.0


def half_region_reading(taus: np.ndarray, dev: np.ndarray, record_s: float) -> tuple:
    """(reading °/√h, τ first, τ last) of the −½ region (module doc)."""
    use = (taus <= 0.1 * record_s) & (dev > 0)
    lt, la = np.log10(taus[use]), np.log10(dev[use])
    ok = np.abs(np.diff(la) / np.diff(lt) + 0.5) <= DOMINANCE_TOL
    best, i = (0, -1), 0
    while i < ok.size:
        if ok[i]:
            j = i
            while j + 1 < ok.size and ok[j + 1]:
                j += 1
            if j - i > best[1] - best[0]:
                best = (i, j)
            i = j + 1
        else:
            i += 1
    a, b = best[0], best[1] + 1  # points a..b
    c = float(np.mean(la[a : b + 1] + 0.5 * lt[a : b + 1]))
    return 60.0 * 10.0**c, float(10.0 ** lt[a]), float(10.0 ** lt[b])


def main(argv: list[str]) -> int:
    import allantools

    checkout = Path(argv[1])
    t0 = time.time()
    load0 = " ".join(f"{v:.1f}" for v in __import__("os").getloadavg())
    rows, dev_arw, dev_peer = [], [], []
    for rec in RECORDS:
        q = read_record(checkout, rec)
        for k, axis in enumerate("XYZ"):
            x = q[:, k] * LSB
            r = allan_deviation(x, RATE_HZ, taus="octave")
            ref, lo, hi = half_region_reading(r.taus, r.dev, r.duration_s)
            ta, da, _, _ = allantools.oadev(x, rate=RATE_HZ, data_type="freq", taus="octave")
            ref_peer = half_region_reading(np.asarray(ta), np.asarray(da), x.size / RATE_HZ)[0]
            s1 = 60.0 * math.exp(np.interp(0.0, np.log(r.taus), np.log(r.dev)))
            corner = filter_corner_tau(x, RATE_HZ)
            nt = noise_terms(r, tau_min=corner)
            single = noise_terms(r, slope_tol=None, terms=("N", "B"), tau_min=corner)
            metric = single.deg_h()["arw_deg_per_sqrt_h"]
            fit = noise_terms(r, method="fit", tau_min=corner)
            old = noise_terms(r).deg_h()["arw_deg_per_sqrt_h"]
            old_fit = noise_terms(r, method="fit").deg_h()["arw_deg_per_sqrt_h"]
            arw = nt.deg_h()["arw_deg_per_sqrt_h"]
            b_slope = nt.deg_h()["bias_instability_deg_per_h"]
            b_ub = 3600.0 * nt.upper_bounds.get("B", float("nan"))
            b_fit = fit.deg_h()["bias_instability_deg_per_h"]
            use = r.taus <= 0.1 * r.duration_s
            i_min = int(np.argmin(np.where(use, r.dev, np.inf)))
            b_bound = 3600.0 * float(r.dev[i_min]) / FLICKER_FLOOR
            b_limit = 3600.0 * float(r.dev_hi[i_min]) / FLICKER_FLOOR
            fit_arw = fit.deg_h()["arw_deg_per_sqrt_h"]
            dev_arw += [arw / ref - 1.0, metric / ref - 1.0, fit_arw / ref - 1.0]
            dev_peer.append(ref_peer / ref - 1.0)
            b_txt = f"{b_slope:.1f}" if b_slope is not None else f"≤ {b_ub:.1f}"
            bf_txt = "withheld" if b_fit is None else f"{b_fit:.1f}"
            rows.append(
                f"| {rec} {axis} | {lo:.2g}–{hi:.2g} | {ref:.3f} | {ref_peer:.3f} | {s1:.3f} "
                f"| {corner:.2f} | {arw:.3f} ({100 * (arw / ref - 1):+.1f} %) "
                f"| {metric:.3f} ({100 * (metric / ref - 1):+.1f} %) "
                f"| {fit_arw:.3f} ({100 * (fit_arw / ref - 1):+.1f} %) "
                f"| {old:.3f} ({100 * (old / ref - 1):+.1f} %) "
                f"| {old_fit:.3f} ({100 * (old_fit / ref - 1):+.1f} %) "
                f"| {b_txt} | {bf_txt} | {b_bound:.1f} ({b_limit:.1f}) |"
            )
    load1 = " ".join(f"{v:.1f}" for v in __import__("os").getloadavg())
    print(
        f"`python benchmarks/noise_terms_real.py IMUDATA` — "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.machine()}, "
        f"Python {platform.python_version()}, 5 records × 3 axes, 100 Hz, 2.78 h each; "
        f"wall clock {time.time() - t0:.0f} s, load average {load0} before, {load1} after."
    )
    print()
    print(
        "| record axis | −½ region τ s | −½ reading °/√h | allantools' | σ(1 s)·60 "
        "| corner s | ARW slope | ARW single-point | ARW fit | old slope (no corner) "
        "| old fit (no corner) | B slope °/h | B fit °/h | bound σ_min/0.664 (up to its CI) |"
    )
    print("| --- | --- |" + " ---: |" * 12)
    print("\n".join(rows))
    worst = max(abs(v) for v in dev_arw)
    print(
        f"\nWorst |ARW ÷ −½ reading − 1| over the three readings above the corner, 15 axes: "
        f"{100 * worst:.1f} %; allantools' curve gives the same reading within "
        f"{100 * max(abs(v) for v in dev_peer):.2g} %."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
