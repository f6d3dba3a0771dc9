"""Build a controller by name: ivfc, t1fc, smc or pid.

Functions here take an airframe already read (an ``AirframeSpec``): the process reads
its airframe file once, at its command line, and passes the spec in.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from autopilot.control.cascade import (
    BASIS_IT2,
    BASIS_T1,
    AttitudeModel,
    SlidingModeCascade,
    nominal_attitude_model,
    regressor_scales,
)
from autopilot.control.pid import PidCascade
from autopilot.models.ts_model import FuzzyModelSet
from contracts.airframe import Airframe
from contracts.airframe_file import AirframeSpec
from contracts.vectors import ATTITUDE_CHANNELS

CONTROLLERS = ("ivfc", "t1fc", "smc", "pid")


def attitude_model_from_fuzzy(models: FuzzyModelSet, kind: str, af: Airframe) -> AttitudeModel:
    """IVFC takes the interval type-2 model, T1FC the type-1 model of the same clusters.

    g starts from identification where the data allowed it, else from the airframe.
    """
    nominal = dict(zip(ATTITUDE_CHANNELS, (float(b) for b in af.input_gains), strict=True))
    missing = [name for name in ATTITUDE_CHANNELS if name not in models.channels]
    if missing:
        raise ValueError(f"fuzzy model lacks attitude channel(s) {', '.join(missing)}")
    lower, upper, theta, g, scales = [], [], [], [], []
    for name in ATTITUDE_CHANNELS:
        ch = models.channels[name]
        if kind == "ivfc":
            lower.append(np.ascontiguousarray(ch.ivfm.lower, dtype=float))
            upper.append(np.ascontiguousarray(ch.ivfm.upper, dtype=float))
            theta.append(np.array(ch.ivfm.theta_f, dtype=float))
        else:
            lower.append(np.ascontiguousarray(ch.t1fm.mfs, dtype=float))
            upper.append(np.ascontiguousarray(ch.t1fm.mfs, dtype=float))
            theta.append(np.array(ch.t1fm.theta_f, dtype=float))
        halves = 2 if kind == "ivfc" else 1
        scales.append(regressor_scales(ch.ivfm.input_ranges, ch.n_clusters, halves))
        identified_g = ch.ivfm.g if kind == "ivfc" else ch.t1fm.g
        g.append(float(identified_g) if identified_g is not None else nominal[name])
    return AttitudeModel(BASIS_IT2 if kind == "ivfc" else BASIS_T1, tuple(lower), tuple(upper),
                         tuple(theta), tuple(g), tuple(scales))


def make_controller(
    kind: str,
    airframe: Airframe,
    period_s: float = 0.01,
    models: FuzzyModelSet | None = None,
    parameters: dict[str, float] | None = None,
) -> SlidingModeCascade | PidCascade:
    if kind not in CONTROLLERS:
        raise ValueError(f"unknown controller {kind!r}; known: {', '.join(CONTROLLERS)}")
    if kind == "pid":
        return PidCascade(airframe, period_s, parameters)
    if kind == "smc":
        return SlidingModeCascade(nominal_attitude_model(airframe), airframe, period_s,
                                  parameters, adaptive=False)
    if models is None:
        raise ValueError(f"controller {kind} needs an identified fuzzy model")
    return SlidingModeCascade(attitude_model_from_fuzzy(models, kind, airframe), airframe,
                              period_s, parameters, adaptive=True)


SHIPPED_MODEL = "paper.json"  # the paper's airframe; others have theirs by name


def shipped_model_name(airframe: AirframeSpec | None) -> str:
    """The model shipped for an airframe (``autopilot/models/<airframe name>.json``), or
    the paper's when none is."""
    if airframe is None:
        return SHIPPED_MODEL
    own = f"{airframe.name}.json"
    return own if resources.files("autopilot.models").joinpath(own).is_file() else SHIPPED_MODEL


def load_models(path: Path | None, airframe: AirframeSpec | None = None,
                any_airframe: bool = False) -> FuzzyModelSet:
    """The given model file, or the model shipped for the airframe. With ``airframe``, a
    model identified on another airframe is refused unless ``any_airframe``."""
    from autopilot.models.model_file import load_model

    if path is None:
        name = shipped_model_name(airframe)
        with resources.as_file(resources.files("autopilot.models") / name) as shipped:
            models = load_model(shipped)
    else:
        models = load_model(path)
    missing = [name for name in ATTITUDE_CHANNELS if name not in models.channels]
    if missing:
        raise ValueError(f"{path}: the controller needs channel(s) {', '.join(missing)}, "
                         f"the model has {', '.join(models.channels) or 'none'}")
    if airframe is not None and not any_airframe:
        check_model_airframe(models, airframe, str(path or f"the shipped model "
                                                   f"{shipped_model_name(airframe)}"))
    return models


def model_airframe_metadata(spec: AirframeSpec) -> dict[str, str]:
    """What a model file records of the airframe it was identified on."""
    return {"airframe": spec.name, "airframe_fingerprint": spec.fingerprint()}


def check_model_airframe(models: FuzzyModelSet, spec: AirframeSpec, source: str) -> None:
    """A model flies the airframe it was identified on: same numbers (fingerprint), or,
    for files that record only a name, the same name."""
    recorded = models.metadata.get("airframe")
    fingerprint = models.metadata.get("airframe_fingerprint")
    same = (fingerprint == spec.fingerprint() if fingerprint is not None
            else recorded in (None, spec.name))
    if not same:
        raise ValueError(
            f"{source} was identified on airframe {recorded!r}"
            f"{' (other numbers)' if recorded == spec.name else ''}, not on {spec.name!r}: "
            f"identify one for it (ivfm identify --airframe {spec.argument} "
            "--out model.json), "
            "or fly it anyway with --any-airframe-model")
