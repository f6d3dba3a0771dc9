"""Readiness profiles and the checks of an airframe and a parameter set that need no
flight (``ivfm rehearse``, docs/rehearsal.md). Pure: numbers in, verdicts out.

A profile (TOML; ``default`` is shipped beside this file) holds the limits of the static
checks and the flights to rehearse, each a scenario file with its own ``[expect]``::

    name = "default"
    [airframe]
    thrust_to_weight_min = 1.5        # torque-free full thrust / weight
    hover_command_max = 0.8           # largest motor command at a level hover
    tilt_thrust_margin_min = 0.1      # 1 - thrust at MPC_TILTMAX_AIR / full thrust
    motor_time_constant_max_s = 0.05  # the slowest rotor's first-order lag
    [parameters]
    MPC_TILTMAX_AIR = [5.0, 45.0]     # NAME = [min, max]
    [[flight]]
    scenario = "flights/timing.toml"  # relative to the profile
    realtime = true                   # flown paced to the wall clock (default lockstep)
    advice = "what to change when it fails"
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from autopilot.parameters import PARAMETER_SPECS
from contracts.airframe_file import AirframeError, AirframeSpec, check_controllable
from contracts.frames import GRAVITY_MPS2
from contracts.toml_tables import array_of_tables, check_fields, number, subtable
from ground.scenario.expectations import Outcome

AIRFRAME_LIMITS = {  # key: (what it limits, "min" or "max", unit)
    "thrust_to_weight_min": ("thrust-to-weight", "min", ""),
    "hover_command_max": ("motor command at hover", "max", ""),
    "tilt_thrust_margin_min": ("thrust margin at full tilt", "min", ""),
    "motor_time_constant_max_s": ("motor time constant", "max", " s"),
}
_TOP = {"name", "description", "airframe", "parameters", "flight"}
_FLIGHT_KEYS = {"scenario", "realtime", "advice"}
# What to change, per static check, when it fails.
ADVICE = {
    "airframe": "fix the airframe file: its rotors cannot hover the vehicle",
    "rotor spins": "two rotors spin cw and two ccw, each pair diagonally opposite (PX4's "
                   "quad X: 1 and 2 ccw, 3 and 4 cw); check each rotor's spin and propeller",
    "thrust-to-weight": "stronger motors or propellers (a higher max_rad_s or thrust "
                        "coefficient), or a lighter vehicle",
    "motor command at hover": "more thrust per motor, or less mass: the vehicle hovers "
                              "near the top of its motors' range",
    "thrust margin at full tilt": "lower MPC_TILTMAX_AIR, or more thrust",
    "motor time constant": "faster motors and ESCs (or lighter propellers): the attitude "
                           "loop cannot be faster than the rotors",
    "parameters": "set the parameter inside the profile's safe range",
}


@dataclass(frozen=True)
class Flight:
    """One rehearsal flight: a scenario file and how to fly it."""

    scenario: Path
    realtime: bool
    advice: str


@dataclass(frozen=True)
class Profile:
    name: str
    description: str
    source: str
    airframe_limits: dict[str, float]
    parameter_ranges: dict[str, tuple[float, float]]
    flights: tuple[Flight, ...]


def shipped_profile_path(name: str = "default") -> Path:
    return Path(str(resources.files("ground.rehearsal").joinpath("profiles", f"{name}.toml")))


def load_profile(source: str | Path | None = None) -> Profile:
    """A readiness profile: the shipped ``default`` or a .toml file; ValueError names the
    field that is wrong."""
    path = shipped_profile_path() if source is None or str(source) == "default" \
        else Path(source)
    where = f"profile {path}"
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{where}: no such file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{where}: not TOML: {exc}") from None
    return parse_profile(data, path, where)


def parse_profile(data: dict[str, Any], path: Path, where: str) -> Profile:

    check_fields(data, _TOP, where)
    limits = subtable(data, "airframe", f"{where}: airframe")
    bad = sorted(set(limits) - set(AIRFRAME_LIMITS))
    if bad:
        raise ValueError(f"{where}: airframe: unknown limit(s) {', '.join(bad)}; known: "
                         f"{', '.join(AIRFRAME_LIMITS)}")
    airframe_limits = {k: number(v, f"{where}: airframe.{k}")
                       for k, v in limits.items()}
    ranges: dict[str, tuple[float, float]] = {}
    for name, value in subtable(data, "parameters", f"{where}: parameters").items():
        if name not in PARAMETER_SPECS:
            raise ValueError(f"{where}: parameters.{name}: no such parameter (ivfm params)")
        if not (isinstance(value, list) and len(value) == 2):
            raise ValueError(f"{where}: parameters.{name} must be [min, max]")
        low, high = (number(v, f"{where}: parameters.{name}") for v in value)
        if low > high:
            raise ValueError(f"{where}: parameters.{name}: min {low:g} above max {high:g}")
        ranges[name] = (low, high)
    parsed = []
    for at, f in array_of_tables(data, "flight", f"{where}: flight", _FLIGHT_KEYS):
        if not isinstance(f.get("scenario"), str):
            raise ValueError(f"{at}: scenario must be the path of a scenario file")
        realtime = f.get("realtime", False)
        if not isinstance(realtime, bool):
            raise ValueError(f"{at}: realtime must be true or false")
        parsed.append(Flight(path.parent / f["scenario"], realtime,
                             str(f.get("advice", ""))))
    return Profile(str(data.get("name", path.stem)), str(data.get("description", "")),
                   str(path), airframe_limits, ranges, tuple(parsed))


# -- the static checks ------------------------------------------------------------------

def airframe_checks(spec: AirframeSpec, parameters: dict[str, float],
                    limits: dict[str, float]) -> list[Outcome]:
    """The airframe against the profile: that it can hover at all, its rotor spins,
    thrust-to-weight, the motor command at hover, the thrust margin at the largest tilt
    the position loop asks for (MPC_TILTMAX_AIR) and the slowest motor's lag."""
    out = [_spins(spec)]
    try:
        check_controllable(spec, spec.source)
    except AirframeError as exc:
        out.append(Outcome("airframe", False, None, None, str(exc)))
        hover = None
    else:
        out.append(Outcome("airframe", True, None, None,
                           "the rotors can hover it with no torque"))
        hover = np.linalg.inv(spec.effectiveness())[:, 0]  # W_i^2 per newton, no torque
    weight_n = spec.mass_kg * GRAVITY_MPS2
    full_thrust_n = None if hover is None else min(
        r.max_rad_s**2 / share for r, share in zip(spec.rotors, hover, strict=True))
    for key, limit in limits.items():
        what, bound, unit = AIRFRAME_LIMITS[key]
        if key == "motor_time_constant_max_s":
            slowest = max(spec.rotors, key=lambda r: r.time_constant_s)
            value = slowest.time_constant_s
            detail = f" (rotor {spec.rotors.index(slowest) + 1})"
        elif full_thrust_n is None:
            out.append(Outcome(what, False, None, limit,
                               f"{what}: not measurable, the rotors cannot hover it"))
            continue
        elif key == "thrust_to_weight_min":
            value, detail = full_thrust_n / weight_n, f" ({full_thrust_n:.1f} N for " \
                f"{weight_n:.1f} N)"
        elif key == "hover_command_max":
            commands = [_command(spec, r, share * weight_n) for r, share
                        in zip(spec.rotors, hover, strict=True)]  # W_i^2 at hover
            value = max(commands)
            detail = f" (rotor {commands.index(value) + 1}, {spec.command_map} map)"
        else:
            tilt_rad = math.radians(parameters["MPC_TILTMAX_AIR"])
            needed_n = weight_n / math.cos(tilt_rad)
            value = 1.0 - needed_n / full_thrust_n
            detail = (f" ({needed_n:.1f} N of {full_thrust_n:.1f} N at MPC_TILTMAX_AIR "
                      f"{parameters['MPC_TILTMAX_AIR']:g} deg)")
        passed = value >= limit if bound == "min" else value <= limit
        sign = (">=" if passed else "<") if bound == "min" else ("<=" if passed else ">")
        out.append(Outcome(what, passed, value, limit,
                           f"{what} {value:.3g}{unit} {sign} limit {limit:g}{unit}{detail}"))
    return out


def _command(spec: AirframeSpec, rotor: Any, speed2_rad2_s2: float) -> float:
    """The motor command spinning this rotor at sqrt(speed2), through the command map:
    W / W_max (speed) or T / T_max (thrust)."""
    fraction = math.sqrt(speed2_rad2_s2) / rotor.max_rad_s
    return fraction**2 if spec.command_map == "thrust" else fraction


def _spins(spec: AirframeSpec) -> Outcome:
    """A quad's spins cancel: two each way, each pair diagonally opposite."""
    cw = [i for i, r in enumerate(spec.rotors) if r.spin > 0]
    ccw = [i for i, r in enumerate(spec.rotors) if r.spin < 0]
    names = lambda rotors: ", ".join(str(i + 1) for i in rotors)  # noqa: E731
    if len(cw) != 2 or len(ccw) != 2:
        return Outcome("rotor spins", False, None, None,
                       f"rotor spins do not cancel: cw {names(cw) or 'none'}, ccw "
                       f"{names(ccw) or 'none'} (a quad needs two of each)")
    for pair in (cw, ccw):
        a, b = (np.asarray(spec.rotors[i].position_m[:2]) for i in pair)
        if float(a @ b) >= 0.0:
            return Outcome("rotor spins", False, None, None,
                           f"rotors {names(pair)} spin the same way side by side, not "
                           f"diagonally opposite")
    return Outcome("rotor spins", True, None, None,
                   f"cw {names(cw)}, ccw {names(ccw)}, each pair diagonally opposite")


def parameter_checks(parameters: dict[str, float],
                     ranges: dict[str, tuple[float, float]]) -> list[Outcome]:
    """Each parameter the profile bounds, inside its safe range."""
    out = []
    for name, (low, high) in ranges.items():
        value = parameters[name]
        passed = low <= value <= high
        out.append(Outcome(f"parameter {name}", passed, value, [low, high],
                           f"{name} = {value:g} {'inside' if passed else 'outside'} the "
                           f"safe range [{low:g}, {high:g}]"))
    return out
