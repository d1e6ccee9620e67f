"""Every drift-model family implements the interface of
gyrolab.compensation.drift_model the same way: sample by sample (what firmware runs)
equals vectorised bit for bit — inside the calibrated range and beyond it, where the
networks continue linearly —, saving and loading gives the same model, and the exported
form's own evaluation gives the same drift."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from test_causal import _staircase_run

from gyrolab.compensation.causal import causal_from_state, causal_state, fit_causal
from gyrolab.compensation.config import PipelineConfig
from gyrolab.compensation.drift_model import drift_sample_by_sample
from gyrolab.compensation.firmware import Poly3
from gyrolab.compensation.temperature_model import (
    TemperatureModel,
    fit_temperature_model,
    load_temperature_model,
    temperature_inputs,
)
from gyrolab.export.model_json import evaluate

torch.set_num_threads(1)
FAST = PipelineConfig(
    ga_population=8, ga_generations=3, bp_max_iter=60, hidden=4,
    causal_families=("poly", "structured", "structured_rate", "bp", "gabp"),
)  # fmt: skip


@pytest.fixture(scope="module")
def cal():
    return _staircase_run(tau_die=300.0, hyst=1e-3, seed=4, hours=3.0)


@pytest.fixture(scope="module")
def causal(cal):
    return fit_causal(cal, config=FAST, seed=1)


def _probe(cal) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Readings past the calibrated range (5 °C beyond both ends) and samples at 3 per
    reading interval, some before, on and after each reading."""
    pt_t = cal.pt_t[::20]
    pt_c = np.concatenate(
        [cal.pt_c[::20][: pt_t.size // 2] - 5.0, cal.pt_c[::20][pt_t.size // 2 :] + 5.0]
    )
    t = np.sort(np.concatenate([pt_t, pt_t + 3.0, pt_t + 11.7]))
    return t, pt_t, pt_c


@pytest.mark.parametrize("name", ["poly", "structured", "structured_rate", "bp", "gabp"])
def test_causal_families_sample_by_sample_equals_vectorised(cal, causal, name) -> None:
    m = causal.alternatives[name]
    assert m.family == name
    t, pt_t, pt_c = _probe(cal)
    vec = m.drift_at(t, pt_t, pt_c)
    assert np.array_equal(drift_sample_by_sample(m, t, pt_t, pt_c), vec)
    # saved and loaded by its family: the same numbers
    m.cv_rmse, m.selection = causal.cv_rmse, causal.selection
    meta, arrays = causal_state(m, "causal.")
    back = causal_from_state(meta, arrays, "causal.")
    assert type(back) is type(m) and np.array_equal(back.drift_at(t, pt_t, pt_c), vec)
    assert back.describe() == m.describe()
    # the exported form, evaluated from the JSON alone
    np.testing.assert_allclose(evaluate(m.spec(), t, pt_t, pt_c), vec, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("use_dtdt", [False, True])
@pytest.mark.parametrize("name", ["gabp", "bp", "poly"])
def test_temperature_models_sample_by_sample_equals_vectorised(cal, name, use_dtdt) -> None:
    cfg = replace(FAST, use_dtdt=use_dtdt, dtdt_window_s=120.0)
    w = cfg.dtdt_window_s if use_dtdt else None
    X = temperature_inputs(cal.t, cal.pt_t, cal.pt_c, w)
    m = fit_temperature_model(name, X, cal.rate, cfg, seed=2)
    t, pt_t, pt_c = _probe(cal)
    vec = m.drift_at(t, pt_t, pt_c)
    assert np.array_equal(drift_sample_by_sample(m, t, pt_t, pt_c), vec)
    meta, arrays = m.save("drift.")
    back = load_temperature_model(meta, arrays, "drift.", cfg, name)
    assert np.array_equal(back.drift_at(t, pt_t, pt_c), vec)
    np.testing.assert_allclose(evaluate(m.spec(), t, pt_t, pt_c), vec, rtol=1e-9, atol=1e-15)


def test_the_firmware_cubic_is_a_drift_model(cal) -> None:
    m = TemperatureModel(Poly3((1e-3, 2e-4, -1e-6, 3e-8), 25.0, -10.0, 60.0), family="poly3")
    t, pt_t, pt_c = _probe(cal)
    vec = m.drift_at(t, pt_t, pt_c)
    assert np.array_equal(drift_sample_by_sample(m, t, pt_t, pt_c), vec)
    np.testing.assert_allclose(evaluate(m.spec(), t, pt_t, pt_c), vec, rtol=1e-13)


def test_selection_records_every_family_and_the_winner(causal) -> None:
    fams = {"poly", "structured", "structured_rate", "bp", "gabp"}
    assert set(causal.cv_rmse) == set(causal.alternatives) == fams
    assert causal.selection["winner"] == causal.family
    assert causal.alternatives[causal.family] is causal
