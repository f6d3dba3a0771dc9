"""Perturbations: what the ground station may change, where, and when.

A perturbation is one entry of a schedule in sim time: a kind, its parameters, and a
window ``start_s <= t < end_s`` (``end_s`` may be infinite). Requests arrive as JSON
(scenario files, ``ivfm ground perturb``, the Python API, Zenoh queries); ``parse_request``
is the one validator all of them go through, so a bad request is refused the same way
everywhere and changes nothing.

Each kind is defined once, in ``KINDS`` below: its parameters and their ranges, the
process it acts in, what an active entry contributes to the **effects** of that process
(``contracts/perturbation_effects.py``: what each is and how contributions combine), and
whether the one-process runner supports it. A new kind that acts through existing effects
is one entry in ``KINDS``. ``Perturbations`` and ``SensorEffects`` are the plant's and the
link's effects in force at one instant, as the simulator applies them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from contracts import AUTOPILOT, SITL
from contracts.perturbation_effects import (
    EFFECTS,
    FORCE_RANGE_N,
    INERTIA_SCALE_RANGE,
    LINK_EFFECTS,
    PLANT_EFFECTS,
    TORQUE_RANGE_NM,
    WIND_RANGE_MPS,
    Effect,
)
from contracts.toml_tables import number


@dataclass(frozen=True)
class Param:
    """One request parameter: a scalar (size 0) or a vector, with its range and default."""

    low: float
    high: float
    default: float | tuple[float, ...]
    size: int = 0
    integer: bool = False
    required: bool = False


def _vec3(low: float, high: float, required: bool = False) -> Param:
    return Param(low, high, (0.0, 0.0, 0.0), size=3, required=required)


def _needed(low: float, high: float, integer: bool = False) -> Param:
    return Param(low, high, low, integer=integer, required=True)


# -- kinds ----------------------------------------------------------------------------------

Contribution = Callable[["Perturbation", float], dict[str, Any]]


@dataclass(frozen=True)
class Kind:
    """A perturbation kind: where it acts, its parameters, what an active entry adds to
    the effects at sim time t, and whether the one-process runner applies it."""

    target: str
    params: dict[str, Param]
    description: str
    contributes: Contribution
    in_process: bool = True
    needs_end: bool = False  # its shape spans the window


def _scale(effect: str) -> Contribution:
    return lambda e, t: {effect: e.params["scale"]}


def _vector(effect: str, param: str) -> Contribution:
    return lambda e, t: {effect: e.params[param]}


def _one_motor(e: Perturbation, efficiency: float) -> dict[str, Any]:
    factors = [1.0, 1.0, 1.0, 1.0]
    factors[e.params["motor"] - 1] = efficiency
    return {"motor_efficiency": tuple(factors)}


def _gust(e: Perturbation, t_s: float) -> dict[str, Any]:
    """1 - cos over the window, peaking at ``ned_mps`` mid-window."""
    phase = (t_s - e.start_s) / (e.end_s - e.start_s) if e.end_s > e.start_s else 0
    shape = 0.5 * (1.0 - math.cos(2.0 * math.pi * phase))
    return {"wind_ned_mps": tuple(shape * v for v in e.params["ned_mps"])}


_SENSED = ("position_m", "velocity_mps", "angle_rad", "rate_rad_s")

KINDS: dict[str, Kind] = {
    "inertia": Kind(SITL, {"scale": _needed(*INERTIA_SCALE_RANGE)},
                    "body inertia I scaled", _scale("inertia_scale")),
    "rotor_inertia": Kind(SITL, {"scale": _needed(*INERTIA_SCALE_RANGE)},
                          "rotor inertia Jr scaled", _scale("rotor_inertia_scale")),
    "mass": Kind(SITL, {"scale": _needed(*INERTIA_SCALE_RANGE)}, "mass scaled",
                 _scale("mass_scale")),
    "motor_efficiency": Kind(SITL, {"motor": _needed(1, 4, integer=True),
                                    "efficiency": _needed(0.0, 1.0)},
                             "one motor's thrust and torque scaled by efficiency",
                             lambda e, t: _one_motor(e, e.params["efficiency"])),
    "motor_failure": Kind(SITL, {"motor": _needed(1, 4, integer=True)},
                          "one motor gives nothing", lambda e, t: _one_motor(e, 0.0)),
    "wind": Kind(SITL, {"ned_mps": _vec3(*WIND_RANGE_MPS, True)}, "steady wind (NED)",
                 _vector("wind_ned_mps", "ned_mps")),
    "gust": Kind(SITL, {"ned_mps": _vec3(*WIND_RANGE_MPS, True)},
                 "1 - cos gust peaking at ned_mps mid-window (needs a finite end)", _gust,
                 needs_end=True),
    "force": Kind(SITL, {"ned_n": _vec3(*FORCE_RANGE_N, True)}, "external force (NED)",
                  _vector("force_ned_n", "ned_n")),
    "torque": Kind(SITL, {"frd_nm": _vec3(*TORQUE_RANGE_NM, True)}, "external torque (FRD)",
                   _vector("torque_frd_nm", "frd_nm")),
    "sensor_noise": Kind(SITL, {"position_m": Param(0.0, 10.0, 0.0),
                                "velocity_mps": Param(0.0, 10.0, 0.0),
                                "angle_rad": Param(0.0, 0.5, 0.0),
                                "rate_rad_s": Param(0.0, 5.0, 0.0)},
                         "Gaussian noise (standard deviations) on the state sent",
                         lambda e, t: {f"noise_{k}": e.params[k] for k in _SENSED},
                         in_process=False),
    "sensor_bias": Kind(SITL, {"position_m": _vec3(-100.0, 100.0),
                               "velocity_mps": _vec3(-10.0, 10.0),
                               "angle_rad": _vec3(-0.5, 0.5),
                               "rate_rad_s": _vec3(-5.0, 5.0)},
                        "constant offsets on the state sent",
                        lambda e, t: {f"bias_{k}": e.params[k] for k in _SENSED},
                        in_process=False),
    "link_delay": Kind(SITL, {"samples": _needed(0, 100, integer=True)},
                       "the state sent is this many samples old",
                       lambda e, t: {"delay_samples": int(e.params["samples"])},
                       in_process=False),
    "link_loss": Kind(SITL, {"fraction": _needed(0.0, 0.95)},
                      "this fraction of samples is not sent (seeded)",
                      lambda e, t: {"loss_fraction": e.params["fraction"]}, in_process=False),
    "gps_outage": Kind(SITL, {}, "the GPS receiver has no fix (fix type 0)",
                       lambda e, t: {"gps_outage": 1.0}),
    "mag_disturbance": Kind(SITL, {"frd_gauss": _vec3(-2.0, 2.0, True)},
                            "a field added to the magnetometer (body axes), e.g. a cable",
                            _vector("mag_field_gauss", "frd_gauss")),
    "imu_bias_step": Kind(SITL, {"gyro_rad_s": _vec3(-1.0, 1.0),
                                 "accel_mps2": _vec3(-5.0, 5.0)},
                          "biases added to the gyro and the accelerometer",
                          lambda e, t: {"gyro_bias_rad_s": e.params["gyro_rad_s"],
                                        "accel_bias_mps2": e.params["accel_mps2"]}),
    "baro_drift": Kind(SITL, {"rate_mps": _needed(-1.0, 1.0)},
                       "the barometer's altitude drifts at this rate (and stays drifted)",
                       _vector("baro_drift_mps", "rate_mps")),
    # The whole simulator freezes once, at start_s, for freeze_s of wall time: no physics,
    # no samples (a simulator that answers late); sim time goes on where it stopped.
    "sim_stall": Kind(SITL, {"freeze_s": _needed(0.001, 10.0)},
                      "the simulator freezes once for freeze_s of wall time (real time)",
                      lambda e, t: {}, in_process=False),
    "kick": Kind(AUTOPILOT, {"phi_rad": Param(-1.0, 1.0, 0.0),
                             "theta_rad": Param(-1.0, 1.0, 0.0)},
                 "added to the desired roll and pitch",
                 lambda e, t: {"kick_rad": (e.params["phi_rad"], e.params["theta_rad"])}),
}
IN_PROCESS_KINDS = frozenset(name for name, kind in KINDS.items() if kind.in_process)


@dataclass(frozen=True)
class Perturbation:
    """One validated schedule entry. ``start_s`` None means "now" (the receiver's next
    sample fixes it)."""

    kind: str
    params: dict[str, Any]
    start_s: float | None = 0.0
    end_s: float = math.inf
    id: str = ""
    now_duration_s: float = math.inf  # the window's length when start_s is "now"

    @property
    def target(self) -> str:
        return KINDS[self.kind].target

    def active(self, t_s: float) -> bool:
        return self.start_s is not None and self.start_s <= t_s < self.end_s

    def to_request(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, **{
            k: list(v) if isinstance(v, tuple) else v for k, v in self.params.items()}}
        out["start_s"] = "now" if self.start_s is None else self.start_s
        if self.start_s is None and math.isfinite(self.now_duration_s):
            out["duration_s"] = self.now_duration_s
        elif math.isfinite(self.end_s):
            out["end_s"] = self.end_s
        if self.id:
            out["id"] = self.id
        return out


def parse_request(data: Any, default_id: str = "") -> Perturbation:
    """Validate one request (a dict as in a scenario file); raises ValueError naming the
    bad field. ``duration_s`` may stand for ``end_s``; ``start_s`` may be "now"."""
    if not isinstance(data, dict):
        raise ValueError(f"a perturbation is a table of fields, got {type(data).__name__}")
    kind_name = data.get("kind")
    if not isinstance(kind_name, str) or kind_name not in KINDS:  # [] is not hashable
        raise ValueError(f"unknown perturbation kind {kind_name!r}; known: "
                         f"{', '.join(KINDS)}")
    kind = KINDS[kind_name]
    allowed = set(kind.params) | {"kind", "start_s", "end_s", "duration_s", "id"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ValueError(f"{kind_name}: unknown field(s) {', '.join(unknown)}; it takes "
                         f"{', '.join(kind.params) or 'no parameters'}")
    start = data.get("start_s", 0.0)
    start = None if start == "now" else _number(kind_name, "start_s", start, 0.0, 1e9)
    if "end_s" in data and "duration_s" in data:
        raise ValueError(f"{kind_name}: give end_s or duration_s, not both")
    duration = math.inf
    if "duration_s" in data:
        duration = _number(kind_name, "duration_s", data["duration_s"], 0.0, math.inf)
        end = math.inf if start is None else start + duration
    else:
        end = _number(kind_name, "end_s", data.get("end_s", math.inf), 0.0, math.inf)
        if start is not None and end < start:
            raise ValueError(f"{kind_name}: end_s {end} is before start_s {start}")
    if start is None and math.isfinite(end):
        raise ValueError(f"{kind_name}: with start_s \"now\" give duration_s, not end_s")
    if kind.needs_end and math.isinf(end) and math.isinf(duration):
        raise ValueError(f"{kind_name}: needs an end_s or duration_s (its shape spans the "
                         "window)")
    params: dict[str, Any] = {}
    for name, spec in kind.params.items():
        if spec.required and name not in data:
            raise ValueError(f"{kind_name}: {name} is required")
        value = data.get(name, spec.default)
        if spec.size:
            if not isinstance(value, (list, tuple)) or len(value) != spec.size:
                raise ValueError(f"{kind_name}: {name} needs {spec.size} numbers, got "
                                 f"{value!r}")
            params[name] = tuple(_number(kind_name, name, v, spec.low, spec.high)
                                 for v in value)
        else:
            number = _number(kind_name, name, value, spec.low, spec.high)
            if spec.integer:
                if number != int(number):
                    raise ValueError(f"{kind_name}: {name} must be a whole number, got "
                                     f"{value!r}")
                number = int(number)
            params[name] = number
    entry_id = data.get("id", default_id)
    if not isinstance(entry_id, str) or len(entry_id) > 64:
        raise ValueError(f"{kind_name}: id must be a string of at most 64 characters")
    return Perturbation(kind_name, params, start, end, entry_id, duration)


def _number(kind: str, name: str, value: Any, low: float, high: float) -> float:
    return number(value, f"{kind}: {name}", low, high, allow_inf=True)


def resolve_now(entry: Perturbation, now_s: float) -> Perturbation:
    """Fix a "now" entry's window at the receiver's sim time (duration kept)."""
    if entry.start_s is not None:
        return entry
    return Perturbation(entry.kind, entry.params, now_s, now_s + entry.now_duration_s,
                        entry.id)


# -- effects in force ----------------------------------------------------------------------

@dataclass(frozen=True)
class Perturbations:
    """Changes to the plant in force at one instant (what ``Plant`` applies), validated.
    One field per plant effect (``PLANT_EFFECTS``), defaulting to its neutral value."""

    inertia_scale: float = 1.0
    rotor_inertia_scale: float = 1.0
    mass_scale: float = 1.0
    motor_efficiency: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)
    wind_ned_mps: tuple[float, ...] = (0.0, 0.0, 0.0)
    force_ned_n: tuple[float, ...] = (0.0, 0.0, 0.0)
    torque_frd_nm: tuple[float, ...] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name, effect in PLANT_EFFECTS.items():
            value = getattr(self, name)
            values = value if effect.size else (value,)
            low, high = effect.valid
            if len(values) != max(1, effect.size) or not all(
                    math.isfinite(v) and low <= v <= high for v in values):
                raise ValueError(f"perturbation {name} must be {max(1, effect.size)} "
                                 f"value(s) in [{low:g}, {high:g}], got {value!r}")


@dataclass(frozen=True)
class SensorEffects:
    """What the simulator does to the state it sends (noise standard deviations, biases,
    delay, loss). One field per link effect (``LINK_EFFECTS``), defaulting to its neutral
    value."""

    noise_position_m: float = 0.0
    noise_velocity_mps: float = 0.0
    noise_angle_rad: float = 0.0
    noise_rate_rad_s: float = 0.0
    bias_position_m: tuple[float, ...] = (0.0, 0.0, 0.0)
    bias_velocity_mps: tuple[float, ...] = (0.0, 0.0, 0.0)
    bias_angle_rad: tuple[float, ...] = (0.0, 0.0, 0.0)
    bias_rate_rad_s: tuple[float, ...] = (0.0, 0.0, 0.0)
    delay_samples: int = 0
    loss_fraction: float = 0.0
    gps_outage: float = 0.0
    mag_field_gauss: tuple[float, ...] = (0.0, 0.0, 0.0)
    gyro_bias_rad_s: tuple[float, ...] = (0.0, 0.0, 0.0)
    accel_bias_mps2: tuple[float, ...] = (0.0, 0.0, 0.0)
    baro_drift_mps: float = 0.0

    @property
    def idle(self) -> bool:
        return self == NO_SENSOR_EFFECTS


def _check_fields(record: type, effects: dict[str, Effect]) -> None:
    """A record's fields are its group's effects, in order, each defaulting to the
    effect's neutral value: the table and the record cannot drift apart unnoticed."""
    have = [(f.name, f.default) for f in fields(record)]
    want = [(name, effect.neutral_value) for name, effect in effects.items()]
    if have != want:
        raise TypeError(f"{record.__name__} fields {have} do not match the effects {want}")


_check_fields(Perturbations, PLANT_EFFECTS)
_check_fields(SensorEffects, LINK_EFFECTS)
NO_SENSOR_EFFECTS = SensorEffects()


def effects_at(entries: tuple[Perturbation, ...] | list[Perturbation], t_s: float,
               effects: dict[str, Effect]) -> dict[str, Any]:
    """The combined value of each of ``effects`` over the entries active at sim time t
    (clipped to its range); effects no active entry touches are left out."""
    combined: dict[str, Any] = {}
    for e in entries:
        if not e.active(t_s):
            continue
        for name, value in KINDS[e.kind].contributes(e, t_s).items():
            effect = effects.get(name)
            if effect is not None:
                combined[name] = effect.combined(combined.get(name, effect.neutral_value),
                                                 value)
    return {name: effects[name].clipped(value) for name, value in combined.items()}


def plant_perturbations_at(entries: tuple[Perturbation, ...] | list[Perturbation],
                           t_s: float) -> Perturbations:
    """The plant changes in force at sim time t."""
    return Perturbations(**effects_at(entries, t_s, PLANT_EFFECTS))


def sensor_effects_at(entries: tuple[Perturbation, ...] | list[Perturbation],
                      t_s: float) -> SensorEffects:
    """Sensor and link effects in force at sim time t."""
    combined = effects_at(entries, t_s, LINK_EFFECTS)
    return SensorEffects(**combined) if combined else NO_SENSOR_EFFECTS


def kick_at(entries: tuple[Perturbation, ...] | list[Perturbation],
            t_s: float) -> tuple[float, float]:
    """Sum of the reference kicks (phi_d, theta_d) in force at sim time t."""
    return effects_at(entries, t_s, {"kick_rad": EFFECTS["kick_rad"]}).get(
        "kick_rad", EFFECTS["kick_rad"].neutral_value)


# -- schedules as files ---------------------------------------------------------------------

def parse_schedule(items: Any) -> tuple[Perturbation, ...]:
    """A list of requests (scenario ``[[perturbation]]`` tables or a JSON list); errors name
    the entry. Scheduled entries must give a start time: "now" means nothing in a file."""
    if not isinstance(items, list):
        raise ValueError("a perturbation schedule is a list of entries")
    out = []
    for i, item in enumerate(items):
        try:
            entry = parse_request(item, default_id=f"p{i}")
        except ValueError as exc:
            raise ValueError(f"perturbation {i}: {exc}") from None
        if entry.start_s is None:
            raise ValueError(f"perturbation {i}: a schedule needs start_s in sim time")
        out.append(entry)
    return tuple(out)


def schedule_to_json(entries: tuple[Perturbation, ...]) -> str:
    return json.dumps({"format": "ivfm-schedule", "version": 2,
                       "perturbations": [e.to_request() for e in entries]}, indent=1)


def schedule_from_json(text: str) -> tuple[Perturbation, ...]:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"schedule is not JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != "ivfm-schedule":
        raise ValueError("schedule lacks format 'ivfm-schedule'")
    return parse_schedule(data.get("perturbations"))


def load_schedule(path: Path) -> tuple[Perturbation, ...]:
    return schedule_from_json(Path(path).read_text())
