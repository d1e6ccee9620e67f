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

import re
from typing import Any

from gyrolab import __version__
from gyrolab.compensation.drift_model import CModel, c_float


def _axis_code(k: int, m: dict[str, Any]) -> CModel:
    """Axis ``k``'s drift model in C: its kind's :class:`CModel` (names prefixed
    ``m{k}_``)."""
    from gyrolab.compensation.families import spec_kind

    return spec_kind(m["kind"]).c_model(m, f"m{k}_")


def _window(models: list[CModel]) -> float | None:
    ws = {c.window_s for c in models} - {None}
    if len(ws) > 1:
        raise ValueError("axes with different dT/dt windows")
    return ws.pop() if ws else None


def include_guard(header_name: str) -> str:
    """The header's include guard: its file name with every character that cannot be in a C
    identifier replaced by ``_``, upper case, prefixed ``GYROLAB_`` when it would start with
    a digit (``1bad-name;x.h`` → ``GYROLAB_1BAD_NAME_X_H``: a macro name must not, C11
    6.4.2.1)."""
    guard = re.sub(r"[^A-Za-z0-9]", "_", header_name).upper()
    return f"GYROLAB_{guard}" if not guard or guard[0].isdigit() else guard


def check_header_name(header_name: str) -> None:
    """ValueError for a header name that ``#include "NAME"`` cannot carry: a double quote,
    a backslash or a control character (C11 6.4.7)."""
    if re.search(r'["\\\x00-\x1f\x7f]', header_name):
        raise ValueError(
            f"{header_name!r} cannot be named in an #include line (no quote, backslash or "
            "control character)"
        )


def _axis_functions(k: int, c: CModel) -> str:
    """The model's code and its ``reading``/``sample`` bodies as static functions on the
    axis's state (parameters a body does not use are voided: -Wall -Wextra clean)."""
    st = f"gyrolab_comp_axis{k}" if c.state else "void"
    params_r = ("st", "T", "dt", "t", "first")
    params_s = ("st", "x", "t_s")
    unused_r = "".join(f"    (void){p};\n" for p in params_r)
    unused_s = "".join(f"    (void){p};\n" for p in params_s)
    return f"""{c.code}

/* axis {k}: one temperature reading (T degC, dt s since the previous one, t s) */
static void m{k}_reading({st} *st, float T, float dt, double t, int first)
{{
{unused_r}{c.reading}
}}

/* axis {k}: the drift (deg/s) at a sample (x: held T and dT/dt) */
static float m{k}_sample(const {st} *st, const float *x, double t_s)
{{
{unused_s}{c.sample}
}}"""


def generate(spec: dict[str, Any], header_name: str) -> tuple[str, str]:
    """``(header text, source text)`` for the export ``spec``; the source includes
    ``header_name``. Each axis's model comes from its kind (:class:`CModel`); this frame
    keeps the temperature readings (the hold and the dT/dt window), the axes' states and
    the public functions of the module docstring."""
    axes = spec["axes"]
    n_ax = len(axes)
    models = [_axis_code(k, a["model"]) for k, a in enumerate(axes)]
    w = _window(models)
    need_x = any(c.uses_temperature for c in models)
    check_header_name(header_name)
    guard = include_guard(header_name)
    kinds = ", ".join(f"{a['axis']}: {a['model']['kind']}" for a in axes)
    ranges = "; ".join(
        f"{a['axis']}: {a['calibration_range_c'][0]:.3f} .. {a['calibration_range_c'][1]:.3f} °C"
        for a in axes
    )
    rules = "\n".join(f" *   axis {a['axis']}: {c.note}" for a, c in zip(axes, models, strict=True))
    hist = "1024" if w is not None else "4"
    inputs = "T(t)" if w is None else "T(t), dT/dt(t)"
    zoh = "" if w is None else f"; dT/dt = (T(t) - T(t - {w:g})) / {w:g}"
    stateful = any(c.state for c in models)
    causal_note = (
        " *\n * Causal axes: a state machine (e.g. die temperature F, rate R, hysteresis branch\n"
        " * S, warm-up E) runs at every temperature reading; its drift is held until the next.\n"
        " * t_s is the time since power-on (a warm-up term uses it). Push each reading\n"
        " * before the samples at or after its time.\n"
        if stateful
        else ""
    )
    axis_types = "".join(
        f"typedef struct {{ {'; '.join(c.state)}; }} gyrolab_comp_axis{k};\n"
        for k, c in enumerate(models)
        if c.state
    )
    axis_members = "".join(
        f"    gyrolab_comp_axis{k} a{k};\n" for k, c in enumerate(models) if c.state
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

{axis_types}
typedef struct {{
    int n;                                  /* readings held */
    int head;                               /* index of the oldest */
    double t[GYROLAB_COMP_HISTORY];         /* reading times, s */
    float temp[GYROLAB_COMP_HISTORY];       /* readings, degC */
    double t_last;                          /* time of the last reading */
{axis_members}}} gyrolab_comp_state;

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
    body = "\n\n".join(_axis_functions(k, c) for k, c in enumerate(models))

    def axis_state(k: int, c: CModel) -> str:
        return f"&s->a{k}" if c.state else "NULL"

    readings = "\n".join(
        f"    m{k}_reading({axis_state(k, c)}, temp_c, dt, t_s, first);"
        for k, c in enumerate(models)
    )
    samples = "\n".join(
        f"    drift_dps[{k}] = m{k}_sample({axis_state(k, c)}, x, t_s);"
        for k, c in enumerate(models)
    )
    w_lit = "0.0" if w is None else repr(float(w))
    if not need_x:
        inputs_c = "    const float x[2] = {0.0f, 0.0f};"
    elif w is None:
        inputs_c = "    const float x[2] = {zoh(s, t_s), 0.0f};"
    else:
        inputs_c = (
            "    const float T = zoh(s, t_s);\n"
            "    const float Tp = zoh(s, t_s - DTDT_WINDOW_S);\n"
            f"    const float x[2] = {{T, (T - Tp) / {c_float(w)}}};"
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
        if need_x
        else ""
    )
    init_states = "".join(
        f"    memset(&s->a{k}, 0, sizeof s->a{k});\n" for k, c in enumerate(models) if c.state
    )
    source = f"""/* Generated by gyrolab {__version__}; see {header_name} for what it computes. */
#include "{header_name}"

#include <math.h>
#include <stddef.h>
#include <string.h>

#define DTDT_WINDOW_S {w_lit}

static inline float clampf(float x, float lo, float hi)
{{
    return x < lo ? lo : (x > hi ? hi : x);
}}

{body}

void gyrolab_comp_init(gyrolab_comp_state *s)
{{
    s->n = 0;
    s->head = 0;
    s->t_last = 0.0;
{init_states}}}

void gyrolab_comp_temperature(gyrolab_comp_state *s, double t_s, float temp_c)
{{
    const int first = s->n == 0;
    const float dt = first ? 0.0f : (float)(t_s - s->t_last);
{readings}
    s->t_last = t_s;
    /* forget readings no later query can need: the oldest goes once the next one is at
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
{inputs_c}
{samples}
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
