"""Regenerate docs/results.md: the paper's method and the baselines on simulated paper runs.

    python benchmarks/results_paper.py [--work DIR] [--out docs/results.md]

1. ``gyrolab simulate --profile paper`` with seeds 1 and 2, and the reversed (heating)
   paper profile with seed 3 (skipped when the files are already in ``--work``);
2. ``gyrolab compensate paper-s1.mcap --out MODEL --validate paper-s2.mcap``, timed
   wall-clock in a subprocess (the "≤ 90 s" acceptance figure);
3. the fitted model is applied to the heating run (never refitted);
4. the tables and the verdicts below them are written from those numbers.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from docsections import write_section  # noqa: E402

ROWS = [
    ("raw", "raw output"),
    ("oracle", "oracle: the run minus its true simulated deterministic drift (the floor)"),
    ("causal", "**causal headline** (selected causal model, full bandwidth)"),
    ("compensated", "**paper method** (GPSO-VMD, MPE, noise removed, FLP, GA-BP), offline"),
    ("compensated_drift_only", "GA-BP drift model only (no noise removal), causal"),
    ("compensated_streaming_flp", "GA-BP drift model + causal FLP on the 3.6 s stream"),
    ("baselines.poly", "baseline: polynomial in T (order by blocked CV), causal"),
    ("baselines.bp", "baseline: plain BP (random init), causal"),
    ("nr.poly", "paper's noise removal + polynomial drift model, offline"),
    ("nr.bp", "paper's noise removal + plain-BP drift model, offline"),
]


def _get(m: dict[str, Any], key: str) -> dict[str, float]:
    if key.startswith("baselines."):
        return m["baselines"][key.split(".", 1)[1]]
    if key.startswith("nr."):
        return m["baselines_with_noise_removal"][key.split(".", 1)[1]]
    return m[key]


def _pct(raw: float, x: float) -> str:
    return f"{100.0 * (1.0 - x / raw):.1f} %"


def table(m: dict[str, Any]) -> str:
    raw = m["raw"]
    out = [
        "| output | ARW °/√h | bias instability °/h (Allan) | bias stability °/h "
        "(std, 3.6 s) | cut | drift p-p °/s | cut |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    pp100 = m.get("drift_pp_100s_deg_per_s", {})
    out[0] += " drift p-p 100 s °/s | cut |"
    out[1] += " ---: | ---: |"
    for key, label in ROWS:
        if key not in m and "." not in key:
            continue
        r = _get(m, key)
        if key == "causal":
            label = label.replace("selected causal model", f"{m['causal_model']['family']}")
        p100 = pp100.get({"nr.poly": "", "nr.bp": ""}.get(key, key))
        out.append(
            f"| {label} | {r['arw_deg_per_sqrt_h']:.4g} | {r['bias_instability_deg_per_h']:.3g} "
            f"| {r['bias_stability_deg_per_h']:.3g} | "
            f"{'—' if key == 'raw' else _pct(raw['bias_stability_deg_per_h'], r['bias_stability_deg_per_h'])} "  # noqa: E501
            f"| {r['drift_pp_deg_per_s']:.3g} | "
            f"{'—' if key == 'raw' else _pct(raw['drift_pp_deg_per_s'], r['drift_pp_deg_per_s'])} |"
            + (
                " — | — |"
                if p100 is None
                else f" {p100:.3g} | {'—' if key == 'raw' else _pct(pp100['raw'], p100)} |"
            )
        )
    return "\n".join(out)


def verdicts(m: dict[str, Any]) -> list[str]:
    raw, c = m["raw"], m["compensated"]
    lines = []
    cut_pp = 1 - c["drift_pp_deg_per_s"] / raw["drift_pp_deg_per_s"]
    cut_bs = 1 - c["bias_stability_deg_per_h"] / raw["bias_stability_deg_per_h"]
    ok = cut_pp >= 0.9 and cut_bs >= 0.9
    lines.append(
        f"- Acceptance (held out, paper method): drift p-p cut {100 * cut_pp:.1f} %, bias "
        f"stability cut {100 * cut_bs:.1f} % (both must be ≥ 90 %): "
        f"**{'pass' if ok else 'FAIL'}**."
    )
    if "causal" in m:
        cz, pp = m["causal"], m["drift_pp_100s_deg_per_s"]
        c_pp = 1 - pp["causal"] / pp["raw"]
        c_bs = 1 - cz["bias_stability_deg_per_h"] / raw["bias_stability_deg_per_h"]
        c_pp36 = 1 - cz["drift_pp_deg_per_s"] / raw["drift_pp_deg_per_s"]
        ok = c_pp >= 0.9 and c_bs >= 0.9
        line = (
            f"- Acceptance (held out, **causal headline**, {m['causal_model']['family']}): "
            f"drift p-p of 100 s averages cut {100 * c_pp:.1f} %, bias stability cut "
            f"{100 * c_bs:.1f} % (both must be ≥ 90 %): **{'pass' if ok else 'FAIL'}**. "
            f"On 3.6 s averages the p-p cut is {100 * c_pp36:.1f} %"
        )
        if "oracle" in m:
            o36 = 1 - m["oracle"]["drift_pp_deg_per_s"] / raw["drift_pp_deg_per_s"]
            line += (
                f"; the oracle's is {100 * o36:.1f} % — white noise sets the 3.6 s p-p, which"
                " is why the target is on 100 s averages"
            )
        lines.append(line + ".")
    # like for like: each drift model without noise removal, then each behind it
    pairs = [
        ("without noise removal", m["compensated_drift_only"], m["baselines"]),
        ("behind the paper's noise removal", m["compensated"], m["baselines_with_noise_removal"]),
    ]
    for how, d, bases in pairs:
        lines += _compare(how, d, bases)
    return lines


def _compare(how: str, d: dict[str, float], bases: dict[str, dict[str, float]]) -> list[str]:
    """Baseline vs GA-BP on drift p-p and bias stability; a 2 % margin is a tie."""
    lines = []
    keys = {"drift_pp_deg_per_s": "drift p-p", "bias_stability_deg_per_h": "bias stability"}
    for name, b in bases.items():
        parts = []
        for k, label in keys.items():
            if b[k] < 0.98 * d[k]:
                who = f"**{name} wins**"
            elif b[k] > 1.02 * d[k]:
                who = "GA-BP wins"
            else:
                who = "tie (within 2 %)"
            parts.append(f"{label} {b[k]:.3g} vs GA-BP {d[k]:.3g}: {who}")
        lines.append(f"- {how}, baseline {name}: " + "; ".join(parts) + ".")
    return lines


def denoise(m: dict[str, Any]) -> str:
    dn = m["denoising"]
    bw = dn["bandwidth"]
    flp = dn.get("flp") or {}
    s = (
        f"ARW with noise removal {dn['arw_with_noise_removal_deg_per_sqrt_h']:.4g} °/√h, "
        f"without {dn['arw_without_noise_removal_deg_per_sqrt_h']:.4g} °/√h. The offline "
        f"output keeps |H|² ≥ ½ up to {1e3 * bw['f3db_hz']:.2f} mHz and an equivalent noise "
        f"bandwidth of {1e3 * bw['enbw_hz']:.2f} mHz, out of the {1e3 * bw['nyquist_hz']:.1f} "
        f"mHz that 1000 points/h carries (the recording itself: {dn['raw_bandwidth_hz']:.0f} Hz)."
    )
    if flp:
        s += (
            f" FLP on the mixed modes: order {flp.get('order')}, variance "
            f"{flp.get('variance_in', float('nan')):.3g} → "
            f"{flp.get('variance_out', float('nan')):.3g}"
            f" (°/s)², −3 dB at {1e3 * flp.get('bandwidth_hz', float('nan')):.1f} mHz."
        )
    return s


def run(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=REPO, env={**os.environ, "GYROLAB_NO_PROGRESS": "1"})
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/gyrolab-results", help="scratch directory")
    ap.add_argument("--out", default=str(REPO / "docs" / "results.md"))
    a = ap.parse_args()
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    gl = [sys.executable, "-m", "gyrolab"]

    import tomli_w

    from gyrolab import __version__
    from gyrolab.profiles.profile import load_profile

    rev_toml = work / "paper-reversed.toml"
    rev_toml.write_bytes(tomli_w.dumps(load_profile("paper").reversed().to_dict()).encode())
    runs = {
        "s1": (["--profile", "paper", "--seed", "1"], work / "paper-s1.mcap"),
        "s2": (["--profile", "paper", "--seed", "2"], work / "paper-s2.mcap"),
        "rev": (["--profile", str(rev_toml), "--seed", "3"], work / "paper-reversed-s3.mcap"),
    }
    for args, path in runs.values():
        if not path.exists():
            run([*gl, "simulate", *args, "--out", str(path)])
    model = work / "model"
    shutil.rmtree(model, ignore_errors=True)
    s1, s2 = str(runs["s1"][1]), str(runs["s2"][1])
    load0 = os.getloadavg()
    wall = run([*gl, "compensate", s1, "--out", str(model), "--validate", s2])
    m_s2 = json.loads((model / "metrics.json").read_text())

    from gyrolab.compensation.apply import compensate_offline
    from gyrolab.compensation.evaluate import evaluate
    from gyrolab.compensation.model_dir import load_model
    from gyrolab.compensation.prepare import prepare_run
    from gyrolab.record.format import TOPIC_PT100, TOPIC_RATE
    from gyrolab.record.reader import read_recording

    mdl = load_model(str(model))
    rv = prepare_run(read_recording(runs["rev"][1], [TOPIC_RATE, TOPIC_PT100]), mdl.config)
    m_rev = evaluate(mdl, compensate_offline(mdl, rv), rv, held_out=True)
    from gyrolab.compensation.oracle import add_oracle

    add_oracle(m_rev, str(runs["rev"][1]), mdl.config.block_s)
    cal = m_s2["calibration"]
    tb = m_s2["timing_breakdown_s"]
    load = os.getloadavg()

    md = [
        "## The paper's own pair: the paper's method, the causal headline, baselines",
        "",
        "Regenerate with `python benchmarks/results_paper.py` (writes this section). "
        f"gyrolab {__version__}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
        f"{platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}.",
        "",
        "Runs: `gyrolab simulate --profile paper` seed 1 (calibration) and seed 2 (held out), "
        "and the reversed paper profile (`Profile.reversed()`: a heating run, seed 3, held "
        "out). The model is fitted on seed 1 only (`gyrolab compensate paper-s1.mcap --out "
        "MODEL --validate paper-s2.mcap`) and applied unchanged to the other two. Every "
        "metric is computed on the output at the paper's 1000 points/h (3.6 s averages, "
        f"N = {m_s2['n_points']}), with `gyrolab.compensation.metrics.signal_metrics`. "
        '"Bias stability" is the paper\'s figure (standard deviation of the 3.6 s '
        'averages, °/h); "bias instability" is the IEEE 952 Allan floor / 0.664.',
        "",
        f"Model: VMD K = {m_s2['vmd']['K']}, α = {m_s2['vmd']['alpha']:.0f} (GPSO); mode "
        f"classes on the calibration run {cal['imf_classes']} (mean MPE "
        + ", ".join(f"{v:.3f}" for v in cal["mpe_mean"])
        + ").",
        "",
        "### Held out: paper profile, seed 2",
        "",
        table(m_s2),
        "",
        *verdicts(m_s2),
        "",
        denoise(m_s2),
        "",
        "### Held out: heating (reversed) profile, seed 3",
        "",
        table(m_rev),
        "",
        *verdicts(m_rev),
        "",
        denoise(m_rev),
        "",
        f"Temperature on this run {m_rev['temperature']['min_c']:.1f} … "
        f"{m_rev['temperature']['max_c']:.1f} °C against a calibration range of "
        f"{m_rev['temperature']['calibration_min_c']:.1f} … "
        f"{m_rev['temperature']['calibration_max_c']:.1f} °C: "
        f"{100 * m_rev['temperature']['fraction_outside_calibration']:.1f} % of the points "
        "lie outside it, where the networks continue linearly and the polynomial follows "
        "its own curve.",
        "",
        "### In sample: the calibration run (seed 1)",
        "",
        table(cal),
        "",
        "### Against the paper (§4.2)",
        "",
        "| | ARW °/√h | bias stability °/h |",
        "| --- | ---: | ---: |",
        "| paper, raw → compensated | 0.0523 → 0.003832 | 31.428 → 0.273 |",
        f"| here, seed 2 held out, raw → paper method | {m_s2['raw']['arw_deg_per_sqrt_h']:.4g}"
        f" → {m_s2['compensated']['arw_deg_per_sqrt_h']:.4g} | "
        f"{m_s2['raw']['bias_stability_deg_per_h']:.4g} → "
        f"{m_s2['compensated']['bias_stability_deg_per_h']:.3g} |",
        f"| here, seed 2, raw → GA-BP + causal FLP | {m_s2['raw']['arw_deg_per_sqrt_h']:.4g}"
        f" → {m_s2['compensated_streaming_flp']['arw_deg_per_sqrt_h']:.4g} | "
        f"{m_s2['raw']['bias_stability_deg_per_h']:.4g} → "
        f"{m_s2['compensated_streaming_flp']['bias_stability_deg_per_h']:.3g} |",
        "",
        "### Reading these numbers",
        "",
        "- The drift removal is what the temperature model does; the rest of the gain in the "
        "paper method's row is low-pass filtering. Dropping the noise modes keeps only "
        "the slow part of the output (the bandwidth figures above), so its ARW and Allan "
        "bias instability are those of a filtered signal, not the sensor's noise density: "
        "the rows without noise removal give the sensor's real ARW after compensation.",
        "- The GA-BP + causal FLP row reproduces the paper's ARW figure (≈ 3.8e-3 °/√h) "
        "for the same reason: a forward linear predictor outputs only what is predictable "
        "from the past, so white noise is removed — and so would be any real, unpredictable "
        "rotation. It is a static-test figure, not a usable gyro output.",
        "- Drift peak-to-peak without noise removal (≈ 0.004 °/s) is set by the white noise "
        "of the 3.6 s averages (σ ≈ 4.6e-4 °/s, so ≈ 8σ over 13 000 points), not by the "
        "drift model; the noise-removal rows show the drift models' differences.",
        "- The residual after any temperature model is dominated by the simulated 1/f bias "
        "instability wander (hour-scale, ~1e-4 °/s), which no temperature model can remove.",
        "",
        "### Time",
        "",
        f"`gyrolab compensate` on the 13 h, 100 Hz paper run with `--validate` on a second "
        f"one: **{wall:.1f} s** wall clock (issue 23's limit: 50 s on a quiet 2-core "
        f"machine; load average {load0[0]:.1f} before, {load[0]:.1f} after — "
        f"{'within' if wall <= 50 else 'over it here, on a shared machine'}; `causal` is "
        "the causal model selection, whose 5-fold CV trains each network five times), "
        "stages: " + ", ".join(f"{k} {v:.1f} s" for k, v in tb.items()) + ".",
        "",
    ]
    write_section(Path(a.out), "results_paper", "\n".join(md))
    print(f"wrote {a.out}; compensate took {wall:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
