"""Mission scenarios: a QGroundControl plan flown in AUTO.MISSION from the ground through
the processes in lockstep (``[mission] plan`` in a scenario file), with the path metrics
of ground/report/metrics.py."""

from __future__ import annotations

import base64
import json
import threading

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

from autopilot.navigator.plan_file import read_plan
from contracts.frames import DEFAULT_HOME
from ground.record.run_files import log_files
from ground.report.metrics import compute_metrics, distance_to_path
from ground.run.children import free_tcp_port
from ground.run.processes import RunSettings, fly
from ground.scenario.scenario_file import load_scenario, scenario_by_name
from tests.foxglove_client import collect


@pytest.fixture(scope="module")
def six_waypoint_runs(tmp_path_factory):
    """The shipped six-waypoint mission flown twice; the first with a Foxglove viewer
    connected to the live view all along (tests/foxglove_client.py)."""
    scenario = scenario_by_name("mission-six-waypoints")
    settings = RunSettings("ivfc", scenario.plant, scenario.airframe.argument)
    out = tmp_path_factory.mktemp("missions")
    port = free_tcp_port()
    viewer: dict = {}
    watch = threading.Thread(target=lambda: viewer.update(
        received=collect(f"ws://127.0.0.1:{port}", seconds=300.0)), daemon=True)
    watch.start()
    a = fly(scenario, settings, out / "a", view=("127.0.0.1", port))[0]
    watch.join(timeout=30.0)
    b = fly(scenario, settings, out / "b")[0]
    return scenario, a, b, out / "a", viewer.get("received")


@pytest.mark.process
def test_six_waypoints_at_5_mps_in_lockstep(six_waypoint_runs):
    scenario, record, *_ = six_waypoint_runs
    metrics = compute_metrics(record, scenario, "paper")
    path = metrics["path"]
    assert path["all_reached"] and path["items"] == [0, 1, 2, 3, 4, 5, 6]
    # Golden: every waypoint within its acceptance radius; the corners are rounded inside
    # it (NAV_ACC_RAD 2 m) at the corner speed, as PX4 flies them, so the path leaves the
    # legs by up to 0.38 m (0.077 m when it stopped at every corner).
    assert path["cross_track_rmse_m"] == pytest.approx(0.0879, abs=0.002)
    assert path["cross_track_max_m"] == pytest.approx(0.384, abs=0.01)
    assert path["arrival_s"][1] == pytest.approx(11.93, abs=0.1)
    assert np.all(np.diff(path["arrival_s"]) > 0)
    # Landed on the last waypoint (home) and stayed there.
    assert np.linalg.norm(record.measurement[-1, 0:3]) < 0.01
    speed = np.hypot(record.measurement[:, 3], record.measurement[:, 4])
    assert speed.max() == pytest.approx(5.0, abs=0.15)  # MPC_XY_CRUISE


@pytest.mark.process
def test_a_mission_repeats_bit_for_bit_in_lockstep(six_waypoint_runs):
    _, a, b, *_ = six_waypoint_runs  # a with a viewer connected, b without
    np.testing.assert_array_equal(a.measurement, b.measurement)
    np.testing.assert_array_equal(a.motor_commands, b.motor_commands)


def _planned_waypoints(scenario) -> np.ndarray:
    """The plan's six waypoints (between the take-off and the landing, which are drawn
    where the vehicle is) north and east of the run's home [m]."""
    items = read_plan(scenario.plan)[0][1:-1]
    home = scenario.home or DEFAULT_HOME
    return np.array([home.ned_from_geodetic(i.x * 1e-7, i.y * 1e-7, home.alt_amsl_m)[:2]
                     for i in items])


def _scene_waypoints(scene) -> np.ndarray:
    mission = next(e for e in scene.entities if e.id == "mission")
    assert [t.text for t in mission.texts] == [str(i) for i in range(8)]  # item numbers
    return np.array([(s.pose.position.x, s.pose.position.y) for s in mission.spheres])[1:-1]


@pytest.mark.process
def test_the_live_view_serves_the_mission_flight_to_a_foxglove_client(six_waypoint_runs):
    scenario, record, _, _, received = six_waypoint_runs
    assert received is not None and received.server_info["name"] == "ivfm-sitl"
    schemas = {c["topic"]: c["schemaName"] for c in received.channels.values()}
    assert schemas == {
        "/tf": "foxglove.FrameTransforms", "/vehicle1/rotors": "foxglove.FrameTransforms",
        "/vehicle1/scene": "foxglove.SceneUpdate",
        "/vehicle1/path": "foxglove.PosesInFrame",
        "/vehicle1/reference_path": "foxglove.PosesInFrame",
        "/vehicle1/reference": "foxglove.PoseInFrame", "/log": "foxglove.Log",
        "/vehicle1/controller": "ivfm.view.vehicle1.controller"}
    # Every topic served, a subscription the SDK refused included (docs/telemetry.md, "A
    # subscription refused"); /log aside: this flight says two things, and the first
    # goes out with its channel's creation, before any subscription.
    assert all(received.messages[t] for t in schemas if t != "/log"), received.summary()
    # Rates in sim time (the view decimates on it): transforms and plots at 50 Hz, the
    # path at 2 Hz, without a gap to the flight's end. (A channel is advertised with its
    # first message; what comes before the viewer's subscription reaches it is not sent:
    # in lockstep at about 9x real time, up to a second of sim time.)
    for topic, hz in (("/tf", 50), ("/vehicle1/controller", 50), ("/vehicle1/path", 2)):
        stamps = np.array([t for t, _ in received.messages[topic]]) / 1e9
        assert stamps.size and stamps[0] < 5.0 and stamps[-1] > 79.0, received.summary()
        assert np.diff(stamps) == pytest.approx(1 / hz, abs=1e-6), topic
    # The scene update carries the mission's waypoints where the plan puts them.
    channel = next(c for c in received.channels.values() if c["topic"] == "/vehicle1/scene")
    decoder = DecoderFactory().decoder_for("protobuf", Schema(
        id=1, name=channel["schemaName"], encoding="protobuf",
        data=base64.b64decode(channel["schema"])))
    scenes = [decoder(payload) for _, payload in received.messages["/vehicle1/scene"]]
    assert scenes, received.summary()
    np.testing.assert_allclose(_scene_waypoints(scenes[-1]), _planned_waypoints(scenario),
                               atol=1e-3)
    # Plot-ready internals: the mission flown armed, disarmed on landing at its end.
    controller = [json.loads(p) for _, p in received.messages["/vehicle1/controller"]]
    assert controller[0]["mode"] == "MISSION"
    assert controller[0]["armed"] and not controller[-1]["armed"]
    assert set(controller[0]["phi"]) >= {"reference", "measured", "error", "sliding_surface",
                                         "f_hat", "u_eq", "u_s", "control", "theta_g"}


@pytest.mark.process
def test_the_log_holds_foxgloves_scene_transforms_and_path(six_waypoint_runs):
    scenario, record, _, folder, _ = six_waypoint_runs
    decoded: dict[str, list] = {}
    with open(log_files(folder)[0], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, _channel, message, proto in reader.iter_decoded_messages(
                topics=["/tf", "/vehicle1/scene", "/vehicle1/path"]):
            decoded.setdefault(schema.name, []).append((message.publish_time, proto))
    assert set(decoded) == {"foxglove.FrameTransforms", "foxglove.SceneUpdate",
                            "foxglove.PosesInFrame"}
    # The body's transform is the truth the autopilot flew on at the same sim time (as
    # ODOMETRY's float32 carried it).
    t_ns, tf = decoded["foxglove.FrameTransforms"][1000]
    body = next(t for t in tf.transforms if t.child_frame_id == "vehicle1")
    assert body.parent_frame_id == "ned"
    i = int(np.searchsorted(record.sim_time_us, t_ns // 1000))
    assert record.sim_time_us[i] * 1000 == t_ns == 20_000_000_000
    np.testing.assert_allclose([body.translation.x, body.translation.y, body.translation.z],
                               record.measurement[i, 0:3], atol=1e-5)
    assert {t.child_frame_id for t in tf.transforms} == {"ned", "vehicle1"}
    # The rotors' frames, with each scene record, on their own topic.
    with open(log_files(folder)[0], "rb") as f:
        rotors = [proto for *_, proto in make_reader(
            f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/vehicle1/rotors"])]
    assert len(rotors) >= 80  # a scene a second of the 80 s flight, and on changes
    assert {(t.parent_frame_id, t.child_frame_id) for t in rotors[-1].transforms} == {
        ("vehicle1", f"vehicle1/rotor{k}") for k in range(1, 5)}
    _, scene = decoded["foxglove.SceneUpdate"][-1]
    np.testing.assert_allclose(_scene_waypoints(scene), _planned_waypoints(scenario),
                               atol=1e-3)
    _, path = decoded["foxglove.PosesInFrame"][-1]
    assert path.frame_id == "ned" and len(path.poses) == 600  # the last 60 s at 10 Hz


def test_the_cross_track_of_a_path_is_the_distance_to_its_nearest_leg():
    path = np.array([(0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (10.0, 10.0, 0.0)])
    points = np.array([(5.0, 1.0, 0.0), (11.0, 5.0, 0.0), (12.0, -1.0, 0.0), (10.0, 0.0, 2.0)])
    assert np.allclose(distance_to_path(points, path), (1.0, 1.0, np.sqrt(5.0), 2.0))


@pytest.mark.parametrize("text, error", [
    ('[mission]\nplan = "missing.plan"\n', "missing.plan: no such file"),
    ('[mission]\nplan = 3\n', "mission.plan must be the path of a .plan file"),
    ('[mission]\nplan = "ok.plan"\nspeed = 3\n', "mission: unknown field"),
    ('[mission]\nplan = "ok.plan"\n[reference]\nkind = "hover"\n',
     "a scenario flies a [mission] or a [reference], not both"),
    ('[mission]\nplan = "empty.plan"\n', "has no mission items"),
])
def test_bad_mission_scenarios_are_refused_with_the_field(tmp_path, text, error):
    plan = {"fileType": "Plan", "version": 1, "mission": {"items": []}}
    (tmp_path / "empty.plan").write_text(json.dumps(plan))
    shipped = scenario_by_name("mission-six-waypoints").plan
    (tmp_path / "ok.plan").write_text(shipped.read_text())
    path = tmp_path / "mine.toml"
    path.write_text('name = "mine"\n' + text)
    with pytest.raises(ValueError, match=error.replace("[", r"\[").replace("]", r"\]")):
        load_scenario(path)


def test_a_mission_scenario_is_not_flown_in_process():
    from ground.run.inprocess import run_inprocess

    scenario = scenario_by_name("mission-six-waypoints")
    with pytest.raises(ValueError, match="flies a mission"):
        run_inprocess(scenario, "ivfc", "rigid-body", None)
