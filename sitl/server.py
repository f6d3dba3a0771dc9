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

import gc
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from contracts import SITL, timeline
from contracts.airframe import PAPER, Airframe, airframe_from_spec, hover_rotor_speeds
from contracts.airframe_file import AirframeSpec
from contracts.arguments import SIM_RATE_RANGE_HZ
from contracts.frames import DEFAULT_HOME, Home
from contracts.mavlink import SIM_TCP_PORT, LinkDataError, commands_from_actuator
from contracts.paced_loop import Deadlines, PacedProcess, lockstep_waits
from contracts.perturbations import Perturbation
from contracts.telemetry_node import Request
from contracts.zenoh_link import ZenohOptions
from sitl.link import Actuators, AutopilotLink, LinkStats, RealtimeConnection
from sitl.perturbation_service import PerturbationService
from sitl.plant import Plant
from sitl.samples import SampleSource
from sitl.sensors import SensorProfile
from sitl.telemetry import SimulatorTelemetry


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
    handover_cpu: int | None = None  # lockstep: the loop's CPU (None: any)
    # Log the HIL_SENSOR and HIL_GPS frames sent, on the MAVLink mirror: a PX4 log's
    # sensor_combined and sensor_gps (ivfm run --ulog). Off by default: a sample's two
    # frames more for the logger.
    log_sensors: bool = False

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


CATCH_UP_PERIODS = 2  # real time: behind by more, re-anchor instead of catching up
HOLD_WAIT_S = 0.1  # held: the longest wait for a request (a stop is noticed within it)


class Simulator(PacedProcess):
    """The plant and its sensors, one sample period at a time, paced by the autopilot's
    answers (lockstep) or by the wall clock (real time)."""

    process = SITL

    def __init__(self, config: SimulatorConfig,
                 log: Callable[[str], None] | None = None) -> None:
        super().__init__(config.lockstep, config.rt_priority, log or (
            lambda text: print(f"sitl: {text}", file=sys.stderr, flush=True)),
            config.handover_cpu)
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
        self.stats = LinkStats()
        self.link = AutopilotLink(config.host, config.port, self.stats, self.log)
        self._state = self.plant.state()
        self.samples = SampleSource(config.sensors, config.rate_hz, config.seed, config.home,
                                    self._state)
        self._commands = np.zeros(4)
        self.started = not config.hold
        # The compiled code now, not in the first step, and before the Zenoh session:
        # a run releases the simulator once it is heard, and its clock must not start
        # behind. Then what exists (about 120,000 objects: numba, numpy, scipy) is frozen
        # out of the collector's sight: unfrozen, a full collection every minute or two
        # took 17-52 ms, stalling the real-time loop.
        preload_compiled_code()
        gc.collect()
        gc.freeze()
        self.telemetry = SimulatorTelemetry(config.zenoh, config.vehicle_id,
                                            config.perturbations, self.log)
        self.perturbations = PerturbationService(config.schedule, self.plant,
                                                 self.telemetry.publish_event, self.log)
        self._log_readings = (
            (lambda sensor, gps: self.telemetry.mirror_readings(self.time_us, sensor, gps))
            if config.log_sensors else None)

    @property
    def time_us(self) -> int:
        return self.step_index * self.period_us

    # -- the plant side ------------------------------------------------------------------
    def next_sample(self) -> bytes | None:
        """Take requests, apply the perturbations in force at this sample's time, publish
        the truth; the bytes to send, or None when the link loses this sample."""
        self._service_requests()
        time_us = self.time_us
        self.perturbations.update(time_us)
        self.telemetry.publish_state(time_us, self._state, self.perturbations.active,
                                     self._commands)
        self.telemetry.status(time_us, self.stats, self.started)
        return self.samples.frames(time_us, self._state, self.perturbations.sensor_effects,
                                   self.link.mav, self._log_readings)

    def advance(self) -> None:
        """One sample period of plant time with the commands in force."""
        before = self._state
        self.plant.advance(self.period_s)
        self.step_index += 1
        self._state = self.plant.state()
        self.samples.observe(before, self._state, self.period_s)

    def apply_actuators(self, msg) -> int | None:
        """Apply an actuator message; returns the sample time it answers, None if refused."""
        try:
            commands = msg.commands if isinstance(msg, Actuators) else \
                commands_from_actuator(msg)
        except LinkDataError as exc:
            self.stats.bad_messages += 1
            self.log(f"refused actuator message: {exc}")
            return None
        self.plant.set_motor_commands(commands)
        self._commands = commands
        self.stats.commands_received += 1
        return msg.time_usec

    # -- requests over Zenoh -------------------------------------------------------------
    def _service_requests(self, wait_s: float = 0.0) -> None:
        """Answer the requests waiting; ``wait_s``: up to this long for a first one."""
        while (request := self.telemetry.next_request(wait_s)) is not None:
            wait_s = 0.0
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
        self.perturbations.answer(request, self.time_us)

    # -- the process ---------------------------------------------------------------------
    def start_up(self) -> None:
        port = self.link.listen()
        self.log(f"listening on tcp {self.config.host}:{port} "
                 f"({'lockstep' if self.config.lockstep else 'real time'}, "
                 f"{self.config.rate_hz:g} Hz, {self.config.fidelity} plant)")
        timeline.mark(SITL, "listening")

    def shut_down(self) -> None:
        self.link.close()
        self._service_requests()
        self.telemetry.close(self.time_us, self.stats, self.started)

    def report(self) -> None:
        self.log(f"stopped at t={self.time_us / 1e6:.3f} s: {self.stats.samples_sent} samples "
                 f"sent, {self.stats.commands_received} commands, "
                 f"{self.stats.bad_messages} refused")

    def _idle(self) -> None:
        """While sim time stands still: take requests, say we are here."""
        self._service_requests()
        self.telemetry.status(self.time_us, self.stats, self.started)

    def _wait_for_start(self) -> None:
        """Held until the start request, woken by it (or by any request) at once, and
        otherwise ten times a second for its status (it polled every 5 ms: 200 wake-ups
        a second on a machine where other runs may be flying)."""
        while not self.started and not self._stop:
            self._idle()
            self._service_requests(HOLD_WAIT_S)

    def _finished(self) -> bool:
        return self._stop or self.time_us / 1e6 >= self.config.duration_s

    # -- the loops -----------------------------------------------------------------------
    def run_lockstep(self) -> None:
        while not self._finished():
            conn = self.link.accept(self.time_us)
            if conn is None:
                self._idle()
                continue
            lockstep_waits(conn, 0.5)
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
                    self.telemetry.node.usage.restart()
                answered = False
                while not answered and not self._stop:
                    msgs = self.link.read(conn)
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
            self.link.lost(conn, self.time_us)
            if self.config.exit_on_disconnect:
                return

    def run_realtime(self) -> None:
        self.link.stop_blocking()
        peer = RealtimeConnection()
        # Sim time starts with the first autopilot, so a scenario's schedule and the
        # autopilot's reference share an origin; afterwards the world goes on without it.
        while peer.conn is None and not self._finished():
            peer.conn = self.link.accept(self.time_us)
            if peer.conn is None:
                self._idle()
                time.sleep(0.01)
        if peer.conn is None:
            return
        self._wait_for_start()
        peer.attach(peer.conn)
        pace = Deadlines(self.period_s,
                         time.perf_counter() + (self.step_index + 1) * self.period_s)
        while not self._finished():
            if peer.conn is None:
                conn = self.link.accept(self.time_us)
                if conn is not None:
                    peer.attach(conn)
            sample = self.next_sample()
            if peer.conn is not None and sample is not None:
                try:
                    peer.conn.sendall(sample)
                    self.stats.samples_sent += 1
                except OSError:
                    pass
            peer.got_command = False
            if peer.conn is not None:
                pace.serve(lambda remaining_s: self._take_commands(peer, remaining_s))
                if peer.conn is None and self.config.exit_on_disconnect:
                    return
            if peer.conn is None:
                pace.sleep()
            if not peer.got_command:
                self.stats.periods_without_command += 1
            if (not peer.timed_out and self.time_us / 1e6 - peer.last_command_s
                    > self.config.actuator_timeout_s):
                peer.timed_out = True
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
        if peer.conn is not None:
            peer.conn.close()

    def _take_commands(self, peer: RealtimeConnection, remaining_s: float) -> bool:
        """Real time, within a period: apply the actuator messages that arrive in the
        ``remaining_s`` left; False when none came in time or the autopilot went away."""
        if not peer.sel.select(remaining_s):
            return False
        msgs = self.link.read(peer.conn)
        if msgs is None:
            peer.sel.unregister(peer.conn)
            self.link.lost(peer.conn, self.time_us)
            peer.conn = None
            return False
        for msg in msgs:
            if msg.get_type() == "HIL_ACTUATOR_CONTROLS":
                answered = self.apply_actuators(msg)
                if answered is not None:
                    peer.got_command = True
                    peer.last_command_s = self.time_us / 1e6
                    self.stats.latency.add(max(0, self.time_us - answered) / 1e6)
                    if peer.timed_out:
                        self.log(f"actuator commands flowing at t={self.time_us / 1e6:.3f} s")
                        peer.timed_out = False
        return True


def preload_compiled_code() -> None:
    """Load the plant's compiled code (both fidelities) on a scratch plant, and the
    sensors' on a scratch sample: the process loader (contracts/zygote.py) does it once
    for every simulator it forks (a first call loads from numba's cache, about 0.2 s for
    the plant; the sensors' took 20-45 ms of a run's first sample, which the autopilot
    waited for). Nothing outside the scratch objects changes."""
    from contracts.mavlink import SIMULATOR_COMPID, SIMULATOR_SYSID, actuator_message, new_mavlink
    from contracts.perturbations import NO_SENSOR_EFFECTS
    from sitl.dynamics import FIDELITIES

    for fidelity in FIDELITIES:
        plant = Plant(PAPER, fidelity, position_ned_m=(0.0, 0.0, -1.0),
                      rotor_rad_s=hover_rotor_speeds(PAPER), ground_contact=True)
        plant.set_motor_commands(np.full(4, 0.5))
        plant.advance(0.002)
        state = plant.state()
    samples = SampleSource(SensorProfile(), 100.0, 0, DEFAULT_HOME, state)
    samples.observe(state, state, 0.01)
    samples.frames(0, state, NO_SENSOR_EFFECTS, new_mavlink(SIMULATOR_SYSID, SIMULATOR_COMPID))
    link = AutopilotLink("127.0.0.1", 0, LinkStats(), lambda text: None)
    link.messages_of(actuator_message(0, np.zeros(4), True, True).pack(link.mav))
