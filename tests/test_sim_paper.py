"""The default ``paper`` simulation reproduces the paper's bench (docs/sim-model.md tolerances).

Wei et al. (2021) §4.2, evaluated on the recording averaged to 1000 points/h (3.6 s):
case temperature −33.67..55.67 °C (±1.5 °C), output variation 0.0287 °/s (±15 %), raw ARW
0.0523 °/√h and raw bias stability 31.4 °/h (±30 %).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gyrolab.cli import main
from gyrolab.record.format import TOPIC_PT100, TOPIC_RATE
from gyrolab.record.reader import read_recording

BIN_S = 3600.0 / 1000.0  # 1000 points/h


def oadev(x: np.ndarray, ms: np.ndarray) -> np.ndarray:
    """Overlapping Allan deviation at τ = m samples."""
    c = np.concatenate([[0.0], np.cumsum(x)])
    out = []
    for m in ms:
        a = (c[m:] - c[:-m]) / m
        d = a[m:] - a[:-m]
        out.append(math.sqrt(0.5 * float(np.mean(d * d))))
    return np.array(out)


@pytest.fixture(scope="module")
def paper_figures(tmp_path_factory: pytest.TempPathFactory) -> dict[str, float]:
    out = tmp_path_factory.mktemp("paper") / "paper.mcap"
    assert main(["simulate", "--out", str(out)]) == 0  # defaults: paper, 100 Hz, seed 0
    rec = read_recording(out, topics=[TOPIC_RATE, TOPIC_PT100])
    rate = rec.require_rate()
    nb = int(round(BIN_S * rate.rate_hz))
    n = rate.values.size // nb * nb
    y = rate.values[:n].reshape(-1, nb).mean(axis=1)  # °/s at 1000 points/h
    k = np.floor(rec.pt100_t / BIN_S).astype(int)
    cnt = np.bincount(k)
    temp = (np.bincount(k, rec.pt100_c)[cnt > 0]) / cnt[cnt > 0]
    ms = np.array([1, 2, 3])
    # −½ line at the shortest τ: N = σ(τ) √τ, in °/h·√s → °/√h by /60
    arw = float(np.mean(oadev(y, ms) * 3600.0 * np.sqrt(ms * BIN_S) / 60.0))
    return {
        "tmin": float(temp.min()),
        "tmax": float(temp.max()),
        "variation": float(y.max() - y.min()),
        "bias_stability": float(y.std() * 3600.0),
        "arw": arw,
        "hours": rate.t[-1] / 3600.0,
    }


def test_paper_case_temperature_range(paper_figures: dict[str, float]) -> None:
    assert paper_figures["hours"] == pytest.approx(13.0, abs=0.01)
    assert paper_figures["tmin"] == pytest.approx(-33.67, abs=1.5)
    assert paper_figures["tmax"] == pytest.approx(55.67, abs=1.5)


def test_paper_output_variation(paper_figures: dict[str, float]) -> None:
    assert paper_figures["variation"] == pytest.approx(0.0287, rel=0.15)


def test_paper_arw_and_bias_stability(paper_figures: dict[str, float]) -> None:
    assert paper_figures["arw"] == pytest.approx(0.0523, rel=0.30)
    assert paper_figures["bias_stability"] == pytest.approx(31.4, rel=0.30)
