"""PX4 flight logs (ULog) read with pyulog (PX4's own parser): where each signal and
parameter is in the logs of each PX4 version, and the vehicle a log is of.

Topic, field and parameter names changed between PX4 versions; every name the reader knows
is in ``SIGNALS`` and ``PARAMETERS`` below, the one place to add another
(docs/px4-logs.md#px4-versions has them as a table). ground/ulog/identification.py makes
identification data of a log, ground/ulog/clock.py puts its signals on one clock.
"""

from __future__ import annotations

import contextlib
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pyulog import ULog


class ULogError(ValueError):
    """A log that cannot give what was asked; the message names the file and the problem."""


@dataclass(frozen=True)
class Source:
    """Where one signal is in one generation of PX4's logs."""

    topic: str
    fields: tuple[str, ...]
    versions: str  # the PX4 versions that log it so
    sample_time: bool = True  # stamped by ``timestamp_sample`` (the sensor's) when logged

    @property
    def label(self) -> str:
        first = self.fields[0]
        if first.endswith("[0]") and self.fields == _indexed(first[:-3], len(self.fields)):
            return f"{self.topic}.{first[:-3]}[0..{len(self.fields) - 1}]"
        return f"{self.topic}.{', '.join(self.fields)}"


def _indexed(name: str, n: int) -> tuple[str, ...]:
    return tuple(f"{name}[{i}]" for i in range(n))


# Each signal's places in PX4's logs, the preferred first: the version aliases
# (docs/px4-logs.md#px4-versions).
SIGNALS: dict[str, tuple[Source, ...]] = {
    "attitude": (Source("vehicle_attitude", _indexed("q", 4), "every version"),),
    "rates": (
        Source("vehicle_angular_velocity", _indexed("xyz", 3), "1.10 and later"),
        Source("vehicle_attitude", ("rollspeed", "pitchspeed", "yawspeed"), "before 1.10"),
    ),
    "acceleration": (
        Source("vehicle_angular_velocity", _indexed("xyz_derivative", 3), "1.13 and later"),
        Source("vehicle_angular_acceleration", _indexed("xyz", 3), "1.10 to 1.12"),
    ),
    # The time a motor output went out (``timestamp``), not the sample it was computed from.
    "motors": (
        Source("actuator_motors", _indexed("control", 4),
               "1.13 and later (thrust fraction 0..1)", sample_time=False),
        Source("actuator_outputs", _indexed("output", 4), "every version (PWM [us])",
               sample_time=False),
    ),
    "armed": (
        Source("vehicle_status", ("arming_state",), "every version", sample_time=False),
        Source("actuator_armed", ("armed",), "every version", sample_time=False),
    ),
    "landed": (Source("vehicle_land_detected", ("landed",), "every version",
                      sample_time=False),),
    "hover_thrust": (Source("hover_thrust_estimate", ("hover_thrust", "valid"),
                            "1.12 and later"),),
    "nav_state": (Source("vehicle_status", ("nav_state",), "every version",
                         sample_time=False),),
}
# The value of each armed source that means armed: vehicle_status's ARMING_STATE_ARMED (2
# in every version), actuator_armed's flag.
ARMED_VALUE = {"vehicle_status": 2, "actuator_armed": 1}
# Parameters, per meaning, the preferred first; {n} is the output's number (from 1).
PARAMETERS: dict[str, tuple[str, ...]] = {
    "thrust_model_factor": ("THR_MDL_FAC",),
    "hover_thrust": ("MPC_THR_HOVER",),
    "pwm_min": ("PWM_MAIN_MIN{n}", "PWM_MAIN_MIN", "PWM_MIN"),  # 1.13+, 1.12, 1.11 and before
    "pwm_max": ("PWM_MAIN_MAX{n}", "PWM_MAIN_MAX", "PWM_MAX"),
    "output_function": ("PWM_MAIN_FUNC{n}",),  # 1.13+: 101 = Motor 1, ...
}
MOTOR1_FUNCTION = 101  # PX4's output function of Motor 1 (PWM_MAIN_FUNCn)
# The topics the reader loads (pyulog parses only these).
TOPICS = sorted({s.topic for sources in SIGNALS.values() for s in sources} | {"esc_status"})
IDENTIFICATION_SIGNALS = ("attitude", "rates", "motors", "armed", "landed")



@dataclass(frozen=True)
class Series:
    """One signal as logged: sample times [s since the log's start], values (N, k)."""

    signal: str
    source: Source
    time_s: np.ndarray
    values: np.ndarray
    fields: tuple[str, ...]  # the fields read (a remapped output channel differs)

    @property
    def label(self) -> str:
        return Source(self.source.topic, self.fields, self.source.versions).label

    def interval_s(self) -> float:
        """The median sample interval (inf for one sample)."""
        return float(np.median(np.diff(self.time_s))) if len(self.time_s) > 1 else math.inf


@dataclass
class PX4Log:
    """A parsed PX4 log and what the reader needs of it."""

    path: Path
    ulog: ULog
    warnings: list[str] = field(default_factory=list)

    @property
    def parameters(self) -> dict[str, float]:
        """The parameters as the log starts (PX4 logs every one)."""
        return self.ulog.initial_parameters

    @property
    def duration_s(self) -> float:
        return max(0.0, (self.ulog.last_timestamp - self.ulog.start_timestamp) / 1e6)

    def parameter(self, meaning: str, n: int | None = None) -> tuple[str, float] | None:
        """(name, value) of the first alias of ``meaning`` the log sets (per output
        ``n`` where the name has one; -1 means unset in PX4 1.11)."""
        for name in PARAMETERS[meaning]:
            if "{n}" in name:
                if n is None:
                    continue
                name = name.format(n=n)
            value = self.parameters.get(name)
            if value is not None and value != -1:
                return name, float(value)
        return None

    def topic(self, name: str, multi_id: int = 0) -> ULog.Data | None:
        """The topic's samples; None when not logged, or without a timestamp (a format
        damaged in the file)."""
        for data in self.ulog.data_list:
            if data.name == name and data.multi_id == multi_id and "timestamp" in data.data:
                return data
        return None

    def source(self, signal: str) -> tuple[Source, ULog.Data] | None:
        """The first of the signal's sources the log has, with every field."""
        for source in SIGNALS[signal]:
            data = self.topic(source.topic)
            if data is not None and all(f in data.data for f in source.fields):
                return source, data
        return None

    def series(self, signal: str) -> Series:
        """The signal as logged; ULogError names the topics and fields looked for."""
        found = self.source(signal)
        if found is None:
            raise ULogError(f"{self.path}: {missing_message(signal)}")
        source, data = found
        fields = source.fields
        if signal == "motors" and source.topic == "actuator_outputs":
            fields = self._motor_channels(data)
        # PX4 leaves an unset stamp at 0: before a log that starts later, it is no time. A
        # log that starts at 0 (a simulator's) has samples at 0.
        starts_later = self.ulog.start_timestamp > 0
        stamps = data.data["timestamp"]
        if source.sample_time and "timestamp_sample" in data.data:
            sampled = data.data["timestamp_sample"]
            if (np.all(sampled > 0) or not starts_later) and \
                    np.all(np.diff(sampled.astype(np.int64)) >= 0):
                stamps = sampled
        values = np.column_stack([data.data[f].astype(float) for f in fields])
        keep = stamps > 0 if starts_later else np.ones(len(stamps), dtype=bool)
        t = (stamps[keep].astype(np.int64) - int(self.ulog.start_timestamp)) / 1e6
        values = values[keep]
        order = np.argsort(t, kind="stable")
        t, values = t[order], values[order]
        last = np.append(np.diff(t) > 0, True)  # one sample per instant: the last
        return Series(signal, source, t[last], values[last], fields)

    def _motor_channels(self, data: ULog.Data) -> tuple[str, ...]:
        """actuator_outputs' channels of motors 1-4: by PWM_MAIN_FUNCn where set (1.13+),
        else the first four (the mixer's order before 1.13)."""
        channels = {}
        for n in range(1, 17):
            function = self.parameter("output_function", n)
            if function is not None and MOTOR1_FUNCTION <= function[1] < MOTOR1_FUNCTION + 4:
                channels[int(function[1]) - MOTOR1_FUNCTION] = n - 1
        if not channels:
            return _indexed("output", 4)
        if sorted(channels) != [0, 1, 2, 3]:
            raise ULogError(f"{self.path}: PWM_MAIN_FUNC1-16 assign motors "
                            f"{sorted(i + 1 for i in channels)}, not motors 1-4")
        fields = tuple(f"output[{channels[i]}]" for i in range(4))
        missing = [f for f in fields if f not in data.data]
        if missing:
            raise ULogError(f"{self.path}: actuator_outputs has no {missing[0]}")
        return fields

    def version(self) -> str:
        """PX4's version as the log states it (ver_sw_release, else the git hash)."""
        release = self.ulog.msg_info_dict.get("ver_sw_release")
        git = self.ulog.msg_info_dict.get("ver_sw")
        text = px4_release(release) if isinstance(release, int) and release else None
        if text and git:
            return f"{text} ({str(git)[:8]})"
        return text or (f"of no release (ver_sw {str(git)[:8]})" if git else "of no version")


def px4_release(value: int) -> str:
    """ver_sw_release (0xMMmmppTT) as v1.14.0, with its type when not a release."""
    major, minor, patch, kind = (value >> 24) & 0xFF, (value >> 16) & 0xFF, \
        (value >> 8) & 0xFF, value & 0xFF
    suffix = "" if kind == 255 else " rc" if kind >= 192 else " beta" if kind >= 128 \
        else " alpha" if kind >= 64 else " dev"
    return f"v{major}.{minor}.{patch}{suffix}"


def missing_message(signal: str) -> str:
    """What the log lacks, naming every place the signal was looked for."""
    what = {"attitude": "attitude", "rates": "body rates",
            "acceleration": "angular acceleration", "motors": "motor outputs",
            "armed": "arming state", "landed": "land detector state",
            "hover_thrust": "hover thrust estimate", "nav_state": "flight mode"}
    places = "; ".join(f"{s.label} ({s.versions})" for s in SIGNALS[signal])
    return f"the log has no {what[signal]}: looked for {places}"


def read_log(path: str | Path) -> PX4Log:
    """Parse a ULog file; ULogError (a ValueError) says why one cannot be read."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(ULog.HEADER_BYTES))
    except OSError as exc:
        raise ULogError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not head:
        raise ULogError(f"{path}: empty file, not a ULog")
    if head != ULog.HEADER_BYTES[:len(head)] or len(head) < len(ULog.HEADER_BYTES):
        raise ULogError(f"{path}: not a ULog file (it does not start with ULog's magic "
                        f"bytes 'ULog' 01 12 35)")
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said):  # pyulog prints its warnings
            ulog = ULog(str(path), message_name_filter_list=TOPICS)
    except Exception as exc:  # noqa: BLE001 - a hostile file can break the parser anywhere
        raise ULogError(f"{path}: not a readable ULog ({type(exc).__name__}: {exc})") from None
    log = PX4Log(path, ulog)
    if ulog.file_corruption or "corrupt" in said.getvalue():
        log.warnings.append("pyulog found corrupt data in the log and skipped it")
    if not ulog.data_list:
        raise ULogError(f"{path}: the log holds no data (cut short in its header?)")
    return log


# -- the vehicle ------------------------------------------------------------------------------

def rotor_count(log: PX4Log) -> tuple[int | None, str]:
    """The rotor count and where it comes from: CA_ROTOR_COUNT (1.13+), else MAV_TYPE."""
    count = log.parameters.get("CA_ROTOR_COUNT")
    if count is not None:
        return int(count), "CA_ROTOR_COUNT"
    mav_type = log.parameters.get("MAV_TYPE")
    if mav_type is not None and int(mav_type) in MULTICOPTER_ROTORS:
        return MULTICOPTER_ROTORS[int(mav_type)], f"MAV_TYPE {int(mav_type)}"
    return None, "neither CA_ROTOR_COUNT nor a multicopter's MAV_TYPE"


def mav_type_name(value: float | None) -> str:
    """MAV_TYPE's name (MAVLink's enum, as pymavlink has it)."""
    if value is None:
        return "not set"
    from pymavlink.dialects.v20 import common

    entry = common.enums["MAV_TYPE"].get(int(value))
    name = entry.name.removeprefix("MAV_TYPE_") if entry is not None else "unknown"
    return f"{int(value)} ({name})"


def check_quad_log(log: PX4Log) -> None:
    """A quadrotor's log, as far as the log says; ULogError names what is not."""
    airframe = log.parameters.get("CA_AIRFRAME")
    if airframe is not None and int(airframe) != 0:
        raise ULogError(f"{log.path}: CA_AIRFRAME = {int(airframe)} "
                        f"({CA_AIRFRAMES.get(int(airframe), 'unknown')}): this stack flies "
                        "multicopters (CA_AIRFRAME 0) with 4 rotors")
    count, where = rotor_count(log)
    if count is not None and count != 4:
        raise ULogError(f"{log.path}: {where} says {count} rotors: this stack flies "
                        "quadrotors (4 rotors)")
    mav_type = log.parameters.get("MAV_TYPE")
    if count is None and mav_type is not None:
        raise ULogError(f"{log.path}: MAV_TYPE = {mav_type_name(mav_type)} and no "
                        "CA_ROTOR_COUNT: this stack flies quadrotors (MAV_TYPE 2)")


# Rotors per multicopter MAV_TYPE: quadrotor, hexarotor, octorotor, tricopter.
MULTICOPTER_ROTORS = {2: 4, 13: 6, 14: 8, 15: 3}
CA_AIRFRAMES = {0: "Multirotor", 1: "Fixed Wing", 2: "Standard VTOL", 3: "Tiltrotor VTOL",
                4: "Tailsitter VTOL", 5: "Rover (Ackermann)", 6: "Rover (Differential)",
                7: "Motors (6DOF)", 8: "Multirotor with Tilt", 9: "Custom",
                10: "Helicopter (tail ESC)", 11: "Helicopter (tail Servo)",
                12: "Helicopter (Coaxial)"}
