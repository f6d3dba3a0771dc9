"""The autopilot process: the simulator link, the fixed-rate control loop, ground links.

* lockstep: each simulator sample (the state message that closes it) runs the control
  step when its sim time reaches the next control deadline, then the actuator message
  answers that sample with the lockstep flag set.
* real time: a wall-clock timer at the control rate uses the newest sample; loop
  period, compute time, jitter and deadline misses are measured.

Each control step publishes the controller's internals and the loop timing over Zenoh,
and mirrors the MAVLink it produces (``contracts/telemetry.py``); perturbation requests
(reference kicks) are taken between steps.
"""

from __future__ import annotations

import gc
import json
import math
import queue
import selectors
import signal
import socket
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from autopilot.commander.commander import Commander
from autopilot.estimation.estimator import Estimator, GpsFix
from autopilot.flight_tasks import shaper
from autopilot.mavlink.server import MavlinkServer
from autopilot.refusal import RefusedError
from contracts.airframe import max_thrust_n
from contracts.frames import (
    GRAVITY_MPS2,
    HOME_ALT_AMSL_M,
    HOME_LAT_DEG,
    HOME_LON_DEG,
    euler_from_quat,
    wrap_pi,
)
from contracts.mavlink import (
    AUTOPILOT_COMPID,
    AUTOPILOT_SYSID,
    HIL_SENSOR_ALL_FIELDS,
    SIM_TCP_PORT,
    STATE_SOURCES,
    GpsSample,
    LinkDataError,
    SensorSample,
    TruthSample,
    actuator_message,
    fix_from_hil_gps,
    imu_from_hil_sensor,
    mavlink,
    measurement_from_hil_state,
    measurement_from_odometry,
    new_mavlink,
    sample_messages,
    split_frames,
)
from contracts.modes import FlightMode
from contracts.realtime import LoopTiming, set_realtime_priority
from contracts.telemetry import (
    AUTOPILOT,
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
from contracts.vectors import CHANNEL_INTERNALS, MEAS_Z, MEASUREMENT_SIZE, REF_SIZE
from contracts.zenoh_link import Request, TelemetryNode, ZenohOptions

SIM_HEARTBEAT_S = 1.0  # to the simulator, from the connection on (jMAVSim waits for one)
RECONNECT_S = 0.5
SPIN_S = 0.0005  # the last stretch before a real-time deadline is busy-waited
POLL_MIN_S = 0.0015  # below this, sleep (ns resolution) instead of epoll (ms resolution)
# Ground links get a bounded share of each period, after the control step (bad input:
# docs/architecture.md).
GROUND_SHARE = 0.4  # of the period at most, for reading ground links
GROUND_GUARD_S = 0.0005  # ground work ends at least this long before the next spin
GROUND_SLICE = 16  # datagrams per link per turn
SERVICE_PERIOD_S = 0.005  # telemetry out, link failsafes, Zenoh requests, status
LOCKSTEP_GROUND_BUDGET_S = 0.001  # per service period in lockstep
MODE_INDEX = {mode: i for i, mode in enumerate(FlightMode)}
# The MAVLink mirror's sim-time streams (message, period in microseconds of sim time).
MIRROR_STREAMS_US = ((mavlink.MAVLINK_MSG_ID_HEARTBEAT, 1_000_000),
                     (mavlink.MAVLINK_MSG_ID_ATTITUDE, 100_000),
                     (mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 100_000),
                     (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 100_000))
MIRRORED_TOOL_MESSAGES = frozenset({"STATUSTEXT", "COMMAND_ACK"})


@dataclass
class AutopilotConfig:
    sim_host: str = "127.0.0.1"
    sim_port: int = SIM_TCP_PORT
    lockstep: bool = True
    rate_hz: float = 100.0
    state_source: str = "auto"
    duration_s: float = math.inf  # stop after this much sim time of control
    sysid: int = AUTOPILOT_SYSID  # also the vehicle id in telemetry keys
    rt_priority: int = 50  # SCHED_FIFO priority of the real-time loop (0: normal)
    zenoh: ZenohOptions = field(default_factory=lambda: ZenohOptions(enabled=False))

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_hz) and 1.0 <= self.rate_hz <= 1000.0):
            raise ValueError(f"control rate must be in [1, 1000] Hz, got {self.rate_hz!r}")
        if abs(1e6 / self.rate_hz - round(1e6 / self.rate_hz)) > 1e-6:
            raise ValueError(f"rate {self.rate_hz} Hz does not give a whole microsecond period")
        if not 0 <= self.rt_priority <= 99:
            raise ValueError(f"real-time priority must be in [0, 99], got {self.rt_priority}")
        if self.state_source not in STATE_SOURCES:
            raise ValueError(f"unknown state source {self.state_source!r}; known: "
                             f"{', '.join(STATE_SOURCES)}")


class SimLink:
    """TCP client of the simulator; reconnects while the simulator is away."""

    def __init__(self, host: str, port: int, source: str, sysid: int = AUTOPILOT_SYSID,
                 estimator: Estimator | None = None) -> None:
        self.address = (host, port)
        self.sock: socket.socket | None = None
        self.source_types = STATE_SOURCES[source]
        self.estimator = estimator if source == "estimator" else None
        self.source_ids = frozenset(getattr(mavlink, f"MAVLINK_MSG_ID_{t}")
                                    for t in self.source_types) | {-1}
        self._pending = b""
        self.odometry_seen = False  # auto: once ODOMETRY arrives, HIL_STATE is not used
        self.next_heartbeat_s = math.inf
        self.sysid = sysid
        self.mav = new_mavlink(sysid, AUTOPILOT_COMPID)
        self.next_attempt_s = 0.0
        self.bad_messages = 0
        self.last_bad: str | None = None

    def connect(self, now: float) -> bool:
        if self.sock is not None or now < self.next_attempt_s:
            return False
        self.next_attempt_s = now + RECONNECT_S
        try:
            sock = socket.create_connection(self.address, timeout=0.2)
        except OSError:
            return False
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        self.sock = sock
        self.mav = new_mavlink(self.sysid, AUTOPILOT_COMPID)
        self._pending = b""
        self.odometry_seen = False
        self.next_heartbeat_s = now  # at once: some simulators wait for it
        return True

    def heartbeat_due(self, now: float) -> bool:
        """Send the simulator a HEARTBEAT on connecting and every SIM_HEARTBEAT_S."""
        if self.sock is None or now < self.next_heartbeat_s:
            return False
        self.next_heartbeat_s = max(self.next_heartbeat_s + SIM_HEARTBEAT_S, now)
        msg = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0,
            mavlink.MAV_STATE_ACTIVE, 3)
        return self.send(msg.pack(self.mav))

    def decode(self, msg) -> np.ndarray | None:
        """The measurement of a state message (raises LinkDataError on bad data). On the
        estimator: a fix goes into it (None: not a sample), an IMU sample steps it and the
        sample's measurement is the estimate (None until it has aligned)."""
        kind = msg.get_type()
        if kind == "ODOMETRY":
            return measurement_from_odometry(msg)
        if kind == "HIL_STATE_QUATERNION":
            return measurement_from_hil_state(msg)
        est = self.estimator
        if kind == "HIL_GPS":
            position, velocity, fix_type, satellites = fix_from_hil_gps(msg)
            est.gps(msg.time_usec, GpsFix(position, velocity, fix_type, satellites))
            return None
        gyro, accel, baro_alt, mag = imu_from_hil_sensor(msg)
        est.imu(msg.time_usec, gyro, accel, baro_alt, mag)
        return est.measurement() if est.aligned else None

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def read(self) -> list[tuple[int, np.ndarray | None]] | None:
        """Samples (time_us, measurement) now available (measurement None: the estimator
        has not aligned yet); None when the link closed."""
        try:
            data = self.sock.recv(262144)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError:
            return None
        if not data:
            return None
        frames, self._pending = split_frames(self._pending + data)
        wanted = b"".join(f for msgid, f in frames if msgid in self.source_ids)
        msgs = [m for m in (self.mav.parse_buffer(wanted) if wanted else None) or []
                if m.get_type() in self.source_types]
        if not self.odometry_seen and any(m.get_type() == "ODOMETRY" for m in msgs):
            self.odometry_seen = True
        samples = []
        for msg in msgs:
            if self.odometry_seen and msg.get_type() != "ODOMETRY":
                continue  # the same sample, from the message the controller prefers
            try:
                measurement = self.decode(msg)
            except LinkDataError as exc:
                self.bad_messages += 1
                self.last_bad = str(exc)
                continue
            if msg.get_type() != "HIL_GPS":
                samples.append((msg.time_usec, measurement))
        return samples

    def send(self, data: bytes) -> bool:
        try:
            self.sock.sendall(data)
            return True
        except OSError:
            return False


class Autopilot:
    def __init__(self, config: AutopilotConfig, vehicle: Commander, ground: MavlinkServer,
                 arm_in_reference: bool = False, start_mission: bool = False,
                 log=None) -> None:
        self.config = config
        self.vehicle = vehicle
        self.ground = ground
        self.arm_in_reference = arm_in_reference
        self.start_mission = start_mission  # until armed in AUTO.MISSION
        self.log = log or (lambda text: print(f"autopilot: {text}", file=sys.stderr, flush=True))
        self.period_us = round(1e6 / config.rate_hz)
        estimator = (Estimator(gps_delay_s=vehicle.parameters["EKF2_GPS_DELAY"] / 1e3)
                     if config.state_source == "estimator" else None)
        self.sim = SimLink(config.sim_host, config.sim_port, config.state_source, config.sysid,
                           estimator)
        self.timing = LoopTiming(self.period_us / 1e6)
        self.node = TelemetryNode(config.zenoh, config.sysid, AUTOPILOT, self.log)
        self._control_pub = self.node.publisher("control")
        self._timing_pub = self.node.publisher("timing")
        self._estimate_pub = (self.node.publisher("estimate") if estimator is not None
                              else None)
        self._estimate_record = ESTIMATE.buffer()
        self._event_pub = self.node.publisher("perturbation")
        self.node.serve("perturb")
        self._control_record = CONTROL.buffer()
        self._timing_record = TIMING.buffer()
        self._channel_internals = self._control_record.block(
            tuple(f"ch_{name}" for name in CHANNEL_INTERNALS))
        self._mirror_mav = new_mavlink(config.sysid, AUTOPILOT_COMPID)
        self._mirror_due_us = [0] * len(MIRROR_STREAMS_US)
        self._previous_control_wall: float | None = None
        if self.node.enabled:
            ground.on_sent = self._mirror_tool_message
            # Declared now: a first declaration inside the loop would cost a deadline.
            for name in ("HIL_ACTUATOR_CONTROLS", *MIRRORED_TOOL_MESSAGES,
                         *(mavlink.mavlink_map[i].msgname for i, _ in MIRROR_STREAMS_US)):
                self.node.mirror_publisher(config.sysid, AUTOPILOT_COMPID, name)
        self.steps = 0
        self.max_steps = (math.inf if math.isinf(config.duration_s)
                          else round(config.duration_s * 1e6 / self.period_us))
        self.next_control_us: int | None = None
        self._step_start = 0.0  # when the last control step began (perf_counter)
        self._command_sent = 0.0  # when the last motor command went out (perf_counter)
        self.latest: tuple[int, np.ndarray] | None = None
        self.sel = selectors.DefaultSelector()  # the simulator link only: ground links
        self._next_service = 0.0               # are read within a budget (_ground_work)
        self._stop = False
        self._progress_at = 0.1
        self._gps_ok: bool | None = None

    def stop(self, *_args) -> None:
        self._stop = True

    def _start_mission(self, sim_t_s: float) -> None:
        """Scenario runs: arm in AUTO.MISSION as soon as the vehicle allows it (on the
        estimator, once it has converged), on sim time."""
        try:
            self.vehicle.set_mode(FlightMode.MISSION, sim_t_s)
            self.vehicle.arm(sim_t_s)
        except RefusedError:
            return
        self.start_mission = False
        self.log(f"flying the mission from t={sim_t_s:.3f} s")

    def _control(self, time_us: int, measurement: np.ndarray,
                 step_start: float | None = None) -> np.ndarray:
        """One control step; ``step_start`` is when the step began (real time: its
        deadline, before the newest sample was read), for the timing record."""
        start = time.perf_counter() if step_start is None else step_start
        if not self.node.requests.empty():
            self._service_requests()
        self.vehicle.sample(time_us / 1e6, measurement)
        if self.arm_in_reference and not self.vehicle.armed and self.steps == 0:
            self.vehicle.arm_in_reference()
            self.log(f"flying the {self.vehicle.reference.kind} reference from "
                     f"t={time_us / 1e6:.3f} s")
        if self.start_mission:
            self._start_mission(time_us / 1e6)
        commands = self.vehicle.control()
        self._step_start = start
        self.steps += 1
        if self.max_steps < math.inf and self.steps >= self._progress_at * self.max_steps:
            self.log(f"{100 * self._progress_at:.0f} % ({time_us / 1e6:.1f} s sim)")
            self._progress_at += 0.1
        return commands

    def _answer(self, time_us: int, commands: np.ndarray, stepped: bool) -> None:
        """The motor command goes out first; telemetry of the step after it."""
        msg = actuator_message(time_us, commands, self.vehicle.armed, self.config.lockstep)
        frame = msg.pack(self.sim.mav)
        if not self.sim.send(frame):
            self._sim_lost()
            return
        self._command_sent = time.perf_counter()
        if not self.node.enabled:
            return
        if stepped:
            self._publish_step(time_us, self._command_sent - self._step_start,
                               self._step_start)
        self.node.mirror(self.config.sysid, AUTOPILOT_COMPID, "HIL_ACTUATOR_CONTROLS",
                         frame, time_us)

    # -- Zenoh ---------------------------------------------------------------------------
    def _publish_step(self, time_us: int, compute_s: float, start_wall_s: float) -> None:
        """The control record, the timing record, kick events and the mirror streams."""
        v = self.vehicle
        c = v.controller
        record = self._control_record
        record["seq"], record["sim_time_us"] = self._control_pub.count, time_us
        record["mode"] = MODE_INDEX[v.mode]
        record["flags"] = (FLAG_ARMED if v.armed else 0) | (FLAG_FAILSAFE if v.failsafe else 0)
        record["reference_time_s"] = time_us / 1e6 - v.reference_start_s
        record["measurement"], record["reference"] = v.measurement, v.flight.last_ref
        record["kick_rad"], record["motor_commands"] = v.flight.last_kick, v.last_commands
        self._channel_internals[...] = c.telemetry.T
        theta_g = getattr(c, "theta_g", None)
        record["theta_g"] = np.nan if theta_g is None else theta_g
        theta_f = getattr(c, "theta_f", None)
        self._control_pub.put(record.encode(
            tuple(theta_f[:3]) if theta_f is not None else ((), (), ())))
        previous, self._previous_control_wall = self._previous_control_wall, start_wall_s
        record = self._timing_record
        record["seq"], record["sim_time_us"] = self._timing_pub.count, time_us
        record["deadline_misses"] = self.timing.misses
        record["compute_s"] = compute_s
        record["period_s"] = math.nan if previous is None else start_wall_s - previous
        self._timing_pub.put(record.encode())
        if self._estimate_pub is not None and v.estimator_status is not None:
            self._publish_estimate(time_us, v.estimator_status)
        if v.perturbations.entries:
            for event, e in v.perturbations.changes(time_us / 1e6):
                self._event_pub.put(json_record(self._event_pub.count, time_us, event=event,
                                                **e.to_request()))
                self.log(f"t={time_us / 1e6:.3f} s perturbation {e.id} ({e.kind}) {event}")
        for i, (msg_id, every_us) in enumerate(MIRROR_STREAMS_US):
            if time_us >= self._mirror_due_us[i]:
                self._mirror_due_us[i] = time_us - time_us % every_us + every_us
                msg = self.ground.telemetry(msg_id, boot_ms=(time_us // 1000) & 0xFFFFFFFF)
                self.node.mirror(self.config.sysid, AUTOPILOT_COMPID, msg.get_type(),
                                 msg.pack(self._mirror_mav), time_us)

    def _publish_estimate(self, time_us: int, status) -> None:
        x = self.sim.estimator.x
        record = self._estimate_record
        record["seq"], record["sim_time_us"] = self._estimate_pub.count, time_us
        record["flags"] = ((ESTIMATE_ALIGNED if status.aligned else 0)
                           | (ESTIMATE_CONVERGED if status.converged else 0)
                           | (ESTIMATE_GPS_OK if status.gps_ok else 0))
        record["position_ned_m"], record["velocity_ned_mps"] = x[0:3], x[3:6]
        record["quaternion"], record["gyro_bias_rad_s"] = x[6:10], x[10:13]
        record["accel_bias_mps2"], record["baro_offset_m"] = x[13:16], x[16]
        for name in ("tilt_sigma_rad", "yaw_sigma_rad", "horizontal_sigma_m",
                     "vertical_sigma_m", "velocity_sigma_mps", "gps_test_ratio",
                     "baro_test_ratio", "mag_test_ratio"):
            record[name] = getattr(status, name)
        self._estimate_pub.put(record.encode())

    def _mirror_tool_message(self, link, msg, frame: bytes) -> None:
        """Announcements and acknowledgements to ground tools go into the log too."""
        kind = msg.get_type()
        if kind in MIRRORED_TOOL_MESSAGES and (kind == "COMMAND_ACK" or
                                               link is self.ground.links[0]):
            self.node.mirror(self.config.sysid, AUTOPILOT_COMPID, kind, frame,
                             round(self.vehicle.sim_t_s * 1e6))

    def _service_requests(self) -> None:
        while True:
            try:
                request: Request = self.node.requests.get_nowait()
            except queue.Empty:
                return
            now_s = self.vehicle.sim_t_s
            try:
                answer = self.vehicle.perturbations.handle(request.data, now_s)
            except ValueError as exc:
                self.log(f"refused {request.topic} request: {exc}")
                request.reply(False, error=str(exc))
                continue
            self.log(f"perturbation request answered: {answer}")
            request.reply(True, sim_time_us=round(now_s * 1e6), **answer)

    def _status(self, final: bool = False) -> None:
        if not self.node.status_due(final):
            return  # asked every 5 ms, published once a second: gather nothing till then
        # The timing summary only goes into the final status (it reads whole histograms).
        summary = self.timing.summary() if final and not self.config.lockstep else {}
        self.node.status(round(self.vehicle.sim_t_s * 1e6), final=final, steps=self.steps,
                         armed=self.vehicle.armed, mode=self.vehicle.mode.value,
                         timing=summary, links=self.ground.link_status())

    def _sim_lost(self) -> None:
        self.sim.close()
        if self.vehicle.sim_link_ok:
            self.log("simulator link lost")
        self.vehicle.sim_link_lost()
        self.next_control_us = None

    def _connect(self, now: float) -> None:
        if self.sim.connect(now):
            self.log(f"connected to the simulator at {self.sim.address[0]}:"
                     f"{self.sim.address[1]}")
            self.sel.register(self.sim.sock, selectors.EVENT_READ, "sim")

    def _on_sim_readable(self) -> None:
        samples = self.sim.read()
        if samples is None:
            self.sel.unregister(self.sim.sock)
            self._sim_lost()
            return
        if self.sim.last_bad:
            self.log(f"refused simulator data: {self.sim.last_bad}")
            self.sim.last_bad = None
        for time_us, measurement in samples:
            if measurement is None:  # the estimator is aligning: nothing to fly on yet
                self.vehicle.navigation_problem = \
                    f"estimator {self.sim.estimator.status(time_us).reason}"
                self._answer(time_us, np.zeros(4), False)
                continue
            if self.sim.estimator is not None:
                self._estimator_news(time_us)
            if self.latest is not None and time_us < self.latest[0]:
                self.next_control_us = None  # a new simulator: its clock starts again
            self.latest = (time_us, measurement)
            if not self.config.lockstep:
                self.vehicle.sample(time_us / 1e6, measurement)
                continue
            stepped = self.next_control_us is None or time_us >= self.next_control_us
            if stepped:
                # Control instants keep the control rate whatever the simulator's rate: the
                # next deadline is a period after this one, not after this sample.
                if self.next_control_us is None:
                    self.next_control_us = time_us
                while self.next_control_us <= time_us:
                    self.next_control_us += self.period_us
                commands = self._control(time_us, measurement)
            else:
                commands = self.vehicle.last_commands
            self._answer(time_us, commands, stepped)
            if self.steps >= self.max_steps:
                self._stop = True
                return

    def _estimator_news(self, time_us: int) -> None:
        """Arming waits for the estimator; GPS loss and return are announced."""
        est = self.sim.estimator
        est.gps_delay_us = round(self.vehicle.parameters["EKF2_GPS_DELAY"] * 1e3)
        status = est.status(time_us)
        self.vehicle.navigation_problem = None if status.converged else \
            f"estimator {status.reason}"
        if status.gps_ok != self._gps_ok:
            if self._gps_ok is not None:
                self.vehicle.say("GPS regained" if status.gps_ok else
                                 "GPS lost: dead reckoning", 6 if status.gps_ok else 4)
            self._gps_ok = status.gps_ok
        self.vehicle.estimator_status = status

    def _sim_watchdog(self, now: float) -> None:
        """Real time: no sample for COM_SIM_LOSS_T means the simulator is gone."""
        if self.config.lockstep or self.sim.sock is None:
            return
        if now - self._last_sample_wall > self.vehicle.parameters["COM_SIM_LOSS_T"] and \
                self.vehicle.sim_link_ok:
            self.log("no samples from the simulator: link lost")
            self.vehicle.sim_link_lost()

    def run(self) -> int:
        signal.signal(signal.SIGTERM, self.stop)
        mode = "lockstep" if self.config.lockstep else "real time"
        self.log(f"{mode} at {self.config.rate_hz:g} Hz; simulator at "
                 f"{self.sim.address[0]}:{self.sim.address[1]}; ground links "
                 + ", ".join(f"{ln.name} udp:{ln.sock.getsockname()[1]}"
                             for ln in self.ground.links))
        self._warm_up()
        self._last_sample_wall = time.monotonic()
        try:
            if self.config.lockstep:
                self._run_lockstep()
            else:
                self._run_realtime()
        except KeyboardInterrupt:
            pass
        finally:
            self.sim.close()
            self._service_requests()
            self._status(final=True)
            self.node.close()
        summary = self.timing.summary() if not self.config.lockstep else {}
        if summary:
            self.log("timing " + json.dumps(summary))
        self.log("ground links " + json.dumps(self.ground.link_status()))
        self.log(f"stopped after {self.steps} control steps")
        return 0

    def _warm_up(self) -> None:
        """Load the compiled control law and setpoint shaper before the loop: a first
        call takes ~0.1 s from numba's cache (seconds to compile on a fresh install),
        which would otherwise be a deadline miss, or a simulator-link loss in real time."""
        scratch = self.vehicle.make_controller(self.vehicle.parameters)
        hover = np.zeros(MEASUREMENT_SIZE)
        hover[MEAS_Z] = -1.0
        scratch.step(hover, np.zeros(REF_SIZE), True, np.zeros(2))
        scratch.step(hover, np.zeros(REF_SIZE), True, np.zeros(2), math.nan, True)
        scratch.step(hover, np.zeros(REF_SIZE), False, np.zeros(2), 10.0, True)
        shaper.warm_up(self.vehicle.state.limits, self.period_us / 1e6)
        wrap_pi(1.0)
        euler_from_quat(np.array([1.0, 0.0, 0.0, 0.0]))
        max_thrust_n(scratch.airframe)
        # A first decoded sample and a first round of ground work cost milliseconds; the
        # estimator's compiled steps load on a scratch estimator.
        scratch_link = SimLink(*self.sim.address, self.config.state_source, self.config.sysid,
                               Estimator())
        for k in range(3):
            truth = TruthSample(k * 10_000, (0.0, 0.0, -1.0), (0.0, 0.0, 0.0),
                                (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, -GRAVITY_MPS2))
            sensor = SensorSample(k * 10_000, (0.0, 0.0, -GRAVITY_MPS2), (0.0, 0.0, 0.0),
                                  (0.2, 0.0, 0.4), 950.0, 500.0, 20.0, HIL_SENSOR_ALL_FIELDS)
            fix = GpsSample(k * 10_000, HOME_LAT_DEG, HOME_LON_DEG, HOME_ALT_AMSL_M + 1.0,
                            (0.0, 0.0, 0.0), 0.8, 1.2, 3, 12)
            for msg in sample_messages(truth, sensor, fix):
                if msg.get_type() in scratch_link.source_types:
                    scratch_link.decode(msg)
        self._ground_work(LOCKSTEP_GROUND_BUDGET_S)
        # What exists now lives for the whole run: out of the collector's sight, so its
        # passes in the loop look at the few objects a step makes, not at all of them.
        gc.collect()
        gc.freeze()

    def _poll(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` for the simulator and read what it sent."""
        for _key, _ in self.sel.select(max(0.0, timeout_s)):
            if self.sim.sock is not None:
                self._on_sim_readable()
                self._last_sample_wall = time.monotonic()

    def _ground_work(self, budget_s: float) -> None:
        """Every SERVICE_PERIOD_S the telemetry out, Zenoh requests and status; then the
        ground links with what is left of ``budget_s`` (shared by the links in turn)."""
        end = time.perf_counter() + budget_s
        now = time.monotonic()
        if now >= self._next_service:
            self._next_service = now + SERVICE_PERIOD_S
            self.sim.heartbeat_due(now)  # on connecting and at 1 Hz: after a step, not before
            self.ground.service()
            self._service_requests()
            self._status()
        busy = list(self.ground.links)  # round robin in slices: a flooded link cannot
        while busy:                      # take a quiet one's turn, nor leave budget unused
            for link in tuple(busy):
                left = end - time.perf_counter()
                if left <= 0:
                    busy.clear()
                    break
                if self.ground.receive(link, left, GROUND_SLICE) < GROUND_SLICE:
                    busy.remove(link)  # read empty

    def _run_lockstep(self) -> None:
        while not self._stop:
            now = time.monotonic()
            self._connect(now)
            self._poll(max(0.0, min(0.02, self._next_service - now)))
            if time.monotonic() >= self._next_service:
                self._ground_work(LOCKSTEP_GROUND_BUDGET_S)

    def _run_realtime(self) -> None:
        self.log(set_realtime_priority(self.config.rt_priority))
        period_s = self.period_us / 1e6
        ground_share_s = GROUND_SHARE * period_s
        next_deadline = time.perf_counter()
        previous_start: float | None = None
        while not self._stop:
            now = time.monotonic()
            self._connect(now)
            self._sim_watchdog(now)
            remaining = next_deadline - time.perf_counter()
            if remaining > POLL_MIN_S:
                # epoll counts whole milliseconds and rounds up: ask for whole ones, early.
                self._poll(math.floor((remaining - SPIN_S) * 1000.0) / 1000.0)
                continue
            if remaining > SPIN_S:
                time.sleep(remaining - SPIN_S)  # nanosecond sleep; I/O waits in the buffers
            while time.perf_counter() < next_deadline:
                pass
            # The step starts on the deadline by reading its input: the newest sample's
            # decoding counts as compute, and cannot make the start late.
            start = time.perf_counter()
            self._poll(0.0)
            stepped = self.latest is not None and self.vehicle.sim_link_ok
            if stepped:
                time_us, measurement = self.latest
                commands = self._control(time_us, measurement, start)
                self._answer(time_us, commands, stepped=True)
                self.timing.record_compute(max(0.0, self._command_sent - start))
                if previous_start is not None:
                    self.timing.record_period(start - previous_start)
                previous_start = start
                if self.steps >= self.max_steps:
                    break
            else:
                previous_start = None
            next_deadline += period_s
            self._ground_work(min(ground_share_s, next_deadline - SPIN_S - GROUND_GUARD_S
                                  - time.perf_counter()))
            late = time.perf_counter() - next_deadline
            if late > 0:  # a whole period lost: count it (if there was control to do)
                skipped = int(late // period_s) + 1
                if stepped:
                    self.timing.record_miss(skipped, late)
                next_deadline += skipped * period_s  # and re-anchor
                previous_start = None
