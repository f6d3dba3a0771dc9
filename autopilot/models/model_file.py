"""The fuzzy model file (JSON) the identification writes and the autopilot loads.

Layout (format "ivfm-fuzzy-model", version 1; MF arrays are [cluster][input][h, c, s]):

    {
      "format": "ivfm-fuzzy-model", "version": 1,
      "metadata": {... free: seed, data source, split ...},
      "channels": {
        "phi": {
          "regressors": ["theta_rate_rad_s", "psi_rate_rad_s", "w_r_rad_s"],
          "input_ranges": [[min, max], ...],          one pair per regressor
          "n_clusters": c,
          "output": "f" | "acc",                      what the RMSEs are of
          "cluster_centers": [[x..., y], ...],        (c, n + 1), original units
          "notes": ["..."],
          "ivfm": {"lower": (c, n, 3), "upper": (c, n, 3), "theta_f": 2 c (n + 1) numbers,
                   "g": number | null, "rmse_ident": number, "rmse_valid": number},
          "t1fm": {"mfs": (c, n, 3), "theta_f": c (n + 1) numbers,
                   "g": number | null, "rmse_ident": number, "rmse_valid": number}
        }, ...
      }
    }

Everything is checked on load and before saving (shapes, finite numbers, 0 < h <= 1,
sigma > 0, lower <= upper everywhere, known channel and regressors, format and version);
a bad file raises ModelFileError naming the field, and a bad model is never written.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from autopilot.models.membership import Gaussian, interval_holds
from autopilot.models.regressors import CHANNEL_REGRESSORS, current_column_name
from autopilot.models.ts_model import ChannelModel, FuzzyModelSet, It2Model, T1Model
from contracts.atomic_file import write_atomic

FORMAT_NAME = "ivfm-fuzzy-model"
FORMAT_VERSION = 1
OUTPUT_KINDS = ("f", "acc")

_CHANNEL_KEYS = {
    "regressors",
    "input_ranges",
    "n_clusters",
    "output",
    "cluster_centers",
    "notes",
    "ivfm",
    "t1fm",
}
_IVFM_KEYS = {"lower", "upper", "theta_f", "g", "rmse_ident", "rmse_valid"}
_T1FM_KEYS = {"mfs", "theta_f", "g", "rmse_ident", "rmse_valid"}


class ModelFileError(ValueError):
    """A model file or model that breaks the format; the message names the field."""


# ---------------------------------------------------------------- field checks


def _require(obj: Any, key: str, where: str) -> Any:
    if not isinstance(obj, dict):
        raise ModelFileError(f"{where}: must be a JSON object")
    if key not in obj:
        raise ModelFileError(f"{where}.{key}: missing")
    return obj[key]


def _check_keys(obj: Any, allowed: set[str], where: str) -> None:
    if not isinstance(obj, dict):
        raise ModelFileError(f"{where}: must be a JSON object")
    for key in obj:
        if key not in allowed:
            raise ModelFileError(f"{where}.{key}: unknown field")
    for key in sorted(allowed):
        if key not in obj:
            raise ModelFileError(f"{where}.{key}: missing")


def _number_array(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    """A nested list of finite numbers (not booleans) with the given shape."""

    def walk(v: Any) -> None:
        if isinstance(v, list):
            for item in v:
                walk(item)
        elif isinstance(v, bool) or not isinstance(v, int | float):
            raise ModelFileError(f"{where}: {v!r} is not a number")

    walk(value)
    try:
        arr = np.array(value, dtype=float)
    except ValueError:
        raise ModelFileError(f"{where}: ragged array, expected shape {shape}") from None
    if arr.shape != shape:
        raise ModelFileError(f"{where}: shape {arr.shape}, expected {shape}")
    if not np.all(np.isfinite(arr)):
        raise ModelFileError(f"{where}: contains NaN or infinity")
    return arr


def _number(value: Any, where: str, *, minimum: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ModelFileError(f"{where}: {value!r} is not a number")
    if not math.isfinite(value):
        raise ModelFileError(f"{where}: {value!r} is not finite")
    if minimum is not None and value < minimum:
        raise ModelFileError(f"{where}: {value!r} is below {minimum}")
    return float(value)


def _optional_number(value: Any, where: str) -> float | None:
    return None if value is None else _number(value, where)


def _check_mfs(arr: np.ndarray, where: str) -> None:
    """Heights in (0, 1] (ln h must be finite for the firing) and sigmas > 0."""
    h, s = arr[..., 0], arr[..., 2]
    bad_h = np.argwhere(~((h > 0.0) & (h <= 1.0)))
    if bad_h.size:
        i, j = bad_h[0]
        raise ModelFileError(f"{where}[{i}][{j}]: height {h[i, j]} not in (0, 1]")
    bad_s = np.argwhere(s <= 0.0)
    if bad_s.size:
        i, j = bad_s[0]
        raise ModelFileError(f"{where}[{i}][{j}]: sigma {s[i, j]} is not > 0")


def _channel_from_dict(name: str, d: Any, where: str) -> ChannelModel:
    _check_keys(d, _CHANNEL_KEYS, where)
    expected = CHANNEL_REGRESSORS[name]
    regs = d["regressors"]
    if isinstance(regs, list) and all(isinstance(r, str) for r in regs):
        regs = [current_column_name(r) for r in regs]
    if not isinstance(regs, list) or tuple(regs) != expected:
        raise ModelFileError(f"{where}.regressors: {regs!r}, expected {list(expected)}")
    n = len(expected)
    c = d["n_clusters"]
    if isinstance(c, bool) or not isinstance(c, int) or c < 2:
        raise ModelFileError(f"{where}.n_clusters: {c!r} is not an integer >= 2")
    ranges = _number_array(d["input_ranges"], (n, 2), f"{where}.input_ranges")
    if np.any(ranges[:, 0] > ranges[:, 1]):
        raise ModelFileError(f"{where}.input_ranges: a minimum exceeds its maximum")
    output = d["output"]
    if output not in OUTPUT_KINDS:
        raise ModelFileError(f"{where}.output: {output!r}, expected one of {OUTPUT_KINDS}")
    centers = _number_array(d["cluster_centers"], (c, n + 1), f"{where}.cluster_centers")
    notes = d["notes"]
    if not isinstance(notes, list) or not all(isinstance(s, str) for s in notes):
        raise ModelFileError(f"{where}.notes: must be a list of strings")

    wi = f"{where}.ivfm"
    iv = d["ivfm"]
    _check_keys(iv, _IVFM_KEYS, wi)
    lower = _number_array(iv["lower"], (c, n, 3), f"{wi}.lower")
    upper = _number_array(iv["upper"], (c, n, 3), f"{wi}.upper")
    _check_mfs(lower, f"{wi}.lower")
    _check_mfs(upper, f"{wi}.upper")
    for i in range(c):
        for j in range(n):
            if not interval_holds(Gaussian(*lower[i, j]), Gaussian(*upper[i, j])):
                raise ModelFileError(f"{wi}.lower[{i}][{j}]: lower MF exceeds upper MF for some x")
    ivfm = It2Model(
        lower=lower,
        upper=upper,
        theta_f=_number_array(iv["theta_f"], (2 * c * (n + 1),), f"{wi}.theta_f"),
        regressor_names=expected,
        input_ranges=ranges,
        g=_optional_number(iv["g"], f"{wi}.g"),
    )

    wt = f"{where}.t1fm"
    t1 = d["t1fm"]
    _check_keys(t1, _T1FM_KEYS, wt)
    mfs = _number_array(t1["mfs"], (c, n, 3), f"{wt}.mfs")
    _check_mfs(mfs, f"{wt}.mfs")
    t1fm = T1Model(
        mfs=mfs,
        theta_f=_number_array(t1["theta_f"], (c * (n + 1),), f"{wt}.theta_f"),
        regressor_names=expected,
        input_ranges=ranges,
        g=_optional_number(t1["g"], f"{wt}.g"),
    )
    return ChannelModel(
        ivfm=ivfm,
        t1fm=t1fm,
        n_clusters=c,
        output=output,
        rmse_ident_ivfm=_number(iv["rmse_ident"], f"{wi}.rmse_ident", minimum=0.0),
        rmse_valid_ivfm=_number(iv["rmse_valid"], f"{wi}.rmse_valid", minimum=0.0),
        rmse_ident_t1fm=_number(t1["rmse_ident"], f"{wt}.rmse_ident", minimum=0.0),
        rmse_valid_t1fm=_number(t1["rmse_valid"], f"{wt}.rmse_valid", minimum=0.0),
        cluster_centers=centers,
        notes=tuple(notes),
    )


def model_set_from_dict(d: Any, where: str = "model") -> FuzzyModelSet:
    """Validate a parsed model document and build the models; ModelFileError names the field."""
    fmt = _require(d, "format", where)
    if fmt != FORMAT_NAME:
        raise ModelFileError(f"{where}.format: {fmt!r}, expected {FORMAT_NAME!r}")
    version = _require(d, "version", where)
    if isinstance(version, bool) or version != FORMAT_VERSION:
        raise ModelFileError(f"{where}.version: {version!r}, expected {FORMAT_VERSION}")
    for key in d:
        if key not in ("format", "version", "metadata", "channels"):
            raise ModelFileError(f"{where}.{key}: unknown field")
    metadata = d.get("metadata", {})
    if not isinstance(metadata, dict):
        raise ModelFileError(f"{where}.metadata: must be a JSON object")
    channels = _require(d, "channels", where)
    if not isinstance(channels, dict) or not channels:
        raise ModelFileError(f"{where}.channels: must be a non-empty JSON object")
    out: dict[str, ChannelModel] = {}
    for name, body in channels.items():
        if name not in CHANNEL_REGRESSORS:
            raise ModelFileError(
                f"{where}.channels.{name}: unknown channel (known: {list(CHANNEL_REGRESSORS)})"
            )
        out[name] = _channel_from_dict(name, body, f"{where}.channels.{name}")
    return FuzzyModelSet(channels=out, metadata=dict(metadata))


def _list(a: np.ndarray) -> list:
    return np.asarray(a, dtype=float).tolist()


def model_set_to_dict(model: FuzzyModelSet) -> dict[str, Any]:
    """The JSON document of a model set (not validated; model_set_from_dict checks it)."""
    channels: dict[str, Any] = {}
    for name, ch in model.channels.items():
        channels[name] = {
            "regressors": list(ch.ivfm.regressor_names),
            "input_ranges": _list(ch.ivfm.input_ranges),
            "n_clusters": int(ch.n_clusters),
            "output": ch.output,
            "cluster_centers": _list(ch.cluster_centers),
            "notes": list(ch.notes),
            "ivfm": {
                "lower": _list(ch.ivfm.lower),
                "upper": _list(ch.ivfm.upper),
                "theta_f": _list(ch.ivfm.theta_f),
                "g": None if ch.ivfm.g is None else float(ch.ivfm.g),
                "rmse_ident": float(ch.rmse_ident_ivfm),
                "rmse_valid": float(ch.rmse_valid_ivfm),
            },
            "t1fm": {
                "mfs": _list(ch.t1fm.mfs),
                "theta_f": _list(ch.t1fm.theta_f),
                "g": None if ch.t1fm.g is None else float(ch.t1fm.g),
                "rmse_ident": float(ch.rmse_ident_t1fm),
                "rmse_valid": float(ch.rmse_valid_t1fm),
            },
        }
    return {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "metadata": dict(model.metadata),
        "channels": channels,
    }


def save_model(path: str | os.PathLike[str], model: FuzzyModelSet) -> None:
    """Validate, then write the model file atomically (temp file + rename)."""
    doc = model_set_to_dict(model)
    model_set_from_dict(doc, where=str(path))
    try:
        text = json.dumps(doc, indent=1, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ModelFileError(f"{path}.metadata: not JSON-serialisable ({exc})") from None
    write_atomic(Path(path), text + "\n")


def load_model(path: str | os.PathLike[str]) -> FuzzyModelSet:
    """Read and validate a model file; ModelFileError names the file and the field."""
    where = str(path)
    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
    except OSError as exc:
        raise ModelFileError(f"{where}: cannot read file ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelFileError(f"{where}: not valid JSON ({exc})") from None
    return model_set_from_dict(doc, where=where)
