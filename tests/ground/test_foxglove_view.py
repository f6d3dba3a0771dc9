"""What Foxglove draws of the telemetry (ground/telemetry/foxglove_view.py): frames, decimation on
sim time, the scene from the autopilot's scene record, and bad scene records refused."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

from contracts.frames import quat_from_euler, rotation_from_quat
from contracts.modes import FlightMode
from contracts.telemetry import CONTROL, STATE
from contracts.vectors import CHANNEL_INTERNALS, CHANNELS, MEASUREMENT
from ground.telemetry.controller_text import INTERNAL_NAMES
from ground.telemetry.foxglove_scene import encode, json_schema
from ground.telemetry.foxglove_view import FoxgloveView

STATE_KEY = "ivfm/vehicle/1/sitl/state"
CONTROL_KEY = "ivfm/vehicle/1/autopilot/control"
SCENE_KEY = "ivfm/vehicle/1/autopilot/scene"
ROTORS = [[0.23, 0.0, 0.0, 1.0], [0.0, 0.23, 0.0, -1.0], [-0.23, 0.0, 0.0, 1.0],
          [0.0, -0.23, 0.0, -1.0]]


def state_payload(t_us: int, position=(1.0, 2.0, -3.0), euler=(0.1, -0.2, 0.3)) -> bytes:
    record = STATE.buffer()
    record["seq"], record["sim_time_us"] = t_us // 1000, t_us
    record["position_ned_m"], record["quaternion"] = position, quat_from_euler(*euler)
    record["euler_rad"] = euler
    return record.encode()


def scene_payload(**fields) -> bytes:
    scene = {"airframe": {"name": "paper", "rotors": ROTORS}, "home": [47.0, 8.0, 400.0],
             "mission": [[0, 0.0, 0.0, -5.0], [1, 30.0, 0.0, -5.0]], "current": 1,
             "fence": [{"inclusion": True, "centre": [0.0, 0.0], "radius_m": 25.0},
                       {"inclusion": False, "polygon": [[1, 1], [1, 2], [2, 2]]}],
             "rally": [[0, 5.0, 5.0, 0.0]]}
    scene.update(fields)
    # As a peer could send it: json.dumps lets NaN through, json_record would not.
    return json.dumps({"seq": 0, "sim_time_us": 1_000_000, **scene}).encode()


_DECODERS: dict[str, object] = {}


def decoded(message):
    """A Foxglove message read back from its protobuf (the SDK's objects are write-only),
    as a log reader decodes it."""
    schema = type(message).get_schema()
    decoder = _DECODERS.get(schema.name)
    if decoder is None:
        decoder = _DECODERS[schema.name] = DecoderFactory().decoder_for(
            "protobuf", Schema(id=len(_DECODERS) + 1, name=schema.name, encoding="protobuf",
                               data=bytes(schema.data)))
    return decoder(message.encode())


def transforms(outputs, topic: str = "/tf") -> dict[str, object]:
    (tf,) = [decoded(o.message) for o in outputs if o.topic == topic]
    return {t.child_frame_id: t for t in tf.transforms}


def test_the_body_sits_in_ned_which_sits_in_east_north_up():
    view = FoxgloveView()
    rotors = transforms(view.feed(SCENE_KEY, scene_payload()), "/vehicle1/rotors")
    tf = transforms(view.feed(STATE_KEY, state_payload(0)))
    assert set(tf) == {"ned", "vehicle1"}
    # The rotors' frames come with the scene record (whatever order the truth arrives in).
    assert set(rotors) == {f"vehicle1/rotor{i}" for i in range(1, 5)}
    assert {t.parent_frame_id for t in rotors.values()} == {"vehicle1"}
    body = tf["vehicle1"]
    assert (body.parent_frame_id, body.translation.x, body.translation.z) == ("ned", 1.0, -3.0)
    q = quat_from_euler(0.1, -0.2, 0.3)
    assert [body.rotation.w, body.rotation.x, body.rotation.y, body.rotation.z] == \
        pytest.approx(list(q))
    # ned in world: north is world y, east world x, down world -z.
    r = tf["ned"].rotation
    ned_in_world = rotation_from_quat(np.array([r.w, r.x, r.y, r.z]))
    np.testing.assert_allclose(ned_in_world, [[0, 1, 0], [1, 0, 0], [0, 0, -1]], atol=1e-12)
    assert rotors["vehicle1/rotor2"].translation.y == 0.23


def test_outputs_are_decimated_on_sim_time_whatever_the_record_rate():
    view = FoxgloveView(rate_hz=50.0, path_hz=2.0)
    counts: dict[str, int] = {}
    for t_us in range(0, 2_000_000, 1000):  # a 1 kHz simulator for 2 s
        for out in view.feed(STATE_KEY, state_payload(t_us)):
            counts[out.topic] = counts.get(out.topic, 0) + 1
            assert out.sim_time_ns == t_us * 1000
    assert counts == {"/tf": 100, "/vehicle1/path": 4}


def test_the_path_keeps_the_last_minute_at_10_hz():
    view = FoxgloveView(rate_hz=10.0, path_hz=1.0)
    last = None
    for t_us in range(0, 90_000_000, 100_000):
        outs = view.feed(STATE_KEY, state_payload(t_us, position=(t_us / 1e6, 0.0, 0.0)))
        last = next((decoded(o.message) for o in outs if o.topic == "/vehicle1/path"), last)
    assert len(last.poses) == 600
    assert last.poses[0].position.x == pytest.approx(29.1)  # 600 samples up to 89.0 s
    assert last.poses[-1].position.x == pytest.approx(89.0)


def test_the_scene_draws_the_vehicle_mission_fence_home_and_rally():
    out, _rotors = FoxgloveView().feed(SCENE_KEY, scene_payload())
    entities = {e.id: e for e in decoded(out.message).entities}
    assert set(entities) == {"vehicle", "home", "mission", "fence", "rally"}
    vehicle = entities["vehicle"]
    assert vehicle.frame_id == "vehicle1" and len(vehicle.cylinders) == 4
    mission = entities["mission"]
    assert [(s.pose.position.x, s.pose.position.z) for s in mission.spheres] == \
        [(0.0, -5.0), (30.0, -5.0)]
    assert [s.size.x for s in mission.spheres] == [0.5, 0.8]  # the current item larger
    circle, polygon = entities["fence"].lines
    assert len(circle.points) == 64 and len(polygon.points) == 3
    radii = [math.hypot(p.x, p.y) for p in circle.points]
    assert radii == pytest.approx([25.0] * 64)


@pytest.mark.parametrize("fields, error", [
    ({"mission": [[0, 1.0, math.nan, 0.0]]}, "finite"),
    ({"mission": "all of them"}, "mission must be a list"),
    ({"mission": [[0, 1.0]]}, "expected 4 numbers"),
    ({"mission": [[i, 0.0, 0.0, 0.0] for i in range(600)]}, "at most 512"),
    ({"fence": [{"inclusion": "yes", "centre": [0, 0], "radius_m": 5}]}, "boolean"),
    ({"fence": [{"inclusion": True, "centre": [0, 0], "radius_m": -5}]}, "radius"),
    ({"airframe": {"rotors": [[0, 0, 0, 1]] * 17}}, "at most 16"),
    ({"current": 1.5}, "whole number"),
])
def test_a_bad_scene_record_is_refused_and_changes_nothing(fields, error):
    view = FoxgloveView()
    before = [(o.topic, o.message.encode()) for o in view.feed(SCENE_KEY, scene_payload())]
    payload = scene_payload(**fields)
    with pytest.raises(ValueError, match=error):
        view.feed(SCENE_KEY, payload)
    # Nothing kept of it: the good record converts as it did.
    assert [(o.topic, o.message.encode()) for o in view.feed(SCENE_KEY, scene_payload())] \
        == before


def test_plot_ready_channels_name_every_internal_and_encode_as_json():
    record = CONTROL.buffer()
    record["seq"], record["sim_time_us"], record["flags"] = 0, 20_000, 1
    record["theta_g"] = np.nan  # PID: no weights; plotted as gaps
    payload = record.encode(((0.1, 0.2), (), ()))
    outputs = {o.topic: o.message for o in FoxgloveView().feed(CONTROL_KEY, payload)}
    text = outputs["/vehicle1/controller"]
    controller = json.loads(encode(text))
    assert controller["armed"] and controller["theta_g"]["phi"] is None
    assert controller["phi"]["theta_f_norm"] == pytest.approx(math.hypot(0.1, 0.2))
    assert controller["theta"]["theta_f_norm"] is None
    assert text.schema == json_schema(controller)
    assert text.schema["properties"]["phi"]["properties"]["sliding_surface"]["type"] == \
        ["number", "null"]
    assert decoded(outputs["/vehicle1/reference"]).frame_id == "ned"


def _controller_as_a_dict(payload: bytes) -> dict:
    """The controller's record built the plain way (a dict for json.dumps), to hold the
    view's template to."""
    c = CONTROL.decode(payload)

    def number(x):
        return float(x) if math.isfinite(x) else None

    flags, mode = int(c["flags"]), int(c["mode"])
    v = c["measurement"][MEASUREMENT.velocity_ned_mps]
    record = {"t_s": int(c["sim_time_us"]) / 1e6,
              "mode": list(FlightMode)[mode].name if 0 <= mode < len(FlightMode) else "",
              "armed": bool(flags & 1), "failsafe": bool(flags & 4),
              "motors": [number(x) for x in c["motor_commands"]],
              "speed_mps": number(np.sqrt(v @ v))}
    for i, channel in enumerate(CHANNELS):
        record[channel] = {INTERNAL_NAMES[name]: number(c[f"ch_{name}"][i])
                           for name in CHANNEL_INTERNALS}
        if i < 3:
            w = c[("theta_f_phi", "theta_f_theta", "theta_f_psi")[i]]
            record[channel]["theta_f_norm"] = number(np.sqrt(w @ w)) if len(w) else None
    record["theta_g"] = {channel: number(c["theta_g"][i]) for i, channel in enumerate(CHANNELS)}
    return record


@pytest.mark.filterwarnings("ignore:overflow encountered in matmul:RuntimeWarning")  # the
# dict built here from huge values, as the view's own (which overflow quietly) to null
def test_the_controllers_json_is_json_dumps_of_its_record_byte_for_byte():
    """The template gives json.dumps's own bytes for any record: NaN and infinities as
    null, -0.0, the shortest float text with and without exponents, every mode. Half the
    records hold no number below 1e-4 (where orjson's text is Python's as it is), half
    hold them anywhere down to the smallest (where it is written again)."""
    rng = np.random.default_rng(7)
    special = np.array([np.nan, np.inf, -np.inf, -0.0, 0.0, 1e-4, -1e16, 1e300, 10.00001,
                        123456789.125, 0.1, 9999999999999998.0])
    tiny = np.array([5e-324, 1e-5, -9.999999999999999e-05, 2.2250738585072014e-308])
    record = CONTROL.buffer()
    view = FoxgloveView()
    for k in range(800):
        low, chosen = ((-4, 30), special) if k % 2 else ((-330, 30), np.r_[special, tiny])
        for name, kind, count in CONTROL.fields:
            if kind == "f8":
                values = rng.normal(size=count or None) * 10.0 ** rng.integers(
                    *low, size=count or None)
                if k % 2:
                    values = np.where(np.abs(values) < 1e-4, 1.0, values)
                pick = rng.random(count or ()) < 0.25
                record[name] = np.where(pick, rng.choice(chosen, size=count or None), values)
        if k % 4 == 3:  # one number that orjson writes 0.0000..., with no exponent about
            record["motor_commands"][k % 4] = rng.choice([-1, 1]) * rng.uniform(1e-5, 1e-4)
        record["seq"], record["sim_time_us"] = k, 20_000 * (k + 1)
        record["mode"], record["flags"] = int(rng.integers(-2, 20)), int(rng.integers(0, 8))
        payload = record.encode(tuple(tuple(rng.choice(special, size=rng.integers(0, 4)))
                                      for _ in range(3)))
        text = {o.topic: o.message for o in view.feed(CONTROL_KEY, payload)}[
            "/vehicle1/controller"]
        assert encode(text) == encode(_controller_as_a_dict(payload))


def test_records_too_short_to_hold_their_time_are_refused():
    with pytest.raises(ValueError, match="too short"):
        FoxgloveView().feed(STATE_KEY, b"\x00\x01\x00\x00" + b"\x00" * 10)


@pytest.mark.parametrize("key", [STATE_KEY, CONTROL_KEY])
def test_a_malformed_record_that_is_due_is_refused_and_leaves_the_next_draw_due(key):
    """The view reads the few fields it draws where they sit: a record of the right length
    but the wrong header, or sequences that do not fit, is refused, not drawn."""
    view = FoxgloveView()
    good = state_payload(0) if key == STATE_KEY else CONTROL.buffer().encode(((), (), ()))
    bad = [b"\x00\x00\x00\x00" + good[4:], good + bytes(8)]
    for payload in bad:
        with pytest.raises(ValueError):
            view.feed(key, payload)
    assert view.feed(key, good)  # still due: the refusals moved no decimation clock


def test_routes_to_the_drawing_are_remembered_for_a_bounded_number_of_keys():
    from ground.telemetry.foxglove_view import MAX_ROUTES

    view = FoxgloveView()
    for i in range(MAX_ROUTES + 100):
        assert view.feed(f"ivfm/vehicle/1/junk/k{i}", b"x") == []
    assert len(view._routes) == MAX_ROUTES  # noqa: SLF001
    assert transforms(view.feed(STATE_KEY, state_payload(0)))  # a new key still draws
    assert view.feed("mavlink/1/1/HEARTBEAT", b"\xfd") == []
    assert view.feed("ivfm/vehicle/0/sitl/state", state_payload(0)) == []  # vehicle 0


def test_every_plot_of_the_shipped_layout_names_a_field_the_view_writes():
    """The Foxglove layout (ground/telemetry/layouts) plots fields by path: each must exist."""
    import re
    from importlib.resources import files

    from contracts.telemetry import ESTIMATE

    layout = json.loads(files("ground.telemetry").joinpath(
        "layouts/ivfm-sitl.foxglove-layout.json").read_text())
    view = FoxgloveView()
    control = CONTROL.buffer()
    control["sim_time_us"] = 0
    estimate = ESTIMATE.buffer()
    outputs = view.feed(STATE_KEY, state_payload(0))
    outputs += view.feed(CONTROL_KEY, control.encode(((), (), ())))
    outputs += view.feed("ivfm/vehicle/1/autopilot/estimate", estimate.encode())
    plots = {o.topic: json.loads(encode(o.message)) for o in outputs
             if o.topic.endswith(("/controller", "/estimator"))}  # the JSON channels
    paths = [p["value"] for panel in layout["configById"].values() for p in panel.get("paths", [])]
    assert len(paths) == 28
    for path in paths:
        topic, _, fields = path.partition(".")
        value = plots[topic]
        for name, index in re.findall(r"([A-Za-z_]+)(?:\[(\d+)\])?", fields):
            value = value[name]
            if index:
                value = value[int(index)]
        assert value is None or isinstance(value, float), path
    topics = set(layout["configById"]["3D!scene"]["topics"]) | {"/log"}
    assert topics <= {o.topic for o in outputs} | {"/vehicle1/scene", "/log"}


def _estimate_payload(t_us: int, north_m: float) -> bytes:
    from contracts.telemetry import ESTIMATE

    record = ESTIMATE.buffer()
    record["sim_time_us"] = t_us
    record["position_ned_m"] = (north_m, 2.0, -3.0)
    record["quaternion"] = quat_from_euler(0.1, -0.2, 0.3)
    return record.encode()


@pytest.mark.parametrize("estimates_first", [True, False])
def test_the_estimate_is_drawn_against_the_truth_of_its_time_in_any_arrival_order(
        estimates_first):
    """The truth and the estimate come on two streams: whichever comes first, each
    estimate is paired with the truth at its own sim time (a lockstep log is the same
    on every run)."""
    view = FoxgloveView(rate_hz=50.0)
    truths = [(STATE_KEY, state_payload(t, position=(t / 1e6, 2.0, -3.0)))
              for t in range(0, 200_000, 20_000)]
    estimates = [("ivfm/vehicle/1/autopilot/estimate", _estimate_payload(t, t / 1e6 + 0.5))
                 for t in range(0, 200_000, 20_000)]
    order = estimates + truths if estimates_first else \
        [r for pair in zip(truths, estimates, strict=True) for r in pair]
    drawn = [o.message for key, payload in order for o in view.feed(key, payload)
             if o.topic == "/vehicle1/estimator"]
    assert [d["t_s"] for d in drawn] == pytest.approx([k * 0.02 for k in range(10)])
    assert [d["position_error_m"]["n"] for d in drawn] == pytest.approx([0.5] * 10)
    assert all(d["truth_age_s"] == 0 for d in drawn)


@pytest.mark.process
def test_ivfm_ground_view_serves_what_it_hears_over_zenoh(tmp_path):
    """`ivfm ground view` as a process: records published on a real Zenoh session reach a
    WebSocket client as Foxglove messages; a hostile scene record is said and skipped."""
    import signal
    import subprocess
    import sys
    import threading
    import time

    from contracts.zenoh_link import ZenohOptions, open_session
    from ground.run.children import free_tcp_port
    from tests.foxglove_client import collect

    endpoint, port = f"tcp/127.0.0.1:{free_tcp_port()}", free_tcp_port()
    session = open_session(ZenohOptions("peer", listen=[endpoint], connect=[]))
    view = subprocess.Popen([sys.executable, "-m", "ground.cli", "ground", "view", "--view",
                             f"127.0.0.1:{port}", "--zenoh-connect", endpoint],
                            stderr=subprocess.PIPE, text=True,  # stops on SIGINT, as Ctrl-C
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    got: dict = {}
    watcher = threading.Thread(target=lambda: got.update(received=collect(
        f"ws://127.0.0.1:{port}", 20.0, until=lambda r: len(r.messages["/tf"]) >= 40)))
    try:
        watcher.start()
        # Until the view's subscriber is there: a second's sleep, before, let the first
        # (hostile) record go to nobody while the view still started beside busy work.
        scene = session.declare_publisher(SCENE_KEY)
        deadline = time.monotonic() + 60.0
        while not scene.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.01)
        scene.put(scene_payload(mission=[[0, 1.0, 0.0, 0.0]] * 600))  # refused
        for t_us in range(0, 4_000_000, 10_000):  # 100 Hz for 4 s of sim time
            session.put(STATE_KEY, state_payload(t_us))
            if t_us % 500_000 == 0:
                session.put(SCENE_KEY, scene_payload())
            time.sleep(0.002)
        watcher.join(timeout=30)
    finally:
        session.close()
        view.send_signal(signal.SIGINT)
        _, err = view.communicate(timeout=20)
    received = got["received"]
    assert {"/tf", "/vehicle1/scene", "/vehicle1/path"} <= received.topics()
    stamps = np.array([t for t, _ in received.messages["/tf"]])
    assert len(stamps) >= 40, received.summary()
    assert np.all(np.diff(stamps) == 20_000_000)  # 50 Hz of sim time
    assert "cannot draw a record on ivfm/vehicle/1/autopilot/scene" in err
    assert "at most 512" in err and view.returncode == 0


def test_a_long_statustext_is_one_log_message_when_its_chunks_are_in():
    from contracts.mavlink import new_mavlink, statustext_messages
    from contracts.telemetry import MIRROR_ATTACHMENT

    mav = new_mavlink(1, 1)
    text = "geofence breached: 31.2 m from home, beyond 30 m; GF_ACTION hold" * 2
    view = FoxgloveView()
    logs = []
    for i, msg in enumerate(statustext_messages(4, text, 7)):
        logs += view.feed("mavlink/1/1/STATUSTEXT", msg.pack(mav),
                          MIRROR_ATTACHMENT.pack(i, 5_000_000))
    (log,) = logs
    assert log.topic == "/log" and log.sim_time_ns == 5_000_000_000
    assert decoded(log.message).message == text
