"""The autopilot process: the fixed-rate control loop between the simulator link and the
ground links.

* lockstep: each simulator sample (the state message that closes it) runs the control
  step when its sim time reaches the next control deadline, then the actuator message
  answers that sample with the lockstep flag set.
* real time: a wall-clock timer at the control rate uses the newest sample; loop
  period, compute time, jitter and deadline misses are measured.

The pieces around the loop are their own: the simulator link decodes
(``sim_link.py``), navigation turns samples into measurements and owns the estimator
(``navigation.py``), telemetry builds and publishes the records (``telemetry.py``),
the paced-loop shell and deadlines are shared with the simulator
(``contracts/paced_loop.py``). Perturbation requests (reference kicks) are taken
between steps.
"""

from __future__ import annotations

import gc
import json
import math
import queue
import selectors
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from autopilot.commander.commander import Commander
from autopilot.mavlink.server import MavlinkServer
from autopilot.process.navigation import Navigation
from autopilot.process.scenario_start import ScenarioStart
from autopilot.process.sim_link import SimLink
from autopilot.process.stall_watch import SAME_SAMPLE_WAIT, StallWatch
from autopilot.process.telemetry import TelemetryPublisher
from autopilot.process.warm_up import load_compiled_code
from contracts import timeline
from contracts.airframe_file import AirframeSpec
from contracts.arguments import CONTROL_RATE_RANGE_HZ
from contracts.frames import Home
from contracts.mavlink import (
    AUTOPILOT_SYSID,
    SEVERITY_NAMES,
    SIM_TCP_PORT,
    STATE_SOURCES,
)
from contracts.paced_loop import MAX_SPIN_S, SPIN_S, Deadlines, PacedProcess
from contracts.realtime import LoopTiming
from contracts.telemetry import AUTOPILOT
from contracts.telemetry_node import PERTURBATIONS_OFF, Request, TelemetryNode
from contracts.zenoh_link import ZenohOptions

# Ground links get a bounded share of each period, after the control step (bad input:
# docs/architecture.md).
GROUND_SHARE = 0.4  # of the period at most, for reading ground links
GROUND_GUARD_S = 0.0005  # ground work ends at least this long before the next spin
GROUND_SLICE = 16  # datagrams per link per turn
SERVICE_PERIOD_S = 0.005  # telemetry out, link failsafes, Zenoh requests, status
LOCKSTEP_GROUND_BUDGET_S = 0.001  # per service period in lockstep


@dataclass
class AutopilotConfig:
    sim_host: str = "127.0.0.1"
    sim_port: int = SIM_TCP_PORT
    # Serve perturbation requests over Zenoh (scenario runs, tests); off by default, so
    # that a vehicle started by hand is never blown or kicked by whoever reaches it.
    perturbations: bool = False
    lockstep: bool = True
    rate_hz: float = 100.0
    state_source: str = "auto"
    duration_s: float = math.inf  # stop after this much sim time of control
    sysid: int = AUTOPILOT_SYSID  # also the vehicle id in telemetry keys
    rt_priority: int = 50  # SCHED_FIFO priority of the real-time loop (0: normal)
    zenoh: ZenohOptions = field(default_factory=lambda: ZenohOptions(enabled=False))
    home: Home | None = None  # None: the simulator's first position, as PX4 takes it
    airframe: AirframeSpec | None = None  # drawn by viewers (the scene record)
    handover_cpu: int | None = None  # lockstep: the loop's CPU (None: any)
    spin_s: float = SPIN_S  # real time: the last stretch before each step, busy-waited

    def __post_init__(self) -> None:
        low, high = CONTROL_RATE_RANGE_HZ
        if not (math.isfinite(self.rate_hz) and low <= self.rate_hz <= high):
            raise ValueError(f"control rate must be in [{low:g}, {high:g}] Hz, got "
                             f"{self.rate_hz!r}")
        if abs(1e6 / self.rate_hz - round(1e6 / self.rate_hz)) > 1e-6:
            raise ValueError(f"rate {self.rate_hz} Hz does not give a whole microsecond period")
        if not 0 <= self.rt_priority <= 99:
            raise ValueError(f"real-time priority must be in [0, 99], got {self.rt_priority}")
        if not 0.0 <= self.spin_s <= MAX_SPIN_S:  # (NaN fails it too)
            raise ValueError(f"spin must be in [0, {MAX_SPIN_S * 1e6:g}] us, got "
                             f"{self.spin_s * 1e6!r} us")
        if self.state_source not in STATE_SOURCES:
            raise ValueError(f"unknown state source {self.state_source!r}; known: "
                             f"{', '.join(STATE_SOURCES)}")


def airframe_rotors(spec: AirframeSpec | None
                    ) -> tuple[str, tuple[tuple[float, ...], ...]] | None:
    """The airframe's name and rotors (x, y, z [m] body FRD, spin) for the scene record."""
    if spec is None:
        return None
    return spec.name, tuple((*r.position_m, r.spin) for r in spec.rotors)


def said_into(log: Callable[[str], None], vehicle: Commander) -> Callable[[int, str], None]:
    """What the vehicle says, into the process log too, as PX4's console shows it: at its
    sim time, for whoever reads a run's logs after the fact."""
    return lambda severity, text: log(
        f"t={vehicle.sim_t_s:.3f} s {SEVERITY_NAMES.get(severity, 'INFO')}: {text}")


class Autopilot(PacedProcess):
    """The control loop: samples from the simulator link become control steps at the
    control rate, each answered with a motor command; between steps, the ground links
    and Zenoh requests get a bounded share of time."""

    process = AUTOPILOT

    def __init__(self, config: AutopilotConfig, vehicle: Commander, ground: MavlinkServer,
                 arm_in_reference: bool = False, start_mission: bool = False,
                 log: Callable[[str], None] | None = None) -> None:
        super().__init__(config.lockstep, config.rt_priority, log or (
            lambda text: print(f"autopilot: {text}", file=sys.stderr, flush=True)),
            config.handover_cpu)
        self.config = config
        self.vehicle = vehicle
        self.ground = ground
        ground.on_said = said_into(self.log, vehicle)
        self.scenario = ScenarioStart(vehicle, arm_in_reference, start_mission,
                                      lambda text: self.log(text))
        self.period_us = round(1e6 / config.rate_hz)
        self.navigation = Navigation.for_source(vehicle, config.state_source)
        self.sim = SimLink(config.sim_host, config.sim_port, config.state_source, config.sysid,
                           config.home, SERVICE_PERIOD_S if config.lockstep else 0.0)
        if config.home is not None:
            self._set_home(config.home, "given")
        self.timing = LoopTiming(self.period_us / 1e6)
        self.node = TelemetryNode(config.zenoh, config.sysid, AUTOPILOT, self.log)
        self.telemetry = TelemetryPublisher(self.node, config.sysid, vehicle, ground,
                                            self.timing, self.navigation.estimator,
                                            config.lockstep, self.log,
                                            airframe_rotors(config.airframe))
        self.node.serve("perturb", None if config.perturbations else PERTURBATIONS_OFF)
        self.steps = 0
        self.max_steps = (math.inf if math.isinf(config.duration_s)
                          else round(config.duration_s * 1e6 / self.period_us))
        self.next_control_us: int | None = None
        self._step_start = 0.0  # when the last control step began (perf_counter)
        self._command_sent = 0.0  # when the last motor command went out (perf_counter)
        self.latest: tuple[int, np.ndarray] | None = None
        self.sel = selectors.DefaultSelector()  # the simulator link only: ground links
        self._next_service = 0.0               # are read within a budget (_ground_work)
        self._progress_at = 0.1
        self._last_sample_wall = 0.0  # when the simulator last sent (time.monotonic)
        self._sample_period_us = 0  # between the simulator's last two samples
        self.stall = StallWatch(self.timing, lambda text: self.log(text))

    def _control(self, time_us: int, measurement: np.ndarray,
                 step_start: float | None = None) -> np.ndarray:
        """One control step; ``step_start`` is when the step began (real time: its
        deadline, before the newest sample was read), for the timing record."""
        start = time.perf_counter() if step_start is None else step_start
        if not self.node.requests.empty():
            self._service_requests()
        self.vehicle.sample(time_us / 1e6, measurement)
        self.scenario.before_step(time_us / 1e6, self.steps == 0)
        commands = self.vehicle.control()
        self._step_start = start
        self.steps += 1
        if self.steps == 1:
            timeline.mark(AUTOPILOT, "first control step")
            self.node.usage.restart()
        if self.max_steps < math.inf and self.steps >= self._progress_at * self.max_steps:
            self.log(f"{100 * self._progress_at:.0f} % ({time_us / 1e6:.1f} s sim)")
            self._progress_at += 0.1
        return commands

    def _answer(self, time_us: int, commands: np.ndarray, stepped: bool) -> None:
        """The motor command goes out first; telemetry of the step after it."""
        commands = self.vehicle.failures.motor_outputs(commands)  # injected motor failures
        frame = self.sim.actuators_frame(time_us, commands, self.vehicle.armed,
                                         self.config.lockstep)
        if not self.sim.send(frame):
            self._sim_lost()
            return
        self._command_sent = time.perf_counter()
        if stepped:
            self.ground.announce()  # at the step that said it
        if not self.telemetry.enabled:
            return
        if stepped:
            self.telemetry.publish_step(time_us, self._command_sent - self._step_start,
                                        self._step_start)
        self.telemetry.mirror_actuators(frame, time_us)
        self.telemetry.end_step(time_us)

    def _service_requests(self) -> None:
        """Perturbation requests over Zenoh, answered on sim time."""
        while True:
            try:
                request: Request = self.node.requests.get_nowait()
            except queue.Empty:
                return
            now_s = self.vehicle.sim_t_s
            try:
                answer = self.vehicle.perturbations.handle(request.data, now_s)
            except Exception as exc:  # noqa: BLE001 (bad input, or a defect: refused)
                request.refuse(exc, self.log)
                continue
            self.log(f"perturbation request answered: {answer}")
            request.reply(True, sim_time_us=round(now_s * 1e6), **answer)

    # -- the simulator link ----------------------------------------------------------------
    def _sim_lost(self) -> None:
        if self.sim.sock is not None and self.sim.sock.fileno() in self.sel.get_map():
            self.sel.unregister(self.sim.sock)  # first: a new socket may reuse its number
        self.sim.close()
        self.stall.stepped_us = None
        if self.vehicle.sim_link_ok:
            self.log("simulator link lost")
        self.vehicle.sim_link_lost()
        self.next_control_us = None

    def _set_home(self, home: Home, how: str) -> None:
        self.vehicle.set_origin(home)  # home with it, until a tool moves home
        self.navigation.set_home(home)
        self.log(f"home {home.lat_deg:.7f}, {home.lon_deg:.7f}, {home.alt_amsl_m:.2f} m "
                 f"({how})")

    def _connect(self, now: float) -> None:
        if self.sim.connect(now):
            timeline.mark(AUTOPILOT, "connected to the simulator")
            self.log(f"connected to the simulator at {self.sim.address[0]}:"
                     f"{self.sim.address[1]}")
            self.sel.register(self.sim.sock, selectors.EVENT_READ, "sim")

    def _on_sim_readable(self) -> None:
        readings = self.sim.read()
        if readings is None:
            self._sim_lost()
            return
        if self.sim.last_bad:
            self.log(f"refused simulator data: {self.sim.last_bad}")
            self.sim.last_bad = None
        if self.sim.home is not None and not self.vehicle.home_known:
            self._set_home(self.sim.home, self.sim.home_source or "")
        for time_us, measurement in self.navigation.measurements(readings):
            if measurement is None:  # the estimator is aligning: nothing to fly on yet
                self.navigation.aligning(time_us)
                self._answer(time_us, np.zeros(4), False)
                continue
            self.navigation.update(time_us)
            if self.latest is not None and time_us < self.latest[0]:
                self.next_control_us = None  # a new simulator: its clock starts again
            elif self.latest is not None and time_us > self.latest[0]:
                self._sample_period_us = time_us - self.latest[0]
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
                timeline.mark(AUTOPILOT, "last control step")
                self._stop = True
                return

    def _sim_watchdog(self, now: float) -> None:
        """Real time: no sample for COM_SIM_LOSS_T means the simulator is gone."""
        if self.config.lockstep or self.sim.sock is None:
            return
        if now - self._last_sample_wall > self.vehicle.parameters["COM_SIM_LOSS_T"] and \
                self.vehicle.sim_link_ok:
            self.log("no samples from the simulator: link lost")
            self.vehicle.sim_link_lost()

    # -- the run ---------------------------------------------------------------------------
    def start_up(self) -> None:
        mode = "lockstep" if self.config.lockstep else "real time"
        self.log(f"{mode} at {self.config.rate_hz:g} Hz; simulator at "
                 f"{self.sim.address[0]}:{self.sim.address[1]}; ground links "
                 + ", ".join(f"{ln.name} udp:{ln.sock.getsockname()[1]}"
                             for ln in self.ground.links))
        self._warm_up()
        self._last_sample_wall = time.monotonic()

    def shut_down(self) -> None:
        self.sim.close()
        self.ground.save_signing(force=True)
        self._service_requests()
        self.telemetry.status(self.steps, final=True)
        self.node.close()

    def report(self) -> None:
        if not self.config.lockstep:
            self.log("timing " + json.dumps(self.timing.summary()))
        self.log("ground links " + json.dumps(self.ground.link_status()))
        self.log(f"stopped after {self.steps} control steps")

    def _warm_up(self) -> None:
        """Load the compiled code and make a first round of ground work before the loop
        (either would cost a deadline inside it), then freeze what exists."""
        load_compiled_code(self.vehicle, self.period_us / 1e6, self.sim)
        timeline.mark(AUTOPILOT, "compiled code loaded")
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
            self.ground.announce()  # what was said since the last step
            self.ground.service()
            self._service_requests()
            self.telemetry.status(self.steps)
        busy = list(self.ground.links)  # round robin in slices: a flooded link cannot
        while busy:                      # take a quiet one's turn, nor leave budget unused
            for link in tuple(busy):
                left = end - time.perf_counter()
                if left <= 0:
                    busy.clear()
                    break
                if self.ground.receive(link, left, GROUND_SLICE) < GROUND_SLICE:
                    busy.remove(link)  # read empty

    def run_lockstep(self) -> None:
        while not self._stop:
            self._connect(now := time.monotonic())
            if self.sim.sock is not None:  # its read waits for the next sample (wait_s)
                self._on_sim_readable()
            else:
                self._poll(max(0.0, min(0.02, self._next_service - now)))
            if time.monotonic() >= self._next_service:
                self._ground_work(LOCKSTEP_GROUND_BUDGET_S)

    def _realtime_instant(self, start: float, period_s: float) -> bool:
        """A real-time control instant, on its deadline ``start`` (perf_counter): the step
        reads its input first (the newest sample's decoding counts as compute, and cannot
        make the start late), then flies it, unless there is nothing new to fly: returns
        whether it stepped."""
        self._poll(0.0)
        if self.latest is None or not self.vehicle.sim_link_ok:
            return False
        if self.stall.stalled(time.monotonic(), self._last_sample_wall, period_s,
                              self._sample_period_us / 1e6):
            return False  # a simulator stall: the last command holds, not flown on old data
        if self.stall.flown(self.latest[0], self._sample_period_us, self.period_us):
            self._poll(SAME_SAMPLE_WAIT * self._sample_period_us / 1e6)  # the one due
        time_us, measurement = self.latest
        if self.sim.sock is None or self.stall.flown_already(
                time_us, self._sample_period_us, self.period_us):
            return False  # the link lost while waiting; or the last command holds, counted
        self.stall.stepped_us = time_us
        commands = self._control(time_us, measurement, start)
        self._answer(time_us, commands, stepped=True)
        self.timing.record_compute(max(0.0, self._command_sent - start))
        return True

    def run_realtime(self) -> None:
        period_s = self.period_us / 1e6
        ground_share_s = GROUND_SHARE * period_s
        pace = Deadlines(period_s, time.perf_counter(), spin_s=self.config.spin_s)
        previous_start: float | None = None
        while not self._stop:
            now = time.monotonic()
            self._connect(now)
            self._sim_watchdog(now)
            if not pace.wait(self._poll):
                continue  # polled the simulator link: connect and watch again
            start = time.perf_counter()
            stepped = self._realtime_instant(start, period_s)
            if stepped:
                if previous_start is not None:
                    self.timing.record_period(start - previous_start)
                previous_start = start
                if self.steps >= self.max_steps:
                    timeline.mark(AUTOPILOT, "last control step")
                    break
            else:
                previous_start = None
            pace.advance()
            self._ground_work(min(ground_share_s, pace.until_spin_s() - GROUND_GUARD_S))
            skipped, late = pace.skip_missed()
            if skipped:  # a whole period lost: count it (if there was control to do)
                if stepped:
                    self.timing.record_miss(skipped, late)
                previous_start = None
