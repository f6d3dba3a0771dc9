"""The simulator link: message mapping round trips, and bad input from either side."""

from __future__ import annotations

import math
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from contracts.airframe import PAPER, hover_rotor_speeds
from contracts.frames import DEFAULT_HOME, Home
from contracts.mavlink import (
    LinkDataError,
    actuator_message,
    commands_from_actuator,
    mavlink,
    measurement_from_hil_state,
    measurement_from_odometry,
    split_frames,
)
from contracts.sim_samples import sample_messages
from contracts.vectors import MEASUREMENT
from sitl.plant import Plant
from sitl.truth import ideal_readings
from tests.harness import free_port


def _flying_plant(fidelity: str) -> Plant:
    plant = Plant(PAPER, fidelity, position_ned_m=(1.0, -2.0, -3.0), euler_rad=(0.3, -0.2, 1.0),
                  rotor_rad_s=hover_rotor_speeds(PAPER))
    plant.set_motor_commands(np.array([0.5, 0.45, 0.48, 0.47]))
    plant.advance(0.5)
    return plant


def _decoded(plant: Plant) -> dict[str, object]:
    s = plant.state()
    mav = mavlink.MAVLink(None, 1, 51)
    data = b"".join(m.pack(mav) for m in sample_messages(
        *ideal_readings(123456, s, np.zeros(3)), DEFAULT_HOME))
    return {m.get_type(): m for m in mavlink.MAVLink(None, 1, 1).parse_buffer(data)}


@pytest.mark.parametrize("fidelity", ["paper", "rigid-body"])
def test_odometry_gives_the_plant_measurement_to_float32(fidelity):
    plant = _flying_plant(fidelity)
    msgs = _decoded(plant)
    assert set(msgs) == {"HIL_SENSOR", "HIL_GPS", "HIL_STATE_QUATERNION", "ODOMETRY"}
    np.testing.assert_allclose(measurement_from_odometry(msgs["ODOMETRY"]),
                               plant.true_measurement(), atol=1e-5)
    # HIL_STATE_QUATERNION alone: 1e-7 deg (~1 cm), mm, cm/s.
    hil = measurement_from_hil_state(msgs["HIL_STATE_QUATERNION"], DEFAULT_HOME)
    truth = plant.true_measurement()
    np.testing.assert_allclose(hil[0:3], truth[0:3], atol=0.02)
    np.testing.assert_allclose(hil[3:6], truth[3:6], atol=0.006)
    np.testing.assert_allclose(hil[6:12], truth[6:12], atol=1e-5)


def test_hil_sensor_reads_gravity_at_rest():
    plant = Plant(PAPER, "rigid-body", ground_contact=True)
    sensor = _decoded(plant)["HIL_SENSOR"]
    assert (sensor.xacc, sensor.yacc) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert sensor.zacc == pytest.approx(-PAPER.gravity_mps2)  # FRD: up is -z
    assert sensor.abs_pressure == pytest.approx(956.0, abs=0.5)  # ISA at 488 m AMSL


@pytest.mark.parametrize("controls,armed,why", [
    ([math.nan, 0, 0, 0], True, "NaN"), ([0.5, math.inf, 0, 0], True, "NaN or infinity"),
    ([1.5, 0, 0, 0], True, "in [0, 1]"), ([-0.2, 0, 0, 0], True, "in [0, 1]")])
def test_bad_actuator_messages_are_refused(controls, armed, why):
    msg = actuator_message(0, np.zeros(4), armed, True)
    msg.controls[:4] = controls
    with pytest.raises(LinkDataError, match=why.split()[0]):
        commands_from_actuator(msg)


def test_disarmed_actuator_message_means_motors_off():
    msg = actuator_message(0, np.full(4, 0.7), False, True)
    np.testing.assert_array_equal(commands_from_actuator(msg), np.zeros(4))


def test_bad_odometry_is_refused():
    msg = _decoded(_flying_plant("rigid-body"))["ODOMETRY"]
    msg.x = math.nan
    with pytest.raises(LinkDataError):
        measurement_from_odometry(msg)
    msg.x, msg.q = 0.0, [0.1, 0.0, 0.0, 0.0]
    with pytest.raises(LinkDataError, match="norm"):
        measurement_from_odometry(msg)


def test_split_frames_keeps_partial_frames_for_later():
    plant = _flying_plant("paper")
    s = plant.state()
    mav = mavlink.MAVLink(None, 1, 51)
    data = b"".join(m.pack(mav) for m in sample_messages(
        *ideal_readings(1, s, np.zeros(3)), DEFAULT_HOME))
    frames, rest = split_frames(b"\x00\x01" + data + data[:20])
    assert [i for i, _ in frames] == [-1, 113, 107, 115, 331] and rest == data[:20]


@pytest.mark.process
def test_simulator_survives_garbage_and_bad_commands(tmp_path):
    """A fake autopilot: garbage bytes, then NaN motor commands, then good ones."""
    port = free_port(socket.SOCK_STREAM)
    log = tmp_path / "sitl.log"
    with open(log, "w") as out:
        sim = subprocess.Popen([sys.executable, "-m", "sitl", "--port", str(port), "--plant",
                                "paper"], stdout=out, stderr=subprocess.STDOUT)
    try:
        conn = _connect(port)
        mav = mavlink.MAVLink(None, 1, 1)
        got = mavlink.MAVLink(None, 1, 1)

        def next_sample_time() -> int:
            while True:
                for m in got.parse_buffer(conn.recv(65536)) or []:
                    if m.get_type() == "ODOMETRY":
                        return m.time_usec

        t = next_sample_time()
        conn.sendall(b"garbage, not mavlink")
        bad = actuator_message(t, np.zeros(4), True, True)
        bad.controls[0] = math.nan
        conn.sendall(bad.pack(mav))  # refused; lockstep still goes on
        t2 = next_sample_time()
        assert t2 == t + 10000
        for _ in range(5):
            conn.sendall(actuator_message(t2, np.full(4, 0.2), True, True).pack(mav))
            t2 = next_sample_time()
        assert t2 == t + 60000
        conn.close()
        deadline = time.monotonic() + 5
        while "autopilot disconnected" not in log.read_text() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert sim.poll() is None
        text = log.read_text()
        assert "refused actuator message" in text and "autopilot disconnected" in text
    finally:
        sim.terminate()
        sim.wait(5)


def _connect(port: int) -> socket.socket:
    deadline = time.monotonic() + 20
    while True:
        try:
            return socket.create_connection(("127.0.0.1", port), timeout=5)
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


@pytest.mark.process
def test_autopilot_refuses_bad_simulator_data_and_keeps_serving(tmp_path):
    """A fake simulator sends NaN odometry: refused, logged, no motor output, no crash."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    log = tmp_path / "autopilot.log"
    with open(log, "w") as out:
        ap = subprocess.Popen([sys.executable, "-m", "autopilot", "--sim", f"127.0.0.1:{port}",
                               "--gcs", "none", "--gcs-bind", "0", "--api", "none",
                               "--api-bind", "0"], stdout=out, stderr=subprocess.STDOUT)
    try:
        server.settimeout(20)
        conn, _ = server.accept()
        conn.settimeout(5)
        mav = mavlink.MAVLink(None, 1, 51)
        plant = Plant(PAPER, "paper", ground_contact=True)
        s = plant.state()
        msgs = sample_messages(*ideal_readings(0, s, np.zeros(3)), DEFAULT_HOME)
        msgs[3].vx = math.nan
        conn.sendall(b"".join(m.pack(mav) for m in msgs))
        time.sleep(0.5)
        good = sample_messages(*ideal_readings(10000, s, np.zeros(3)), DEFAULT_HOME)
        conn.sendall(b"".join(m.pack(mav) for m in good))
        reply = []
        reader = mavlink.MAVLink(None, 1, 51)
        while not reply:
            reply = [m for m in reader.parse_buffer(conn.recv(65536)) or []
                     if m.get_type() == "HIL_ACTUATOR_CONTROLS"]
        # Only the good sample is answered, disarmed, motors off.
        assert [m.time_usec for m in reply] == [10000]
        assert reply[0].mode == 0 and list(reply[0].controls[:4]) == [0, 0, 0, 0]
        assert ap.poll() is None
        assert "refused simulator data: ODOMETRY holds NaN" in log.read_text()
        conn.close()
    finally:
        ap.terminate()
        ap.wait(5)
        server.close()


def test_world_to_body_is_the_transposed_rotation():
    from contracts.frames import quat_from_euler, rotation_from_quat, world_to_body

    rng = np.random.default_rng(3)
    for _ in range(20):
        q = quat_from_euler(*rng.uniform(-1.5, 1.5, 3))
        v = rng.normal(size=3)
        np.testing.assert_allclose(world_to_body(*q, *v), rotation_from_quat(q).T @ v,
                                   atol=1e-12)


def test_odometry_velocity_in_body_frd_is_turned_into_ned():
    """PX4 publishes ODOMETRY velocity in BODY_FRD: the same motion, either frame."""
    from contracts.frames import body_to_world, world_to_body

    msgs = _decoded(_flying_plant("rigid-body"))
    ned = msgs["ODOMETRY"]
    w, x, y, z = ned.q
    body = mavlink.MAVLink_odometry_message(
        ned.time_usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD, ned.x, ned.y,
        ned.z, ned.q, *world_to_body(w, x, y, z, ned.vx, ned.vy, ned.vz), ned.rollspeed,
        ned.pitchspeed, ned.yawspeed, [math.nan] * 21, [math.nan] * 21, 0, 0, 100)
    np.testing.assert_allclose(measurement_from_odometry(body), measurement_from_odometry(ned),
                               atol=1e-6)
    np.testing.assert_allclose(body_to_world(w, x, y, z, *world_to_body(w, x, y, z, 1, 2, 3)),
                               (1, 2, 3), atol=1e-12)
    frd_position = mavlink.MAVLink_odometry_message(
        ned.time_usec, mavlink.MAV_FRAME_LOCAL_FRD, mavlink.MAV_FRAME_BODY_FRD, ned.x, ned.y,
        ned.z, ned.q, 0, 0, 0, 0, 0, 0, [math.nan] * 21, [math.nan] * 21, 0, 0, 100)
    with pytest.raises(LinkDataError, match="position in MAV_FRAME_LOCAL_NED"):
        measurement_from_odometry(frd_position)


def _autopilot_on_a_socket(rate_hz: float = 100.0, source: str = "auto",
                           home: Home | None = DEFAULT_HOME, lockstep: bool = True,
                           log=lambda text: None):
    """The autopilot process's simulator side on one end of a socket pair (its home given,
    as scenario runs give it, unless ``home`` is None)."""
    from autopilot.commander.commander import Commander
    from autopilot.control.factory import make_controller
    from autopilot.mavlink.server import MavlinkServer
    from autopilot.process.loop import Autopilot, AutopilotConfig

    vehicle = Commander(lambda p: make_controller("smc", PAPER, 1 / rate_hz, None, p),
                      1 / rate_hz)
    autopilot = Autopilot(AutopilotConfig(rate_hz=rate_hz, state_source=source, home=home,
                                          lockstep=lockstep),
                          vehicle,
                          MavlinkServer(vehicle, []), log=log)
    ours, theirs = socket.socketpair()
    ours.setblocking(False)
    autopilot.sim.sock = ours
    return autopilot, theirs


def _send_samples(theirs: socket.socket, times_us, kinds=("HIL_STATE_QUATERNION", "ODOMETRY")):
    plant = _flying_plant("paper")
    s = plant.state()
    mav = mavlink.MAVLink(None, 1, 51)
    for t in times_us:
        msgs = sample_messages(*ideal_readings(t, s, np.zeros(3)), DEFAULT_HOME)
        theirs.sendall(b"".join(m.pack(mav) for m in msgs if m.get_type() in kinds))


def _answers(theirs: socket.socket) -> list[int]:
    theirs.setblocking(False)
    data = b""
    try:
        while chunk := theirs.recv(65536):
            data += chunk
    except BlockingIOError:
        pass
    return [m.time_usec for m in mavlink.MAVLink(None, 1, 1).parse_buffer(data) or []
            if m.get_type() == "HIL_ACTUATOR_CONTROLS"]


@pytest.mark.parametrize("sim_rate_hz", [100, 250, 400, 1000])
def test_lockstep_answers_every_sample_and_controls_at_its_own_rate(sim_rate_hz):
    autopilot, theirs = _autopilot_on_a_socket(100.0)
    origin_us = 5_000_000_123  # any origin
    period_us = round(1e6 / sim_rate_hz)
    times = [origin_us + k * period_us for k in range(2 * sim_rate_hz)]  # 2 s
    answers = []
    for chunk in range(0, len(times), 10):
        _send_samples(theirs, times[chunk:chunk + 10])
        autopilot._on_sim_readable()
        answers += _answers(theirs)
    assert answers == times  # each sample once, in order, with its own time
    assert autopilot.steps == 200  # 100 Hz of control over 2 s, whatever the sample rate


def test_auto_source_takes_odometry_when_sent_and_hil_state_when_not():
    autopilot, theirs = _autopilot_on_a_socket()
    _send_samples(theirs, [0, 10_000], kinds=("HIL_SENSOR", "HIL_STATE_QUATERNION"))
    autopilot._on_sim_readable()
    assert not autopilot.sim.odometry_seen and autopilot.steps == 2
    hil_position = autopilot.latest[1][0:3].copy()
    _send_samples(theirs, [20_000, 30_000])  # both: one answer per sample, from ODOMETRY
    autopilot._on_sim_readable()
    assert autopilot.sim.odometry_seen and autopilot.steps == 4
    assert _answers(theirs) == [0, 10_000, 20_000, 30_000]
    odometry_position = autopilot.latest[1][0:3]
    assert 0 < np.max(np.abs(odometry_position - hil_position)) < 0.02  # float32 vs 1e-7 deg


def _samples_with_gyro(times_us, gyro_frd_rad_s, kinds, fields_updated=None) -> bytes:
    """The flying plant's samples, HIL_SENSOR's gyro replaced by ``gyro_frd_rad_s`` (a
    simulator whose gyro and ground truth disagree) and its fields_updated by the given."""
    s = _flying_plant("paper").state()
    mav = mavlink.MAVLink(None, 1, 51)
    data = b""
    for t in times_us:
        truth, sensor, fix = ideal_readings(t, s, np.zeros(3))
        sensor = sensor._replace(gyro_frd_rad_s=tuple(gyro_frd_rad_s),
                                 fields_updated=fields_updated or sensor.fields_updated)
        data += b"".join(m.pack(mav) for m in sample_messages(truth, sensor, fix, DEFAULT_HOME)
                         if m.get_type() in kinds)
    return data


@pytest.mark.parametrize("source, truth", [("hil-state", "HIL_STATE_QUATERNION"),
                                           ("odometry", "ODOMETRY"),
                                           ("auto", "ODOMETRY")])
def test_on_the_truth_body_rates_come_from_the_gyro(source, truth):
    """As PX4's rate loop: attitude and position from the truth message, the body rates
    from HIL_SENSOR's gyro of the same sample (here 0.1, -0.2, 0.3 rad/s, unlike the
    truth's); the Euler rates the controller flies on are the gyro's."""
    from contracts.frames import euler_rates_from_body_rates

    autopilot, theirs = _autopilot_on_a_socket(source=source)
    gyro = (0.1, -0.2, 0.3)
    theirs.sendall(_samples_with_gyro([0, 10_000], gyro, ("HIL_SENSOR", truth)))
    autopilot._on_sim_readable()
    assert autopilot.steps == 2 and _answers(theirs) == [0, 10_000]
    m = autopilot.latest[1]
    phi, theta = m[MEASUREMENT.euler_rad][:2]
    np.testing.assert_allclose(m[MEASUREMENT.euler_rate_rad_s],
                               euler_rates_from_body_rates(phi, theta, *gyro), rtol=1e-6)
    # The attitude is still the truth's: the gyro only rates it.
    truth_euler = _flying_plant("paper").true_measurement()[MEASUREMENT.euler_rad]
    np.testing.assert_allclose(m[MEASUREMENT.euler_rad], truth_euler, atol=1e-5)


def test_without_hil_sensor_the_truth_gives_its_own_rates():
    autopilot, theirs = _autopilot_on_a_socket(source="hil-state")
    theirs.sendall(_samples_with_gyro([0], (0.1, -0.2, 0.3), ("HIL_STATE_QUATERNION",)))
    autopilot._on_sim_readable()
    plant = _flying_plant("paper")
    np.testing.assert_allclose(autopilot.latest[1][MEASUREMENT.euler_rate_rad_s],
                               plant.true_measurement()[MEASUREMENT.euler_rate_rad_s],
                               rtol=1e-5, atol=1e-6)


def test_a_simulator_with_only_an_imu_and_ground_truth_flies_on_the_truth():
    """HIL_SENSOR with the IMU bits alone (no barometer, no magnetometer) and
    HIL_STATE_QUATERNION, no HIL_GPS: every sample answered, flown on the truth with the
    gyro's rates, nothing refused."""
    from contracts.mavlink import HIL_SENSOR_IMU

    autopilot, theirs = _autopilot_on_a_socket(source="auto", home=None)
    times = [k * 10_000 for k in range(50)]
    theirs.sendall(_samples_with_gyro(times, (0.0, 0.0, 0.05),
                                      ("HIL_SENSOR", "HIL_STATE_QUATERNION"), HIL_SENSOR_IMU))
    autopilot._on_sim_readable()
    assert _answers(theirs) == times and autopilot.steps == 50
    assert autopilot.sim.bad_messages == 0
    assert autopilot.vehicle.home_known  # from HIL_STATE_QUATERNION
    m = autopilot.latest[1]
    phi, theta = m[MEASUREMENT.euler_rad][:2]
    # psi rate of a pure body yaw rate r: r cos(phi) / cos(theta).
    assert m[MEASUREMENT.euler_rate_rad_s][2] == pytest.approx(
        0.05 * math.cos(phi) / math.cos(theta), rel=1e-6)


def test_a_stall_is_a_gap_over_two_periods_counted_once_per_episode():
    """The real-time stall rule on an injected clock: a sample gap of up to two periods
    (of the control or of the simulator, the longer) is no stall; beyond it each control
    instant is held and counted, one episode until a sample comes again."""
    autopilot, _theirs = _autopilot_on_a_socket(100.0)
    logged = []
    autopilot.log = logged.append
    autopilot._last_sample_wall = 100.0
    autopilot._sample_period_us = 4_000  # a 250 Hz simulator: the control period rules

    def stalled(now: float) -> bool:  # as the real-time instant asks, at a 10 ms period
        return autopilot.stall.stalled(now, autopilot._last_sample_wall, 0.01,
                                       autopilot._sample_period_us / 1e6)

    assert not stalled(100.020)
    assert stalled(100.021) and stalled(100.031)
    autopilot._last_sample_wall = 100.035  # a sample again
    assert not stalled(100.040)
    summary = autopilot.timing.summary()
    assert (summary["sim_stalls"], summary["sim_stall_steps"]) == (1, 2)
    assert summary["sim_stall_longest_ms"] == pytest.approx(31.0)
    assert logged == ["simulator late: no sample for at least 31 ms; 2 control step(s) "
                      "held the last command"]
    autopilot._sample_period_us = 50_000  # a 20 Hz simulator: its period rules
    assert not stalled(100.130)
    assert stalled(100.140)


def test_a_real_time_instant_flies_only_a_sample_not_flown_yet():
    """After a late step the next instant on the grid often finds no sample since: it
    holds the last command and counts it (flown again, the setpoints moved a period on,
    ahead of the vehicle for good). A step after lost periods moves the setpoints on by
    all of them."""
    import selectors

    autopilot, theirs = _autopilot_on_a_socket(lockstep=False)
    autopilot.sel.register(autopilot.sim.sock, selectors.EVENT_READ, "sim")
    # A control period long enough that no pause of this test's process is a stall.
    period_s = 100.0

    def instant() -> bool:
        return autopilot._realtime_instant(time.perf_counter(), period_s)

    assert not instant()  # no sample yet
    _send_samples(theirs, [0])
    assert instant() and _answers(theirs) == [0]
    assert not instant() and _answers(theirs) == []
    _send_samples(theirs, [10_000, 20_000, 30_000, 40_000])  # the late step's samples
    assert instant() and _answers(theirs) == [40_000]
    assert autopilot.vehicle.state.step_s == pytest.approx(0.04)
    assert not instant() and not instant()
    _send_samples(theirs, [50_000])
    assert instant() and _answers(theirs) == [50_000]
    assert autopilot.vehicle.state.step_s == pytest.approx(0.01)
    assert autopilot.steps == 3
    assert autopilot.timing.summary()["same_sample_held"] == 3
    # A simulator slower than the control rate (20 Hz): every instant flies, its samples
    # again, as its samples are not due at every instant.
    _send_samples(theirs, [100_000])
    assert instant() and instant() and _answers(theirs) == [100_000, 100_000]
    assert autopilot.timing.summary()["same_sample_held"] == 3


def test_an_instant_waits_a_little_for_the_sample_due_rather_than_hold():
    """The simulator's grid in phase with the control instants: the sample due arrives
    just after the instant. The instant waits for it (a quarter of the simulator's
    period at most) and flies it; one later than that is held, counted."""
    import selectors
    import threading

    # Both at 1 Hz, so that the wait (0.25 s) is long beside this process's pauses.
    autopilot, theirs = _autopilot_on_a_socket(rate_hz=1.0, lockstep=False)
    autopilot.sel.register(autopilot.sim.sock, selectors.EVENT_READ, "sim")
    period_s = 100.0  # no pause of this test's process is a stall

    def instant() -> bool:
        return autopilot._realtime_instant(time.perf_counter(), period_s)

    _send_samples(theirs, [0, 1_000_000])
    assert instant() and _answers(theirs) == [1_000_000]
    late = threading.Timer(0.02, _send_samples, (theirs, [2_000_000]))
    late.start()
    started = time.perf_counter()
    assert instant() and _answers(theirs) == [2_000_000]  # 20 ms late: waited for
    late.join()
    assert time.perf_counter() - started < 0.25
    started = time.perf_counter()
    assert not instant()  # nothing comes: held after the wait, counted
    assert 0.25 <= time.perf_counter() - started < 1.0
    assert autopilot.timing.summary()["same_sample_held"] == 1


def test_a_simulator_lost_during_that_wait_is_not_flown_on():
    """The simulator goes while an instant waits for the sample due: the instant holds,
    the link is lost and the vehicle says so (the autopilot once flew on and sent the
    command to the closed link: a crash, seen as a missing "simulator link lost" in CI)."""
    import selectors
    import threading

    autopilot, theirs = _autopilot_on_a_socket(rate_hz=1.0, lockstep=False)
    autopilot.sel.register(autopilot.sim.sock, selectors.EVENT_READ, "sim")
    period_s = 100.0

    def instant() -> bool:
        return autopilot._realtime_instant(time.perf_counter(), period_s)

    _send_samples(theirs, [0, 1_000_000])
    assert instant() and _answers(theirs) == [1_000_000]
    autopilot.vehicle.messages.clear()
    gone = threading.Timer(0.02, theirs.close)  # gone before the next sample: the
    gone.start()                                # wait reads the end of the link
    assert not instant()
    gone.join()
    assert autopilot.sim.sock is None and not autopilot.vehicle.sim_link_ok
    assert any("simulator link lost" in text for _, text in autopilot.vehicle.messages)


def test_what_the_vehicle_says_inside_the_ground_service_goes_into_the_log_too():
    """Texts go into the process log where they go out, in the ground server: those
    said between steps and those said inside its own service (an acknowledged reboot,
    a ground link's failsafe), each once, at the vehicle's sim time."""
    logged: list[str] = []
    autopilot, _theirs = _autopilot_on_a_socket(log=logged.append)
    autopilot.vehicle.say("said between steps")
    autopilot.ground.reboot_pending = True  # carried out inside the server's service
    autopilot._ground_work(0.0)
    said = [line for line in logged if line.startswith("t=0.000 s ")]
    assert said == ["t=0.000 s INFO: said between steps", "t=0.000 s INFO: rebooted"]
    assert not autopilot.vehicle.messages  # and all of it went out


def test_a_refused_command_loses_the_link_and_a_new_one_registers_on_its_number():
    """A send refused (the simulator gone) loses the link: out of the selector before the
    socket closes, so that the next connection, which the kernel may give the same file
    number, registers; later answers into the lost link are no-ops, not a crash."""
    import selectors

    autopilot, theirs = _autopilot_on_a_socket()
    autopilot.sel.register(autopilot.sim.sock, selectors.EVENT_READ, "sim")
    theirs.close()
    autopilot._answer(10_000, np.zeros(4), stepped=True)  # EPIPE: lost
    autopilot._answer(20_000, np.zeros(4), stepped=True)  # the rest of a batch
    # Nothing left registered: a new socket on the old number registers (a stale key
    # would make that a KeyError in _connect).
    assert autopilot.sim.sock is None and len(autopilot.sel.get_map()) == 0


def test_the_autopilot_tries_the_simulator_every_20_ms_at_first_then_backs_off():
    """A scenario run starts both processes at once; the simulator listens a few hundred
    milliseconds later: the autopilot's attempts come every 20 ms at first (growing by
    half each time, to 0.5 s), so it connects within a fraction of that once it listens,
    and quickly again after losing it."""
    from autopilot.process.sim_link import RECONNECT_S, SimLink

    port = free_port()  # nothing listens there yet
    link = SimLink("127.0.0.1", port, "auto")
    attempts, now = [], 0.0
    while now < 3.0:
        before = link.next_attempt_s
        link.connect(now)
        if link.next_attempt_s != before:
            attempts.append(round(now, 3))
        now += 0.001
    gaps = [round(b - a, 3) for a, b in zip(attempts, attempts[1:], strict=False)]
    assert gaps[:4] == [0.02, 0.03, 0.045, 0.068]  # 20 ms, then x1.5 (to the ms tick)
    assert max(gaps) <= RECONNECT_S + 0.001 and gaps[-1] > 0.4
    server = socket.create_server(("127.0.0.1", port))
    try:
        while not link.connect(now):
            now += 0.001
        assert link.sock is not None
        link.close()  # lost: the next attempt comes 20 ms on, not 0.5 s
        assert not link.connect(now + 0.019) and link.connect(now + 0.021)
    finally:
        link.close()
        server.close()


def test_a_lockstep_link_waits_for_the_next_sample_and_a_silent_simulator_is_not_a_loss():
    """Lockstep reads without a selector: ``read`` waits up to ``wait_s`` for the
    simulator. A simulator that says nothing for that long gives no samples, not a lost
    link (the socket's timeout is an OSError too); what it then sends is read whole; its
    end is the link's end."""
    from autopilot.process.sim_link import SimLink

    server = socket.create_server(("127.0.0.1", 0))
    link = SimLink("127.0.0.1", server.getsockname()[1], "auto", home=DEFAULT_HOME,
                   wait_s=0.05)
    try:
        assert link.connect(0.0)
        simulator, _ = server.accept()
        t0 = time.monotonic()
        assert link.read() == []
        assert 0.04 <= time.monotonic() - t0 < 1.0
        mav = mavlink.MAVLink(None, 1, 51)
        simulator.sendall(b"".join(m.pack(mav) for m in sample_messages(
            *ideal_readings(10_000, _flying_plant("paper").state(), np.zeros(3)),
            DEFAULT_HOME)))
        readings = link.read()
        assert readings and {r.time_us for r in readings} == {10_000}
        simulator.close()
        assert link.read() is None
    finally:
        link.close()
        server.close()
