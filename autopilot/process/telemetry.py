"""The autopilot's telemetry over Zenoh (record layouts: ``contracts/telemetry.py``).

Each control step: the control record (the controller's internals), the timing record,
the estimate record (on the estimator), perturbation events as they happen, and the
MAVLink mirror: the motor command, a few telemetry streams on sim time, and the
announcements and acknowledgements sent to ground tools; once a second of wall time,
the status; once a second of sim time and whenever the mission lists or home change,
the scene (what a viewer draws: airframe, home, mission, fence, rally).
The control loop says when; this class knows what goes into each record.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from autopilot.commander.commander import Commander
from autopilot.estimation.estimator import Estimator, EstimatorStatus
from autopilot.mavlink.server import MavlinkServer
from autopilot.navigator.geofence import zones_from_items
from autopilot.navigator.mission_runner import item_position_ned
from autopilot.navigator.mission_store import FENCE, MISSION, RALLY, WITHOUT_POSITION
from contracts.mavlink import AUTOPILOT_COMPID, mavlink, new_mavlink
from contracts.mavlink_codec import pack_message
from contracts.modes import FlightMode
from contracts.realtime import LoopTiming
from contracts.telemetry import (
    CONTROL,
    ESTIMATE,
    ESTIMATE_ALIGNED,
    ESTIMATE_CONVERGED,
    ESTIMATE_GPS_OK,
    FLAG_ARMED,
    FLAG_FAILSAFE,
    TIMING,
    json_record,
)
from contracts.telemetry_node import TelemetryNode
from contracts.vectors import CHANNEL_INTERNALS, MEASUREMENT

MODE_INDEX = {mode: i for i, mode in enumerate(FlightMode)}
# The MAVLink mirror's sim-time streams (message, period in microseconds of sim time).
MIRROR_STREAMS_US = ((mavlink.MAVLINK_MSG_ID_HEARTBEAT, 1_000_000),
                     (mavlink.MAVLINK_MSG_ID_ATTITUDE, 100_000),
                     (mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 100_000),
                     (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 100_000))
MIRRORED_TOOL_MESSAGES = frozenset({"STATUSTEXT", "COMMAND_ACK"})
ESTIMATE_STATUS_FIELDS = ("tilt_sigma_rad", "yaw_sigma_rad", "horizontal_sigma_m",
                          "vertical_sigma_m", "velocity_sigma_mps", "gps_test_ratio",
                          "baro_test_ratio", "mag_test_ratio")


class TelemetryPublisher:
    """Builds and publishes the autopilot's records on ``node``. Records are buffers
    made once and refilled each step: publishing must not cost a deadline."""

    def __init__(self, node: TelemetryNode, sysid: int, vehicle: Commander,
                 ground: MavlinkServer, timing: LoopTiming, estimator: Estimator | None,
                 lockstep: bool, log: Callable[[str], None],
                 airframe_rotors: tuple[tuple[str, tuple[tuple[float, ...], ...]], ...] | None
                 = None) -> None:
        self.node = node
        self.sysid = sysid
        self.vehicle = vehicle
        self.ground = ground
        self.timing = timing
        self.estimator = estimator
        self.lockstep = lockstep
        self.log = log
        self.control_pub = node.publisher("control")
        self.timing_pub = node.publisher("timing")
        self.estimate_pub = node.publisher("estimate") if estimator is not None else None
        self._estimate_record = ESTIMATE.buffer()
        self.event_pub = node.publisher("perturbation")
        self._control_record = CONTROL.buffer()
        self._timing_record = TIMING.buffer()
        self._channel_internals = self._control_record.block(
            tuple(f"ch_{name}" for name in CHANNEL_INTERNALS))
        # Runs of consecutive fields and the fields' own views, each filled in one
        # assignment (no per-field lookup).
        self._control_head = self._control_record.run(("seq", "sim_time_us", "mode", "flags"))
        self._control_views = tuple(self._control_record[name] for name in (
            "reference_time_s", "measurement", "reference", "kick_rad", "motor_commands",
            "theta_g"))
        self._timing_head = self._timing_record.run(("seq", "sim_time_us", "deadline_misses"))
        self._timing_times = self._timing_record.run(("compute_s", "period_s"))
        self._mirror_mav = new_mavlink(sysid, AUTOPILOT_COMPID)
        self._mirror_due_us = [0] * len(MIRROR_STREAMS_US)
        self._mirror_next_us = 0  # the soonest of them
        self._previous_control_wall: float | None = None
        self.scene_pub = node.publisher("scene")
        self._airframe = ({"name": airframe_rotors[0],
                           "rotors": [list(r) for r in airframe_rotors[1]]}
                          if airframe_rotors else {"name": "", "rotors": []})
        self._scene_of: tuple | None = None  # the lists and home the last scene drew
        self._scene_due_us = 0  # the next sim time a scene goes out unchanged
        if node.enabled:
            ground.on_sent = self.mirror_tool_message
            # Declared now: a first declaration inside the loop would cost a deadline.
            for name in ("HIL_ACTUATOR_CONTROLS", *MIRRORED_TOOL_MESSAGES,
                         *(mavlink.mavlink_map[i].msgname for i, _ in MIRROR_STREAMS_US)):
                node.mirror_publisher(sysid, AUTOPILOT_COMPID, name)

    @property
    def enabled(self) -> bool:
        return self.node.enabled

    def publish_step(self, time_us: int, compute_s: float, start_wall_s: float) -> None:
        """The control record, the timing record, the estimate, perturbation events and
        the mirror streams of the step at ``time_us``."""
        v = self.vehicle
        c = v.controller
        self._control_head[:] = (self.control_pub.count, time_us, MODE_INDEX[v.mode],
                                 (FLAG_ARMED if v.armed else 0)
                                 | (FLAG_FAILSAFE if v.failsafe else 0))
        reference_time, measurement, reference, kick, motors, weights = self._control_views
        reference_time[...] = time_us / 1e6 - v.reference_start_s
        measurement[...], reference[...] = v.measurement, v.flight.last_ref
        kick[...], motors[...] = v.flight.last_kick, v.last_commands
        self._channel_internals[...] = c.telemetry.T
        theta_g, theta_f = c.theta_g, c.theta_f  # None: no adaptive weights (PID)
        weights[...] = np.nan if theta_g is None else theta_g
        self.control_pub.put(self._control_record.encode(
            tuple(theta_f[:3]) if theta_f is not None else ((), (), ())))
        previous, self._previous_control_wall = self._previous_control_wall, start_wall_s
        self._timing_head[:] = (self.timing_pub.count, time_us, self.timing.misses)
        self._timing_times[:] = (compute_s,
                                 math.nan if previous is None else start_wall_s - previous)
        self.timing_pub.put(self._timing_record.encode())
        self.scene(time_us)
        if self.estimate_pub is not None and v.estimator_status is not None:
            self._publish_estimate(time_us, v.estimator_status)
        if v.perturbations.entries:
            for event, e in v.perturbations.changes(time_us / 1e6):
                self.event_pub.put(json_record(self.event_pub.count, time_us, event=event,
                                               **e.to_request()))
                self.log(f"t={time_us / 1e6:.3f} s perturbation {e.id} ({e.kind}) {event}")
        if time_us >= self._mirror_next_us:
            self._mirror_streams(time_us)

    def _mirror_streams(self, time_us: int) -> None:
        """The mirror's sim-time streams that are due."""
        for i, (msg_id, every_us) in enumerate(MIRROR_STREAMS_US):
            if time_us >= self._mirror_due_us[i]:
                self._mirror_due_us[i] = time_us - time_us % every_us + every_us
                msg = self.ground.telemetry(msg_id, boot_ms=(time_us // 1000) & 0xFFFFFFFF)
                self.node.mirror(self.sysid, AUTOPILOT_COMPID, msg.get_type(),
                                 pack_message(msg, self._mirror_mav), time_us)
        self._mirror_next_us = min(self._mirror_due_us)

    def _publish_estimate(self, time_us: int, status: EstimatorStatus) -> None:
        x = self.estimator.x
        record = self._estimate_record
        record["seq"], record["sim_time_us"] = self.estimate_pub.count, time_us
        record["flags"] = ((ESTIMATE_ALIGNED if status.aligned else 0)
                           | (ESTIMATE_CONVERGED if status.converged else 0)
                           | (ESTIMATE_GPS_OK if status.gps_ok else 0))
        record["position_ned_m"], record["velocity_ned_mps"] = x[0:3], x[3:6]
        record["quaternion"], record["gyro_bias_rad_s"] = x[6:10], x[10:13]
        record["accel_bias_mps2"], record["baro_offset_m"] = x[13:16], x[16]
        for name in ESTIMATE_STATUS_FIELDS:
            record[name] = getattr(status, name)
        self.estimate_pub.put(record.encode())

    def mirror_actuators(self, frame: bytes, time_us: int) -> None:
        """The motor command as sent to the simulator."""
        self.node.mirror(self.sysid, AUTOPILOT_COMPID, "HIL_ACTUATOR_CONTROLS", frame,
                         time_us)

    def end_step(self, time_us: int) -> None:
        """The step's records are all out: the batch goes if its span is over."""
        self.node.end_step(time_us)

    def mirror_tool_message(self, link: object, msg: mavlink.MAVLink_message,
                            frame: bytes) -> None:
        """Announcements and acknowledgements to ground tools go into the log too."""
        kind = msg.get_type()
        if kind in MIRRORED_TOOL_MESSAGES and (kind == "COMMAND_ACK" or
                                               link is self.ground.links[0]):
            self.node.mirror(self.sysid, AUTOPILOT_COMPID, kind, frame,
                             round(self.vehicle.sim_t_s * 1e6))

    def scene(self, time_us: int) -> None:
        """The scene record once a second of sim time (for viewers that join late), and
        at once when what it draws changed (the stored lists are replaced whole, so
        identity tells). On sim time, so a lockstep log is the same on every run."""
        v = self.vehicle
        lists = v.mission.lists
        drawn = (lists[MISSION], lists[FENCE], lists[RALLY], v.places, v.mission.current)
        # (a tuple compares its items by identity first, then by equality)
        if time_us < self._scene_due_us and drawn == self._scene_of:
            return
        self._scene_of = drawn
        self._scene_due_us = time_us - time_us % 1_000_000 + 1_000_000
        self.scene_pub.put(json_record(self.scene_pub.count, time_us,
                                       **scene_fields(v, self._airframe)))

    def status(self, steps: int, final: bool = False) -> None:
        """The status record, when due (once a second) or ``final``."""
        self.node.flush_stale()
        if not self.node.status_due(final):
            return  # asked every 5 ms, published once a second: gather nothing till then
        # The timing summary only goes into the final status (it reads whole histograms).
        summary = self.timing.summary() if final and not self.lockstep else {}
        self.node.status(round(self.vehicle.sim_t_s * 1e6), final=final, steps=steps,
                         armed=self.vehicle.armed, mode=self.vehicle.mode.value,
                         timing=summary, links=self.ground.link_status())


def scene_fields(vehicle: Commander, airframe: dict) -> dict:
    """What a viewer draws, in local NED around the origin [m]: the airframe's rotors (body
    FRD, with their spin), the positioned mission items and rally points (each
    ``[seq, n, e, d]``), the fence's zones, and the mission's current item
    (ground/telemetry/foxglove_view.py reads it)."""
    places = vehicle.places
    here = (np.zeros(3) if vehicle.measurement is None  # before the first sample
            else vehicle.measurement[MEASUREMENT.position_ned_m])
    lists = vehicle.mission.lists

    def positions(items: tuple) -> list[list[float]]:
        """[seq, north, east, down] of each positioned item."""
        out = []
        for item in items:
            if item.command in WITHOUT_POSITION:
                continue
            p = item_position_ned(item, here, places)
            if np.all(np.isfinite(p)):
                out.append([item.seq, *(round(float(x), 3) for x in p)])
        return out

    fence = []
    for zone in zones_from_items(lists[FENCE], places.origin):
        if zone.vertices is not None:
            fence.append({"inclusion": zone.inclusion,
                          "polygon": [[round(float(n), 3), round(float(e), 3)]
                                      for n, e in zone.vertices]})
        else:
            fence.append({"inclusion": zone.inclusion,
                          "centre": [round(float(c), 3) for c in zone.centre],
                          "radius_m": float(zone.radius_m)})
    return {"airframe": airframe, "home": list(places.origin), "mission": positions(lists[MISSION]),
            "current": vehicle.mission.current, "fence": fence,
            "rally": positions(lists[RALLY])}
