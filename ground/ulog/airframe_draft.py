"""A draft airframe file (docs/airframes.md) from a PX4 log: what the log holds of the
vehicle, every other number marked for the user to fill in.

From the log: the rotor count, positions, spin directions and moment ratios of PX4's
control allocation (CA_ROTOR_COUNT, CA_ROTORn_PX/PY/PZ, CA_ROTORn_KM: > 0 counter-clockwise,
|KM| = moment / thrust; PX4 1.13 and later), the thrust model (THR_MDL_FAC: the command
map), the hover thrust (hover_thrust_estimate in flight, else MPC_THR_HOVER) which with
the mass gives each rotor's full thrust, T_max,i = m g / hover x CT_i / sum CT (the
CA_ROTORn_CT share), and the rotors' top speed from ESC telemetry (esc_status rpm, when
logged) or --max-rad-s; then k = T_max / W_max^2 and km = |KM| k.

Not in a PX4 log, marked ``TO_FILL`` (every command refuses the file until none is left,
naming them): the inertia, and whatever of the above the log lacks. Marked ``ASSUMED``
(a default, to check): airframe drag, the motors' time constant, the rotors' inertia.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from contracts.airframe_file import TO_FILL, AirframeError, check_controllable, parse_airframe
from contracts.frames import GRAVITY_MPS2
from ground.ulog.clock import airborne_spans, flight_reach
from ground.ulog.read import (
    MOTOR1_FUNCTION,
    PX4Log,
    ULogError,
    check_quad_log,
    mav_type_name,
    read_log,
)

ROTORS = 4
AXIS_TOLERANCE = 1e-3  # a rotor axis this close to (0, 0, -1) is straight up
ESC_MIN_FRACTION = 0.05  # ESC samples below this thrust fraction (idle) are not fitted
ESC_MIN_R2 = 0.8


def f32(value: float) -> float:
    """A float32 parameter as the shortest decimal that is it: what the user typed into
    PX4 (0.175, not 0.17499999701976776)."""
    return float(np.format_float_positional(np.float32(value), unique=True, trim="0"))


def g6(value: float) -> float:
    """A derived number to 6 significant digits."""
    return float(f"{value:.6g}")


@dataclass(frozen=True)
class Rotor:
    """One rotor of PX4's control allocation (CA_ROTORn, n from 0)."""

    n: int
    position_m: tuple[float, float, float] | None
    km: float | None  # moment ratio; sign: spin (> 0 counter-clockwise)
    ct: float | None

    @property
    def spin(self) -> str | None:
        if self.km is None or self.km == 0.0:
            return None
        return "ccw" if self.km > 0 else "cw"

    def where(self) -> str:
        if self.position_m is None:
            return ""
        x, y = self.position_m[:2]
        front = "front" if x > 1e-6 else "rear" if x < -1e-6 else ""
        side = "right" if y > 1e-6 else "left" if y < -1e-6 else ""
        return " ".join(w for w in (front, side) if w) or "centre"


def rotors_from_log(log: PX4Log) -> tuple[Rotor, ...] | None:
    """The control allocation's four rotors, or None when the log has no CA_ parameters
    (PX4 before 1.13 kept the geometry in a mixer file). ULogError for an allocation this
    stack cannot fly: not a multicopter, not 4 rotors, a tilted rotor."""
    check_quad_log(log)
    p = log.parameters
    if "CA_ROTOR_COUNT" not in p:
        return None
    rotors = []
    for n in range(ROTORS):
        name = f"CA_ROTOR{n}"
        tilt = p.get(f"{name}_TILT")
        if tilt is not None and int(tilt) != 0:
            raise ULogError(f"{log.path}: {name}_TILT = {int(tilt)}: rotor {n + 1} tilts on "
                            "a servo; this stack's rotors are fixed, pushing along -z")
        axis = np.array([p.get(f"{name}_AX", 0.0), p.get(f"{name}_AY", 0.0),
                         p.get(f"{name}_AZ", -1.0)], dtype=float)
        norm = np.linalg.norm(axis)
        if not (norm > 0 and np.all(np.abs(axis / norm - [0, 0, -1]) < AXIS_TOLERANCE)):
            raise ULogError(f"{log.path}: {name}_AX/AY/AZ = ({', '.join(f'{a:g}' for a in axis)})"
                            f": rotor {n + 1} is tilted; this stack's rotors push along -z "
                            "(axis 0, 0, -1)")
        px, py, pz = (p.get(f"{name}_P{c}") for c in "XYZ")
        position = None if px is None or py is None else (f32(px), f32(py), f32(pz or 0.0))
        km, ct = p.get(f"{name}_KM"), p.get(f"{name}_CT")
        rotors.append(Rotor(n, position, None if km is None else f32(km),
                            None if ct is None else f32(ct)))
    spins = [r.spin for r in rotors]
    if None not in spins and spins.count("cw") != 2:
        raise ULogError(f"{log.path}: CA_ROTOR0-3_KM: rotors 1-4 spin {', '.join(spins)}: a "
                        "quadrotor needs two of each (their drag torques cancel), each pair "
                        "diagonally opposite")
    return tuple(rotors)


def _in_spans(t: np.ndarray, spans) -> np.ndarray:
    inside = np.zeros(len(t), dtype=bool)
    for a, b in spans:
        inside |= (t >= a) & (t <= b)
    return inside


def _spans(log: PX4Log):
    try:
        return airborne_spans(log, (1.0, 1.0)).spans
    except ULogError:
        return ()


def hover_thrust(log: PX4Log) -> tuple[float, str] | None:
    """The collective thrust fraction at a hover: the median of hover_thrust_estimate's
    valid airborne estimates, else MPC_THR_HOVER."""
    if log.source("hover_thrust") is not None:
        s = log.series("hover_thrust")
        spans = _spans(log)
        keep = (s.values[:, 1] != 0) & np.isfinite(s.values[:, 0])
        if spans:
            keep &= _in_spans(s.time_s, spans)
        values = s.values[keep, 0]
        values = values[(values > 0.0) & (values < 1.0)]
        if len(values):
            return (f32(float(np.median(values))),
                    f"hover_thrust_estimate, median of {len(values)} airborne estimates")
    found = log.parameter("hover_thrust")
    if found is not None and 0.0 < found[1] < 1.0:
        return f32(found[1]), f"{found[0]} = {f32(found[1]):g}"
    return None


def esc_top_speeds(log: PX4Log) -> tuple[tuple[float, ...] | None, str] | None:
    """Each rotor's top speed [rad/s] fitted to ESC telemetry: W = W_max sqrt(thrust
    fraction) over the airborne samples (actuator_motors and esc_status.esc[k].esc_rpm);
    None without both; (None, why) when the fit explains less than 80 % of the
    variance."""
    esc = log.topic("esc_status")
    motors = log.source("motors")
    if esc is None or motors is None or motors[0].topic != "actuator_motors":
        return None
    fractions = log.series("motors")
    t = (esc.data["timestamp"].astype(np.int64) - int(log.ulog.start_timestamp)) / 1e6
    spans = _spans(log)
    keep = _in_spans(t, spans) if spans else np.ones(len(t), dtype=bool)
    keep &= t >= fractions.time_s[0]
    out, worst = [], 1.0
    for j in range(ROTORS):
        k = j
        for e in range(8):
            function = esc.data.get(f"esc[{e}].actuator_function")
            if function is not None and len(function) and int(function[0]) == MOTOR1_FUNCTION + j:
                k = e
        rpm = esc.data.get(f"esc[{k}].esc_rpm")
        if rpm is None:
            return None
        idx = np.searchsorted(fractions.time_s, t[keep], side="right") - 1
        s = np.sqrt(np.clip(fractions.values[idx, j], 0.0, 1.0))
        w = np.abs(rpm[keep].astype(float)) * 2.0 * math.pi / 60.0
        use = np.isfinite(s) & (s * s > ESC_MIN_FRACTION)
        if np.count_nonzero(use) < 20:
            return None
        s, w = s[use], w[use]
        w_max = float(np.sum(w * s) / np.sum(s * s))
        spread = np.sum((w - w.mean()) ** 2)
        r2 = 1.0 - np.sum((w - w_max * s) ** 2) / spread if spread > 0 else 0.0
        worst = min(worst, r2)
        out.append(g6(w_max))
    if worst < ESC_MIN_R2:
        return None, (f"esc_status rpm does not follow W = W_max sqrt(thrust): R^2 "
                      f"{worst:.2f} < {ESC_MIN_R2:g}")
    return tuple(out), f"esc_status rpm fitted to W = W_max sqrt(thrust), R^2 >= {worst:.2f}"


def layout(rotors: tuple[Rotor, ...]) -> str:
    """quad X, quad + or an asymmetric quad, from the positions."""
    xy = [r.position_m[:2] for r in rotors if r.position_m is not None]
    if len(xy) < ROTORS:
        return "quad"
    if all(abs(abs(x) - abs(y)) <= 0.01 * max(abs(x), abs(y)) for x, y in xy):
        return "quad X"
    if all(min(abs(x), abs(y)) <= 1e-6 for x, y in xy):
        return "quad +"
    return "quad (asymmetric)"


@dataclass
class Draft:
    """The draft airframe file and what it says."""

    text: str
    to_fill: list[str]
    assumed: list[str]
    from_log: list[str] = field(default_factory=list)


def _toml(value) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(float(value))


class _Writer:
    """TOML lines with a comment each; records what is to fill, assumed, or read."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.to_fill: list[str] = []
        self.assumed: list[str] = []

    def comment(self, text: str = "") -> None:
        self.lines.append(f"# {text}".rstrip())

    def key(self, name: str, value, note: str, where: str = "") -> None:
        where = where or name
        if value is None:
            self.to_fill.append(where)
            value, note = TO_FILL, f"TO_FILL: {note}"
        elif note.startswith("ASSUMED"):
            self.assumed.append(where)
        self.lines.append(f"{name} = {_toml(value)}  # {note}")


def draft_airframe(path: str | Path, mass_kg: float, max_rad_s: float | None = None,
                   name: str = "my-quad") -> Draft:
    """The draft airframe file of the log at ``path``, for a vehicle of ``mass_kg``;
    ULogError when the log is not a quadrotor's this stack can fly."""
    log = read_log(path)
    rotors = rotors_from_log(log)
    hover = hover_thrust(log)
    esc_note = ""
    if max_rad_s is not None:
        top: tuple[float, ...] | None = (float(max_rad_s),) * ROTORS
        top_said = "given: --max-rad-s"
    else:
        esc = esc_top_speeds(log)
        top, top_said = (esc if esc is not None else (None, ""))
        esc_note = top_said if top is None and top_said else ""
    factor = log.parameter("thrust_model_factor")
    weight_n = mass_kg * GRAVITY_MPS2
    cts = [r.ct for r in rotors] if rotors else [None] * ROTORS
    share_from_ct = all(c is not None and c > 0 for c in cts)
    share = [c / sum(cts) for c in cts] if share_from_ct else [0.25] * ROTORS
    t_max = None if hover is None else [weight_n / hover[0] * s for s in share]

    w = _Writer()
    version = log.version()
    mav_type = mav_type_name(log.parameters.get("MAV_TYPE"))
    autostart = log.parameters.get("SYS_AUTOSTART")
    shape = layout(rotors) if rotors else "quad"
    w.comment(f"Draft airframe from the PX4 log {Path(path).name}: PX4 {version}, "
              f"MAV_TYPE {mav_type}, SYS_AUTOSTART {autostart if autostart is not None else '?'}.")
    w.comment("Written by `ivfm airframe from-ulog` (docs/px4-logs.md; the fields: "
              "docs/airframes.md).")
    w.comment("")
    w.comment('"TO_FILL" marks each number the log does not hold: put in yours. Every command')
    w.comment("refuses this file, naming them, while one is left.")
    w.comment("ASSUMED marks a number the log does not hold either, given a default: check it.")
    w.comment("The others come from the log, as each comment says.")
    w.lines.append("")
    w.lines.append(f"name = {_toml(name)}")
    w.lines.append(f"description = {_toml(f'{shape} from a PX4 log ({Path(path).name}), draft')}")
    w.key("mass_kg", float(mass_kg), "given: --mass-kg")
    w.key("inertia_kgm2", None, "3x3 about the centre of mass, body FRD [kg m^2], e.g. "
          "[[0.02, 0.0, 0.0], [0.0, 0.02, 0.0], [0.0, 0.0, 0.04]] (from CAD, or a "
          "pendulum test)")
    w.key("linear_drag_nspm", 0.0, "ASSUMED: no airframe drag (not in a PX4 log)")
    if factor is not None:
        w.key("command_map", "speed" if factor[1] >= 0.5 else "thrust",
              f"{factor[0]} = {f32(factor[1]):g}: thrust ~ signal"
              + ("^2 (speed ~ signal)" if factor[1] >= 0.5 else " (thrust map)")
              + ("" if factor[1] in (0.0, 1.0) else "; ASSUMED the nearer of the two maps"))
        if factor[1] not in (0.0, 1.0):
            w.assumed.append("command_map")
    else:
        w.key("command_map", "speed", "ASSUMED: no THR_MDL_FAC in the log")
    w.lines.append("")
    w.comment("What the vehicle flies, which the data of `ivfm identify` must cover "
              "(docs/airframes.md;")
    w.comment("without the table: 1 rad, 1 rad/s, 0.5 rad/s).")
    reached = flight_reach(log)
    if reached is not None:
        w.comment(f"This log's flight reached {reached[0]:.2f} rad, {reached[1]:.2f} rad/s "
                  f"(roll, pitch), {reached[2]:.2f} rad/s (yaw).")
    w.comment("[envelope]")
    w.comment("attitude_rad = 0.7")
    w.comment("rate_rad_s = 1.0")
    w.comment("yaw_rate_rad_s = 0.5")
    w.lines.append("")
    w.lines.append("[draft]  # where the numbers came from (may stay once filled)")
    w.lines.append(f"log = {_toml(str(path))}")
    w.lines.append(f"px4 = {_toml(version)}")
    if hover is not None:
        w.lines.append(f"hover_thrust = {_toml(hover[0])}  # {hover[1]}")
    if t_max is not None:
        how = "x CA_ROTORn_CT / sum of them" if share_from_ct else "/ 4 (rotors alike)"
        w.lines.append(f"max_thrust_n = {_toml([g6(t) for t in t_max])}  # per rotor: "
                       f"m g / hover_thrust {how}")
    draft_table = len(w.lines)

    for i in range(ROTORS):
        r = rotors[i] if rotors else Rotor(i, None, None, None)
        ca = f"CA_ROTOR{i}"
        at = f"rotor[{i + 1}]"
        w.lines.append("")
        w.lines.append(f"[[rotor]]  # {i + 1}: {ca}{', ' + r.where() if r.where() else ''}")
        w.key("position_m", None if r.position_m is None else list(r.position_m),
              f"{ca}_PX, _PY, _PZ" if r.position_m is not None else
              "[x, y, z] from the centre of mass, FRD [m] (not in the log: PX4 before 1.13 "
              f"kept it in the mixer of SYS_AUTOSTART {autostart})", f"{at}.position_m")
        w.key("spin", r.spin, f"{ca}_KM = {r.km:g} " + (
            "> 0: counter-clockwise seen from above" if r.spin == "ccw" else
            "< 0: clockwise seen from above") if r.spin else
            '"cw" or "ccw" seen from above (no CA_ROTORn_KM sign in the log)', f"{at}.spin")
        k = None if (t_max is None or top is None) else g6(t_max[i] / top[i] ** 2)
        k_note = (f"max thrust {t_max[i]:.4g} N / max_rad_s^2" if k is not None else
                  f"= {t_max[i]:.4g} N (its max thrust) / max_rad_s^2" if t_max is not None
                  else "its max thrust [N] / max_rad_s^2 (no hover thrust in the log)")
        w.key("thrust_coeff_ns2", k, k_note, f"{at}.thrust_coeff_ns2")
        km = None if (k is None or r.km is None) else g6(abs(r.km) * k)
        km_note = (f"|{ca}_KM| x thrust_coeff_ns2" if km is not None else
                   f"= {abs(r.km):g} (|{ca}_KM|) x thrust_coeff_ns2" if r.km is not None
                   else "the rotor's drag torque per W^2 [N m s^2] (no CA_ROTORn_KM)")
        w.key("moment_coeff_nms2", km, km_note, f"{at}.moment_coeff_nms2")
        w.key("max_rad_s", None if top is None else top[i], top_said if top is not None else
              "the rotor's top speed [rad/s] (motor KV x battery volts x 2 pi / 60, less "
              "under load; or --max-rad-s, or log esc_status)"
              + (f"; {esc_note}" if esc_note else ""), f"{at}.max_rad_s")
        w.key("time_constant_s", 0.0, "ASSUMED: no motor lag (not in a PX4 log); a 10\" "
              "propeller's is 0.02-0.05 s", f"{at}.time_constant_s")
        w.key("inertia_kgm2", 0.0, "ASSUMED: no rotor inertia (not in a PX4 log)",
              f"{at}.inertia_kgm2")

    w.lines[draft_table:draft_table] = [
        f"to_fill = {_toml(w.to_fill)}",
        f"assumed = {_toml(w.assumed)}"]
    text = "\n".join(w.lines) + "\n"
    _check(text, w.to_fill, log, rotors)
    return Draft(text, w.to_fill, w.assumed)


def _check(text: str, to_fill: list[str], log: PX4Log, rotors) -> None:
    """The draft as TOML reads back; filled, it flies; with TO_FILL left, its geometry
    (with stand-in numbers for the rest) can fly."""
    data = tomllib.loads(text)
    if not to_fill:
        try:
            parse_airframe(data, f"the draft of {log.path}")
        except AirframeError as exc:
            raise ULogError(f"{log.path}: the log's vehicle cannot fly here: {exc}") from None
        return
    if rotors is None or any(r.position_m is None or r.spin is None for r in rotors):
        return
    probe = dict(data)
    probe.pop("draft")
    probe["inertia_kgm2"] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    probe["rotor"] = [{**rotor, "thrust_coeff_ns2": 1e-5, "moment_coeff_nms2": 1e-7,
                       "max_rad_s": 1e4} for rotor in data["rotor"]]
    try:
        spec = parse_airframe(probe, "probe", controllable=False)
        check_controllable(spec, f"{log.path}: the rotor geometry of the log's allocation")
    except AirframeError as exc:
        raise ULogError(str(exc)) from None
