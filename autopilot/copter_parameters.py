"""The ArduPilot flavour's parameters: Copter's names, units and AP_Param types, each a
view of one internal parameter (autopilot/parameters.py, the one table) or, where this
vehicle has nothing that obeys it, a value kept for the tools that read and write it.

Why a view and not a second table: the vehicle flies one set of internal values; the
Copter name, its unit (cm, cm/s, centidegrees ...) and its type only change how a ground
tool sees and sets them. A Copter value is ``internal * scale``, or for an enumeration
the Copter number paired with the internal one (``values``).

Copter (AP_Param::set_float) casts what a tool sends to the parameter's own type: a whole
number for INT8/16/32 (rounded by adding 0.01 away from zero, then truncated) clamped to
the type's range. :func:`cast` does the same before the value is mapped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from autopilot.parameters import PARAMETER_SPECS, PARAMETERS, SMC_GROUPS

# AP_Param's integer types and their ranges (REAL32 is a float).
TYPE_RANGES = {"INT8": (-128, 127), "INT16": (-32768, 32767),
               "INT32": (-2147483648, 2147483647)}


@dataclass(frozen=True)
class CopterParam:
    name: str  # Copter's name
    ap_type: str  # Copter's AP_Param type: INT8, INT16, INT32 or REAL32
    unit: str  # Copter's unit
    internal: str | None = None  # the internal parameter shown; None: stored here only
    scale: float = 1.0  # Copter value = internal value * scale
    values: tuple[tuple[float, float], ...] = ()  # enumeration: (Copter, internal) pairs
    default: float = 0.0  # a stored-only parameter's value at start (Copter's default)

    def from_internal(self, internal_value: float) -> float:
        """The Copter value of an internal one (the first Copter number paired with it)."""
        if self.values:
            return next(c for c, i in self.values if i == internal_value)
        return internal_value * self.scale

    def to_internal(self, copter_value: float) -> float:
        """The internal value of a Copter one already cast to its type; ValueError for an
        enumeration number this vehicle has no behaviour for."""
        if self.values:
            for c, i in self.values:
                if c == copter_value:
                    return i
            raise ValueError(f"{self.name} {copter_value:g} is not supported here "
                             f"(one of {', '.join(f'{c:g}' for c, _ in self.values)})")
        return copter_value / self.scale


def cast(ap_type: str, value: float) -> float:
    """``value`` as Copter stores it in ``ap_type`` (AP_Param::set_float's C cast)."""
    if ap_type == "REAL32":
        return value
    low, high = TYPE_RANGES[ap_type]
    nudged = value + (0.01 if value >= 0 else -0.01)
    return float(min(max(math.trunc(nudged), low), high))


def _mapped(name: str, ap_type: str, unit: str, internal: str, scale: float = 1.0,
            values: tuple[tuple[float, float], ...] = ()) -> CopterParam:
    return CopterParam(name, ap_type, unit, internal, scale, values)


def _stored(name: str, ap_type: str, unit: str, default: float) -> CopterParam:
    return CopterParam(name, ap_type, unit, default=default)


# Copter's failsafe action numbers paired with the internal ones (NAV_DLL_ACT 0 none,
# 1 hold, 2 return, 3 land; NAV_RCL_ACT the same without 0; GF_ACTION 0 none, 1 warn,
# 2 hold, 3 return, 5 land). Copter's "brake or land" (7) is the hold.
_FS_GCS = ((0.0, 0.0), (1.0, 2.0), (5.0, 3.0), (7.0, 1.0))
_FENCE_ACTION = ((0.0, 1.0), (1.0, 3.0), (2.0, 5.0), (4.0, 2.0), (0.0, 0.0))

COPTER_PARAMETERS: tuple[CopterParam, ...] = (
    _stored("SYSID_THISMAV", "INT16", "", 1.0),
    _mapped("FS_GCS_ENABLE", "INT8", "", "NAV_DLL_ACT", values=_FS_GCS),
    _mapped("FS_GCS_TIMEOUT", "REAL32", "s", "COM_DL_LOSS_T"),
    _stored("FS_EKF_THRESH", "REAL32", "", 0.8),
    _stored("FS_EKF_ACTION", "INT8", "", 1.0),
    _stored("ARMING_CHECK", "INT32", "", 1.0),
    _mapped("DISARM_DELAY", "INT8", "s", "COM_DISARM_LAND"),
    _stored("MOT_SPIN_ARM", "REAL32", "", 0.1),
    _stored("MOT_SPIN_MIN", "REAL32", "", 0.15),
    _stored("MOT_SPIN_MAX", "REAL32", "", 0.95),
    _stored("MOT_THST_HOVER", "REAL32", "", 0.35),
    _mapped("WPNAV_SPEED", "REAL32", "cm/s", "MPC_XY_CRUISE", 100.0),
    _mapped("WPNAV_SPEED_UP", "REAL32", "cm/s", "MPC_Z_VEL_MAX_UP", 100.0),
    _mapped("WPNAV_SPEED_DN", "REAL32", "cm/s", "MPC_Z_VEL_MAX_DN", 100.0),
    _mapped("WPNAV_ACCEL", "REAL32", "cm/s/s", "MPC_ACC_HOR", 100.0),
    _mapped("WPNAV_RADIUS", "REAL32", "cm", "NAV_ACC_RAD", 100.0),
    _mapped("LOIT_SPEED", "REAL32", "cm/s", "MPC_VEL_MANUAL", 100.0),
    _mapped("PILOT_SPEED_UP", "INT16", "cm/s", "MPC_Z_VEL_MAX_UP", 100.0),
    _mapped("PILOT_SPEED_DN", "INT16", "cm/s", "MPC_Z_VEL_MAX_DN", 100.0),
    _mapped("ANGLE_MAX", "INT16", "cdeg", "MPC_TILTMAX_AIR", 100.0),
    _mapped("RTL_ALT", "INT32", "cm", "RTL_RETURN_ALT", 100.0),
    _stored("RTL_ALT_FINAL", "INT16", "cm", 0.0),
    _stored("RTL_LOIT_TIME", "INT32", "ms", 5000.0),
    _stored("RTL_SPEED", "INT16", "cm/s", 0.0),
    _mapped("LAND_SPEED", "INT16", "cm/s", "MPC_LAND_SPEED", 100.0),
    _stored("FENCE_ENABLE", "INT8", "", 0.0),
    _stored("FENCE_TYPE", "INT8", "", 7.0),
    _mapped("FENCE_ACTION", "INT8", "", "GF_ACTION", values=_FENCE_ACTION),
    _mapped("FENCE_ALT_MAX", "REAL32", "m", "GF_MAX_VER_DIST"),
    _mapped("FENCE_RADIUS", "REAL32", "m", "GF_MAX_HOR_DIST"),
    _stored("FENCE_MARGIN", "REAL32", "m", 2.0),
    _stored("CIRCLE_RADIUS", "REAL32", "cm", 1000.0),
    _stored("CIRCLE_RATE", "REAL32", "deg/s", 20.0),
    _stored("FOLL_ENABLE", "INT8", "", 0.0),
    _stored("FOLL_SYSID", "INT16", "", 0.0),
    _stored("FOLL_DIST_MAX", "REAL32", "m", 100.0),
    _stored("FOLL_OFS_TYPE", "INT8", "", 0.0),
    _stored("FOLL_OFS_X", "REAL32", "m", 0.0),
    _stored("FOLL_OFS_Y", "REAL32", "m", 0.0),
    _stored("FOLL_OFS_Z", "REAL32", "m", 0.0),
    _stored("FOLL_YAW_BEHAVE", "INT8", "", 1.0),
    _stored("FOLL_POS_P", "REAL32", "", 0.1),
    _stored("FOLL_ALT_TYPE", "INT8", "", 1.0),
    # GUIDED holds its last target (no stream failsafe there): Copter's stop-on-silence
    # is not built, so the value is only kept.
    _stored("GUID_TIMEOUT", "REAL32", "s", 3.0),
)

# Internal parameters only the ArduPilot flavour has, under their own (Copter) names:
# one name here lists one, identity-mapped, once it is in the internal table.
ARDUPILOT_ONLY: dict[str, str] = {
    "SYSID_MYGCS": "INT16",
    **{f"FLTMODE{i}": "INT8" for i in range(1, 7)},
    "FLTMODE_CH": "INT8",
    "RC_OVERRIDE_TIME": "REAL32",
    "FS_THR_ENABLE": "INT8",
    "FS_THR_VALUE": "INT16",
    "THR_DZ": "INT16",
}


def _own_gains() -> tuple[CopterParam, ...]:
    """This vehicle's controller gains (sliding mode, command filter, PID), which neither
    autopilot has: listed under their internal names in both flavours."""
    own = (*SMC_GROUPS, "CMDF", "PID")
    return tuple(_mapped(spec.name, "REAL32", spec.unit, spec.name) for spec in PARAMETERS
                 if spec.name.split("_")[0] in own)


def ardupilot_parameters() -> tuple[CopterParam, ...]:
    """What the ArduPilot flavour lists, in order: Copter's names, our own gains, then the
    ArduPilot-only internal parameters present in the table."""
    only = tuple(_mapped(name, ap_type, PARAMETER_SPECS[name].unit, name,
                         values=tuple((c, c) for c in PARAMETER_SPECS[name].choices))
                 for name, ap_type in ARDUPILOT_ONLY.items() if name in PARAMETER_SPECS)
    return (*COPTER_PARAMETERS, *_own_gains(), *only)


def px4_parameters() -> tuple[str, ...]:
    """What the PX4 flavour lists: the internal table without the ArduPilot-only names."""
    return tuple(spec.name for spec in PARAMETERS if spec.name not in ARDUPILOT_ONLY)


def _check() -> None:
    for p in ardupilot_parameters():
        assert len(p.name) <= 16 and (p.ap_type == "REAL32" or p.ap_type in TYPE_RANGES)
        if p.internal is not None:
            spec = PARAMETER_SPECS[p.internal]
            assert p.values or not spec.choices, p.name  # enumerations are paired
            for value in (spec.default, *spec.choices):  # each has a Copter number
                p.from_internal(value)
            for _, internal in p.values:
                assert internal in spec.choices, p.name


_check()
