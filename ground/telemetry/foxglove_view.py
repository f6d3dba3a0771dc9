"""What Foxglove draws: telemetry records as Foxglove's schemas (docs/telemetry.md#foxglove).

One converter serves both the live view (``ground/telemetry/live_view.py``, over WebSocket) and the
logger (the same messages written into the MCAP file beside our own records), so a
flight looks the same live and afterwards and one layout opens both.

Frames (a transform tree per vehicle ``V``):

* ``world``: east-north-up, the frame Foxglove's 3D panel looks at (its up is +z);
* ``ned``: the local north-east-down frame around home, a fixed rotation of ``world``;
* ``vehicleV``: the body (front-right-down), from the truth's pose;
* ``vehicleV/rotorI``: each rotor, at its place on the airframe.

Topics (``V`` the vehicle id):

=============================  ==================  ====================================
topic                          schema              what
=============================  ==================  ====================================
``/tf``                        FrameTransforms     world -> ned -> vehicle
``/vehicleV/rotors``           FrameTransforms     vehicle -> rotors (with each scene)
``/vehicleV/scene``            SceneUpdate         vehicle model, home, mission, fence
``/vehicleV/path``             PosesInFrame        the path flown (last TRAIL_S seconds)
``/vehicleV/reference_path``   PosesInFrame        the reference over the same time
``/vehicleV/reference``        PoseInFrame         the reference now
``/vehicleV/controller``       JSON                per channel: reference, measured,
                                                   error, sliding surface, f_hat, u_eq,
                                                   u_s, control, theta_g; motors, mode
``/vehicleV/estimator``        JSON                estimate against the truth (on the
                                                   estimator)
``/log``                       Log                 STATUSTEXT and perturbation events
=============================  ==================  ====================================

Records arrive at any rate; each output is decimated on sim time (``rate_hz``, the path at
``path_hz``), so what the view costs does not grow with the vehicle's rate. Timestamps are
sim time.
"""

from __future__ import annotations

import functools
import math
import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from foxglove import messages as fg

from contracts import AUTOPILOT, SITL
from contracts.frames import euler_from_quat, quat_from_euler, wrap_pi_array
from contracts.mavlink import StatustextAssembler, mavlink
from contracts.telemetry import (
    CONTROL,
    ESTIMATE,
    MIRROR_ATTACHMENT,
    STATE,
    decode_json_record,
    json_record,
    parse_key,
)
from contracts.vectors import MEAS_VEL, REF_EULER, REF_POS
from ground.telemetry.controller_text import CONTROLLER_TEXT
from ground.telemetry.foxglove_scene import (
    FRAME_NED,
    FRAME_WORLD,
    IDENTITY,
    body_frame,
    fence_entity,
    fg_color,
    fg_pose,
    fg_quaternion,
    fg_vector,
    finite_list,
    finite_or_none,
    item_rows,
    mission_entity,
    rotor_frame,
    text_pose,
    timestamp,
    vehicle_model,
    vehicle_topic,
    zone_dict,
)

DEFAULT_RATE_HZ = 50.0
DEFAULT_PATH_HZ = 2.0
TRAIL_S = 60.0  # the path and reference trail drawn
TRAIL_SAMPLE_S = 0.1  # one pose of the trail every this much sim time
MATCH_WINDOW = 64  # truths kept, estimates waiting, to pair them by sim time
MAX_ROUTES = 4096  # keys whose drawing is remembered
TF_TOPIC = "/tf"
LOG_TOPIC = "/log"
# world (ENU) -> ned: x_ned = north = y_enu, y_ned = east = x_enu, z_ned = -z_enu.
NED_IN_WORLD = fg.Quaternion(x=math.sqrt(0.5), y=math.sqrt(0.5), z=0.0, w=0.0)
SEVERITY_LEVEL = {0: fg.LogLevel.Fatal, 1: fg.LogLevel.Fatal, 2: fg.LogLevel.Fatal,
                  3: fg.LogLevel.Error, 4: fg.LogLevel.Warning, 5: fg.LogLevel.Info,
                  6: fg.LogLevel.Info, 7: fg.LogLevel.Debug}
_SIM_TIME = struct.Struct("<q")  # after the CDR header (4) and seq (8)
# The few fields drawn, read where they sit rather than decoding whole records (a
# control record's decode alone was 15 us, a seventh of drawing it).
_XYZ, _WXYZ, _MODE_FLAGS = struct.Struct("<3d"), struct.Struct("<4d"), struct.Struct("<2q")
_STATE_POSITION_AT = STATE.offset("position_ned_m")
_STATE_QUATERNION_AT = STATE.offset("quaternion")
_CONTROL_MODE_AT = CONTROL.offset("mode")
_REFERENCE_POSITION_AT = CONTROL.offset("reference", REF_POS)
_REFERENCE_EULER_AT = CONTROL.offset("reference", REF_EULER)
_MEASURED_VELOCITY_AT = CONTROL.offset("measurement", MEAS_VEL)


@dataclass
class Output:
    """One Foxglove message: its topic, sim time [ns] and the message (a Foxglove schema
    object, or a dict for a JSON channel)."""

    topic: str
    sim_time_ns: int
    message: Any


@dataclass
class _Vehicle:
    next_tf_us: int = -1
    next_control_us: int = -1
    next_estimate_us: int = -1
    next_path_us: int = -1
    next_trail_us: int = -1
    next_reference_trail_us: int = -1
    path: deque = field(default_factory=lambda: deque(maxlen=int(TRAIL_S / TRAIL_SAMPLE_S)))
    reference_path: deque = field(
        default_factory=lambda: deque(maxlen=int(TRAIL_S / TRAIL_SAMPLE_S)))
    next_reference_path_us: int = -1
    # Truth states drawn (by sim time) and estimates waiting for the truth of their time:
    # the two streams arrive in their own order, so an estimate is drawn once the truth
    # has reached its time, against the latest truth at or before it (the same pairs on
    # every run).
    truths: deque = field(default_factory=lambda: deque(maxlen=MATCH_WINDOW))
    estimates: deque = field(default_factory=lambda: deque(maxlen=MATCH_WINDOW))
    statustext: StatustextAssembler = field(default_factory=StatustextAssembler)


class FoxgloveView:
    """Turns telemetry records into Foxglove messages. ``feed`` takes what the logger
    takes (a record that passed the logger's check); malformed content of a valid record
    (a scene record's fields) raises ValueError and changes nothing."""

    def __init__(self, rate_hz: float = DEFAULT_RATE_HZ,
                 path_hz: float = DEFAULT_PATH_HZ) -> None:
        if not (0.1 <= rate_hz <= 1000.0 and 0.1 <= path_hz <= rate_hz):
            raise ValueError(f"view rates must be 0.1 <= path ({path_hz}) <= rate ({rate_hz})"
                             " <= 1000 Hz")
        self.period_us = round(1e6 / rate_hz)
        self.path_period_us = round(1e6 / path_hz)
        self.vehicles: dict[int, _Vehicle] = {}
        self._routes: dict[str, Callable[[bytes, bytes | None], list[Output]]] = {}

    def _vehicle(self, vehicle: int) -> _Vehicle:
        v = self.vehicles.get(vehicle)
        if v is None:
            if len(self.vehicles) >= 255:
                raise ValueError("more than 255 vehicles")
            v = self.vehicles[vehicle] = _Vehicle()
        return v

    def feed(self, key: str, payload: bytes, attachment: bytes | None = None) -> list[Output]:
        draw = self._routes.get(key)
        if draw is None:
            draw = self._route(key)
            if len(self._routes) < MAX_ROUTES:  # past it (hostile keys), routed each time
                self._routes[key] = draw
        return draw(payload, attachment)

    def draws(self, key: str) -> bool:
        """Whether any record on ``key`` can give an output (a caller that knows its keys
        skips ``feed`` for the others: the timing records, most of the MAVLink mirror)."""
        return self._route(key) is not _nothing

    def _route(self, key: str) -> Callable[[bytes, bytes | None], list[Output]]:
        """What draws the records of ``key``: worked out once per key, not per record."""
        if key.startswith("mavlink/"):
            parts = key.split("/")
            if len(parts) != 4 or parts[3] != "STATUSTEXT" or not parts[1].isdigit() or \
                    not 1 <= int(parts[1]) <= 255:
                return _nothing
            return functools.partial(self._statustext, int(parts[1]))
        parsed = parse_key(key)
        if parsed is None or not 1 <= parsed[0] <= 255:
            return _nothing
        vehicle, process, topic = parsed
        if process == SITL and topic == "state":
            return lambda payload, _attachment: self._state(vehicle, payload)
        if process == AUTOPILOT and topic == "control":
            return lambda payload, _attachment: self._control(vehicle, payload)
        if process == AUTOPILOT and topic == "estimate":
            return lambda payload, _attachment: self._estimate(vehicle, payload)
        if process == AUTOPILOT and topic == "scene":
            return lambda payload, _attachment: self._scene(vehicle,
                                                            decode_json_record(payload))
        if topic == "perturbation":
            return lambda payload, _attachment: self._perturbation(
                vehicle, process, decode_json_record(payload))
        return _nothing

    # -- truth: transforms and the path flown ---------------------------------------------
    def _state(self, vehicle: int, payload: bytes) -> list[Output]:
        v = self._vehicle(vehicle)
        t_us = _sim_time_us(payload, STATE)
        if t_us < v.next_tf_us and t_us < v.next_path_us:
            return []
        STATE.check(payload)
        pos = _XYZ.unpack_from(payload, _STATE_POSITION_AT)
        q = _WXYZ.unpack_from(payload, _STATE_QUATERNION_AT)
        if not all(map(math.isfinite, (*pos, *q))):
            return []
        v.truths.append((t_us, payload))
        out = self._matched_estimates(vehicle, v)
        stamp = timestamp(t_us)
        if t_us >= v.next_tf_us:
            v.next_tf_us = t_us - t_us % self.period_us + self.period_us
            transforms = [
                fg.FrameTransform(timestamp=stamp, parent_frame_id=FRAME_WORLD,
                                  child_frame_id=FRAME_NED, rotation=NED_IN_WORLD),
                fg.FrameTransform(timestamp=stamp, parent_frame_id=FRAME_NED,
                                  child_frame_id=body_frame(vehicle),
                                  translation=fg_vector(pos), rotation=fg_quaternion(q))]
            out.append(Output(TF_TOPIC, t_us * 1000, fg.FrameTransforms(transforms=transforms)))
        if t_us >= v.next_trail_us:
            v.next_trail_us = t_us + round(TRAIL_SAMPLE_S * 1e6)
            v.path.append(fg_pose(pos, q))
        if t_us >= v.next_path_us:
            v.next_path_us = t_us - t_us % self.path_period_us + self.path_period_us
            out.append(Output(vehicle_topic(vehicle, "path"), t_us * 1000,
                              fg.PosesInFrame(timestamp=stamp, frame_id=FRAME_NED,
                                              poses=list(v.path))))
        return out

    # -- the controller: reference pose, plot-ready internals ----------------------------
    def _control(self, vehicle: int, payload: bytes) -> list[Output]:
        v = self._vehicle(vehicle)
        t_us = _sim_time_us(payload, CONTROL)
        if t_us < v.next_control_us:
            return []
        theta_f = CONTROL.sequence_arrays(payload)  # checks the payload's sizes first
        v.next_control_us = t_us - t_us % self.period_us + self.period_us
        mode, flags = _MODE_FLAGS.unpack_from(payload, _CONTROL_MODE_AT)
        ref_pos = _XYZ.unpack_from(payload, _REFERENCE_POSITION_AT)
        ref_q = quat_from_euler(*_XYZ.unpack_from(payload, _REFERENCE_EULER_AT))
        stamp = timestamp(t_us)
        out = []
        if all(map(math.isfinite, (*ref_pos, *ref_q))):
            pose = fg_pose(ref_pos, ref_q)
            out.append(Output(vehicle_topic(vehicle, "reference"), t_us * 1000,
                              fg.PoseInFrame(timestamp=stamp, frame_id=FRAME_NED, pose=pose)))
            if t_us >= v.next_reference_trail_us:
                v.next_reference_trail_us = t_us + round(TRAIL_SAMPLE_S * 1e6)
                v.reference_path.append(pose)
        if t_us >= v.next_reference_path_us:  # on the control records' own clock
            v.next_reference_path_us = (t_us - t_us % self.path_period_us
                                        + self.path_period_us)
            out.append(Output(vehicle_topic(vehicle, "reference_path"), t_us * 1000,
                              fg.PosesInFrame(timestamp=stamp, frame_id=FRAME_NED,
                                              poses=list(v.reference_path))))
        # np.dot: the same sums as ``w @ w`` bit for bit, without a ufunc's overflow
        # warning (huge values give inf, drawn null) and at half its cost.
        norms = [math.sqrt(np.dot(w, w)) if len(w) else math.nan for w in theta_f]
        velocity = np.frombuffer(payload, "<f8", 3, _MEASURED_VELOCITY_AT)
        speed = math.sqrt(np.dot(velocity, velocity))
        text = CONTROLLER_TEXT.encode(payload, t_us, mode, flags, speed, norms)
        out.append(Output(vehicle_topic(vehicle, "controller"), t_us * 1000, text))
        return out

    # -- the estimator against the truth --------------------------------------------------
    def _estimate(self, vehicle: int, payload: bytes) -> list[Output]:
        v = self._vehicle(vehicle)
        t_us = _sim_time_us(payload, ESTIMATE)
        if t_us < v.next_estimate_us:
            return []
        v.next_estimate_us = t_us - t_us % self.period_us + self.period_us
        v.estimates.append(ESTIMATE.decode(payload))
        return self._matched_estimates(vehicle, v)

    def _matched_estimates(self, vehicle: int, v: _Vehicle) -> list[Output]:
        """The waiting estimates whose time the truth has reached."""
        out = []
        while v.estimates and v.truths and \
                v.truths[-1][0] >= int(v.estimates[0]["sim_time_us"]):
            e = v.estimates.popleft()
            t_us = int(e["sim_time_us"])
            before = [payload for truth_us, payload in v.truths if truth_us <= t_us]
            if before:
                out.append(self._estimate_record(vehicle, t_us, e, STATE.decode(before[-1])))
        return out

    def _estimate_record(self, vehicle: int, t_us: int, e: dict[str, Any],
                         truth: dict[str, Any]) -> Output:
        error = e["position_ned_m"] - truth["position_ned_m"]
        velocity_error = e["velocity_ned_mps"] - truth["velocity_ned_mps"]
        attitude_error = wrap_pi_array(euler_from_quat(e["quaternion"])
                                       - truth["euler_rad"])
        record = {
            "t_s": t_us / 1e6,
            "truth_age_s": (t_us - int(truth["sim_time_us"])) / 1e6,
            "position_error_m": dict(zip("ned", map(finite_or_none, error), strict=True)),
            "horizontal_error_m": finite_or_none(float(np.hypot(error[0], error[1]))),
            "velocity_error_mps": dict(zip("ned", map(finite_or_none, velocity_error),
                                           strict=True)),
            "attitude_error_rad": dict(zip(("roll", "pitch", "yaw"),
                                           map(finite_or_none, attitude_error), strict=True)),
            "estimate": {"position_ned_m": [finite_or_none(x) for x in e["position_ned_m"]],
                         "velocity_ned_mps": [finite_or_none(x) for x in e["velocity_ned_mps"]]},
            "truth": {"position_ned_m": [finite_or_none(x) for x in truth["position_ned_m"]],
                      "velocity_ned_mps": [finite_or_none(x) for x in truth["velocity_ned_mps"]]},
            "horizontal_sigma_m": finite_or_none(e["horizontal_sigma_m"]),
            "vertical_sigma_m": finite_or_none(e["vertical_sigma_m"]),
            "gps_test_ratio": finite_or_none(e["gps_test_ratio"]),
            "flags": int(e["flags"]),
        }
        return Output(vehicle_topic(vehicle, "estimator"), t_us * 1000, record)

    # -- the scene: vehicle model, home, mission, fence, rally ----------------------------
    def _scene(self, vehicle: int, record: dict[str, Any]) -> list[Output]:
        """A scene record (autopilot/process/telemetry.py) as a SceneUpdate; a malformed
        one raises ValueError and changes nothing."""
        t_us = record["sim_time_us"]
        airframe = record.get("airframe") or {}
        rotors = airframe.get("rotors", [])
        if not isinstance(rotors, list) or len(rotors) > 16:
            raise ValueError("scene: airframe rotors must be a list of at most 16")
        rotors_m = tuple(tuple(finite_list(r, 4)[:3]) for r in rotors)
        spins = [finite_list(r, 4)[3] for r in rotors]
        mission = item_rows(record.get("mission", []), 4, "mission")  # seq, n, e, d
        rally = [p[1:] for p in item_rows(record.get("rally", []), 4, "rally")]
        fence = record.get("fence", [])
        if not isinstance(fence, list) or len(fence) > 64:
            raise ValueError("scene: fence must be a list of at most 64 zones")
        zones = [zone_dict(z) for z in fence]
        current = record.get("current", -1)
        if not isinstance(current, int):
            raise ValueError("scene: current must be a whole number")
        # Checked: take it.
        stamp = timestamp(t_us)
        entities = [vehicle_model(vehicle, stamp, rotors_m, spins, str(airframe.get("name",
                                                                                      "")))]
        entities.append(fg.SceneEntity(
            timestamp=stamp, frame_id=FRAME_NED, id="home",
            spheres=[fg.SpherePrimitive(pose=IDENTITY, size=fg.Vector3(x=0.4, y=0.4, z=0.4),
                                        color=fg_color(0.1, 0.8, 0.2))],
            texts=[fg.TextPrimitive(pose=text_pose((0, 0, -0.6)), billboard=True,
                                    font_size=14, scale_invariant=True,
                                    color=fg_color(1, 1, 1), text="H")]))
        entities.append(mission_entity(stamp, mission, current))
        entities.append(fence_entity(stamp, zones))
        entities.append(fg.SceneEntity(
            timestamp=stamp, frame_id=FRAME_NED, id="rally",
            spheres=[fg.SpherePrimitive(pose=text_pose(p), size=fg.Vector3(x=0.5, y=0.5,
                                                                             z=0.5),
                                        color=fg_color(0.9, 0.5, 0.1)) for p in rally]))
        # The rotors' frames come with the scene, which carries them, on their own topic:
        # in /tf, drawn from whichever state record came after the first scene record,
        # they made the log depend on the order two subscriptions delivered in.
        rotors = fg.FrameTransforms(transforms=[
            fg.FrameTransform(timestamp=stamp, parent_frame_id=body_frame(vehicle),
                              child_frame_id=rotor_frame(vehicle, i + 1),
                              translation=fg_vector(r))
            for i, r in enumerate(rotors_m)])
        return [Output(vehicle_topic(vehicle, "scene"), t_us * 1000,
                       fg.SceneUpdate(entities=entities)),
                Output(vehicle_topic(vehicle, "rotors"), t_us * 1000, rotors)]

    # -- events ---------------------------------------------------------------------------
    def _perturbation(self, vehicle: int, process: str, record: dict[str, Any]) -> list[Output]:
        t_us = record["sim_time_us"]
        text = (f"perturbation {record.get('id', '?')} ({record.get('kind', '?')}) "
                f"{record.get('event', '?')}")
        return [Output(LOG_TOPIC, t_us * 1000, fg.Log(
            timestamp=timestamp(t_us), level=fg.LogLevel.Warning, message=text[:400],
            name=f"{body_frame(vehicle)}/{process}"))]

    def _statustext(self, vehicle: int, payload: bytes,
                    attachment: bytes | None) -> list[Output]:
        if attachment is None or len(attachment) != MIRROR_ATTACHMENT.size:
            return []
        _seq, t_us = MIRROR_ATTACHMENT.unpack(attachment)
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        try:
            msg = parser.decode(bytearray(payload))
        except (mavlink.MAVError, struct.error, IndexError, ValueError):
            return []
        if msg.get_type() != "STATUSTEXT":
            return []
        text = self._vehicle(vehicle).statustext.add(msg)  # chunks joined, as tools do
        if text is None:
            return []
        return [Output(LOG_TOPIC, t_us * 1000, fg.Log(
            timestamp=timestamp(t_us), level=SEVERITY_LEVEL.get(msg.severity,
                                                                fg.LogLevel.Info),
            message=text.rstrip("\x00"), name=body_frame(vehicle)))]


def warm_up() -> None:
    """Load what drawing needs (compiled code from numba's cache, the SDK's message types)
    by drawing one record of each kind on a scratch view: a logger that loaded it at the
    flight's first records took half a second of CPU from the vehicles mid-flight."""
    from ground.telemetry.foxglove_scene import encode

    view = FoxgloveView(DEFAULT_RATE_HZ)
    state, control, estimate = STATE.buffer(), CONTROL.buffer(), ESTIMATE.buffer()
    state["quaternion"] = estimate["quaternion"] = (1.0, 0.0, 0.0, 0.0)
    records = (("ivfm/vehicle/1/sitl/state", state.encode()),
               ("ivfm/vehicle/1/autopilot/control", control.encode(((1.0,), (), ()))),
               ("ivfm/vehicle/1/autopilot/estimate", estimate.encode()),
               ("ivfm/vehicle/1/sitl/state", state.encode()),
               ("ivfm/vehicle/1/autopilot/scene", json_record(0, 0, airframe={
                   "name": "", "rotors": [[0.1, 0.1, 0.0, 1]]}, mission=[[1, 1.0, 0.0, -1.0]],
                   fence=[], rally=[], current=1)))
    for key, payload in records:
        for output in view.feed(key, payload):
            encode(output.message)


def _nothing(_payload: bytes, _attachment: bytes | None) -> list[Output]:
    return []


def _sim_time_us(payload: bytes, schema: Any) -> int:
    """A record's sim time, read before deciding to decode it (most are not drawn)."""
    if len(payload) < schema.fixed_size:
        raise ValueError(f"{schema.name}: payload of {len(payload)} bytes is too short")
    return _SIM_TIME.unpack_from(payload, 12)[0]
