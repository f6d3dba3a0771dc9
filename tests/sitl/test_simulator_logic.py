"""The simulator in process: samples, actuator answers, perturbations and sensor effects on
sim time, the vehicle flying it through the wire format without sockets, and lockstep
over a loopback TCP connection (test_sim_link.py runs the processes)."""

from __future__ import annotations

import math
import select
import signal
import socket
import threading

import numpy as np
import pytest

from autopilot.commander.commander import Commander
from autopilot.control.factory import make_controller
from contracts.airframe import PAPER, hover_rotor_speeds
from contracts.mavlink import (
    actuator_message,
    measurement_from_odometry,
    new_mavlink,
)
from contracts.perturbations import parse_request
from sitl.server import Simulator, SimulatorConfig

# Every sample: the IMU (and the baro, magnetometer when fresh), then the truth; a GPS fix
# first when one comes out of the receiver (10 Hz with the default sensors).
SAMPLE_TYPES = ["HIL_SENSOR", "HIL_STATE_QUATERNION", "ODOMETRY"]


def make_simulator(**config) -> tuple[Simulator, list[str]]:
    """A simulator (Zenoh off) and the lines it logs."""
    lines: list[str] = []
    sim = Simulator(SimulatorConfig(airframe=PAPER, **config), log=lines.append)
    return sim, lines


def decode(data: bytes) -> list:
    return new_mavlink(1, 1).parse_buffer(data) or []


def odometry(sim: Simulator):
    (msg,) = [m for m in decode(sim.next_sample()) if m.get_type() == "ODOMETRY"]
    return msg


def answer(sim: Simulator, commands, armed: bool = True, time_us: int | None = None):
    """The actuator message as the simulator's parser gets it off the wire."""
    msg = actuator_message(sim.time_us if time_us is None else time_us,
                           np.asarray(commands, dtype=float), armed, True)
    (decoded,) = sim.link.mav.parse_buffer(msg.pack(new_mavlink(1, 1)))
    return decoded


# -- samples ---------------------------------------------------------------------------
@pytest.mark.parametrize("rate_hz, period_us", [(100.0, 10_000), (250.0, 4_000)])
def test_each_sample_is_stamped_with_sim_time_and_fixes_come_at_10_hz(rate_hz, period_us):
    sim, _ = make_simulator(rate_hz=rate_hz)
    fixes = []
    n = round(0.3 * rate_hz)
    for k in range(n):
        msgs = decode(sim.next_sample())
        kinds = [m.get_type() for m in msgs]
        if kinds[0] == "HIL_GPS":
            fixes.append(k * period_us)
            kinds = kinds[1:]
        assert kinds == SAMPLE_TYPES
        assert {m.time_usec for m in msgs} == {k * period_us}
        sim.advance()
    assert sim.time_us == n * period_us
    assert fixes == [0, 100_000, 200_000]


def test_the_vehicle_starts_on_the_ground_or_hovering_at_the_start_altitude():
    ground, _ = make_simulator()
    msg = odometry(ground)
    assert (msg.x, msg.y, msg.z) == (0.0, 0.0, 0.0)
    hover, _ = make_simulator(start_altitude_m=2.0, fidelity="rigid-body")
    assert odometry(hover).z == -2.0
    assert np.all(hover.plant.state().rotor_rad_s == hover_rotor_speeds(PAPER))
    for _ in range(100):  # hover commands keep it there
        hover.advance()
    assert abs(hover.plant.state().position_ned_m[2] + 2.0) < 0.01


@pytest.mark.parametrize("bad", [[math.nan, 0.5, 0.5, 0.5], [1.2, 0.5, 0.5, 0.5],
                                 [-0.1, 0.5, 0.5, 0.5]])
def test_bad_actuator_answers_are_refused_and_the_last_commands_stay(bad):
    sim, lines = make_simulator()
    assert sim.apply_actuators(answer(sim, [0.5, 0.5, 0.5, 0.5])) == 0
    assert sim.stats.commands_received == 1
    assert sim.apply_actuators(answer(sim, bad)) is None
    assert sim.stats.bad_messages == 1 and sim.stats.commands_received == 1
    assert np.array_equal(sim._commands, [0.5, 0.5, 0.5, 0.5])
    assert lines[-1].startswith("refused actuator message")


def test_a_disarmed_answer_stops_the_motors():
    sim, _ = make_simulator()
    sim.apply_actuators(answer(sim, [0.5, 0.5, 0.5, 0.5]))
    sim.apply_actuators(answer(sim, [0.5, 0.5, 0.5, 0.5], armed=False))
    assert np.array_equal(sim._commands, np.zeros(4))


# -- perturbations and sensor effects on sim time -----------------------------------------
def test_a_scheduled_plant_change_takes_effect_at_its_sample():
    mass = parse_request({"kind": "mass", "scale": 1.5, "start_s": 0.05, "end_s": 0.1})
    sim, lines = make_simulator(schedule=(mass,))
    masses = []
    for _ in range(12):
        sim.next_sample()
        masses.append(sim.plant.model.mass_kg / PAPER.mass_kg)
        sim.advance()
    assert masses == [1.0] * 5 + [1.5] * 5 + [1.0] * 2  # [0.05 s, 0.1 s) of sim time
    assert any("perturbation" in line and "mass" in line for line in lines)


def test_a_sensor_bias_offsets_what_is_sent_not_the_truth():
    bias = parse_request({"kind": "sensor_bias", "position_m": [1.0, -2.0, 0.5]})
    sim, _ = make_simulator(schedule=(bias,), start_altitude_m=3.0)
    msg = odometry(sim)
    assert (msg.x, msg.y, msg.z) == (1.0, -2.0, -2.5)
    assert np.array_equal(sim.plant.state().position_ned_m, [0.0, 0.0, -3.0])


def test_a_link_delay_sends_the_state_of_that_many_samples_ago():
    delay = parse_request({"kind": "link_delay", "samples": 3})
    sim, _ = make_simulator(schedule=(delay,), start_altitude_m=1.0)
    sim.plant.set_motor_commands(np.zeros(4))  # falling: each sample a new altitude
    truth, sent = [], []
    for _ in range(10):
        truth.append(np.float32(sim.plant.state().position_ned_m[2]))
        sent.append(odometry(sim).z)
        sim.advance()
    assert len(set(truth)) == 10
    # The first samples send the oldest state there is; then three samples old.
    assert sent == [truth[0], truth[1], truth[1], truth[1], *truth[1:7]]


@pytest.mark.parametrize("seed", [0, 7])
def test_link_loss_drops_the_seeded_fraction_the_same_way_each_run(seed):
    loss = parse_request({"kind": "link_loss", "fraction": 0.5})

    def pattern(seed: int) -> list[bool]:
        sim, _ = make_simulator(schedule=(loss,), seed=seed)
        out = []
        for _ in range(200):
            out.append(sim.next_sample() is None)
            sim.advance()
        return out

    lost = pattern(seed)
    assert pattern(seed) == lost
    assert 70 <= sum(lost) <= 130
    assert pattern(seed + 1) != lost


# -- the vehicle flying the simulator through the wire format, no sockets ------------------
def test_the_vehicle_flies_the_simulator_through_the_messages_in_lockstep():
    sim, _ = make_simulator(fidelity="rigid-body")
    vehicle = Commander(lambda p: make_controller("smc", PAPER, 0.01, None, p), 0.01,
                      {"MIS_TAKEOFF_ALT": 1.5, "COM_DISARM_LAND": 0.5})
    autopilot_side = new_mavlink(1, 1)
    said: list[str] = []

    def step() -> None:
        msgs = autopilot_side.parse_buffer(sim.next_sample())
        (odo,) = [m for m in msgs if m.get_type() == "ODOMETRY"]
        commands = vehicle.step(odo.time_usec / 1e6, measurement_from_odometry(odo))
        said.extend(text for _s, text in vehicle.messages)
        vehicle.messages.clear()
        reply = actuator_message(odo.time_usec, commands, vehicle.armed, True)
        (decoded,) = sim.link.mav.parse_buffer(reply.pack(autopilot_side))
        assert sim.apply_actuators(decoded) == odo.time_usec  # the answer is for this sample
        sim.advance()

    for _ in range(5):
        step()
    vehicle.arm(0.0)
    vehicle.takeoff(None)
    while vehicle.takeoff_altitude_m is not None:
        step()
        assert sim.time_us < 10_000_000, "take-off did not complete"
    assert abs(sim.plant.state().position_ned_m[2] + 1.5) < 0.1
    vehicle.land()
    while vehicle.armed:
        step()
        assert sim.time_us < 30_000_000, "landing did not complete"
    assert said == ["simulator link up", "armed", "taking off to 1.5 m", "take-off complete",
                    "mode hold", "mode land", "landed", "landed: disarmed"]
    assert abs(sim.plant.state().position_ned_m[2]) < 0.05
    assert sim.stats.commands_received == sim.step_index and sim.stats.bad_messages == 0


# -- lockstep over loopback TCP ----------------------------------------------------------
def test_lockstep_waits_for_the_answer_to_each_sample():
    """``run`` in this thread (it installs a SIGTERM handler); the autopilot stand-in in
    another answers every sample, once first with a wrong time, which must not count."""
    ready = threading.Event()
    port: list[int] = []

    def log(line: str) -> None:
        if line.startswith("listening on tcp"):
            port.append(int(line.split()[3].rsplit(":", 1)[1]))
            ready.set()

    sim = Simulator(SimulatorConfig(airframe=PAPER, port=0, duration_s=0.2,
                                    exit_on_disconnect=True), log=log)
    seen: list[int] = []
    waited_alone: list[bool] = []
    errors: list[BaseException] = []

    def autopilot() -> None:
        try:
            assert ready.wait(5.0)
            with socket.create_connection(("127.0.0.1", port[0]), timeout=5.0) as conn:
                mav, parser = new_mavlink(1, 1), new_mavlink(1, 1)
                while len(seen) < 20:
                    data = conn.recv(65536)
                    if not data:
                        break
                    for msg in parser.parse_buffer(data) or []:
                        if msg.get_type() != "ODOMETRY":
                            continue
                        seen.append(msg.time_usec)
                        if msg.time_usec == 50_000:
                            wrong = actuator_message(msg.time_usec + 1, np.zeros(4), False,
                                                     True)
                            conn.sendall(wrong.pack(mav))
                            # No next sample until the right answer.
                            waited_alone.append(not select.select([conn], [], [], 0.1)[0])
                        conn.sendall(actuator_message(msg.time_usec, np.zeros(4), False,
                                                      True).pack(mav))
        except BaseException as exc:  # noqa: BLE001 - reported in the main thread
            errors.append(exc)

    thread = threading.Thread(target=autopilot, daemon=True)
    previous = signal.getsignal(signal.SIGTERM)
    thread.start()
    try:
        assert sim.run() == 0
    finally:
        signal.signal(signal.SIGTERM, previous)
        thread.join(5.0)
    assert not errors, errors
    assert seen == [k * 10_000 for k in range(20)]
    assert waited_alone == [True]
    assert (sim.stats.samples_sent, sim.stats.commands_received) == (20, 20)
    assert sim.time_us == 200_000


FIRST_SAMPLES = """
import sys
from numba.core.dispatcher import Dispatcher
from contracts.airframe import PAPER, hover_rotor_speeds
from contracts.frames import DEFAULT_HOME
from contracts.mavlink import SIMULATOR_COMPID, SIMULATOR_SYSID, new_mavlink
from contracts.perturbations import NO_SENSOR_EFFECTS
from sitl.plant import Plant
from sitl.samples import SampleSource
from sitl.sensors import read_profile
from sitl.server import preload_compiled_code


def loaded():
    return {(m, n): len(d.overloads) for m in list(sys.modules)
            if m.split(".")[0] in ("sitl", "contracts")
            for n, d in vars(sys.modules[m]).items() if isinstance(d, Dispatcher)}


preload_compiled_code()
before = loaded()
plant = Plant(PAPER, "rigid-body", position_ned_m=(0.0, 0.0, -1.0),
              rotor_rad_s=hover_rotor_speeds(PAPER), ground_contact=True)
samples = SampleSource(read_profile("typical"), 250.0, 7, DEFAULT_HOME, plant.state())
for k in range(3):
    state = plant.state()
    samples.frames(k * 4000, state, NO_SENSOR_EFFECTS,
                   new_mavlink(SIMULATOR_SYSID, SIMULATOR_COMPID))
    plant.advance(0.004)
    samples.observe(state, plant.state(), 0.004)
after = loaded()
print(sorted({name for key, name in after if after[(key, name)] != before.get((key, name), 0)}))
"""


@pytest.mark.process
def test_the_preload_leaves_no_compiled_code_to_the_first_samples():
    """What the process loader and each simulator load before the loop: a run's first
    samples then load nothing from numba's cache. The sensors' code did load there,
    20-45 ms of the first sample, which the autopilot's first step waited for. A fresh
    interpreter: in this one, other tests may have loaded it all."""
    import subprocess
    import sys
    from pathlib import Path

    done = subprocess.run([sys.executable, "-c", FIRST_SAMPLES], capture_output=True,
                          text=True, check=True, cwd=Path(__file__).parents[2])
    assert done.stdout.strip() == "[]"


def test_a_held_simulator_is_woken_by_its_start_request():
    """Held (``--hold``), the simulator waits for its start request woken by the request
    itself, a few idle turns in all; it polled every 5 ms, and a held simulator beside
    another run's flight woke 200 times a second. Real Zenoh on loopback, the ground's
    own client."""
    import time

    from contracts.zenoh_link import ZenohOptions
    from ground.run.children import free_tcp_port
    from ground.uplink.perturb import PerturbationClient

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    sim, _lines = make_simulator(hold=True, zenoh=ZenohOptions(listen=[endpoint]))
    turns: list[float] = []
    idle = sim._idle

    def counted_idle() -> None:
        turns.append(time.monotonic())
        idle()

    sim._idle = counted_idle
    answers: list[dict] = []

    def release() -> None:
        with PerturbationClient(ZenohOptions(connect=[endpoint], listen=[]),
                                timeout_s=10.0) as client:
            time.sleep(0.3)
            answers.append(client.start(1))

    releaser = threading.Thread(target=release)
    releaser.start()
    start = time.monotonic()
    try:
        sim._wait_for_start()
        waited_s = time.monotonic() - start
    finally:
        releaser.join()
        sim.telemetry.node.close()
    assert sim.started and answers and answers[0]["ok"]  # released by the request
    assert len(turns) <= 2 + waited_s / 0.1  # an idle turn per 0.1 s at most (was 5 ms)
