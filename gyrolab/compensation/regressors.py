"""The output maps of the built-in drift models in their exported form: the eq. 15–17
network (``mlp``), the Legendre polynomial (``legendre``), the firmware cubic
(``poly3``) and the structured model (``structured``) — each one's reference evaluation
on its inputs (:func:`evaluate_inputs`, float64, from the JSON alone) and its C99
float32 function (:func:`c_function`). The drift models of
:mod:`gyrolab.compensation.temperature_model` (inputs T, dT/dt) and
:mod:`gyrolab.compensation.causal` (inputs F, R, S, E) put their inputs in front.

The forms (docs/export.md has the JSON reference):

* ``mlp``: ``f = y_std·(Σ_h w_h σ(Σ_i W_ih z_i + a_h) + b + Σ_i g_i (x_i − c_i)/x_std_i)
  + y_mean`` with ``c = clip(x, x_min, x_max)``, ``z = (c − x_mean)/x_std``, σ the
  logistic function and ``g_i = Σ_h W_ih w_h σ_h (1 − σ_h)`` (linear continuation
  outside the calibrated range; inside it the last term is 0);
* ``legendre``: ``Σ c_k P_k(u)`` (+ ``rate_coef``·x_1), ``u = (2 x_0 − lo − hi)/(hi −
  lo)``, not clamped;
* ``poly3``: ``Σ c_k Δ^k``, ``Δ = clamp(x_0, t_min, t_max) − t_ref``;
* ``structured``: ``Σ c_i L_i(u) + k x_1 + h x_2 + A x_3 + kp max(x_1, 0) + k2 q(x_1) +
  hT x_2 v``, ``u`` as above in x_0 = F, ``v`` = u clipped to [−1, 1], the Legendre part
  continued linearly beyond u = ±1; ``q(R) = R|R|`` on ``[r_lo, r_hi]`` (the calibrated
  rate range) and its tangent beyond, ``q = R_c|R_c| + 2|R_c|(R − R_c)`` with ``R_c`` = R
  clipped (``kp``, ``k2``, ``hT`` absent = 0: models written before issue 23; ``r_lo``,
  ``r_hi`` absent: unbounded).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from gyrolab.compensation.drift_model import c_array, c_float


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def _eval_poly3(m: dict[str, Any], X: np.ndarray) -> np.ndarray:
    d = np.clip(X[:, 0], m["t_min"], m["t_max"]) - m["t_ref"]
    c = m["coef"]
    return c[0] + d * (c[1] + d * (c[2] + d * c[3]))


def _eval_legendre(m: dict[str, Any], X: np.ndarray) -> np.ndarray:
    u = (2.0 * X[:, 0] - (m["t_lo"] + m["t_hi"])) / (m["t_hi"] - m["t_lo"])
    y = np.polynomial.legendre.legval(u, m["coef"])
    if m["rate_coef"] is not None:
        y = y + m["rate_coef"] * X[:, 1]
    return y


def _eval_mlp(m: dict[str, Any], X: np.ndarray) -> np.ndarray:
    W, a, w = (np.asarray(m[n], dtype=float) for n in ("W", "a", "w"))
    xm, xs = np.asarray(m["x_mean"]), np.asarray(m["x_std"])
    c = np.clip(X, m["x_min"], m["x_max"])
    s = _sigmoid(((c - xm) / xs) @ W + a)
    y = s @ w + m["b"]
    g = (s * (1.0 - s) * w) @ W.T
    y = y + np.sum(g * (X - c) / xs, axis=1)
    return y * m["y_std"] + m["y_mean"]


def _eval_structured(m: dict[str, Any], X: np.ndarray) -> np.ndarray:
    lo, hi = m["lo"], m["hi"]
    u = (2.0 * X[:, 0] - (lo + hi)) / (hi - lo)
    uc = np.clip(u, -1.0, 1.0)
    c = np.asarray(m["coef"], dtype=float)
    y = np.polynomial.legendre.legval(uc, c)
    y = y + np.polynomial.legendre.legval(uc, np.polynomial.legendre.legder(c)) * (u - uc)
    y = y + m["k"] * X[:, 1] + m["h"] * X[:, 2] + m["A"] * X[:, 3]
    R = X[:, 1]
    # R|R| on [r_lo, r_hi] and its tangent beyond (absent: unbounded)
    Rc = np.clip(R, m.get("r_lo", -np.inf), m.get("r_hi", np.inf))
    return (
        y
        + m.get("kp", 0.0) * np.maximum(R, 0.0)
        + m.get("k2", 0.0) * (Rc * np.abs(Rc) + 2.0 * np.abs(Rc) * (R - Rc))
        + m.get("hT", 0.0) * X[:, 2] * uc
    )


_EVALUATE: dict[str, Callable[[dict[str, Any], np.ndarray], np.ndarray]] = {
    "poly3": _eval_poly3,
    "legendre": _eval_legendre,
    "mlp": _eval_mlp,
    "structured": _eval_structured,
}


def evaluate_inputs(m: dict[str, Any], X: np.ndarray) -> np.ndarray:
    """``f(inputs)`` of an exported output map ``m`` (module docstring), ``X`` = (N,
    n_inputs), float64 — the equations, independent of the fitting code."""
    X = np.asarray(X, dtype=float)
    X = X[:, None] if X.ndim == 1 else X
    try:
        f = _EVALUATE[m["kind"]]
    except KeyError:
        raise ValueError(f"unknown model kind {m['kind']!r}") from None
    return f(m, X)


# ----------------------------------------------------------------------------- C


def _c_poly3(name: str, m: dict[str, Any]) -> list[str]:
    c = m["coef"]
    return [
        f"static float {name}(const float *x)",
        "{",
        f"    const float d = clampf(x[0], {c_float(m['t_min'])}, {c_float(m['t_max'])}) - "
        f"{c_float(m['t_ref'])};",
        f"    return {c_float(c[0])} + d * ({c_float(c[1])} + d * ({c_float(c[2])} + d * "
        f"{c_float(c[3])}));",
        "}",
    ]


def _c_legendre(name: str, m: dict[str, Any]) -> list[str]:
    """The Legendre series (``legendre``) or the structured model (``structured``: the
    series continued linearly beyond u = ±1, plus its rate, branch and warm-up terms)."""
    c = m["coef"]
    structured = m["kind"] == "structured"
    lo, hi = (m["lo"], m["hi"]) if structured else (m["t_lo"], m["t_hi"])
    out = [
        c_array(f"{name}_C", c),
        f"static float {name}(const float *x)",
        "{",
        f"    const float u = (2.0f * x[0] - {c_float(lo + hi)}) / {c_float(hi - lo)};",
        "    const float v = " + ("clampf(u, -1.0f, 1.0f);" if structured else "u;"),
        "    /* Legendre P_n(v) and P_n'(v) by their three-term recurrences */",
        "    float p0 = 1.0f, p1 = v, d0 = 0.0f, d1 = 1.0f;",
        f"    float y = {name}_C[0], dy = 0.0f;",
        f"    if ({len(c)} > 1) {{ y += {name}_C[1] * p1; dy += {name}_C[1] * d1; }}",
        f"    for (int n = 1; n + 1 < {len(c)}; ++n) {{",
        "        const float p2 = ((float)(2 * n + 1) * v * p1 - (float)n * p0) / (float)(n + 1);",
        "        const float d2 = d0 + (float)(2 * n + 1) * p1;",
        f"        y += {name}_C[n + 1] * p2;",
        f"        dy += {name}_C[n + 1] * d2;",
        "        p0 = p1; p1 = p2; d0 = d1; d1 = d2;",
        "    }",
    ]
    if structured:
        out.append("    y += dy * (u - v);")
        out.append(
            f"    y += {c_float(m['k'])} * x[1] + {c_float(m['h'])} * x[2] + "
            f"{c_float(m['A'])} * x[3];"
        )
        if m.get("kp") or m.get("k2") or m.get("hT"):
            # issue 23 terms: heating-only rate, R|R|, hysteresis amplitude across T
            # R|R| on the calibrated rate range, its tangent beyond
            rc = "x[1]"
            if "r_lo" in m and "r_hi" in m:
                rc = f"clampf(x[1], {c_float(m['r_lo'])}, {c_float(m['r_hi'])})"
            out += [
                f"    const float rc = {rc};",
                f"    y += {c_float(m.get('kp', 0.0))} * fmaxf(x[1], 0.0f) + "
                f"{c_float(m.get('k2', 0.0))} * (rc * fabsf(rc) + 2.0f * fabsf(rc) * "
                f"(x[1] - rc)) + {c_float(m.get('hT', 0.0))} * x[2] * v;",
            ]
    else:
        out.append("    (void)dy;")
        if m["rate_coef"] is not None:
            out.append(f"    y += {c_float(m['rate_coef'])} * x[1];")
    return [*out, "    return y;", "}"]


def _c_mlp(name: str, m: dict[str, Any]) -> list[str]:
    n, h = len(m["inputs"]), int(m["hidden"])
    flat_w = [v for row in m["W"] for v in row]
    return [
        c_array(f"{name}_W", flat_w) + f"  /* [{n}][{h}] row-major */",
        c_array(f"{name}_A", m["a"]),
        c_array(f"{name}_WO", m["w"]),
        c_array(f"{name}_XM", m["x_mean"]),
        c_array(f"{name}_XS", m["x_std"]),
        c_array(f"{name}_XLO", m["x_min"]),
        c_array(f"{name}_XHI", m["x_max"]),
        f"static float {name}(const float *x)",
        "{",
        f"    float z[{n}], dx[{n}], g[{n}];",
        f"    for (int i = 0; i < {n}; ++i) {{",
        f"        const float c = clampf(x[i], {name}_XLO[i], {name}_XHI[i]);",
        f"        z[i] = (c - {name}_XM[i]) / {name}_XS[i];",
        f"        dx[i] = (x[i] - c) / {name}_XS[i];",
        "        g[i] = 0.0f;",
        "    }",
        f"    float y = {c_float(m['b'])};",
        f"    for (int j = 0; j < {h}; ++j) {{",
        f"        float u = {name}_A[j];",
        f"        for (int i = 0; i < {n}; ++i) u += z[i] * {name}_W[i * {h} + j];",
        "        const float s = 0.5f * (1.0f + tanhf(0.5f * u));  /* logistic */",
        f"        y += s * {name}_WO[j];",
        f"        const float d = s * (1.0f - s) * {name}_WO[j];",
        f"        for (int i = 0; i < {n}; ++i) g[i] += {name}_W[i * {h} + j] * d;",
        "    }",
        "    /* linear continuation outside the calibrated range (0 inside it) */",
        f"    for (int i = 0; i < {n}; ++i) y += g[i] * dx[i];",
        f"    return y * {c_float(m['y_std'])} + {c_float(m['y_mean'])};",
        "}",
    ]


_C: dict[str, Callable[[str, dict[str, Any]], list[str]]] = {
    "poly3": _c_poly3,
    "legendre": _c_legendre,
    "structured": _c_legendre,
    "mlp": _c_mlp,
}

#: What each output map does outside its calibrated range (a line of the C header).
RANGE_RULES = {
    "mlp": "network inputs clipped to the calibrated range, first-order Taylor "
    "continuation beyond it (linear extrapolation)",
    "legendre": "no clamping (the polynomial is evaluated as fitted)",
    "poly3": "temperature clamped to [t_min, t_max] (constant beyond)",
    "structured": "Legendre part in the die temperature F continued linearly beyond "
    "the calibrated range of F",
}


def c_function(name: str, m: dict[str, Any]) -> str:
    """``static float name(const float *x)``: the output map ``m`` on its input vector."""
    try:
        emit = _C[m["kind"]]
    except KeyError:
        raise ValueError(f"no C emitter for model kind {m['kind']!r}") from None
    return "\n".join([f"/* {name}: {m['kind']} */", *emit(name, m)])


__all__ = ["RANGE_RULES", "c_function", "evaluate_inputs"]
