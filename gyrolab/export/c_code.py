"""Dependency-free C99 source of an exported model (:mod:`.spec`), float32.

``gyrolab export MODEL_DIR --format c --out NAME.c`` writes ``NAME.c`` and ``NAME.h``.
The code needs only ``<math.h>`` (``tanhf``) and implements, per axis, exactly the
equations of the JSON schema (:mod:`.spec`): the GA-BP/BP network with its input/output
standardisation and its linear continuation outside the calibrated range, the Legendre
polynomial baseline, or the firmware cubic. Arithmetic is float32; times are double (a
float32 second counter loses milliseconds after 4.6 h).

Use (docs/export.md)::

    gyrolab_comp_state st;
    gyrolab_comp_init(&st);
    /* for every temperature reading, in time order, before the samples at or after it: */
    gyrolab_comp_temperature(&st, t_reading_s, temp_c);
    /* for every gyro sample: */
    float out[GYROLAB_COMP_AXES];
    int ok = gyrolab_comp_apply(&st, t_sample_s, raw_dps, out);  /* out = raw − drift */

The temperature input is the zero-order hold of the readings (the last reading at or
before the sample's time), kept with dT/dt's history in a ring buffer of
``GYROLAB_COMP_HISTORY`` readings (enough for the dT/dt window at the reading rate; when it
overflows the oldest reading is dropped). Before the first reading the output is the raw
rate and ``gyrolab_comp_apply`` returns 0.
"""

from __future__ import annotations

import math
import re
from typing import Any

from gyrolab import __version__


def _lit(v: float) -> str:
    """A float32 C literal that reads back as ``float32(v)``."""
    if not math.isfinite(v):
        raise ValueError(f"non-finite model constant {v}")
    s = f"{v:.9g}"
    if not any(ch in s for ch in ".en"):
        s += ".0"
    return s + "f"


def _arr(name: str, values: list[float]) -> str:
    return f"static const float {name}[{len(values)}] = {{{', '.join(_lit(v) for v in values)}}};"


def _inner_fn(name: str, m: dict[str, Any]) -> str:
    """``static float name(const float *x)``: one model on its input vector ``x``."""
    kind = m["kind"]
    out = [f"/* {name}: {kind} */"]
    if kind == "poly3":
        c = m["coef"]
        out += [
            f"static float {name}(const float *x)",
            "{",
            f"    const float d = clampf(x[0], {_lit(m['t_min'])}, {_lit(m['t_max'])}) - "
            f"{_lit(m['t_ref'])};",
            f"    return {_lit(c[0])} + d * ({_lit(c[1])} + d * ({_lit(c[2])} + d * "
            f"{_lit(c[3])}));",
            "}",
        ]
    elif kind in ("legendre", "structured"):
        c = m["coef"]
        lo, hi = (m["t_lo"], m["t_hi"]) if kind == "legendre" else (m["lo"], m["hi"])
        linear = kind == "structured"  # continued linearly beyond u = ±1
        out += [
            _arr(f"{name}_C", c),
            f"static float {name}(const float *x)",
            "{",
            f"    const float u = (2.0f * x[0] - {_lit(lo + hi)}) / {_lit(hi - lo)};",
            "    const float v = " + ("clampf(u, -1.0f, 1.0f);" if linear else "u;"),
            "    /* Legendre P_n(v) and P_n'(v) by their three-term recurrences */",
            "    float p0 = 1.0f, p1 = v, d0 = 0.0f, d1 = 1.0f;",
            f"    float y = {name}_C[0], dy = 0.0f;",
            f"    if ({len(c)} > 1) {{ y += {name}_C[1] * p1; dy += {name}_C[1] * d1; }}",
            f"    for (int n = 1; n + 1 < {len(c)}; ++n) {{",
            "        const float p2 = ((float)(2 * n + 1) * v * p1 - (float)n * p0) / "
            "(float)(n + 1);",
            "        const float d2 = d0 + (float)(2 * n + 1) * p1;",
            f"        y += {name}_C[n + 1] * p2;",
            f"        dy += {name}_C[n + 1] * d2;",
            "        p0 = p1; p1 = p2; d0 = d1; d1 = d2;",
            "    }",
        ]
        if linear:
            out.append("    y += dy * (u - v);")
        else:
            out.append("    (void)dy;")
        if kind == "structured":
            out.append(
                f"    y += {_lit(m['k'])} * x[1] + {_lit(m['h'])} * x[2] + {_lit(m['A'])} * x[3];"
            )
            if m.get("kp") or m.get("k2") or m.get("hT"):
                # issue 23 terms: heating-only rate, R|R|, hysteresis amplitude across T
                out.append(
                    f"    y += {_lit(m.get('kp', 0.0))} * fmaxf(x[1], 0.0f) + "
                    f"{_lit(m.get('k2', 0.0))} * x[1] * fabsf(x[1]) + "
                    f"{_lit(m.get('hT', 0.0))} * x[2] * v;"
                )
        elif m["rate_coef"] is not None:
            out.append(f"    y += {_lit(m['rate_coef'])} * x[1];")
        out += ["    return y;", "}"]
    elif kind == "mlp":
        n, h = len(m["inputs"]), int(m["hidden"])
        flat_w = [v for row in m["W"] for v in row]
        out += [
            _arr(f"{name}_W", flat_w) + f"  /* [{n}][{h}] row-major */",
            _arr(f"{name}_A", m["a"]),
            _arr(f"{name}_WO", m["w"]),
            _arr(f"{name}_XM", m["x_mean"]),
            _arr(f"{name}_XS", m["x_std"]),
            _arr(f"{name}_XLO", m["x_min"]),
            _arr(f"{name}_XHI", m["x_max"]),
            f"static float {name}(const float *x)",
            "{",
            f"    float z[{n}], dx[{n}], g[{n}];",
            f"    for (int i = 0; i < {n}; ++i) {{",
            f"        const float c = clampf(x[i], {name}_XLO[i], {name}_XHI[i]);",
            f"        z[i] = (c - {name}_XM[i]) / {name}_XS[i];",
            f"        dx[i] = (x[i] - c) / {name}_XS[i];",
            "        g[i] = 0.0f;",
            "    }",
            f"    float y = {_lit(m['b'])};",
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
            f"    return y * {_lit(m['y_std'])} + {_lit(m['y_mean'])};",
            "}",
        ]
    else:
        raise ValueError(f"no C emitter for model kind {kind!r}")
    return "\n".join(out)


def _axis_fn(k: int, m: dict[str, Any]) -> str:
    """The drift function(s) of axis ``k``: ``model_k`` on its inputs, and for a causal
    model ``features_k``, its state machine (:func:`.spec.causal_readings`), float32."""
    if m["kind"] != "causal":
        return _inner_fn(f"model_{k}", m)
    f = m["features"]
    tau, tau_r = f["tau_s"], max(f["tau_s"], f["rate_tau_min_s"])
    half = 0.5 * f["width_c"]
    a = f"-expm1f(-dt / {_lit(tau)})" if tau > 0 else "1.0f"
    return "\n".join(
        [
            _inner_fn(f"model_{k}", m["model"]),
            f"/* axis {k}: causal features (family {m['family']}); x = F, R, S, E */",
            f"static void features_{k}(gyrolab_comp_state *s, float T, float dt, double t)",
            "{",
            f"    const float a = {a};",
            f"    s->F[{k}] += a * (T - s->F[{k}]);",
            f"    s->G[{k}] += -expm1f(-dt / {_lit(tau_r)}) * (T - s->G[{k}]);",
            f"    s->p[{k}] = clampf(s->p[{k}], s->F[{k}] - {_lit(half)}, "
            f"s->F[{k}] + {_lit(half)});",
            f"    const float x[4] = {{s->F[{k}], (T - s->G[{k}]) / {_lit(tau_r)},",
            f"                        (s->F[{k}] - s->p[{k}]) / {_lit(half)},",
            f"                        expf(-(float)(t / {f['warmup_tau_s']!r}))}};",
            f"    s->held[{k}] = model_{k}(x);",
            "}",
        ]
    )


def _window(spec: dict[str, Any]) -> float | None:
    ws = {a["model"].get("dtdt_window_s") for a in spec["axes"]} - {None}
    if len(ws) > 1:
        raise ValueError("axes with different dT/dt windows")
    return ws.pop() if ws else None


def generate(spec: dict[str, Any], header_name: str) -> tuple[str, str]:
    """``(header text, source text)`` for the export ``spec``; the source includes
    ``header_name``."""
    axes = spec["axes"]
    n_ax = len(axes)
    w = _window(spec)
    causal = [a["model"]["kind"] == "causal" for a in axes]
    guard = re.sub(r"[^A-Za-z0-9]", "_", header_name).upper()
    kinds = ", ".join(f"{a['axis']}: {a['model']['kind']}" for a in axes)
    ranges = "; ".join(
        f"{a['axis']}: {a['calibration_range_c'][0]:.3f} .. {a['calibration_range_c'][1]:.3f} °C"
        for a in axes
    )
    clamp_rule = {
        "mlp": "network inputs clipped to the calibrated range, first-order Taylor "
        "continuation beyond it (linear extrapolation)",
        "legendre": "no clamping (the polynomial is evaluated as fitted)",
        "poly3": "temperature clamped to [t_min, t_max] (constant beyond)",
        "structured": "Legendre part in the die temperature F continued linearly beyond "
        "the calibrated range of F",
    }

    def rule(m: dict[str, Any]) -> str:
        if m["kind"] == "causal":
            return f"causal {m['family']}: " + clamp_rule[m["model"]["kind"]]
        return clamp_rule[m["kind"]]

    rules = "\n".join(f" *   axis {a['axis']}: {rule(a['model'])}" for a in axes)
    hist = "1024" if w is not None else "4"
    inputs = "T(t)" if w is None else "T(t), dT/dt(t)"
    zoh = "" if w is None else f"; dT/dt = (T(t) - T(t - {w:g})) / {w:g}"
    causal_note = (
        " *\n * Causal axes: a state machine (die temperature F, rate R, hysteresis branch S,\n"
        " * warm-up E) runs at every temperature reading; its drift is held until the next.\n"
        " * t_s is the time since power-on (the warm-up term uses it). Push each reading\n"
        " * before the samples at or after its time.\n"
        if any(causal)
        else ""
    )
    header = f"""/* {header_name}: gyro temperature-drift compensation, generated by
 * gyrolab {__version__} from {spec["model_dir"]}
 * (model kind {spec["model_kind"]}; {kinds}).
 * Export schema {spec["format"]} v{spec["format_version"]}. C99, float32, needs <math.h> only.
 *
 * out = raw - drift({inputs}), rates in deg/s, temperature in degC, times in s.
 * T(t) is the last temperature reading at or before t (zero-order hold){zoh}.
 * Calibrated range: {ranges}.
 * Outside it:
{rules}
{causal_note} */
#ifndef {guard}
#define {guard}

#define GYROLAB_COMP_AXES {n_ax}
#ifndef GYROLAB_COMP_HISTORY
#define GYROLAB_COMP_HISTORY {hist}  /* temperature readings kept (dT/dt window) */
#endif

typedef struct {{
    int n;                                  /* readings held */
    int head;                               /* index of the oldest */
    double t[GYROLAB_COMP_HISTORY];         /* reading times, s */
    float temp[GYROLAB_COMP_HISTORY];       /* readings, degC */
    double t_last;                          /* causal axes: time of the last reading */
    float F[GYROLAB_COMP_AXES], G[GYROLAB_COMP_AXES], p[GYROLAB_COMP_AXES];
    float held[GYROLAB_COMP_AXES];          /* causal axes: drift held since the reading */
}} gyrolab_comp_state;

void gyrolab_comp_init(gyrolab_comp_state *s);
/* Add a temperature reading (times increasing). */
void gyrolab_comp_temperature(gyrolab_comp_state *s, double t_s, float temp_c);
/* Drift of every axis at time t_s (deg/s); returns 0 (drift 0) before the first reading. */
int gyrolab_comp_drift(const gyrolab_comp_state *s, double t_s, float drift_dps[]);
/* out[a] = raw_dps[a] - drift; returns 0 (out = raw) before the first reading. */
int gyrolab_comp_apply(const gyrolab_comp_state *s, double t_s, const float raw_dps[],
                       float out_dps[]);

#endif /* {guard} */
"""
    body = "\n\n".join(_axis_fn(k, a["model"]) for k, a in enumerate(axes))
    w_lit = "0.0" if w is None else repr(float(w))
    calls = "\n".join(
        f"    drift_dps[{k}] = s->held[{k}];" if c else f"    drift_dps[{k}] = model_{k}(x);"
        for k, c in enumerate(causal)
    )
    need_t = not all(causal)
    dtdt = (
        ""
        if not need_t
        else "    const float T = zoh(s, t_s);\n"
        + (
            "    const float x[2] = {T, 0.0f};"
            if w is None
            else "    const float Tp = zoh(s, t_s - DTDT_WINDOW_S);\n"
            f"    const float x[2] = {{T, (T - Tp) / {_lit(w)}}};"
        )
    )
    if not need_t:
        dtdt = "    (void)t_s;"
    updates = "\n".join(
        f"    features_{k}(s, temp_c, first ? 0.0f : (float)(t_s - s->t_last), t_s);"
        for k, c in enumerate(causal)
        if c
    )
    init_causal = "\n".join(
        f"        s->F[{k}] = s->G[{k}] = s->p[{k}] = temp_c;" for k, c in enumerate(causal) if c
    )
    causal_push = (
        f"""    const int first = s->n == 0;
    if (first) {{
{init_causal}
    }}
{updates}
    s->t_last = t_s;
"""
        if any(causal)
        else ""
    )
    clampf = (
        "static float clampf(float x, float lo, float hi)\n{\n"
        "    return x < lo ? lo : (x > hi ? hi : x);\n}\n"
        if any(
            a["model"]["kind"] in ("mlp", "poly3", "causal")
            or a["model"].get("model", {}).get("kind") == "structured"
            for a in axes
        )
        else ""
    )
    zoh_fn = (
        """/* the last reading at or before tq (the oldest held when tq precedes them all) */
static float zoh(const gyrolab_comp_state *s, double tq)
{
    for (int k = s->n - 1; k >= 0; --k) {
        const int i = (s->head + k) % GYROLAB_COMP_HISTORY;
        if (s->t[i] <= tq) return s->temp[i];
    }
    return s->temp[s->head];
}
"""
        if need_t
        else ""
    )
    source = f"""/* Generated by gyrolab {__version__}; see {header_name} for what it computes. */
#include "{header_name}"

#include <math.h>

#define DTDT_WINDOW_S {w_lit}

{clampf}
{body}

void gyrolab_comp_init(gyrolab_comp_state *s)
{{
    s->n = 0;
    s->head = 0;
    s->t_last = 0.0;
    for (int a = 0; a < GYROLAB_COMP_AXES; ++a) s->F[a] = s->G[a] = s->p[a] = s->held[a] = 0.0f;
}}

void gyrolab_comp_temperature(gyrolab_comp_state *s, double t_s, float temp_c)
{{
{causal_push}    /* forget readings no later query can need: the oldest goes once the next one is at
       or before t_s - window (samples come at or after t_s) */
    while (s->n >= 2 && s->t[(s->head + 1) % GYROLAB_COMP_HISTORY] <= t_s - DTDT_WINDOW_S) {{
        s->head = (s->head + 1) % GYROLAB_COMP_HISTORY;
        s->n--;
    }}
    if (s->n == GYROLAB_COMP_HISTORY) {{ /* overflow: drop the oldest */
        s->head = (s->head + 1) % GYROLAB_COMP_HISTORY;
        s->n--;
    }}
    const int i = (s->head + s->n) % GYROLAB_COMP_HISTORY;
    s->t[i] = t_s;
    s->temp[i] = temp_c;
    s->n++;
}}

{zoh_fn}
int gyrolab_comp_drift(const gyrolab_comp_state *s, double t_s, float drift_dps[])
{{
    if (s->n == 0) {{
        for (int a = 0; a < GYROLAB_COMP_AXES; ++a) drift_dps[a] = 0.0f;
        return 0;
    }}
{dtdt}
{calls}
    return 1;
}}

int gyrolab_comp_apply(const gyrolab_comp_state *s, double t_s, const float raw_dps[],
                       float out_dps[])
{{
    float d[GYROLAB_COMP_AXES];
    const int ok = gyrolab_comp_drift(s, t_s, d);
    for (int a = 0; a < GYROLAB_COMP_AXES; ++a) out_dps[a] = raw_dps[a] - d[a];
    return ok;
}}
"""
    return header, source
