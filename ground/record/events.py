"""What happened during a run, read from its log: mode changes, arming, failsafes,
landing and the texts the vehicle said to ground tools (STATUSTEXT).

Every event carries its sim time; expectations (``ground/scenario/expectations.py``) look for
events in time windows. The control records give mode and flags at each step; the
MAVLink mirror gives the STATUSTEXT frames with the sim time of the step that said them.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from contracts.mavlink import AUTOPILOT_COMPID, StatustextAssembler, mavlink
from contracts.modes import FlightMode
from contracts.telemetry import FLAG_ARMED, FLAG_FAILSAFE, mavlink_key
from ground.record.run_files import LogRecords, iter_messages

MODES = tuple(FlightMode)
# Disarmed this close to the ground (true altitude above the start of NED's ground plane,
# z = 0) counts as landed.
LANDED_ALTITUDE_M = 0.3


@dataclass(frozen=True)
class Event:
    """One event: ``kind`` (ground.scenario.expectations.EVENT_KINDS), its sim time and what it
    says (the mode entered or in force, the text said)."""

    kind: str
    t_s: float
    mode: str = ""
    text: str = ""

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v != ""}


def step_events(sim_time_s: np.ndarray, mode_index: np.ndarray, flags: np.ndarray,
                altitude_m: np.ndarray) -> list[Event]:
    """Events from the per-step mode, flags and true altitude (positive up)."""
    events: list[Event] = []
    previous_mode, previous_flags = None, 0
    for t, index, flag, altitude in zip(sim_time_s, mode_index, flags, altitude_m,
                                        strict=True):
        mode = MODES[int(index)].name if 0 <= int(index) < len(MODES) else f"#{int(index)}"
        t = float(t)
        if mode != previous_mode:
            events.append(Event("mode", t, mode))
        rose, fell = int(flag) & ~previous_flags, previous_flags & ~int(flag)
        if rose & FLAG_ARMED:
            events.append(Event("armed", t, mode))
        if fell & FLAG_ARMED:
            events.append(Event("disarmed", t, mode))
            if altitude < LANDED_ALTITUDE_M:
                events.append(Event("landed", t, mode))
        if rose & FLAG_FAILSAFE:
            events.append(Event("failsafe", t, mode))
        previous_mode, previous_flags = mode, int(flag)
    return events


def statustexts(log: Path | LogRecords, sysid: int) -> Iterator[tuple[int, int, str]]:
    """The vehicle's STATUSTEXT announcements as logged (a long text's chunks joined, one
    text when whole): (publish time [ns of sim time], MAV_SEVERITY, text)."""
    key = mavlink_key(sysid, AUTOPILOT_COMPID, "STATUSTEXT")
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    texts = StatustextAssembler()
    for topic, message, data in iter_messages(log, key):
        if topic != key:
            continue
        try:
            msgs = parser.parse_buffer(data) or []
        except mavlink.MAVError:
            continue
        for msg in msgs:
            if msg.get_type() == "STATUSTEXT" and (text := texts.add(msg)) is not None:
                yield message.publish_time, int(msg.severity), text


def statustext_events(log: Path | LogRecords, sysid: int) -> list[Event]:
    """The vehicle's STATUSTEXT announcements, at the sim time each was sent."""
    return [Event("statustext", t_ns / 1e9, text=text)
            for t_ns, _, text in statustexts(log, sysid)]


def run_events(log: Path | LogRecords, sysid: int, sim_time_us: np.ndarray, mode_index: np.ndarray,
               flags: np.ndarray, altitude_m: np.ndarray) -> list[Event]:
    """Every event of a run, in time order (steps first at equal times)."""
    events = step_events(sim_time_us / 1e6, mode_index, flags, altitude_m)
    events += statustext_events(log, sysid)
    return sorted(events, key=lambda e: e.t_s)
