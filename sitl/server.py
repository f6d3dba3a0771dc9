"""The simulator process: the plant behind PX4's simulator protocol on TCP (docs/architecture.md).

It listens (TCP 4560 by default) for one autopilot at a time. Each sample it sends
HIL_SENSOR, HIL_GPS, HIL_STATE_QUATERNION and ODOMETRY stamped with sim time and
applies the HIL_ACTUATOR_CONTROLS it gets back. Over Zenoh it publishes its truth state
each sample and every perturbation as it takes effect, and takes perturbation requests
(``contracts/perturbations.py``) at any time; with ``hold`` a lockstep run waits for a
start request, so a ground station can deliver a schedule before sim time moves.

* lockstep: send the sample for time t, wait for the actuator message answering t, then
  advance one period. Time stands still while no autopilot is connected.
* real time: advance one period per wall-clock period whatever the autopilot does; the
  motors stop if commands stay away longer than ``actuator_timeout_s`` (an ESC timeout).
"""

from __future__ import annotations

import collections
import gc
import math
import queue
import selectors
import socket
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from contracts import timeline
from contracts.airframe import Airframe, airframe_from_spec, hover_rotor_speeds
from contracts.airframe_file import AirframeSpec
from contracts.arguments import SIM_RATE_RANGE_HZ
from contracts.frames import DEFAULT_HOME, Home
from contracts.mavlink import (
    SIM_TCP_PORT,
    SIMULATOR_COMPID,
    SIMULATOR_SYSID,
    LinkDataError,
    commands_from_actuator,
    new_mavlink,
    sample_messages,
)
from contracts.paced_loop import Deadlines, PacedProcess
from contracts.perturbation_book import PerturbationBook
from contracts.perturbation_effects import PLANT_EFFECTS
from contracts.perturbations import (
    NO_SENSOR_EFFECTS,
    Perturbation,
    Perturbations,
    plant_perturbations_at,
    sensor_effects_at,
)
from contracts.realtime import Histogram
from contracts.telemetry import SITL, STATE, json_record
from contracts.zenoh_link import PERTURBATIONS_OFF, Request, TelemetryNode, ZenohOptions
from sitl.plant import Plant, VehicleState
from sitl.sensors import (
    SensorProfile,
    SensorSuite,
    seen_by_the_gyro,
    sensed_state,
    truth_sample,
)

# STATE record fields that are VehicleState's of the same name (then the plant effects).
STATE_FROM_PLANT = ("position_ned_m", "velocity_ned_mps", "quaternion", "euler_rad",
                    "euler_rate_rad_s", "body_rate_rad_s", "rotor_rad_s")


@dataclass
class SimulatorConfig:
    airframe: Airframe | AirframeSpec  # any quadrotor
    fidelity: str = "paper"
    host: str = "127.0.0.1"
    port: int = SIM_TCP_PORT
    # Serve perturbation requests over Zenoh (scenario runs, tests); off by default, so
    # that a vehicle started by hand is never blown or kicked by whoever reaches it.
    perturbations: bool = False
    lockstep: bool = True
    rate_hz: float = 100.0
    plant_step_s: float = 0.001
    start_altitude_m: float = 0.0  # > 0 starts in hover at that altitude
    schedule: tuple[Perturbation, ...] = ()
    exit_on_disconnect: bool = False
    duration_s: float = math.inf
    actuator_timeout_s: float = 0.1
    vehicle_id: int = 1
    zenoh: ZenohOptions = field(default_factory=lambda: ZenohOptions(enabled=False))
    hold: bool = False  # wait for a start request before the first sample
    seed: int = 0  # sensor noise and link loss
    sensors: SensorProfile = field(default_factory=SensorProfile)  # ideal by default
    rt_priority: int = 40  # real time: SCHED_FIFO priority (0: normal), below the autopilot's
    home: Home = DEFAULT_HOME  # where on Earth the local frame's origin is

    def __post_init__(self) -> None:
        if not 0 <= self.rt_priority <= 99:
            raise ValueError(f"real-time priority must be in [0, 99], got {self.rt_priority}")
        low, high = SIM_RATE_RANGE_HZ
        if not (math.isfinite(self.rate_hz) and low <= self.rate_hz <= high):
            raise ValueError(f"rate must be in [{low:g}, {high:g}] Hz, got {self.rate_hz!r}")
        period_us = 1e6 / self.rate_hz
        if abs(period_us - round(period_us)) > 1e-6:
            raise ValueError(f"rate {self.rate_hz} Hz does not give a whole microsecond period")
        steps = 1.0 / self.rate_hz / self.plant_step_s
        if abs(steps - round(steps)) > 1e-9:
            raise ValueError(f"the sample period 1/{self.rate_hz} s is not a whole number of "
                             f"{self.plant_step_s} s plant steps")
        if not (math.isfinite(self.start_altitude_m) and 0.0 <= self.start_altitude_m <= 1e4):
            raise ValueError(f"start altitude must be in [0, 1e4] m, got "
                             f"{self.start_altitude_m!r}")


@dataclass
class LinkStats:
    """What the simulator measures about the autopilot (real time mostly)."""

    samples_sent: int = 0
    commands_received: int = 0
    bad_messages: int = 0
    periods_without_command: int = 0
    latency: Histogram = field(default_factory=Histogram)  # sample -> its answer [s]


CATCH_UP_PERIODS = 2  # real time: behind by more, re-anchor instead of catching up


class Simulator(PacedProcess):
    """The plant and its sensors, one sample period at a time, paced by the autopilot's
    answers (lockstep) or by the wall clock (real time)."""

    process = SITL

    def __init__(self, config: SimulatorConfig,
                 log: Callable[[str], None] | None = None) -> None:
        super().__init__(config.lockstep, config.rt_priority, log or (
            lambda text: print(f"sitl: {text}", file=sys.stderr, flush=True)))
        self.config = config
        alt = config.start_altitude_m
        model = (airframe_from_spec(config.airframe)
                 if isinstance(config.airframe, AirframeSpec) else config.airframe)
        self.plant = Plant(model, config.fidelity, config.plant_step_s,
                           position_ned_m=(0.0, 0.0, -alt),
                           rotor_rad_s=hover_rotor_speeds(model) if alt > 0 else 0.0,
                           ground_contact=True)
        self.period_us = round(1e6 / config.rate_hz)
        self.period_s = self.period_us / 1e6
        self.step_index = 0
        self.mav = new_mavlink(SIMULATOR_SYSID, SIMULATOR_COMPID)
        self.stats = LinkStats()
        self._active = Perturbations()
        self._sensor = NO_SENSOR_EFFECTS
        self.book = PerturbationBook(SITL, config.schedule)
        self.rng = np.random.default_rng(config.seed)
        self.sensors = SensorSuite(config.sensors, config.rate_hz, config.seed, config.home)
        self._state = self.plant.state()
        self._imu_state = self._state  # what the IMU reads (seen_by_the_gyro)
        self._history: collections.deque[VehicleState] = collections.deque(maxlen=101)
        self._commands = np.zeros(4)
        self._previous_velocity = self._state.velocity_ned_mps
        self._acceleration = np.zeros(3)
        self._server: socket.socket | None = None
        self.started = not config.hold
        # The compiled code now, not in the first step, and before the Zenoh session:
        # a run releases the simulator once it is heard, and its clock must not start
        # behind. Then what exists (about 120,000 objects: numba, numpy, scipy) is frozen
        # out of the collector's sight: unfrozen, a full collection every minute or two
        # took 17-52 ms, stalling the real-time loop.
        preload_compiled_code()
        gc.collect()
        gc.freeze()
        self.node = TelemetryNode(config.zenoh, config.vehicle_id, SITL, self.log)
        self._state_pub = self.node.publisher("state")
        self._event_pub = self.node.publisher("perturbation")
        self.node.serve("perturb", None if config.perturbations else PERTURBATIONS_OFF)
        self.node.serve("start")
        self._state_record = STATE.buffer()

    @property
    def time_us(self) -> int:
        return self.step_index * self.period_us

    # -- the plant side ------------------------------------------------------------------
    def next_sample(self) -> bytes | None:
        """Take requests, apply the perturbations in force at this sample's time, publish
        the truth; the bytes to send, or None when the link loses this sample."""
        self._service_requests()
        if self.book.entries:
            self._update_perturbations(self.time_us / 1e6)
        self._publish_state()
        self.node.status(self.time_us, **self._status_fields())
        effects = self._sensor
        readings, fix = self.sensors.sample(self.time_us, self._imu_state, self._acceleration,
                                            effects)
        if effects is NO_SENSOR_EFFECTS:
            truth = truth_sample(self.time_us, self._state, self._acceleration)
        else:
            if effects.loss_fraction > 0.0 and self.rng.random() < effects.loss_fraction:
                return None
            position, velocity, quaternion, body_rate = sensed_state(
                self._state, self._history, effects, self.rng)
            truth = truth_sample(self.time_us, self._state, self._acceleration, position,
                                 velocity, quaternion, body_rate)
        msgs = sample_messages(truth, readings, fix, self.config.home)
        return b"".join(m.pack(self.mav) for m in msgs)

    def _update_perturbations(self, t_s: float) -> None:
        entries = self.book.entries
        wanted = plant_perturbations_at(entries, t_s)
        if wanted != self._active:
            self.plant.set_perturbations(wanted)
            self._active = wanted
        self._sensor = sensor_effects_at(entries, t_s)
        for event, e in self.book.changes(t_s):
            self._event_pub.put(json_record(self._event_pub.count, self.time_us, event=event,
                                            **e.to_request()))
            self.log(f"t={t_s:.3f} s perturbation {e.id} ({e.kind}) {event}")
            if event == "start" and e.kind == "sim_stall":
                self._freeze(e.params["freeze_s"])

    def _freeze(self, freeze_s: float) -> None:
        """A stalled simulator: the whole process stops (no physics, no samples, no
        requests served), as a suspended or overloaded one would."""
        self.log(f"frozen for {freeze_s:g} s of wall time (sim_stall)")
        time.sleep(freeze_s)

    def _publish_state(self) -> None:
        if not self.node.enabled:
            return
        s, p, record = self._state, self._active, self._state_record
        record["seq"], record["sim_time_us"] = self._state_pub.count, self.time_us
        for name in STATE_FROM_PLANT:
            record[name] = getattr(s, name)
        for name in PLANT_EFFECTS:
            record[name] = getattr(p, name)
        record["motor_commands"] = self._commands
        self._state_pub.put(record.encode())

    def advance(self) -> None:
        """One sample period of plant time with the commands in force."""
        before = self._state
        self.plant.advance(self.period_s)
        self.step_index += 1
        self._state = self.plant.state()
        self._imu_state = seen_by_the_gyro(before, self._state, self.period_s)
        self._history.append(self._state)
        velocity = self._state.velocity_ned_mps
        self._acceleration = (velocity - self._previous_velocity) / self.period_s
        self._previous_velocity = velocity

    # -- requests over Zenoh -------------------------------------------------------------
    def _service_requests(self) -> None:
        while True:
            try:
                request = self.node.requests.get_nowait()
            except queue.Empty:
                return
            try:
                self._answer_request(request)
            except Exception as exc:  # noqa: BLE001 (bad input, or a defect: refused)
                request.refuse(exc, self.log)

    def _answer_request(self, request: Request) -> None:
        if request.topic == "start":
            if not self.started:
                timeline.mark(SITL, "released")
                self.log(f"start requested at t={self.time_us / 1e6:.3f} s")
            self.started = True
            request.reply(True, sim_time_us=self.time_us)
            return
        answer = self.book.handle(request.data, self.time_us / 1e6)
        self.log(f"perturbation request answered: {answer}")
        request.reply(True, sim_time_us=self.time_us, **answer)

    def _status_fields(self) -> dict:
        return {"samples_sent": self.stats.samples_sent,
                "commands_received": self.stats.commands_received,
                "refused": self.stats.bad_messages,
                "periods_without_command": self.stats.periods_without_command,
                "started": self.started}

    def apply_actuators(self, msg) -> int | None:
        """Apply an actuator message; returns the sample time it answers, None if refused."""
        try:
            commands = commands_from_actuator(msg)
        except LinkDataError as exc:
            self.stats.bad_messages += 1
            self.log(f"refused actuator message: {exc}")
            return None
        self.plant.set_motor_commands(commands)
        self._commands = commands
        self.stats.commands_received += 1
        return msg.time_usec

    # -- the link ------------------------------------------------------------------------
    def start_up(self) -> None:
        self._server = socket.create_server((self.config.host, self.config.port),
                                            reuse_port=False)
        self._server.settimeout(0.2)
        self.log(f"listening on tcp {self.config.host}:{self._server.getsockname()[1]} "
                 f"({'lockstep' if self.config.lockstep else 'real time'}, "
                 f"{self.config.rate_hz:g} Hz, {self.config.fidelity} plant)")
        timeline.mark(SITL, "listening")

    def shut_down(self) -> None:
        self._server.close()
        self._service_requests()
        self.node.status(self.time_us, final=True, **self._status_fields(),
                         latency=self._latency_summary())
        self.node.close()

    def report(self) -> None:
        self.log(f"stopped at t={self.time_us / 1e6:.3f} s: {self.stats.samples_sent} samples "
                 f"sent, {self.stats.commands_received} commands, "
                 f"{self.stats.bad_messages} refused")

    def _latency_summary(self) -> dict:
        h = self.stats.latency
        if h.n == 0:
            return {}
        return {"p50_ms": h.percentile(50) * 1e3, "p99_ms": h.percentile(99) * 1e3,
                "max_ms": h.max_s * 1e3}

    def _idle(self) -> None:
        """While sim time stands still: take requests, say we are here."""
        self._service_requests()
        self.node.status(self.time_us, **self._status_fields())

    def _wait_for_start(self) -> None:
        while not self.started and not self._stop:
            self._idle()
            time.sleep(0.005)

    def _finished(self) -> bool:
        return self._stop or self.time_us / 1e6 >= self.config.duration_s

    def _accept(self) -> socket.socket | None:
        try:
            conn, peer = self._server.accept()
        except (TimeoutError, BlockingIOError):
            return None
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        timeline.mark(SITL, "autopilot connected")
        self.log(f"autopilot connected from {peer[0]}:{peer[1]} at t={self.time_us / 1e6:.3f} s")
        # A fresh parser per connection: a half message from the last one must not linger.
        self.mav = new_mavlink(SIMULATOR_SYSID, SIMULATOR_COMPID)
        return conn

    def _read(self, conn: socket.socket) -> list | None:
        """Messages available now; None when the autopilot has gone."""
        try:
            data = conn.recv(65536)
        except (BlockingIOError, TimeoutError):
            return []
        except OSError:
            return None
        if not data:
            return None
        msgs = self.mav.parse_buffer(data) or []
        bad = [m for m in msgs if m.get_type() == "BAD_DATA"]
        if bad:
            self.stats.bad_messages += len(bad)
            self.log(f"unreadable bytes from the autopilot: {bad[0].reason}")
        return [m for m in msgs if m.get_type() != "BAD_DATA"]

    def _lost(self, conn: socket.socket) -> None:
        conn.close()
        self.log(f"autopilot disconnected at t={self.time_us / 1e6:.3f} s")

    def run_lockstep(self) -> None:
        while not self._finished():
            conn = self._accept()
            if conn is None:
                self._idle()
                continue
            conn.settimeout(0.5)
            connected = True
            self._wait_for_start()
            while connected and not self._finished():
                sample = self.next_sample()
                if sample is None:  # lost on the link: the motors keep the last commands
                    self.advance()
                    continue
                try:
                    conn.sendall(sample)
                except OSError:
                    break
                self.stats.samples_sent += 1
                if self.stats.samples_sent == 1:
                    timeline.mark(SITL, "first sample sent")
                answered = False
                while not answered and not self._stop:
                    msgs = self._read(conn)
                    if msgs is None:
                        connected = False
                        break
                    for msg in msgs:
                        if msg.get_type() == "HIL_ACTUATOR_CONTROLS" and \
                                msg.time_usec == self.time_us:
                            # A refused answer keeps the previous commands; time goes on.
                            self.apply_actuators(msg)
                            answered = True
                if answered:
                    self.advance()
            self._lost(conn)
            if self.config.exit_on_disconnect:
                return

    def run_realtime(self) -> None:
        self._server.setblocking(False)
        link = _RealtimeLink()
        # Sim time starts with the first autopilot, so a scenario's schedule and the
        # autopilot's reference share an origin; afterwards the world goes on without it.
        while link.conn is None and not self._finished():
            link.conn = self._accept()
            if link.conn is None:
                self._idle()
                time.sleep(0.01)
        if link.conn is None:
            return
        self._wait_for_start()
        link.attach(link.conn)
        pace = Deadlines(self.period_s,
                         time.perf_counter() + (self.step_index + 1) * self.period_s)
        while not self._finished():
            if link.conn is None:
                conn = self._accept()
                if conn is not None:
                    link.attach(conn)
            sample = self.next_sample()
            if link.conn is not None and sample is not None:
                try:
                    link.conn.sendall(sample)
                    self.stats.samples_sent += 1
                except OSError:
                    pass
            link.got_command = False
            if link.conn is not None:
                pace.serve(lambda remaining_s: self._take_commands(link, remaining_s))
                if link.conn is None and self.config.exit_on_disconnect:
                    return
            if link.conn is None:
                pace.sleep()
            if not link.got_command:
                self.stats.periods_without_command += 1
            if (not link.timed_out and self.time_us / 1e6 - link.last_command_s
                    > self.config.actuator_timeout_s):
                link.timed_out = True
                self.plant.set_motor_commands(np.zeros(4))
                self._commands = np.zeros(4)
                self.log(f"no actuator commands for {self.config.actuator_timeout_s:g} s at "
                         f"t={self.time_us / 1e6:.3f} s: motors stopped")
            self.advance()
            passed_s = pace.next_s
            pace.advance()
            # A period or two late is caught up. Further behind (frozen, suspended), the
            # world resumes at its pace from where it stopped: a burst of periods would
            # run the plant on commands the autopilot had no time to answer.
            behind_s = pace.catch_up(passed_s, CATCH_UP_PERIODS * self.period_s)
            if behind_s:
                self.log(f"{1e3 * behind_s:.0f} ms behind the wall clock at "
                         f"t={self.time_us / 1e6:.3f} s: resumed from there")
        if link.conn is not None:
            link.conn.close()

    def _take_commands(self, link: _RealtimeLink, remaining_s: float) -> bool:
        """Real time, within a period: apply the actuator messages that arrive in the
        ``remaining_s`` left; False when none came in time or the autopilot went away."""
        if not link.sel.select(remaining_s):
            return False
        msgs = self._read(link.conn)
        if msgs is None:
            link.sel.unregister(link.conn)
            self._lost(link.conn)
            link.conn = None
            return False
        for msg in msgs:
            if msg.get_type() == "HIL_ACTUATOR_CONTROLS":
                answered = self.apply_actuators(msg)
                if answered is not None:
                    link.got_command = True
                    link.last_command_s = self.time_us / 1e6
                    self.stats.latency.add(max(0, self.time_us - answered) / 1e6)
                    if link.timed_out:
                        self.log(f"actuator commands flowing at t={self.time_us / 1e6:.3f} s")
                        link.timed_out = False
        return True


class _RealtimeLink:
    """Real time: the autopilot's connection (None while away) and what its commands did."""

    def __init__(self) -> None:
        self.conn: socket.socket | None = None
        self.sel = selectors.DefaultSelector()
        self.got_command = False  # in the period under way
        self.last_command_s = -math.inf  # sim time
        self.timed_out = True  # no commands (yet, or for longer than the ESC timeout)

    def attach(self, conn: socket.socket) -> None:
        conn.setblocking(False)
        self.sel.register(conn, selectors.EVENT_READ)
        self.conn = conn


def preload_compiled_code() -> None:
    """Load the plant's compiled code (both fidelities) on a scratch plant: a warm process
    started ahead of its run does it before the run (a first call loads from numba's
    cache, about 0.2 s). Nothing outside the scratch plant changes."""
    from contracts.airframe import airframe_by_name
    from sitl.dynamics import FIDELITIES

    airframe = airframe_by_name("paper")
    for fidelity in FIDELITIES:
        plant = Plant(airframe, fidelity, position_ned_m=(0.0, 0.0, -1.0),
                      rotor_rad_s=hover_rotor_speeds(airframe), ground_contact=True)
        plant.set_motor_commands(np.full(4, 0.5))
        plant.advance(0.002)
        plant.state()
