"""Flight modes and their numbers in the PX4 and ArduPilot-Copter flavours of MAVLink.

Free of pymavlink: the vehicle logic uses the modes, the MAVLink server maps them.
"""

from __future__ import annotations

import enum


class FlightMode(enum.Enum):
    """The autopilot's flight modes (docs/mavlink.md says what each does)."""

    HOLD = "hold"  # hold the position where the mode started
    TAKEOFF = "takeoff"  # climb to the take-off altitude, then HOLD
    LAND = "land"  # descend, disarm on the ground
    OFFBOARD = "offboard"  # follow streamed setpoints (PX4)
    GUIDED = "guided"  # follow setpoints, hold the last one (ArduPilot)
    REFERENCE = "reference"  # the onboard reference generator of the paper's scenarios
    MISSION = "mission"  # fly the uploaded mission (PX4 AUTO.MISSION)
    RTL = "rtl"  # return to launch: climb, fly home, land, disarm
    POSCTL = "posctl"  # manual: sticks command velocities, centred sticks hold position
    ALTCTL = "altctl"  # manual: sticks command tilt and climb rate, altitude held
    STABILIZED = "stabilized"  # manual: sticks command tilt and collective thrust
    ORBIT = "orbit"  # circle a centre (MAV_CMD_DO_ORBIT)
    FOLLOW_TARGET = "follow_target"  # follow a target's FOLLOW_TARGET messages (Follow Me)
    BRAKE = "brake"  # stop where the vehicle can and hold (ArduPilot Copter's BRAKE only)

    # Members are singletons, equal only to themselves: hashed by identity too, in C
    # (Enum's hash of the name is a Python call, and a control step looks modes up in
    # its tables about eight times).
    __hash__ = object.__hash__


MANUAL_MODES = (FlightMode.POSCTL, FlightMode.ALTCTL, FlightMode.STABILIZED)


# PX4 custom mode: main mode in bits 16-23, sub mode in bits 24-31.
PX4_MAIN_ALTCTL = 2
PX4_MAIN_POSCTL = 3
PX4_MAIN_AUTO = 4
PX4_MAIN_OFFBOARD = 6
PX4_MAIN_STABILIZED = 7
PX4_SUB_AUTO_READY = 1
PX4_SUB_AUTO_TAKEOFF = 2
PX4_SUB_AUTO_LOITER = 3
PX4_SUB_AUTO_MISSION = 4
PX4_SUB_AUTO_RTL = 5
PX4_SUB_AUTO_LAND = 6
PX4_SUB_AUTO_FOLLOW_TARGET = 8
PX4_SUB_POSCTL_ORBIT = 1
PX4_SUB_OFFBOARD_REFERENCE = 1  # ours: PX4's OFFBOARD has no sub modes

PX4_MODES: dict[FlightMode, tuple[int, int]] = {
    FlightMode.HOLD: (PX4_MAIN_AUTO, PX4_SUB_AUTO_LOITER),
    FlightMode.TAKEOFF: (PX4_MAIN_AUTO, PX4_SUB_AUTO_TAKEOFF),
    FlightMode.LAND: (PX4_MAIN_AUTO, PX4_SUB_AUTO_LAND),
    FlightMode.OFFBOARD: (PX4_MAIN_OFFBOARD, 0),
    FlightMode.MISSION: (PX4_MAIN_AUTO, PX4_SUB_AUTO_MISSION),
    FlightMode.RTL: (PX4_MAIN_AUTO, PX4_SUB_AUTO_RTL),
    FlightMode.POSCTL: (PX4_MAIN_POSCTL, 0),
    FlightMode.ALTCTL: (PX4_MAIN_ALTCTL, 0),
    FlightMode.STABILIZED: (PX4_MAIN_STABILIZED, 0),
    FlightMode.ORBIT: (PX4_MAIN_POSCTL, PX4_SUB_POSCTL_ORBIT),
    FlightMode.FOLLOW_TARGET: (PX4_MAIN_AUTO, PX4_SUB_AUTO_FOLLOW_TARGET),
    # PX4 has no such mode. The reference is a setpoint stream from a generator outside
    # PX4's navigator, which is what OFFBOARD means to PX4: tools (pymavlink, DroneKit,
    # MAVSDK, QGroundControl) read it as OFFBOARD; sub mode 1 keeps it apart for our own.
    FlightMode.REFERENCE: (PX4_MAIN_OFFBOARD, PX4_SUB_OFFBOARD_REFERENCE),
}
# PX4 modes without a sub mode (any sub mode a tool sends selects them).
PX4_MAIN_ONLY = (PX4_MAIN_OFFBOARD, PX4_MAIN_POSCTL, PX4_MAIN_ALTCTL, PX4_MAIN_STABILIZED)

# ArduPilot Copter mode numbers (custom_mode is the number itself).
COPTER_MODES: dict[FlightMode, int] = {
    FlightMode.STABILIZED: 0,  # STABILIZE
    FlightMode.ALTCTL: 2,  # ALT_HOLD
    FlightMode.MISSION: 3,  # AUTO
    FlightMode.GUIDED: 4,
    FlightMode.HOLD: 5,  # LOITER
    FlightMode.RTL: 6,
    FlightMode.LAND: 9,
    FlightMode.POSCTL: 16,  # POSHOLD
    FlightMode.ORBIT: 7,  # CIRCLE
    FlightMode.FOLLOW_TARGET: 23,  # FOLLOW
    FlightMode.REFERENCE: 25,  # SYSTEMID: ArduPilot's own excitation mode
    FlightMode.BRAKE: 17,
}

# Every ArduPilot Copter mode number and its name (ArduCopter/mode.h, Mode::Number; the
# names its mode->name() gives, as in "Mode change to ALT_HOLD failed: ..."). The ones this
# vehicle flies are in COPTER_MODES; the others exist in Copter but are refused here.
COPTER_MODE_NAMES: dict[int, str] = {
    0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL",
    7: "CIRCLE", 9: "LAND", 11: "DRIFT", 13: "SPORT", 14: "FLIP", 15: "AUTOTUNE",
    16: "POSHOLD", 17: "BRAKE", 18: "THROW", 19: "AVOID_ADSB", 20: "GUIDED_NOGPS",
    21: "SMART_RTL", 22: "FLOWHOLD", 23: "FOLLOW", 24: "ZIGZAG", 25: "SYSTEMID",
    26: "AUTOROTATE", 27: "AUTO_RTL", 28: "TURTLE",
}

FLAVOURS = ("px4", "ardupilot")


def px4_custom_mode(mode: FlightMode) -> int:
    main, sub = PX4_MODES[mode]
    return (main << 16) | (sub << 24)


def mode_from_px4(custom_mode: int) -> FlightMode | None:
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    for mode, (m, s) in PX4_MODES.items():  # an exact match first (POSCTL's ORBIT)
        if (m, s) == (main, sub):
            return mode
    for mode, (m, s) in PX4_MODES.items():
        if m == main and s == 0 and main in PX4_MAIN_ONLY:
            return mode
    return None


def px4_custom_mode_from_command(main_mode: float, sub_mode: float) -> int:
    """custom_mode from DO_SET_MODE's param2 / param3 (main, sub), or from SET_MODE's
    already packed custom_mode (a number above 255 in param2)."""
    if main_mode > 255:
        return int(main_mode)
    return (int(main_mode) << 16) | (int(sub_mode) << 24)


def custom_mode(flavour: str, mode: FlightMode) -> int:
    """HEARTBEAT custom_mode of ``mode`` (TAKEOFF shows as GUIDED in the ArduPilot flavour)."""
    if flavour == "px4":
        return px4_custom_mode(mode)
    if mode == FlightMode.TAKEOFF:
        mode = FlightMode.GUIDED
    if mode == FlightMode.OFFBOARD:
        mode = FlightMode.GUIDED
    return COPTER_MODES[mode]


def copter_mode_name(mode: FlightMode) -> str:
    """The Copter name of one of our modes, as Copter's texts and MAVProxy write it."""
    return COPTER_MODE_NAMES[custom_mode("ardupilot", mode)]


def mode_from_custom(flavour: str, number: int) -> FlightMode | None:
    """The mode a DO_SET_MODE / SET_MODE custom mode asks for, or None if unknown."""
    if flavour == "px4":
        return mode_from_px4(number)
    for mode, n in COPTER_MODES.items():
        if n == number:
            return mode
    return None
