"""Perturbations: what the ground station may change, where, and when (SPEC section 7).

A perturbation is one entry of a schedule in sim time: a kind, its parameters, and a
window ``start_s <= t < end_s`` (``end_s`` may be infinite). Requests arrive as JSON
(scenario files, ``ivfm ground perturb``, the Python API, Zenoh queries); ``parse_request``
is the one validator all of them go through, so a bad request is refused the same way
everywhere and changes nothing.

Kinds and where they act:

* simulator (plant): ``inertia``, ``rotor_inertia``, ``mass`` (scale factors),
  ``motor_efficiency``, ``motor_failure``, ``wind`` (steady), ``gust`` (1 - cos over the
  window), ``force`` (NED), ``torque`` (FRD);
* simulator (what it sends): ``sensor_noise``, ``sensor_bias``, ``link_delay``,
  ``link_loss``;
* autopilot: ``kick`` (additive on the desired roll / pitch, the paper's position test).

Active entries combine: scale factors and efficiencies multiply, vectors add, noise
standard deviations add in quadrature, link delay and loss take the largest. Combined
plant values are clipped to the ranges ``Perturbations`` accepts.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from contracts.telemetry import AUTOPILOT, SITL

INERTIA_SCALE_RANGE = (0.1, 10.0)
WIND_RANGE_MPS = (-50.0, 50.0)
FORCE_RANGE_N = (-1000.0, 1000.0)
TORQUE_RANGE_NM = (-100.0, 100.0)


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


@dataclass(frozen=True)
class Kind:
    target: str
    params: dict[str, Param]
    description: str


KINDS: dict[str, Kind] = {
    "inertia": Kind(SITL, {"scale": _needed(*INERTIA_SCALE_RANGE)},
                    "body inertia I scaled"),
    "rotor_inertia": Kind(SITL, {"scale": _needed(*INERTIA_SCALE_RANGE)},
                          "rotor inertia Jr scaled"),
    "mass": Kind(SITL, {"scale": _needed(*INERTIA_SCALE_RANGE)}, "mass scaled"),
    "motor_efficiency": Kind(SITL, {"motor": _needed(1, 4, integer=True),
                                         "efficiency": _needed(0.0, 1.0)},
                             "one motor's thrust and torque scaled by efficiency"),
    "motor_failure": Kind(SITL, {"motor": _needed(1, 4, integer=True)},
                          "one motor gives nothing"),
    "wind": Kind(SITL, {"ned_mps": _vec3(*WIND_RANGE_MPS, True)}, "steady wind (NED)"),
    "gust": Kind(SITL, {"ned_mps": _vec3(*WIND_RANGE_MPS, True)},
                 "1 - cos gust peaking at ned_mps mid-window (needs a finite end)"),
    "force": Kind(SITL, {"ned_n": _vec3(*FORCE_RANGE_N, True)}, "external force (NED)"),
    "torque": Kind(SITL, {"frd_nm": _vec3(*TORQUE_RANGE_NM, True)},
                   "external torque (FRD)"),
    "sensor_noise": Kind(SITL, {"position_m": Param(0.0, 10.0, 0.0),
                                     "velocity_mps": Param(0.0, 10.0, 0.0),
                                     "angle_rad": Param(0.0, 0.5, 0.0),
                                     "rate_rad_s": Param(0.0, 5.0, 0.0)},
                         "Gaussian noise (standard deviations) on the state sent"),
    "sensor_bias": Kind(SITL, {"position_m": _vec3(-100.0, 100.0),
                                    "velocity_mps": _vec3(-10.0, 10.0),
                                    "angle_rad": _vec3(-0.5, 0.5),
                                    "rate_rad_s": _vec3(-5.0, 5.0)},
                        "constant offsets on the state sent"),
    "link_delay": Kind(SITL, {"samples": _needed(0, 100, integer=True)},
                       "the state sent is this many samples old"),
    "link_loss": Kind(SITL, {"fraction": _needed(0.0, 0.95)},
                      "this fraction of samples is not sent (seeded)"),
    "kick": Kind(AUTOPILOT, {"phi_rad": Param(-1.0, 1.0, 0.0),
                             "theta_rad": Param(-1.0, 1.0, 0.0)},
                 "added to the desired roll and pitch"),
}


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
    if kind_name not in KINDS:
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
    if kind_name == "gust" and math.isinf(end) and math.isinf(duration):
        raise ValueError("gust: needs an end_s or duration_s (its shape spans the window)")
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
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{kind}: {name} must be a number, got {value!r}")
    value = float(value)
    if math.isnan(value) or not low <= value <= high or (math.isinf(value) and
                                                          not math.isinf(high)):
        raise ValueError(f"{kind}: {name} must be in [{low:g}, {high:g}], got {value!r}")
    return value


def resolve_now(entry: Perturbation, now_s: float) -> Perturbation:
    """Fix a "now" entry's window at the receiver's sim time (duration kept)."""
    if entry.start_s is not None:
        return entry
    return Perturbation(entry.kind, entry.params, now_s, now_s + entry.now_duration_s,
                        entry.id)


# -- what the plant and the links see -------------------------------------------------------

@dataclass(frozen=True)
class Perturbations:
    """Changes to the plant in force at one instant (what ``Plant`` applies)."""

    inertia_scale: float = 1.0
    rotor_inertia_scale: float = 1.0
    mass_scale: float = 1.0
    motor_efficiency: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    wind_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    force_ned_n: tuple[float, float, float] = (0.0, 0.0, 0.0)
    torque_frd_nm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("inertia_scale", "rotor_inertia_scale", "mass_scale"):
            value = getattr(self, name)
            if not (math.isfinite(value) and
                    INERTIA_SCALE_RANGE[0] <= value <= INERTIA_SCALE_RANGE[1]):
                raise ValueError(f"perturbation {name} must be in {INERTIA_SCALE_RANGE}, "
                                 f"got {value!r}")
        _check_vector("motor_efficiency", self.motor_efficiency, 4, 0.0, 1.0)
        _check_vector("wind_ned_mps", self.wind_ned_mps, 3, *WIND_RANGE_MPS)
        _check_vector("force_ned_n", self.force_ned_n, 3, *FORCE_RANGE_N)
        _check_vector("torque_frd_nm", self.torque_frd_nm, 3, *TORQUE_RANGE_NM)


def _check_vector(name: str, value: tuple, size: int, low: float, high: float) -> None:
    if len(value) != size:
        raise ValueError(f"perturbation {name} needs {size} values, got {len(value)}")
    for v in value:
        if not (math.isfinite(v) and low <= v <= high):
            raise ValueError(f"perturbation {name} values must be in [{low}, {high}], got {v!r}")


@dataclass(frozen=True)
class SensorEffects:
    """What the simulator does to the state it sends (noise standard deviations, biases)."""

    noise_position_m: float = 0.0
    noise_velocity_mps: float = 0.0
    noise_angle_rad: float = 0.0
    noise_rate_rad_s: float = 0.0
    bias_position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_velocity_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_angle_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_rate_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    delay_samples: int = 0
    loss_fraction: float = 0.0

    @property
    def idle(self) -> bool:
        return self == NO_SENSOR_EFFECTS


NO_SENSOR_EFFECTS = SensorEffects()
_SENSOR_KINDS = ("sensor_noise", "sensor_bias", "link_delay", "link_loss")


def _clip(value: float, low: float, high: float) -> float:
    return min(max(value, low), high)


def plant_perturbations_at(entries: tuple[Perturbation, ...] | list[Perturbation],
                           t_s: float) -> Perturbations:
    """The plant changes in force at sim time t (see the module docstring)."""
    scales = {"inertia": 1.0, "rotor_inertia": 1.0, "mass": 1.0}
    efficiency = [1.0, 1.0, 1.0, 1.0]
    wind, force, torque = [0.0] * 3, [0.0] * 3, [0.0] * 3
    for e in entries:
        if not e.active(t_s):
            continue
        p = e.params
        if e.kind in scales:
            scales[e.kind] *= p["scale"]
        elif e.kind == "motor_efficiency":
            efficiency[p["motor"] - 1] *= p["efficiency"]
        elif e.kind == "motor_failure":
            efficiency[p["motor"] - 1] = 0.0
        elif e.kind in ("wind", "gust"):
            shape = 1.0
            if e.kind == "gust":
                phase = (t_s - e.start_s) / (e.end_s - e.start_s) if e.end_s > e.start_s else 0
                shape = 0.5 * (1.0 - math.cos(2.0 * math.pi * phase))
            for i in range(3):
                wind[i] += shape * p["ned_mps"][i]
        elif e.kind == "force":
            for i in range(3):
                force[i] += p["ned_n"][i]
        elif e.kind == "torque":
            for i in range(3):
                torque[i] += p["frd_nm"][i]
    return Perturbations(
        inertia_scale=_clip(scales["inertia"], *INERTIA_SCALE_RANGE),
        rotor_inertia_scale=_clip(scales["rotor_inertia"], *INERTIA_SCALE_RANGE),
        mass_scale=_clip(scales["mass"], *INERTIA_SCALE_RANGE),
        motor_efficiency=tuple(efficiency),
        wind_ned_mps=tuple(_clip(w, *WIND_RANGE_MPS) for w in wind),
        force_ned_n=tuple(_clip(f, *FORCE_RANGE_N) for f in force),
        torque_frd_nm=tuple(_clip(m, *TORQUE_RANGE_NM) for m in torque),
    )


def sensor_effects_at(entries: tuple[Perturbation, ...] | list[Perturbation],
                      t_s: float) -> SensorEffects:
    """Sensor and link effects in force at sim time t."""
    active = [e for e in entries if e.kind in _SENSOR_KINDS and e.active(t_s)]
    if not active:
        return NO_SENSOR_EFFECTS
    noise = {"position_m": 0.0, "velocity_mps": 0.0, "angle_rad": 0.0, "rate_rad_s": 0.0}
    bias = {k: [0.0, 0.0, 0.0] for k in noise}
    delay, loss = 0, 0.0
    for e in active:
        if e.kind == "sensor_noise":
            for k in noise:
                noise[k] = math.hypot(noise[k], e.params[k])
        elif e.kind == "sensor_bias":
            for k in bias:
                bias[k] = [a + b for a, b in zip(bias[k], e.params[k], strict=True)]
        elif e.kind == "link_delay":
            delay = max(delay, int(e.params["samples"]))
        else:
            loss = max(loss, e.params["fraction"])
    return SensorEffects(noise["position_m"], noise["velocity_mps"], noise["angle_rad"],
                         noise["rate_rad_s"], tuple(bias["position_m"]),
                         tuple(bias["velocity_mps"]), tuple(bias["angle_rad"]),
                         tuple(bias["rate_rad_s"]), delay, loss)


def kick_at(entries: tuple[Perturbation, ...] | list[Perturbation],
            t_s: float) -> tuple[float, float]:
    """Sum of the reference kicks (phi_d, theta_d) in force at sim time t."""
    phi = theta = 0.0
    for e in entries:
        if e.kind == "kick" and e.active(t_s):
            phi += e.params["phi_rad"]
            theta += e.params["theta_rad"]
    return phi, theta


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


MAX_PERTURBATIONS = 1000  # per process: each step's cost grows with the count


class PerturbationBook:
    """A process's schedule: the entries it was started with plus those requested since.

    ``handle`` answers one request (``op`` add, clear or list) at sim time ``now_s`` or
    raises ValueError and changes nothing; ``changes`` says which entries started or ended
    since the last call, for the "applied at sim time" log.
    """

    def __init__(self, target: str, entries: tuple[Perturbation, ...] = ()) -> None:
        self.target = target
        self.entries: list[Perturbation] = [e for e in entries if e.target == target]
        self._active: set[str] = set()
        self._next_id = 0

    def handle(self, data: Any, now_s: float) -> dict[str, Any]:
        if not isinstance(data, dict):
            raise ValueError("a request is a JSON object")
        data = dict(data)
        op = data.pop("op", "add")
        if op == "list":
            return {"perturbations": [e.to_request() for e in self.entries]}
        if op == "clear":
            return {"cleared": self._clear(data.get("id"), now_s)}
        if op != "add":
            raise ValueError(f"unknown op {op!r}; use add, clear or list")
        entry = self._accept(data, now_s)
        self.entries.append(entry)
        return entry.to_request()

    def _accept(self, data: dict[str, Any], now_s: float) -> Perturbation:
        if len(self.entries) >= MAX_PERTURBATIONS:
            raise ValueError(f"{MAX_PERTURBATIONS} perturbations already: every control step "
                             "looks at each, so no more are taken")
        entry = parse_request(data)
        if entry.target != self.target:
            raise ValueError(f"{entry.kind} acts in the {entry.target}, not the {self.target}")
        entry = resolve_now(entry, now_s)
        if entry.start_s < now_s:
            raise ValueError(f"start_s {entry.start_s:g} is in the past (sim time "
                             f"{now_s:.3f} s)")
        ids = {e.id for e in self.entries}
        if entry.id in ids:
            raise ValueError(f"a perturbation with id {entry.id!r} exists already")
        if not entry.id:
            while f"{self.target}-{self._next_id}" in ids:
                self._next_id += 1
            entry = Perturbation(entry.kind, entry.params, entry.start_s, entry.end_s,
                                 f"{self.target}-{self._next_id}")
        return entry

    def _clear(self, which: Any, now_s: float) -> list[str]:
        """End one perturbation (or all) now."""
        hits = [e for e in self.entries if which in (None, e.id) and e.end_s > now_s]
        if which is not None and not hits:
            raise ValueError(f"no perturbation with id {which!r} is pending or active")
        for e in hits:
            i = self.entries.index(e)
            self.entries[i] = Perturbation(e.kind, e.params, min(e.start_s, now_s), now_s, e.id)
        return [e.id for e in hits]

    def changes(self, t_s: float) -> list[tuple[str, Perturbation]]:
        """("start" | "end", entry) for entries that became active or ended by t."""
        active = {e.id for e in self.entries if e.active(t_s)}
        if active == self._active:
            return []
        out = [("start" if e.id in active else "end", e) for e in self.entries
               if (e.id in active) != (e.id in self._active)]
        self._active = active
        return out
