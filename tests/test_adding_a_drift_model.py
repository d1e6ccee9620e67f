"""Adding a drift-model family touches two code files: the family's module and the list
of family modules (docs/compensation.md, "Adding a drift-model family").

The ``lagline`` family below exists in this test module alone — exactly what its module
``gyrolab/compensation/lagline.py`` would hold — and is registered as the one line in
``gyrolab/compensation/families.py`` (``MODULES``) would register it. It is then taken
through the commands a user runs: ``compensate --config`` (the family named in
``causal_families``) → ``apply`` → ``export --format json`` and ``--format c`` (the C
compiled and run reading by reading), each compared with the family's own prediction.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_export import CC, run_c

from gyrolab.cli import main
from gyrolab.compensation import families
from gyrolab.compensation.causal_features import hold
from gyrolab.compensation.drift_model import (
    Candidate,
    CModel,
    DriftModel,
    Family,
    FitContext,
    SpecKind,
    c_float,
    drift_sample_by_sample,
)
from gyrolab.compensation.model_dir import ModelDir
from gyrolab.export.model_json import evaluate
from gyrolab.profiles.profile import load_profile
from gyrolab.record.reader import read_recording
from gyrolab.sim.model import nominal_model
from gyrolab.sim.simulate import simulate_run

#: The code files a new family needs: its module, and the line that lists it.
FAMILY_FILES = ("gyrolab/compensation/lagline.py", "gyrolab/compensation/families.py")
TAU_GRID_S = (60.0, 150.0, 300.0, 600.0, 1200.0)


# ------------------------------------------------------- the family's module
def lagged(pt_t: np.ndarray, pt_c: np.ndarray, tau_s: float) -> np.ndarray:
    """The die temperature F at every reading: ``F += (1 − e^(−Δt/τ)) (T − F)``, at rest
    at the first reading (the same operations as :meth:`LagLine.reading`)."""
    F = np.empty(len(pt_c))
    f, prev = float(pt_c[0]), float(pt_t[0])
    for i, (t, T) in enumerate(zip(pt_t, pt_c, strict=True)):
        f += -math.expm1(-(float(t) - prev) / tau_s) * (float(T) - f)
        prev = float(t)
        F[i] = f
    return F


@dataclass
class LagState:
    F: float | None = None
    t: float = 0.0
    held: float = 0.0


@dataclass
class LagLine(DriftModel):
    """``d = c0 + c1 F + c2 F²``, F the case temperature lagged by τ."""

    tau_s: float
    coef: tuple[float, float, float]
    family = "lagline"

    def start(self) -> LagState:
        return LagState()

    def reading(self, state: LagState, t_s: float, temp_c: float) -> None:
        if state.F is None:  # at rest at the first reading
            state.F, state.t = temp_c, t_s
        state.F += -math.expm1(-(t_s - state.t) / self.tau_s) * (temp_c - state.F)
        state.t = t_s
        c0, c1, c2 = self.coef
        state.held = c0 + state.F * (c1 + state.F * c2)

    def sample(self, state: LagState, t_s: float) -> float:
        return state.held

    def reading_drift(self, pt_t: np.ndarray, pt_c: np.ndarray) -> np.ndarray:
        F = lagged(pt_t, pt_c, self.tau_s)
        c0, c1, c2 = self.coef
        return c0 + F * (c1 + F * c2)

    def parameters(self) -> dict[str, Any]:
        return {"tau_s": self.tau_s, "coef": list(self.coef)}

    def spec(self) -> dict[str, Any]:
        return {"kind": "lagline", "tau_s": self.tau_s, "coef": list(self.coef)}


def fit_lagline(ctx: FitContext) -> Candidate:
    """τ on a grid by the blocked CV the selection uses, the coefficients by least squares."""
    cal = ctx.cal

    def fitter(tau: float):  # noqa: ANN202 - the CV's fit(train) for one τ
        F = hold(cal.t, cal.pt_t, lagged(cal.pt_t, cal.pt_c, tau))

        def fit(train: np.ndarray) -> LagLine:
            A = np.vander(F[train], 3, increasing=True)
            c = np.linalg.lstsq(A, cal.rate[train], rcond=None)[0]
            return LagLine(tau, (float(c[0]), float(c[1]), float(c[2])))

        return fit

    cv = {tau: ctx.cross_validate(fitter(tau)) for tau in TAU_GRID_S}
    tau = min(cv, key=lambda k: cv[k][0])
    model = fitter(tau)(np.ones(cal.t.size, dtype=bool))
    err, pred = cv[tau]
    return Candidate(model, err, {"tau_s": tau}, pred)


def load_lagline(meta: dict[str, Any], arrays: dict[str, np.ndarray], prefix: str) -> LagLine:
    c = [float(v) for v in meta["coef"]]
    return LagLine(float(meta["tau_s"]), (c[0], c[1], c[2]))


def evaluate_lagline(
    m: dict[str, Any], t: np.ndarray, pt_t: np.ndarray, pt_c: np.ndarray
) -> np.ndarray:
    """The exported model's drift at ``t``, from the JSON alone."""
    F = lagged(pt_t, pt_c, m["tau_s"])
    c = m["coef"]
    return hold(t, pt_t, c[0] + c[1] * F + c[2] * F * F)


def c_lagline(m: dict[str, Any], prefix: str) -> CModel:
    c0, c1, c2 = (c_float(v) for v in m["coef"])
    return CModel(
        code=f"/* {prefix}: lagline, tau = {m['tau_s']} s */",
        state=("float F", "float held"),
        reading="\n".join(
            [
                "    if (first) st->F = T;",
                f"    st->F += -expm1f(-dt / {c_float(m['tau_s'])}) * (T - st->F);",
                f"    st->held = {c0} + st->F * ({c1} + st->F * {c2});",
            ]
        ),
        sample="    return st->held;",
        note="the quadratic in the lagged temperature, not clamped",
    )


FAMILY = Family("lagline", fit_lagline, load_lagline, 10.0, "quadratic in the lagged T")
KIND = SpecKind("lagline", evaluate_lagline, c_lagline)
# -----------------------------------------------------------------------------------


@pytest.fixture
def lagline() -> Iterator[Family]:
    # A family module is listed in families.MODULES; here the registration is undone
    # after the test so that the other tests see the built-in families only.
    families.register([FAMILY], [KIND])
    yield FAMILY
    families.unregister([FAMILY], [KIND])


def test_a_family_needs_its_module_and_the_list_of_modules() -> None:
    """Every built-in family comes from a module of ``families.MODULES`` (the list a new
    family's module is added to) and nothing else registers one."""
    assert len(FAMILY_FILES) <= 2
    declared = {f.name for m in families.MODULES for f in getattr(m, "FAMILIES", ())}
    builtin = {"poly", "structured", "structured_rate", "structured_pi", "bp", "gabp"}
    assert set(families.names()) == declared == builtin
    root = Path(__file__).resolve().parents[1]
    assert (root / FAMILY_FILES[1]).is_file()


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("family")
    m = nominal_model().with_effect("thermal_lag", tau_s=300.0)
    for name, seed in (("cal", 5), ("val", 6)):
        simulate_run(
            d / f"{name}.mcap", load_profile("short"), m, rate_hz=10.0, seed=seed,
            show_progress=False,
        )  # fmt: skip
    (d / "cfg.toml").write_text(
        'causal_families = ["lagline"]\nvmd_K = 5\nvmd_alpha = 2000.0\nga_population = 12\n'
        "ga_generations = 4\nbp_max_iter = 100\nhidden = 5\n"
    )
    return d


def test_a_family_defined_in_its_test_goes_through_compensate_apply_export(
    runs: Path, tmp_path: Path, lagline: Family
) -> None:
    model = tmp_path / "m"
    argv = ["compensate", str(runs / "cal.mcap"), "--validate", str(runs / "val.mcap")]
    assert main([*argv, "--config", str(runs / "cfg.toml"), "--out", str(model)]) == 0
    metrics = json.loads((model / "metrics.json").read_text())
    assert metrics["causal_model"]["family"] == "lagline"
    assert metrics["causal_model"]["selection"]["lagline"]["tau_s"] in TAU_GRID_S
    cm = ModelDir(model).load()
    fam = cm.causal
    assert isinstance(fam, LagLine) and set(fam.cv_rmse) == {"lagline"}
    rec = read_recording(runs / "val.mcap")
    d_py = fam.drift_at(rec.rate.t, rec.pt100_t, rec.pt100_c)
    # causal sample by sample (what firmware runs) = vectorised, bit for bit
    n = 5000
    assert np.array_equal(
        drift_sample_by_sample(fam, rec.rate.t[:n], rec.pt100_t, rec.pt100_c), d_py[:n]
    )

    # apply: /gyro/rate is raw − the family's drift
    out = tmp_path / "applied.mcap"
    assert main(["apply", str(model), str(runs / "val.mcap"), "--out", str(out)]) == 0
    got = read_recording(out)
    want = (rec.rate.values.astype(float) - d_py).astype(np.float32)
    np.testing.assert_array_equal(got.rate.values, want)
    assert "lagline" in got.metadata["compensation"]["topics"]["/gyro/rate"]

    # export json: the family's form, and its kind's evaluation of it equals the model
    js = tmp_path / "m.json"
    assert main(["export", str(model), "--format", "json", "--out", str(js)]) == 0
    spec = json.loads(js.read_text())
    ax = spec["axes"][0]["model"]
    assert ax["kind"] == "lagline" and ax["tau_s"] == fam.tau_s
    np.testing.assert_allclose(
        evaluate(ax, rec.rate.t, rec.pt100_t, rec.pt100_c), d_py, rtol=1e-12, atol=1e-15
    )

    if CC is None:
        pytest.skip("no C compiler on this machine")
    c = tmp_path / "lag.c"
    assert main(["export", str(model), "--format", "c", "--out", str(c)]) == 0
    (tmp_path / "b").mkdir()
    ok, drift_c = run_c(tmp_path / "b", c, rec, 1)
    assert ok.all()
    err = np.abs(drift_c[:, 0] - d_py)
    assert err.max() <= 1e-5 * np.abs(d_py).max()


def test_a_model_of_an_unknown_family_is_one_line(
    runs: Path, tmp_path: Path, lagline: Family, capsys: pytest.CaptureFixture[str]
) -> None:
    model = tmp_path / "m"
    argv = ["compensate", str(runs / "cal.mcap"), "--config", str(runs / "cfg.toml")]
    assert main([*argv, "--out", str(model)]) == 0
    capsys.readouterr()
    families.unregister([FAMILY], [KIND])  # a gyrolab without the family's module
    out = tmp_path / "a.mcap"
    assert main(["apply", str(model), str(runs / "val.mcap"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "model.json" in err[0] and "lagline" in err[0]
    assert not out.exists()
