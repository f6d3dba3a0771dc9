"""Airframe files (TOML): the user's quadrotor as data, read by the simulator (truth), the
autopilot (nominal model, mixer) and identification alike.

A file names the vehicle completely: mass, full inertia matrix, airframe drag, how a motor
command maps to the rotor, and one ``[[rotor]]`` table per rotor in motor order
(``controls[i]`` of HIL_ACTUATOR_CONTROLS drives rotor i+1, PX4's numbering). Conventions
(docs/airframes.md): body FRD; rotor i at r_i pushes T_i = k_i W_i^2 along -z_b, giving
roll torque -y_i T_i and pitch torque x_i T_i; a rotor spinning clockwise seen from above
(``spin = "cw"``, s_i = +1) has its angular velocity along +z_b and its drag reaction
yaws the body by -s_i km_i W_i^2 (counter-clockwise rotors yaw the nose right). The
effectiveness matrix, thrust and torques per W_i^2, comes from that geometry once.

Every field is checked; an error names the file and the field.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from contracts.toml_files import read_named_toml, shipped_names
from contracts.toml_tables import check_fields, number

SHIPPED_DIR = "airframes"
COMMAND_MAPS = ("speed", "thrust")  # c -> W = c W_max (jMAVSim, Gazebo) / T = c T_max (SIH)
SPINS = {"cw": 1.0, "ccw": -1.0}
_TOP_KEYS = {"name", "description", "mass_kg", "inertia_kgm2", "linear_drag_nspm",
             "command_map", "rotor", "parameters", "envelope", "draft"}
# A draft airframe (``ivfm airframe from-ulog``) marks each number it could not read so;
# no command reads the file until none is left. Its [draft] table says where the others
# came from, and may stay.
TO_FILL = "TO_FILL"
# An envelope's largest values: beyond 1.2 rad, roll and pitch together leave no thrust
# to spare.
ENVELOPE_LIMITS = {"attitude_rad": 1.2, "rate_rad_s": 5.0, "yaw_rate_rad_s": 5.0}
_ROTOR_KEYS = {"position_m", "spin", "thrust_coeff_ns2", "moment_coeff_nms2", "max_rad_s",
               "time_constant_s", "inertia_kgm2"}


class Envelope(NamedTuple):
    """The attitude and rates a vehicle flies, which its identification data must cover
    (an airframe file's ``[envelope]``). The default is the paper's attitude-sine: 1 rad
    at 1 rad/s on roll and pitch."""

    attitude_rad: float = 1.0  # roll and pitch
    rate_rad_s: float = 1.0  # roll and pitch rates
    yaw_rate_rad_s: float = 0.5


PAPER_ENVELOPE = Envelope()


class AirframeError(ValueError):
    """An airframe file that breaks the format; the message names the file and field."""


@dataclass(frozen=True)
class RotorSpec:
    position_m: tuple[float, float, float]  # body FRD, from the centre of mass
    spin: float  # +1 clockwise seen from above, -1 counter-clockwise
    thrust_coeff_ns2: float  # k: T = k W^2
    moment_coeff_nms2: float  # km: drag torque km W^2
    max_rad_s: float
    time_constant_s: float  # first-order lag of the rotor speed, 0 = ideal
    inertia_kgm2: float  # rotor and propeller, for the gyroscopic term


@dataclass(frozen=True)
class AirframeSpec:
    name: str
    description: str
    mass_kg: float
    inertia_kgm2: np.ndarray  # 3x3, symmetric positive definite, body FRD
    linear_drag_nspm: float
    command_map: str
    rotors: tuple[RotorSpec, ...]
    source: str = ""
    # The vehicle's own parameter defaults (as a PX4 airframe file sets them): names and
    # values checked by the autopilot's parameter table where they are used; not part of
    # the fingerprint (a model identified on the vehicle does not depend on them).
    parameters: tuple[tuple[str, float], ...] = ()
    # [envelope]: the roll/pitch attitude [rad], roll/pitch rate and yaw rate [rad/s] the
    # vehicle flies, which its identification must cover (ivfm identify); None: the
    # paper's. Not part of the fingerprint either.
    envelope: Envelope | None = None

    @property
    def argument(self) -> str:
        """The ``--airframe`` text it was read from (a shipped name or a file path): what
        a process started for it is given, and what messages tell the user to type."""
        return self.source.removeprefix("airframe file ").removeprefix("airframe ")

    def fingerprint(self) -> str:
        """A short hash of everything that makes the vehicle fly as it does (not its name
        or description): a model identified on it records this."""
        numbers = [self.mass_kg, *self.inertia_kgm2.ravel(), self.linear_drag_nspm,
                   self.command_map]
        for r in self.rotors:
            numbers += [*r.position_m, r.spin, r.thrust_coeff_ns2, r.moment_coeff_nms2,
                        r.max_rad_s, r.time_constant_s, r.inertia_kgm2]
        text = json.dumps([repr(float(n)) if not isinstance(n, str) else n for n in numbers])
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def effectiveness(self) -> np.ndarray:
        """(4, n): collective thrust [N], roll, pitch and yaw torque [N m] per W_i^2."""
        out = np.empty((4, len(self.rotors)))
        for i, r in enumerate(self.rotors):
            x, y, _z = r.position_m
            out[0, i] = r.thrust_coeff_ns2
            out[1, i] = -y * r.thrust_coeff_ns2
            out[2, i] = x * r.thrust_coeff_ns2
            out[3, i] = -r.spin * r.moment_coeff_nms2
        return out


def shipped_airframe_names() -> list[str]:
    return shipped_names("contracts", SHIPPED_DIR)


def read_airframe(source: str | Path, controllable: bool = True) -> AirframeSpec:
    """A shipped airframe by name, or an airframe file by path. ``controllable=False``
    reads a file whose rotors cannot fly it (for a rehearsal to say why, check by check)."""
    data, where = read_named_toml(source, "contracts", SHIPPED_DIR, "airframe", AirframeError)
    return parse_airframe(data, where, default_name=Path(str(source)).stem,
                          controllable=controllable)


def envelope_of(spec: AirframeSpec) -> Envelope:
    """The envelope an airframe file names in ``[envelope]``, else the paper's."""
    return spec.envelope or PAPER_ENVELOPE


def spec_argument(text: str) -> AirframeSpec:
    """argparse type of ``--airframe NAME|FILE`` that keeps what it read: the airframe
    file is read once, at the command line, and the spec passed inward (its
    AirframeError is the usage error)."""
    try:
        return read_airframe(text)
    except AirframeError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def to_fill(data: dict[str, Any]) -> list[str]:
    """The fields of an airframe table still marked TO_FILL, named as errors name them."""
    def marked(value: Any) -> bool:
        return value == TO_FILL or (isinstance(value, list) and any(map(marked, value)))

    out = []
    for key, value in data.items():
        if key == "draft":
            continue
        if key == "rotor" and isinstance(value, list):
            out += [f"rotor[{i + 1}].{k}" for i, r in enumerate(value) if isinstance(r, dict)
                    for k, v in r.items() if marked(v)]
        elif isinstance(value, dict):
            out += [f"{key}.{k}" for k, v in value.items() if marked(v)]
        elif marked(value):
            out.append(key)
    return out


def parse_airframe(data: dict[str, Any], where: str = "airframe",
                   default_name: str = "airframe", controllable: bool = True) -> AirframeSpec:
    missing = to_fill(data)
    if missing:
        raise AirframeError(f"{where}: a draft airframe: fill in {', '.join(missing)} (each "
                            f"marked \"{TO_FILL}\"; docs/px4-logs.md)")
    if "draft" in data and not isinstance(data["draft"], dict):
        raise AirframeError(f"{where}: draft must be a table")
    check_fields(data, _TOP_KEYS, where, AirframeError)
    for key in ("mass_kg", "inertia_kgm2", "rotor"):
        if key not in data:
            raise AirframeError(f"{where}: {key} is required")
    name = data.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise AirframeError(f"{where}: name must be a non-empty string")
    command_map = data.get("command_map", "speed")
    if command_map not in COMMAND_MAPS:
        raise AirframeError(f"{where}: command_map must be one of {', '.join(COMMAND_MAPS)}, "
                            f"got {command_map!r}")
    rotors = data["rotor"]
    if not isinstance(rotors, list) or not rotors:
        raise AirframeError(f"{where}: rotor must be a list of [[rotor]] tables")
    spec = AirframeSpec(
        name=name,
        description=str(data.get("description", "")),
        mass_kg=_number(data["mass_kg"], f"{where}: mass_kg", 1e-3, 1e3),
        inertia_kgm2=_inertia(data["inertia_kgm2"], f"{where}: inertia_kgm2"),
        linear_drag_nspm=_number(data.get("linear_drag_nspm", 0.0),
                                 f"{where}: linear_drag_nspm", 0.0, 1e3),
        command_map=command_map,
        rotors=tuple(_rotor(r, f"{where}: rotor[{i + 1}]") for i, r in enumerate(rotors)),
        source=where,
        parameters=_parameters(data.get("parameters", {}), where),
        envelope=_envelope(data["envelope"], where) if "envelope" in data else None,
    )
    if controllable:
        check_controllable(spec, where)
    return spec


def _parameters(value: Any, where: str) -> tuple[tuple[str, float], ...]:
    """[parameters] NAME = value: the vehicle's parameter defaults."""
    if not isinstance(value, dict):
        raise AirframeError(f"{where}: parameters must be a table of NAME = value")
    out = []
    for name, given in value.items():
        if not (isinstance(name, str) and 0 < len(name) <= 16):
            raise AirframeError(f"{where}: parameters: {name!r} is not a parameter name")
        out.append((name, number(given, f"{where}: parameters.{name}", error=AirframeError)))
    return tuple(out)


def _envelope(value: Any, where: str) -> Envelope:
    """[envelope] attitude_rad, rate_rad_s, yaw_rate_rad_s: all three, each positive."""
    if not isinstance(value, dict) or set(value) != set(Envelope._fields):
        raise AirframeError(f"{where}: envelope must be a table of exactly "
                            f"{', '.join(Envelope._fields)}")
    return Envelope(*(_number(value[k], f"{where}: envelope.{k}", 0.0, ENVELOPE_LIMITS[k],
                              positive=True) for k in Envelope._fields))


def _number(value: Any, what: str, low: float, high: float, positive: bool = False) -> float:
    return number(value, what, low, high, low_open=positive, error=AirframeError)


def _inertia(value: Any, what: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 3 or not all(
            isinstance(row, list) and len(row) == 3 for row in value):
        raise AirframeError(f"{what} must be a 3x3 matrix [[..], [..], [..]], got {value!r}")
    matrix = np.array([[_number(v, f"{what}[{i}][{j}]", -1e3, 1e3) for j, v in enumerate(row)]
                       for i, row in enumerate(value)])
    if not np.allclose(matrix, matrix.T, rtol=0.0, atol=1e-12):
        raise AirframeError(f"{what} must be symmetric, got {value!r}")
    if np.min(np.linalg.eigvalsh(matrix)) <= 0.0:
        raise AirframeError(f"{what} must be positive definite, got {value!r}")
    return matrix


def _rotor(value: Any, where: str) -> RotorSpec:
    if not isinstance(value, dict):
        raise AirframeError(f"{where} must be a table")
    check_fields(value, _ROTOR_KEYS, where, AirframeError)
    missing = sorted(k for k in _ROTOR_KEYS - {"time_constant_s", "inertia_kgm2"}
                     if k not in value)
    if missing:
        raise AirframeError(f"{where}: {', '.join(missing)} required")
    position = value["position_m"]
    if not isinstance(position, list) or len(position) != 3:
        raise AirframeError(f"{where}.position_m must be [x, y, z] in metres (FRD)")
    spin = value["spin"]
    if not isinstance(spin, str) or spin not in SPINS:
        raise AirframeError(f"{where}.spin must be \"cw\" or \"ccw\" (seen from above), "
                            f"got {spin!r}")
    return RotorSpec(
        position_m=tuple(_number(v, f"{where}.position_m", -10.0, 10.0) for v in position),
        spin=SPINS[spin],
        thrust_coeff_ns2=_number(value["thrust_coeff_ns2"], f"{where}.thrust_coeff_ns2",
                                 0.0, 1.0, positive=True),
        moment_coeff_nms2=_number(value["moment_coeff_nms2"], f"{where}.moment_coeff_nms2",
                                  0.0, 1.0, positive=True),
        max_rad_s=_number(value["max_rad_s"], f"{where}.max_rad_s", 0.0, 1e5, positive=True),
        time_constant_s=_number(value.get("time_constant_s", 0.0),
                                f"{where}.time_constant_s", 0.0, 10.0),
        inertia_kgm2=_number(value.get("inertia_kgm2", 0.0), f"{where}.inertia_kgm2", 0.0,
                             1.0),
    )


def check_controllable(spec: AirframeSpec, where: str) -> None:
    """Rotors that can hover it and that reach every axis (the effectiveness matrix has
    full rank), so the mixer can invert it."""
    if len(spec.rotors) != 4:
        raise AirframeError(f"{where}: this stack flies quadrotors: 4 rotors, not "
                            f"{len(spec.rotors)}")
    if np.linalg.matrix_rank(spec.effectiveness(), tol=1e-12) < 4:
        raise AirframeError(f"{where}: the rotors cannot produce thrust, roll, pitch and yaw "
                            "independently (the effectiveness matrix is rank deficient; on a "
                            "quad, rotors of one spin sit diagonally opposite)")
    hover_share = np.linalg.inv(spec.effectiveness())[:, 0]  # W_i^2 per newton, no torque
    spins = [r.spin for r in spec.rotors]
    unbalanced = (f" ({spins.count(1.0)} rotor(s) spin cw and {spins.count(-1.0)} ccw: "
                  "their drag torques cannot cancel)" if sum(spins) != 0.0 else "")
    if np.any(hover_share <= 0.0):
        raise AirframeError(f"{where}: thrust without torque needs a rotor to push down"
                            f"{unbalanced or ' (the centre of mass is outside the rotors)'}: "
                            "no mixer can hover it")
    # The largest thrust with no torque: until the first rotor is at its top.
    max_thrust = min(r.max_rad_s**2 / share for r, share in zip(spec.rotors, hover_share,
                                                                 strict=True))
    weight = spec.mass_kg * 9.81
    if max_thrust <= weight:
        raise AirframeError(f"{where}: the rotors give at most {max_thrust:.3g} N without "
                            f"torque, not more than the weight {weight:.3g} N{unbalanced}: "
                            "it cannot fly")
