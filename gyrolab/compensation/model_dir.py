"""The model directory and its one owner, :class:`ModelDir`: no other module opens its
files (``tests/test_architecture.py`` checks that no other module names them).

Layout (``MODEL_FORMAT_VERSION`` 1) of a single-axis model directory::

    MODEL_DIR/
      model.json         format name + version, software version, the pipeline
                         configuration, VMD (K, alpha), mode classes and MPE values, FLP
                         settings, every drift model's metadata (the paper's drift model,
                         the baselines, the causal model: each one's ``save``), the
                         calibration run's summary
      arrays.npz         every array, numpy ``.npz`` (read with ``allow_pickle=False``):
                         decimated calibration series, VMD modes and centre frequencies,
                         GPSO history, drift target and fit, network weights, polynomial
                         coefficients
      drift_gabp.pt      the paper's drift model's network as a ``torch.nn.Sequential``
      baseline_bp.pt     state dict, and the plain-BP baseline's (both load with
                         ``torch.load(..., weights_only=True)``; the .npz is authoritative)
      metrics.json       what ``gyrolab compensate`` measured (docs/cli.md keys)
      firmware.json      the firmware cubic (:mod:`.firmware`)
      results.json       what the report reads instead of applying the model again
      results.npz        (:mod:`.results`)

A multi-axis model directory holds one single-axis model directory per axis
(``axis_x/``, ``axis_y/``, ``axis_z/``) and a head ``model.json`` (``axes``,
``axis_dirs``) and ``metrics.json`` (``{"axes": {...}, "held_out", "timing_s"}``); a
single-axis unit keeps the single-axis layout, so everything written before axis counts
existed reads as before.

Nothing is pickled: a model directory can be read by any numpy/JSON reader, and loading
it never runs code from the file. Every file is checked when read: a directory whose
``format`` or ``format_version`` this gyrolab does not know, a damaged file, a
non-finite number anywhere in a JSON file (``NaN``, ``Infinity``, ``1e999``), a
non-finite value in an array (NaN is allowed only in the Allan confidence bounds of
results.npz, where a bound is undefined, and in the training histories), or a value
outside its physical range (a calibration range beyond −273.15…1000 °C or reversed, a
non-positive rate, window, VMD penalty or count, a configuration value its key refuses:
:mod:`.model_checks`) is an :class:`~gyrolab.errors.InputError` naming the file and the
field (one line, exit 2) — never a model that runs with a guard silently off.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import zipfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from gyrolab import __version__
from gyrolab.compensation.causal import causal_from_state, causal_state
from gyrolab.compensation.config import PipelineConfig, check_config_dict
from gyrolab.compensation.firmware import Poly3
from gyrolab.compensation.fit import CompensationModel
from gyrolab.compensation.flp import ForwardLinearPredictor
from gyrolab.compensation.model_checks import NonFinite, bad_number, check_model_meta
from gyrolab.compensation.results import RunResults, results_from_parts, results_to_parts
from gyrolab.compensation.temperature_model import load_temperature_model
from gyrolab.errors import InputError
from gyrolab.outputs import json_safe
from gyrolab.record.format import AXIS_NAMES

MODEL_FORMAT = "gyrolab.compensation-model"
MODEL_FORMAT_VERSION = 1
RESULTS_FORMAT = "gyrolab.compensation-results"
RESULTS_FORMAT_VERSION = 1


def _read_json(path: Path) -> Any:
    """A JSON file of the model directory, every number finite (module docstring)."""
    try:
        obj = json.loads(path.read_text(encoding="utf-8"), parse_constant=NonFinite)
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(path, f"damaged file ({e.__class__.__name__})") from None
    except OSError as e:
        raise InputError(path, f"cannot be read ({e.strerror or e.__class__.__name__})") from None
    bad = bad_number(obj)
    if bad:
        raise InputError(path, f"{bad[0] or 'the value'} is {bad[1]}: not a finite number")
    return obj


def _write_json(path: Path, obj: Any) -> None:
    path.write_text(json.dumps(json_safe(obj), indent=2, sort_keys=False) + "\n")


def _read_npz(path: Path, may_be_nan: Callable[[str], bool]) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` (no pickles), each float array finite except those
    ``may_be_nan`` names (NaN there, never ±inf)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise InputError(path, "missing") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise InputError(path, f"damaged arrays ({e.__class__.__name__})") from None
    for k, a in arrays.items():
        if a.dtype.kind not in "fc":
            continue
        bad = ~np.isfinite(a)
        if may_be_nan(k):
            bad = np.isinf(a)
        if bad.any():
            raise InputError(
                path, f"{k} has {int(bad.sum())} non-finite value(s) of {a.size}: refused"
            )
    return arrays


class ModelDir:
    """One model directory (module docstring): the only reader and writer of its files.

    ``ModelDir(path)`` names it; nothing is read until asked. Reads check every file
    (:class:`InputError` naming file and field); writes go into a directory the caller
    makes atomic (:func:`gyrolab.outputs.atomic_dir`)."""

    MODEL_JSON = "model.json"
    ARRAYS_NPZ = "arrays.npz"
    METRICS_JSON = "metrics.json"
    FIRMWARE_JSON = "firmware.json"
    RESULTS_JSON = "results.json"
    RESULTS_NPZ = "results.npz"

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"ModelDir({str(self.path)!r})"

    def __fspath__(self) -> str:
        return str(self.path)

    def __str__(self) -> str:
        return str(self.path)

    # ------------------------------------------------------------------ what it is

    @classmethod
    def is_model_dir(cls, path: str | os.PathLike[str]) -> bool:
        """Whether ``path`` holds a model (its ``model.json``)."""
        return (Path(path) / cls.MODEL_JSON).is_file()

    @classmethod
    def find(cls, paths: Iterable[str | os.PathLike[str]], depth: int = 3) -> list[ModelDir]:
        """Each path: a model directory, or a directory holding model directories
        (searched ``depth`` levels deep, hidden and temporary directories skipped).
        Sorted, unique."""
        out: list[ModelDir] = []
        seen: set[Path] = set()
        for p in map(Path, paths):
            if not p.is_dir():
                raise InputError(p, "not a directory (expected a MODEL_DIR or a directory of them)")
            if cls.is_model_dir(p):
                found = [p]
            else:
                patterns = ["/".join(["*"] * k + [cls.MODEL_JSON]) for k in range(1, depth + 1)]
                found = sorted(
                    m.parent
                    for pattern in patterns
                    for m in p.glob(pattern)
                    if not any(part.startswith(".") for part in m.relative_to(p).parts)
                )
            if not found:
                raise InputError(p, f"holds no model directory (no {cls.MODEL_JSON})")
            for f in found:
                if f.resolve() not in seen:
                    seen.add(f.resolve())
                    out.append(cls(f))
        return out

    def _file(self, name: str) -> Path:
        return self.path / name

    def head(self) -> dict[str, Any]:
        """model.json, checked: present, readable, a gyrolab model of a format version
        this gyrolab reads, every number finite."""
        if not self.path.is_dir():
            raise InputError(self.path, "model directory not found")
        mj = self._file(self.MODEL_JSON)
        if not mj.is_file():
            raise InputError(self.path, f"not a gyrolab model directory (no {self.MODEL_JSON})")
        meta = _read_json(mj)
        if not isinstance(meta, dict) or meta.get("format") != MODEL_FORMAT:
            fmt = meta.get("format") if isinstance(meta, dict) else None
            raise InputError(self.path, f"not a gyrolab compensation model (format {fmt!r})")
        ver = meta.get("format_version")
        if ver != MODEL_FORMAT_VERSION:
            raise InputError(
                self.path,
                f"model format version {ver} (written by gyrolab "
                f"{meta.get('software_version')}); this gyrolab {__version__} reads version "
                f"{MODEL_FORMAT_VERSION} — refit with `gyrolab compensate`",
            )
        return meta

    def axes(self) -> list[tuple[str, ModelDir]]:
        """``[(axis name, single-axis model directory)]`` (``[("x", self)]`` for a
        single-axis one)."""
        meta = self.head()
        dirs = meta.get("axis_dirs")
        if not dirs:
            return [("x", self)]
        names = meta.get("axes") or []
        if len(names) != len(dirs):
            raise InputError(self._file(self.MODEL_JSON), "axes and axis_dirs differ in length")
        out = []
        for a, s in zip(names, dirs, strict=True):
            sub = self.path / str(s)
            if Path(str(s)).name != str(s) or not sub.is_dir():
                raise InputError(self._file(self.MODEL_JSON), f"axis directory {s!r} not found")
            out.append((str(a), ModelDir(sub)))
        return out

    # ------------------------------------------------------------------ the model

    def load(self) -> CompensationModel:
        """The fitted model of a single-axis model directory (module docstring)."""
        meta = self.head()
        mj = self._file(self.MODEL_JSON)
        if meta.get("axis_dirs"):
            raise InputError(
                self.path,
                f"a {len(meta['axis_dirs'])}-axis model: give one axis's directory "
                f"({', '.join(str(x) for x in meta['axis_dirs'])} inside it)",
            )
        npz = self._file(self.ARRAYS_NPZ)
        if not npz.is_file():
            raise InputError(self.path, f"model directory is missing {self.ARRAYS_NPZ}")
        arrays = _read_npz(npz, lambda k: k.endswith("_history"))
        bad = check_model_meta(meta)
        if bad is None:
            try:
                check_config_dict(meta.get("config") or {})
            except InputError as e:
                bad = f"config.{e.problem}"
        if bad:
            raise InputError(mj, bad)
        try:
            return _model_from(meta, arrays)
        except (KeyError, TypeError, ValueError, IndexError) as e:
            raise InputError(mj, f"incomplete or damaged model ({e})") from None

    def write_model(self, model: CompensationModel) -> None:
        """Write model.json, arrays.npz and the ``.pt`` state dicts of ``model``."""
        meta, arrays, torch_states = _model_parts(model)
        head = {
            "format": MODEL_FORMAT,
            "format_version": MODEL_FORMAT_VERSION,
            "software_version": __version__,
        }  # no clock readings: same inputs and seed give the same bytes (when: the marker)
        _write_json(self._file(self.MODEL_JSON), {**head, **meta})
        for k, a in arrays.items():
            if a.dtype == object:
                raise TypeError(f"array {k!r} has dtype object; the model format stores no pickles")
        np.savez_compressed(self._file(self.ARRAYS_NPZ), **arrays)
        if torch_states:
            import torch  # heavy: imported only when a network is written

            for name, state in torch_states.items():
                torch.save(state, self._file(f"{name}.pt"))

    # ------------------------------------------------------------ what was measured

    def metrics(self) -> dict[str, Any] | None:
        """metrics.json (``None`` when there is none)."""
        p = self._file(self.METRICS_JSON)
        if not p.is_file():
            return None
        m = _read_json(p)
        if not isinstance(m, dict):
            raise InputError(p, "not a metrics object")
        return m

    def require_metrics(self) -> dict[str, Any]:
        m = self.metrics()
        if m is None:
            raise InputError(self.path, f"not a gyrolab model directory (no {self.METRICS_JSON})")
        return m

    def run_metrics(self, role: str) -> dict[str, Any] | None:
        """``compensate``'s metrics of the run of ``role`` (the top level, or
        ``calibration`` for the calibration run of a ``--validate`` fit); ``None`` when
        the file or the entry is missing."""
        m = self.metrics()
        if m is None:
            return None
        if role == "calibration" and isinstance(m.get("calibration"), dict):
            m = m["calibration"]
        return m if isinstance(m, dict) and "raw" in m else None

    def write_metrics(self, metrics: dict[str, Any]) -> None:
        _write_json(self._file(self.METRICS_JSON), metrics)

    def firmware(self) -> Poly3 | None:
        """The firmware cubic (``None`` for a model fitted before it existed)."""
        p = self._file(self.FIRMWARE_JSON)
        if not p.is_file():
            return None
        d = _read_json(p)
        try:
            p3 = Poly3.from_dict(d["poly3"])
        except (KeyError, TypeError, ValueError, IndexError) as e:
            raise InputError(p, f"damaged firmware polynomial ({e!r})") from None
        if not p3.t_min <= p3.t_max:
            raise InputError(p, f"poly3.t_min_c = {p3.t_min!r} exceeds t_max_c = {p3.t_max!r}")
        return p3

    def require_firmware(self) -> Poly3:
        p3 = self.firmware()
        if p3 is None:
            raise InputError(
                self.path,
                f"model has no {self.FIRMWARE_JSON} (fitted by an older gyrolab: refit it)",
            )
        return p3

    def write_firmware(self, p3: Poly3) -> None:
        _write_json(self._file(self.FIRMWARE_JSON), {"poly3": p3.to_dict()})

    def results(self) -> dict[str, RunResults]:
        """What ``compensate`` computed on each run it evaluated, by role; ``{}`` when the
        directory has none (written before they were kept)."""
        rj, rn = self._file(self.RESULTS_JSON), self._file(self.RESULTS_NPZ)
        if not rj.is_file():
            return {}
        meta = _read_json(rj)
        if not isinstance(meta, dict) or meta.get("format") != RESULTS_FORMAT:
            raise InputError(rj, "not a gyrolab results file")
        if meta.get("format_version") != RESULTS_FORMAT_VERSION:
            raise InputError(
                rj,
                f"results format version {meta.get('format_version')} (written by gyrolab "
                f"{meta.get('software_version')}); this gyrolab reads version "
                f"{RESULTS_FORMAT_VERSION} — refit with `gyrolab compensate`",
            )
        arrays = _read_npz(rn, lambda k: ".allan." in k and k.endswith((".lo", ".hi")))
        try:
            return results_from_parts(meta["runs"], arrays)
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(rj, f"incomplete or damaged results ({e!r})") from None

    def write_results(self, runs: list[RunResults]) -> None:
        meta, arrays = results_to_parts(runs)
        _write_json(
            self._file(self.RESULTS_JSON),
            {
                "format": RESULTS_FORMAT,
                "format_version": RESULTS_FORMAT_VERSION,
                "software_version": __version__,
                "runs": meta,
            },
        )
        np.savez_compressed(self._file(self.RESULTS_NPZ), **arrays)

    # -------------------------------------------------------------------- axes

    @staticmethod
    def axis_dir_name(k: int) -> str:
        return f"axis_{AXIS_NAMES[k]}"

    def new_axis(self, k: int) -> ModelDir:
        """The directory of axis ``k`` of a multi-axis model being written (created)."""
        sub = self.path / self.axis_dir_name(k)
        sub.mkdir()
        return ModelDir(sub)

    def write_head(self, n_axes: int, axis_metrics: list[dict[str, Any]]) -> None:
        """The head ``model.json`` and ``metrics.json`` of a multi-axis model directory."""
        names = list(AXIS_NAMES[:n_axes])
        _write_json(
            self._file(self.MODEL_JSON),
            {
                "format": MODEL_FORMAT,
                "format_version": MODEL_FORMAT_VERSION,
                "software_version": __version__,
                "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "axes": names,
                "axis_dirs": [self.axis_dir_name(k) for k in range(n_axes)],
            },
        )
        self.write_metrics(
            {
                "axes": dict(zip(names, axis_metrics, strict=True)),
                "held_out": bool(axis_metrics[0]["held_out"]),
                "timing_s": float(sum(m["timing_s"] for m in axis_metrics)),
            }
        )

    def digest(self) -> str:
        """The model's identity, ``sha256:<hex>``: the SHA-256 of its ``model.json`` (which
        holds every setting and no clock reading: the same fit gives the same bytes); for a
        2–3-axis model, of the head ``model.json`` followed by each axis's, in the head's
        order (the catalogue's key, docs/fleet.md)."""
        data = self._file(self.MODEL_JSON).read_bytes()
        h = hashlib.sha256(data)
        try:
            dirs = json.loads(data).get("axis_dirs")
        except (ValueError, AttributeError):
            dirs = None
        for name in dirs if isinstance(dirs, list) else []:
            h.update((self.path / str(name) / self.MODEL_JSON).read_bytes())
        return "sha256:" + h.hexdigest()

    def run_records(self) -> dict[str, dict[str, Any]]:
        """results.json's record of each run ``compensate`` evaluated (``path``,
        ``content_hash``, ``held_out``, …) by role, without the arrays; ``{}`` when there
        are none. Checked as :meth:`results` checks it."""
        rj = self._file(self.RESULTS_JSON)
        if not rj.is_file():
            return {}
        meta = _read_json(rj)
        runs = meta.get("runs") if isinstance(meta, dict) else None
        if meta.get("format") != RESULTS_FORMAT or not isinstance(runs, dict):
            raise InputError(rj, "not a gyrolab results file")
        return runs

    def files(self) -> Iterator[Path]:
        """Every file of the directory (and of its axis directories)."""
        yield from (p for p in self.path.rglob("*") if p.is_file())


# ------------------------------------------------------------------ model <-> parts


def _model_parts(
    model: CompensationModel,
) -> tuple[dict[str, Any], dict[str, np.ndarray], dict[str, dict[str, Any]]]:
    """model.json's content (after the format head), arrays.npz's arrays and the torch
    state dicts of ``model`` (each drift model through its interface)."""
    arrays: dict[str, np.ndarray] = {k: np.asarray(v) for k, v in model.diagnostics.items()}
    cmeta = None
    if model.causal is not None:
        cmeta, carr = causal_state(model.causal, "causal.")
        arrays.update(carr)
    dmeta, darr = model.drift.save("drift.")
    arrays.update(darr)
    bmeta: dict[str, Any] = {}
    for name, m in model.baselines.items():
        bmeta[name], arr = m.save(f"baseline.{name}.")
        arrays.update(arr)
    meta = {
        "seed": model.seed,
        "config": model.config.to_dict(),
        "vmd": {"K": model.K, "alpha": model.alpha},
        "decomposition": model.decomposition_info,
        "drift_model": dmeta,
        "baselines": bmeta,
        "calibration": model.calibration,
        "flp": {
            "mixed": None if model.flp_mixed is None else model.flp_mixed.to_dict(),
            "stream": None if model.flp_stream is None else model.flp_stream.to_dict(),
        },
        "causal_model": cmeta,
        "streaming": {
            "temperature": "zero-order hold of the last PT100 reading",
            "dtdt": "backward difference over config.dtdt_window_s"
            if model.config.use_dtdt
            else None,
        },
    }
    torch_states = {}
    sd = model.drift.torch_state()
    if sd is not None:
        torch_states["drift_gabp"] = sd
    for name, m in model.baselines.items():
        sd = m.torch_state()
        if sd is not None:
            torch_states[f"baseline_{name}"] = sd
    return meta, arrays, torch_states


def _model_from(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> CompensationModel:
    flp = meta.get("flp") or {}
    flp_mixed, flp_stream = flp.get("mixed"), flp.get("stream")
    cfg = PipelineConfig.from_dict(meta["config"])
    drift = load_temperature_model(meta["drift_model"], arrays, "drift.", cfg, cfg.drift_model)
    baselines = {
        name: load_temperature_model(bm, arrays, f"baseline.{name}.", cfg, name)
        for name, bm in meta.get("baselines", {}).items()
    }
    diagnostics = {
        k: v for k, v in arrays.items() if not k.startswith(("drift.", "baseline.", "causal."))
    }
    cmeta = meta.get("causal_model")
    causal = None if cmeta is None else causal_from_state(cmeta, arrays, "causal.")
    return CompensationModel(
        config=cfg,
        drift=drift,
        baselines=baselines,
        K=int(meta["vmd"]["K"]),
        alpha=float(meta["vmd"]["alpha"]),
        calibration=dict(meta.get("calibration", {})),
        flp_mixed=None if flp_mixed is None else ForwardLinearPredictor.from_dict(flp_mixed),
        flp_stream=None if flp_stream is None else ForwardLinearPredictor.from_dict(flp_stream),
        diagnostics=diagnostics,
        decomposition_info=dict(meta.get("decomposition", {})),
        timing_s=dict(meta.get("timing_s", {})),
        causal=causal,
        seed=None if meta.get("seed") is None else int(meta["seed"]),
    )


# ----------------------------------------------------------- the common calls


def load_model(directory: str | os.PathLike[str]) -> CompensationModel:
    """The model of a single-axis model directory (:meth:`ModelDir.load`)."""
    return ModelDir(directory).load()


def save_model(model: CompensationModel, directory: str | os.PathLike[str]) -> None:
    """Write ``model`` into an existing directory (:meth:`ModelDir.write_model`)."""
    ModelDir(directory).write_model(model)


__all__ = [
    "MODEL_FORMAT",
    "MODEL_FORMAT_VERSION",
    "ModelDir",
    "load_model",
    "save_model",
]
