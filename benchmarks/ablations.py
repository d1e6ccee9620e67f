"""Ablations of the paper's components (issue 11 point 4), mean ± sd over seeds.

    python benchmarks/ablations.py [--seeds 5] [--work DIR] [--write docs/results.md]

Per seed s: a calibration run (``gyrolab simulate --profile paper``, nominal unit, seed
100 + s, 10 Hz) and a held-out run on *another trajectory* (the reversed, heating paper
profile, seed 200 + s). Everything is fitted on the calibration run and scored on the
held-out run, at the paper's 1000 points/h (3.6 s averages), by

* bias stability: std of the 3.6 s averages (°/h, the paper's figure);
* drift p-p (100 s): peak-to-peak of 100.8 s averages (°/s; on 3.6 s averages it is set by
  white noise);
* for the BP ablation also the training loss reached (½·MSE on standardised data).

Components, each against the reference = the project's pipeline defaults (GPSO on the
``drift_separation`` fitness, MPE classes, FLP on the mixed modes, GA-BP with L-BFGS):

1. (K, α): GPSO with the project's fitness vs GPSO with the minimum envelope entropy
   (the PSO-VMD literature's fitness) vs fixed (K, α) — the paper's printed optimum
   (11, 4641) and a mid-box (6, 1000).
2. MPE and FLP: mixed modes unfiltered (no FLP); mixed modes dropped (no FLP, no mixed
   class); classes by VMD centre frequency instead of MPE (lowest-frequency mode = drift,
   the rest dropped); no decomposition at all (GA-BP on the raw averages, causal raw − f(T)).
3. GA initialisation vs random (Xavier) initialisation, each with the paper's plain
   gradient-descent BP (η = 0.01, 1000 epochs: the paper prints neither, these are the BP
   toolbox defaults), with a longer gradient descent (η = 0.1, 5000 epochs) and with L-BFGS.

Sizes, to stay within ~10 min on 2 cores: 10 Hz recordings (the model works at 3.6 s
averages, so the recording rate only changes the white noise per average, not the drift),
a GPSO swarm of 20 particles × 12 generations for both fitnesses (the paper's 50 × 30 takes
6.5x longer; on seed 1 both chose the same corner of the box for the project's fitness),
8 seeds. Measured: 29 min at load average ~10 on the shared 2-core machine (results are
deterministic: two runs gave the same table); one seed without the long descent took 20 s
at load ~1, so a quiet machine should need about 5 min (not measured). ``--render``
re-renders the section from ``WORK/ablations.json`` without running anything.
Paired differences are variant − reference per seed; "better" counts seeds where the
variant is lower.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from gyrolab import __version__  # noqa: E402
from gyrolab.compensation.apply import run_flp  # noqa: E402
from gyrolab.compensation.config import PipelineConfig  # noqa: E402
from gyrolab.compensation.fit import Decomposition, decompose, fit_drift_model, fit_flp  # noqa: E402
from gyrolab.compensation.gabp import BPConfig, fit_mlp  # noqa: E402
from gyrolab.compensation.prepare import PreparedRun, prepare_file  # noqa: E402
from gyrolab.numerics.averaging import PAPER_BLOCK_S, block_means  # noqa: E402

GPSO = {"gpso_population": 20, "gpso_generations": 12}  # paper: 50 x 30 (see docstring)
PAPER_KA = (11, 4641.0)
MID_KA = (6, 1000.0)
GD_PAPER = BPConfig(optimizer="gd", learning_rate=0.01, epochs=1000)
GD_LONG = BPConfig(optimizer="gd", learning_rate=0.1, epochs=5000)
LBFGS = BPConfig()
BP_RUNS = (("gd", GD_PAPER), ("gd_long", GD_LONG), ("lbfgs", LBFGS))


def simulate(work: Path, seed: int) -> tuple[Path, Path]:
    from gyrolab.profiles.profile import load_profile
    from gyrolab.sim.model import nominal_model
    from gyrolab.sim.simulate import simulate_run

    prof = load_profile("paper")
    cal, val = work / f"cal-s{seed}.mcap", work / f"heat-s{seed}.mcap"
    for path, p, s in ((cal, prof, 100 + seed), (val, prof.reversed(), 200 + seed)):
        if not path.exists():
            tmp = path.with_suffix(".part")
            simulate_run(tmp, p, nominal_model(), rate_hz=10.0, seed=s, show_progress=False)
            os.replace(tmp, path)
    return cal, val


def scores(y: np.ndarray) -> dict[str, float]:
    """Held-out figures of a 3.6 s series (°/s)."""
    return {
        "bias_stability_deg_per_h": float(np.std(y, ddof=1) * 3600.0),
        "drift_pp_100s_deg_per_s": float(
            np.ptp(block_means(y, 1.0 / PAPER_BLOCK_S, 28 * PAPER_BLOCK_S))
        ),
    }


def classes_by_frequency(dec: Decomposition) -> dict[str, list[int]]:
    k = int(np.argmin(dec.omega))
    return {"noise": [i for i in range(dec.K) if i != k], "mixed": [], "drift": [k]}


def reconstruct(
    cfg: PipelineConfig,
    cal: PreparedRun,
    val: PreparedRun,
    dec_c: Decomposition,
    dec_v: Decomposition,
    seed: int,
    *,
    flp: bool = True,
    drop_mixed: bool = False,
    by_frequency: bool = False,
    drift_fit: Any = None,
) -> tuple[np.ndarray, Any]:
    """The paper's offline output on ``val`` (§3.5) with components switched off."""
    if by_frequency:
        dec_c = replace(dec_c, classes=classes_by_frequency(dec_c))
        dec_v = replace(dec_v, classes=classes_by_frequency(dec_v))
    f = drift_fit or fit_drift_model(cal.X, dec_c.part("drift"), cfg, seed)
    mixed = dec_v.part("mixed")
    if drop_mixed:
        mixed = np.zeros_like(mixed)
    elif flp and dec_c.classes.get("mixed") and dec_v.classes.get("mixed"):
        mixed, _ = run_flp(fit_flp(dec_c.part("mixed"), cfg), mixed, cfg.block_s)
    return mixed + dec_v.part("drift") - f.predict(val.X), f


def one_seed(work: Path, seed: int, log: Any) -> dict[str, Any]:
    t0 = time.perf_counter()
    cal_p, val_p = simulate(work, seed)
    cfg = replace(PipelineConfig(), **GPSO)
    cal, val = prepare_file(str(cal_p), cfg), prepare_file(str(val_p), cfg)
    out: dict[str, Any] = {"raw": scores(val.rate)}
    decs: dict[str, tuple[Decomposition, Decomposition]] = {}
    choices = {
        "gpso_project": (cfg, None),
        "gpso_envelope": (replace(cfg, vmd_fitness="envelope_entropy"), None),
        "fixed_paper": (cfg, PAPER_KA),
        "fixed_mid": (cfg, MID_KA),
    }
    ka: dict[str, tuple[int, float]] = {}
    for name, (c, fixed) in choices.items():
        dc = decompose(cal.rate, c, seed, *(fixed or (None, None)))
        dv = decompose(val.rate, c, 0, K=dc.K, alpha=dc.alpha)
        decs[name] = (dc, dv)
        ka[name] = (dc.K, dc.alpha)
        y, _ = reconstruct(cfg, cal, val, dc, dv, seed)
        out[f"ka.{name}"] = scores(y)
    dc, dv = decs["gpso_project"]
    out["ka.gpso_project"]["classes"] = dc.classes
    for name, kw in {
        "no_flp": {"flp": False},
        "no_mixed": {"drop_mixed": True},
        "freq_classes": {"by_frequency": True},
    }.items():
        y, _ = reconstruct(cfg, cal, val, dc, dv, seed, **kw)
        out[f"mpe.{name}"] = scores(y)
    raw_fit = fit_drift_model(cal.X, cal.rate, cfg, seed)
    out["mpe.no_decomposition"] = scores(val.rate - raw_fit.predict(val.X))
    target = dc.part("drift")
    for init in ("ga", "random"):
        for opt, bp in BP_RUNS:
            ts = time.perf_counter()
            m = fit_mlp(cal.X, target, init=init, bp=bp, ga=cfg.ga(), seed=seed)
            dt = time.perf_counter() - ts
            y, _ = reconstruct(cfg, cal, val, dc, dv, seed, drift_fit=m)
            s = scores(y)
            s["train_loss"] = float(m.bp_loss_history[-1])
            s["init_loss"] = float(m.bp_loss_history[0])
            s["fit_s"] = dt
            out[f"bp.{init}.{opt}"] = s
    out["ka"] = ka
    log(f"seed {seed}: {time.perf_counter() - t0:.0f} s, (K, α) {ka}")
    return out


VARIANTS = [
    (
        "ka.gpso_project",
        "**reference**: GPSO (project fitness `drift_separation`), MPE, FLP, GA-BP",
    ),
    ("ka.gpso_envelope", "GPSO on the minimum envelope entropy (literature fitness)"),
    ("ka.fixed_paper", "fixed (K, α) = (11, 4641), the paper's printed optimum"),
    ("ka.fixed_mid", "fixed (K, α) = (6, 1000)"),
    ("mpe.no_flp", "no FLP: mixed modes kept unfiltered"),
    ("mpe.no_mixed", "no FLP and no mixed class: mixed modes dropped"),
    ("mpe.freq_classes", "no MPE: lowest-frequency mode = drift, the rest dropped"),
    ("mpe.no_decomposition", "no VMD/MPE/FLP: GA-BP on the raw averages, raw − f(T)"),
    ("bp.ga.gd", "GA init + gradient-descent BP (η 0.01, 1000 epochs)"),
    ("bp.random.gd", "random init + gradient-descent BP (η 0.01, 1000 epochs)"),
    ("bp.ga.gd_long", "GA init + gradient-descent BP (η 0.1, 5000 epochs)"),
    ("bp.random.gd_long", "random init + gradient-descent BP (η 0.1, 5000 epochs)"),
    ("bp.ga.lbfgs", "GA init + L-BFGS BP (= reference's drift model)"),
    ("bp.random.lbfgs", "random init + L-BFGS BP"),
]
METRICS = [
    ("bias_stability_deg_per_h", "bias stability °/h"),
    ("drift_pp_100s_deg_per_s", "drift p-p 100 s °/s"),
]


def _sd(v: np.ndarray) -> float:
    return float(np.std(v, ddof=1)) if v.size > 1 else float("nan")


def _ms(v: np.ndarray, digits: int = 3) -> str:
    return f"{np.mean(v):.{digits}g} ± {_sd(v):.2g}"


def table(results: list[dict[str, Any]], keys: list[tuple[str, str]], ref: str) -> list[str]:
    head = "| variant |"
    sep = "| --- |"
    for _, label in METRICS:
        head += f" {label} | Δ vs reference (paired) | better |"
        sep += " ---: | ---: | ---: |"
    lines = [head, sep]
    for key, label in keys:
        row = f"| {label} |"
        for mk, _ in METRICS:
            v = np.array([r[key][mk] for r in results])
            rv = np.array([r[ref][mk] for r in results])
            d = v - rv
            if key == ref:
                row += f" {_ms(v)} | — | — |"
            else:
                better = f"{int((d < 0).sum())}/{d.size}"
                row += f" {_ms(v)} | {np.mean(d):+.2g} ± {_sd(d):.2g} | {better} |"
        lines.append(row)
    return lines


def bp_table(results: list[dict[str, Any]]) -> list[str]:
    lines = [
        "| init + BP | training loss ½·MSE (standardised) | loss at start of BP | fit time s |",
        "| --- | ---: | ---: | ---: |",
    ]
    for init in ("ga", "random"):
        for opt, _ in BP_RUNS:
            k = f"bp.{init}.{opt}"
            lines.append(
                f"| {init} + {opt} | "
                + " | ".join(
                    _ms(np.array([r[k][m] for r in results]))
                    for m in ("train_loss", "init_loss", "fit_s")
                )
                + " |"
            )
    return lines


def paired(results: list[dict[str, Any]], a: str, b: str, metric: str) -> tuple[float, float, int]:
    d = np.array([r[a][metric] - r[b][metric] for r in results])
    return float(np.mean(d)), _sd(d), int((d < 0).sum())


def verdicts(results: list[dict[str, Any]]) -> list[str]:
    """Plain statements: a component adds value when removing it makes the held-out figure
    worse by more than twice the paired standard error, in the same direction on most seeds."""
    n = len(results)

    def judge(variant: str, ref: str, metric: str) -> str:
        m, s, better = paired(results, variant, ref, metric)
        se = s / np.sqrt(n)
        rel = 100.0 * m / np.mean([r[ref][metric] for r in results])
        size = f"{rel:+.1f} % of the figure"
        if abs(rel) < 1.0 and abs(m) > 2 * se:
            return f"resolved but negligible ({m:+.3g} ± {s:.2g}, {size})"
        if m > 2 * se and better <= n // 2:
            return f"worse without it by {m:+.3g} ± {s:.2g} ({size}, {n - better}/{n} seeds)"
        if m < -2 * se and better > n // 2:
            return f"better without it by {m:+.3g} ± {s:.2g} ({size}, {better}/{n} seeds)"
        return f"no measurable difference ({m:+.3g} ± {s:.2g}, {size})"

    bs, pp = METRICS[0][0], METRICS[1][0]
    ref = "ka.gpso_project"
    out = []
    notes = {
        "mpe.freq_classes": " A lower figure here comes from dropping the mixed mode too "
        "(more low-pass filtering, less bandwidth), not from a better classification.",
        "mpe.no_decomposition": " The gain of the decomposition is the noise removal: a "
        "low-pass of the output (docs/results.md, the paper's offline method and its "
        "bandwidth), which any filter behind any drift model gives as well.",
        "ka.fixed_mid": " Fewer, wider modes drop a different share of the signal: the two "
        "figures move in opposite directions.",
    }
    for variant, what in [
        ("ka.fixed_paper", "GPSO search of (K, α) (vs the paper's fixed optimum)"),
        ("ka.fixed_mid", "GPSO search of (K, α) (vs a fixed mid-box (6, 1000))"),
        ("ka.gpso_envelope", "the project's fitness (vs envelope entropy)"),
        ("mpe.no_flp", "FLP on the mixed modes"),
        ("mpe.freq_classes", "MPE classification (vs classes by centre frequency)"),
        ("mpe.no_decomposition", "the whole decomposition (VMD + MPE + FLP)"),
    ]:
        out.append(
            f"- **{what}**: bias stability {judge(variant, ref, bs)}; "
            f"drift p-p (100 s) {judge(variant, ref, pp)}.{notes.get(variant, '')}"
        )
    for opt, name in (
        ("gd", "gradient-descent BP (η 0.01, 1000 epochs)"),
        ("gd_long", "gradient-descent BP (η 0.1, 5000 epochs)"),
        ("lbfgs", "L-BFGS BP"),
    ):
        a, b = f"bp.random.{opt}", f"bp.ga.{opt}"
        ml, sl, bl = paired(results, a, b, "train_loss")
        ga_loss = np.mean([r[b]["train_loss"] for r in results])
        rnd_loss = np.mean([r[a]["train_loss"] for r in results])
        out.append(
            f"- **GA initialisation with {name}**: training loss {ga_loss:.3g} (GA) vs "
            f"{rnd_loss:.3g} (random), paired random − GA = {ml:+.3g} ± {sl:.2g} (random "
            f"lower on {bl}/{n} seeds); held-out bias stability {judge(a, b, bs)}; drift "
            f"p-p (100 s) {judge(a, b, pp)}."
        )
    gd = np.mean([r["bp.ga.gd"]["bias_stability_deg_per_h"] for r in results])
    lb = np.mean([r["bp.ga.lbfgs"]["bias_stability_deg_per_h"] for r in results])
    out.append(
        f"- In short: GA initialisation pays only while BP is far from converged — the "
        f"paper's gradient descent at the toolbox budget — and the method is then "
        f"{gd / lb:.1f}× worse on held-out bias stability than with L-BFGS from any start "
        f"({gd:.3g} vs {lb:.3g} °/h). FLP and the choice of fitness add nothing measurable; "
        "GPSO against the paper's fixed (K, α) adds about 1 %; the decomposition's gain is "
        "low-pass filtering."
    )
    return out


def markdown(results: list[dict[str, Any]], wall: float, load: str) -> str:
    n = len(results)
    ka = [r["ka"] for r in results]
    lines = [
        "## Ablations",
        "",
        f"Regenerate with `python benchmarks/ablations.py --write docs/results.md` (writes this "
        f"section). gyrolab {__version__}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
        f"{platform.machine()} {os.cpu_count()} cores, {wall / 60:.1f} min wall clock, load "
        f"average {load}.",
        "",
        f"{n} seeds. Per seed: calibration on the paper's cooling staircase (seed 100 + s), "
        "scored on the reversed, heating staircase (seed 200 + s) — another trajectory, never "
        "seen in fitting; both `gyrolab simulate` nominal units at 10 Hz. Figures of the "
        "offline output (the paper's reconstruction, §3.5) at 1000 points/h, mean ± sd over "
        "seeds; Δ = variant − reference per seed (mean ± sd), 'better' = seeds where the "
        "variant is lower (a lower figure from dropping more of the signal is more low-pass "
        "filtering, not a better drift model: it removes real rotation too). GPSO: "
        "20 particles × 12 generations (the paper: 50 × 30) to keep the run short. "
        "Raw held-out output: bias stability "
        f"{_ms(np.array([r['raw']['bias_stability_deg_per_h'] for r in results]))} °/h, drift "
        f"p-p (100 s) {_ms(np.array([r['raw']['drift_pp_100s_deg_per_s'] for r in results]))} "
        "°/s.",
        "",
        "(K, α) chosen per seed: "
        + "; ".join(
            f"{k}: " + ", ".join(f"({K}, {a:.0f})" for K, a in (x[k] for x in ka))
            for k in ("gpso_project", "gpso_envelope")
        )
        + ".",
        "",
        "### (K, α), MPE and FLP",
        "",
        *table(results, VARIANTS[:8], "ka.gpso_project"),
        "",
        "### GA initialisation, with the paper's gradient-descent BP and with L-BFGS",
        "",
        "Drift target: the drift modes of the reference decomposition; the rest of the "
        "reconstruction as in the reference. Δ here is against the reference (GA + L-BFGS).",
        "",
        *table(results, VARIANTS[8:], "ka.gpso_project"),
        "",
        *bp_table(results),
        "",
        "### Which component adds value",
        "",
        *verdicts(results),
        "",
    ]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--work", default="/tmp/gyrolab-ablations")
    ap.add_argument("--write", metavar="RESULTS.md", help="replace its marked 'ablations' section")
    ap.add_argument(
        "--render", action="store_true", help="re-render from WORK/ablations.json, no runs"
    )
    a = ap.parse_args()
    os.environ.setdefault("GYROLAB_NO_PROGRESS", "1")
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    import torch

    torch.set_num_threads(1)
    cache = work / "ablations.json"
    if a.render:
        saved = json.loads(cache.read_text())
        results, wall, load = saved["results"], saved["wall_s"], saved["load"]
    else:
        t0 = time.perf_counter()
        results = [
            one_seed(work, s, lambda m: print(m, file=sys.stderr, flush=True))
            for s in range(1, a.seeds + 1)
        ]
        wall = time.perf_counter() - t0
        load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
        cache.write_text(json.dumps({"results": results, "wall_s": wall, "load": load}))
    text = markdown(results, wall, load)
    print(text)
    if a.write:
        from docsections import write_section  # benchmarks/: the marked-section writer

        write_section(Path(a.write), "ablations", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
