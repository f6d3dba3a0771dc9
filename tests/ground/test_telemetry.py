"""The Zenoh telemetry, the MCAP logger and perturbation requests, as processes."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from contracts.telemetry import CONTROL, STATE, TIMING, pack_batch, vehicle_key
from contracts.zenoh_link import ZenohOptions, open_session
from ground.record.run_files import control_records, iter_messages
from ground.run.children import LoggerProcess, free_tcp_port
from ground.run.loader import ProcessRunError
from ground.run.processes import RunSettings, vehicle_commands
from ground.scenario.scenario_file import scenario_by_name
from ground.uplink.perturb import PerturbationClient, PerturbationError

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402


def _endpoint() -> str:
    return f"tcp/127.0.0.1:{free_tcp_port()}"


class Vehicle:
    """A simulator + autopilot pair flying a scenario, with Zenoh to ``endpoint``."""

    def __init__(self, tmp: Path, endpoint: str, vehicle: int = 1, realtime: bool = False,
                 duration_s: float = 5.0, hold: bool = False,
                 zenoh_args: list[str] | None = None) -> None:
        scenario = dataclasses.replace(scenario_by_name("attitude-sine"), duration_s=duration_s)
        settings = RunSettings("ivfc", "paper", "paper", realtime=realtime, vehicle=vehicle)
        sim, ap = vehicle_commands(scenario, settings, free_tcp_port(), endpoint)
        if not hold:
            sim.remove("--hold")
        if zenoh_args is not None:  # replace the endpoint arguments
            for cmd in (sim, ap):
                i = cmd.index("--zenoh-connect")
                del cmd[i:i + 2]
                cmd += zenoh_args
        self.logs = [tmp / f"sitl-{vehicle}.log", tmp / f"autopilot-{vehicle}.log"]
        self.procs = [subprocess.Popen(cmd, stdout=open(log, "w"), stderr=subprocess.STDOUT)  # noqa: SIM115
                      for cmd, log in zip((sim, ap), self.logs, strict=True)]

    def wait(self, timeout_s: float = 60.0) -> None:
        for proc in self.procs:
            proc.wait(timeout_s)
        assert self.procs[1].returncode == 0, self.logs[1].read_text()

    def kill(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


@pytest.fixture
def session():
    """The test's ground session, connecting to where the test's logger will listen."""
    endpoint = _endpoint()
    s = open_session(ZenohOptions(listen=["tcp/127.0.0.1:0"], connect=[endpoint]))
    yield s, endpoint
    s.close()


def _wait_heard(logger: LoggerProcess, s: zenoh.Session, keys: list[str], final: bool):
    return logger.wait_until(s, keys, final=final, timeout_s=60.0)


def _fly_logged(logger: LoggerProcess, s: zenoh.Session, vehicle: Vehicle,
                keys: list[str]) -> dict:
    """Release a held vehicle once the logger hears it; the logger's status at its end."""
    _wait_heard(logger, s, keys, final=False)
    PerturbationClient(session=s).start(1)
    vehicle.wait()
    return _wait_heard(logger, s, keys, final=True)


@pytest.mark.process
def test_log_holds_every_record_and_decodes_with_ros2_cdr(tmp_path, session):
    s, endpoint = session
    logger = LoggerProcess(tmp_path / "log", endpoint, tmp_path / "logger.log")
    vehicle = Vehicle(tmp_path, endpoint, duration_s=3.0, hold=True)
    keys = [vehicle_key(1, p, "status") for p in ("sitl", "autopilot")]
    try:
        status = _fly_logged(logger, s, vehicle, keys)
    finally:
        vehicle.kill()
        assert logger.stop() == 0
    published = {}
    for key in keys:
        published.update(status["heard"][key]["published"])
    assert published[vehicle_key(1, "autopilot", "control")] == 300
    # Count the log with the mcap package itself: every published record is there.
    counts: dict[str, int] = {}
    decoded = {}
    files = sorted((tmp_path / "log").glob("*.mcap"))
    assert len(files) == 1 and not list((tmp_path / "log").glob("*.active"))
    with open(files[0], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for schema, channel, message, ros_msg in reader.iter_decoded_messages(
                topics=[vehicle_key(1, "autopilot", "control"), vehicle_key(1, "sitl", "state"),
                        vehicle_key(1, "autopilot", "timing")]):
            decoded.setdefault(channel.topic, (schema, message, ros_msg))
    for channel_id, channel in summary.channels.items():
        counts[channel.topic] = summary.statistics.channel_message_counts.get(channel_id, 0)
    for key, n in published.items():
        if n:
            assert counts.get(key) == n, key
    # An independent CDR decoder (mcap_ros2) reads our records field for field.
    for key, schema in ((vehicle_key(1, "autopilot", "control"), CONTROL),
                        (vehicle_key(1, "sitl", "state"), STATE),
                        (vehicle_key(1, "autopilot", "timing"), TIMING)):
        mcap_schema, message, ros_msg = decoded[key]
        assert mcap_schema.encoding == "ros2msg"
        ours = schema.decode(message.data)
        for name in ours:
            np.testing.assert_array_equal(np.asarray(getattr(ros_msg, name)), ours[name], name)
    assert decoded[vehicle_key(1, "autopilot", "control")][2].theta_f_phi  # non-empty


@pytest.mark.process
def test_logger_killed_mid_run_is_salvaged_up_to_the_last_second(tmp_path, session):
    s, endpoint = session
    log_dir = tmp_path / "log"
    logger = LoggerProcess(log_dir, endpoint, tmp_path / "logger.log")
    vehicle = Vehicle(tmp_path, endpoint, realtime=True, duration_s=8.0)
    try:
        _wait_heard(logger, s, [vehicle_key(1, "autopilot", "status")], final=False)
        time.sleep(3.0)
        logger.proc.send_signal(signal.SIGKILL)
        killed_ns = time.time_ns()
        logger.proc.wait()
        assert list(log_dir.glob("*.mcap.active"))
        # The control loop does not notice: the autopilot flies on to its end.
        vehicle.wait()
    finally:
        vehicle.kill()
        logger.stop()
    again = LoggerProcess(log_dir, _endpoint(), tmp_path / "logger2.log", name="again")
    time.sleep(0.5)
    try:
        deadline = time.monotonic() + 30
        while list(log_dir.glob("*.mcap.active")) != [log_dir / "telemetry-001.mcap.active"]:
            assert time.monotonic() < deadline, (tmp_path / "logger2.log").read_text()
            time.sleep(0.1)
    finally:
        assert again.stop() == 0
    assert "salvaged" in (tmp_path / "logger2.log").read_text()
    key = vehicle_key(1, "autopilot", "control")
    seqs, log_times = [], []
    for topic, message, data in iter_messages(log_dir / "telemetry-000.mcap", key):
        if topic == key:
            seqs.append(CONTROL.decode(data)["seq"])
            log_times.append(message.log_time)
    assert seqs == list(range(len(seqs)))  # nothing missing up to the last chunk
    assert len(seqs) > 100
    lost_s = (killed_ns - max(log_times)) / 1e9
    assert lost_s < 1.0, f"salvage lost the last {lost_s:.2f} s"
    timing = json.loads((tmp_path / "autopilot-1.log").read_text().split("timing ")[-1]
                        .splitlines()[0])
    assert timing["steps"] == 800


@pytest.mark.process
def test_vehicles_fly_without_a_logger(tmp_path):
    """A Zenoh outage (nobody listening at all) never stalls lockstep."""
    vehicle = Vehicle(tmp_path, _endpoint(), duration_s=5.0)
    try:
        vehicle.wait(timeout_s=60.0)
    finally:
        vehicle.kill()
    assert "stopped after 500 control steps" in vehicle.logs[1].read_text()


@pytest.mark.process
def test_bad_requests_and_payloads_are_refused_and_change_nothing(tmp_path, session):
    s, endpoint = session
    logger = LoggerProcess(tmp_path / "log", endpoint, tmp_path / "logger.log")
    vehicle = Vehicle(tmp_path, endpoint, duration_s=30.0, hold=True)
    client = PerturbationClient(session=s, timeout_s=5.0)
    try:
        client.wait_for(1, "sitl", 30.0)
        client.wait_for(1, "autopilot", 30.0)
        good = client.perturb(1, "wind", start_s=1.0, end_s=2.0, ned_mps=[1.0, 0.0, 0.0])
        assert good["start_s"] == 1.0 and good["id"]
        before = {t: client.list(1, t) for t in ("sitl", "autopilot")}
        both = ("sitl", "autopilot")
        bad_requests = [
            (both, {"kind": "earthquake"}, "unknown perturbation kind"),
            # The long fuzz run's find: a list as the kind raised TypeError out of the
            # request handler, which would have ended both processes' loops.
            (both, {"kind": []}, "unknown perturbation kind"),
            (both, {"op": "explode"}, "unknown op"),
            (("sitl",), {"kind": "mass", "scale": 1e6}, "must be a number in"),
            (("sitl",), {"kind": "motor_failure", "motor": 5}, "must be a number in"),
            (("sitl",), {"kind": "mass", "scale": 1.1, "colour": "red"}, "unknown field"),
            (("sitl",), {"kind": "mass", "scale": 1.1, "id": good["id"]}, "exists already"),
            (("sitl",), {"kind": "kick", "phi_rad": 0.1}, "acts in the autopilot"),
            (("sitl",), {"kind": "gust", "ned_mps": [1, 0, 0]}, "needs an end_s"),
            (("autopilot",), {"kind": "kick", "phi_rad": 2.0}, "must be a number in"),
            (("autopilot",), {"kind": "kick", "start_s": 1, "end_s": 0.5}, "before"),
            (("autopilot",), {"kind": "mass", "scale": 1.1}, "acts in the sitl"),
        ]
        for targets, request, text in bad_requests:
            for target in targets:
                with pytest.raises(PerturbationError, match=text):
                    client.query(1, target, "perturb", request)
        # Raw payloads: not JSON, not an object, NaN and infinity literals.
        for raw, text in ((b"\xff\x00 not json", "not JSON"), (b"[1, 2]", "JSON object"),
                          (b'{"kind": "mass", "scale": NaN}', "must be a number in"),
                          (b'{"kind": "wind", "ned_mps": [Infinity, 0, 0]}',
                           "must be a number in")):
            replies = list(s.get(vehicle_key(1, "sitl", "perturb"), payload=raw, timeout=5.0))
            assert len(replies) == 1 and replies[0].err is not None, raw
            assert text in replies[0].err.payload.to_bytes().decode(), raw
        # A vehicle that does not exist: no answer, said so.
        with pytest.raises(PerturbationError, match="no answer"):
            PerturbationClient(session=s, timeout_s=1.0).perturb(7, "mass", scale=1.1)
        after = {t: client.list(1, t) for t in ("sitl", "autopilot")}
        assert after == before
        # Malformed telemetry on the contract's keys: the logger refuses it, keeps the rest.
        pub = s.declare_publisher(vehicle_key(9, "autopilot", "control"))
        pub.put(b"\x00\x01\x00\x00garbage")
        s.put(vehicle_key(9, "sitl", "status"), b"{not json")
        s.put("mavlink/9/1/HEARTBEAT", b"\xfd\x09")  # no attachment
        # A batch that does not parse, and one holding another vehicle's record: refused
        # whole; a good batch's records are written on their own keys.
        s.put(vehicle_key(9, "autopilot", "batch"), b"IVB1\x01\x00garbage")
        good_payload = CONTROL.buffer().encode(((), (), ()))
        s.put(vehicle_key(9, "autopilot", "batch"), pack_batch(
            [vehicle_key(8, "autopilot", "control")], [0], [good_payload], [b""]))
        s.put(vehicle_key(9, "autopilot", "batch"), pack_batch(
            [vehicle_key(9, "autopilot", "timing")], [0], [TIMING.buffer().encode()], [b""]))
        pub.put(good_payload)
        deadline = time.monotonic() + 10
        while True:
            status = logger.status(s)
            if status and status["rejected"] >= 5 and \
                    status["per_key"].get(vehicle_key(9, "autopilot", "control")):
                break
            assert time.monotonic() < deadline, status
            time.sleep(0.1)
        assert status["rejected"] == 5
        assert status["per_key"][vehicle_key(9, "autopilot", "control")] == 1
        assert status["per_key"][vehicle_key(9, "autopilot", "timing")] == 1
        assert status["rejected_per_key"][vehicle_key(9, "autopilot", "batch")] == 2
        # ... and the vehicle flies its run once started, with only the good perturbation.
        client.start(1)
        vehicle.wait()
    finally:
        vehicle.kill()
        assert logger.stop() == 0
    log = (tmp_path / "logger.log").read_text()
    assert "refused a record on ivfm/vehicle/9/autopilot/control" in log
    assert "stopped after 3000 control steps" in vehicle.logs[1].read_text()
    sim_log = vehicle.logs[0].read_text()
    assert f"t=1.000 s perturbation {good['id']} (wind) start" in sim_log
    assert sim_log.count("perturbation sitl-") == 2  # its start and its end, nothing else


@pytest.mark.process
def test_three_vehicles_into_one_logger_separated_by_vehicle(tmp_path, session):
    s, endpoint = session
    logger = LoggerProcess(tmp_path / "log", endpoint, tmp_path / "logger.log")
    vehicles = [Vehicle(tmp_path, endpoint, vehicle=v, duration_s=4.0, hold=True)
                for v in (1, 2, 3)]
    client = PerturbationClient(session=s)
    keys = [vehicle_key(v, p, "status") for v in (1, 2, 3) for p in ("sitl", "autopilot")]
    try:
        _wait_heard(logger, s, keys, final=False)
        client.perturb(2, "mass", start_s=1.0, scale=1.2)  # only vehicle 2 is perturbed
        for v in (1, 2, 3):
            client.start(v)
        for vehicle in vehicles:
            vehicle.wait()
        _wait_heard(logger, s, keys, final=True)
    finally:
        for vehicle in vehicles:
            vehicle.kill()
        assert logger.stop() == 0
    records = {v: control_records(tmp_path / "log", v) for v in (1, 2, 3)}
    for v in (1, 2, 3):
        assert len(records[v]["seq"]) == 400 and records[v]["missing_count"] == 0
    # 1 and 3 flew the same unperturbed flight; 2 carried 20 % more mass from t = 1 s.
    np.testing.assert_array_equal(records[1]["measurement"], records[3]["measurement"])
    assert np.max(np.abs(records[1]["measurement"] - records[2]["measurement"])) > 1e-4
    masses = [json.loads(d) for t, _m, d in iter_messages(tmp_path / "log", "ivfm/vehicle/")
              if t.endswith("/sitl/perturbation")]
    assert [(m["kind"], m["event"]) for m in masses] == [("mass", "start")]
    assert {t.split("/")[1] for t, _m, _d in iter_messages(tmp_path / "log", "mavlink/")} \
        == {"1", "2", "3"}


@pytest.mark.process
def test_vehicle_and_logger_meet_only_through_the_router(tmp_path):
    router_endpoint = _endpoint()
    router_log = open(tmp_path / "router.log", "w")  # noqa: SIM115
    router = subprocess.Popen([sys.executable, "-m", "ground.cli", "ground", "router",
                               "--listen", router_endpoint],
                              stdout=router_log, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 30
    while "listening" not in (tmp_path / "router.log").read_text():
        assert time.monotonic() < deadline and router.poll() is None
        time.sleep(0.05)
    client_args = ["--zenoh-mode", "client", "--zenoh-connect", router_endpoint]
    logger = LoggerProcess(tmp_path / "log", "none", tmp_path / "logger.log",
                           extra=["--zenoh-mode", "client", "--zenoh-connect",
                                  router_endpoint])
    vehicle = Vehicle(tmp_path, "unused", duration_s=3.0, hold=True, zenoh_args=client_args)
    s = open_session(ZenohOptions("client", connect=[router_endpoint]))
    keys = [vehicle_key(1, p, "status") for p in ("sitl", "autopilot")]
    try:
        status = _fly_logged(logger, s, vehicle, keys)
    finally:
        vehicle.kill()
        logger_rc = logger.stop()
        s.close()
        router.send_signal(signal.SIGINT)
        router.wait(10)
        router_log.close()
    assert logger_rc == 0
    assert status["per_key"][vehicle_key(1, "autopilot", "control")] == 300
    assert "router: listening on " + router_endpoint in (tmp_path / "router.log").read_text()


@pytest.mark.process
def test_tlog_export_reads_in_pymavlink(tmp_path):
    run_dir = tmp_path / "run"
    from ground.cli.main import main

    assert main(["run", "position-kick", "--out", str(run_dir), "--no-figures"]) == 0
    assert main(["ground", "tlog", str(run_dir)]) == 0
    tlog = run_dir / "telemetry.tlog"
    conn = mavutil.mavlink_connection(str(tlog))
    kinds: dict[str, int] = {}
    last_t = -math.inf
    while (msg := conn.recv_match()) is not None:
        kinds[msg.get_type()] = kinds.get(msg.get_type(), 0) + 1
        assert msg._timestamp >= last_t - 1.0
        last_t = msg._timestamp
    run = json.loads((run_dir / "run.json").read_text())
    published = run["telemetry"]["published"]
    for name in ("HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT",
                 "HIL_ACTUATOR_CONTROLS"):
        assert kinds[name] == published[f"mavlink/1/1/{name}"], name
    assert kinds["HIL_ACTUATOR_CONTROLS"] == 2000


@pytest.mark.process
def test_a_logger_on_a_taken_port_says_so(tmp_path):
    with socket.create_server(("127.0.0.1", 0)) as taken:
        endpoint = f"tcp/127.0.0.1:{taken.getsockname()[1]}"
        logger = LoggerProcess(tmp_path, endpoint, tmp_path / "logger.log")
        s = open_session(ZenohOptions(connect=[_endpoint()]))
        try:
            with pytest.raises(ProcessRunError, match="the logger exited"):
                logger.wait_until(s, ["x"], final=False, timeout_s=20.0)
        finally:
            logger.stop()
            s.close()
    assert "cannot open a zenoh session" in (tmp_path / "logger.log").read_text()


def test_the_logger_starts_a_new_file_past_its_chunk_cap(tmp_path):
    """The MCAP writer keeps each chunk's index in memory until its file is finished: the
    chunk cap is what keeps a long run's logger memory flat. In process, no Zenoh."""
    from contracts.telemetry import json_record
    from ground.telemetry.logger import Logger, LoggerConfig

    config = LoggerConfig(tmp_path, ZenohOptions(enabled=False), rotate_chunks=16)
    logger = Logger(config, log=lambda _text: None)
    logger.files.start()
    key = vehicle_key(1, "autopilot", "status")
    for seq in range(40):  # one record per chunk: files of 16, 16 and 8 records
        logger._write(key, json_record(seq, seq * 1000, final=False), None, seq)
        logger.files.flush()
    logger.files.file.finish()
    files = sorted(tmp_path.glob("*.mcap"))
    assert [p.name for p in files] == [f"telemetry-00{i}.mcap" for i in range(3)]
    assert [len(list(iter_messages(p))) for p in files] == [16, 16, 8]
    with pytest.raises(ValueError, match="at least 16"):
        LoggerConfig(tmp_path, ZenohOptions(enabled=False), rotate_chunks=15)


def test_records_are_filled_by_name_and_decode_to_the_same_values():
    from contracts.telemetry import STATE
    from contracts.vectors import CHANNEL_INTERNALS, MEASUREMENT, REFERENCE

    record = CONTROL.buffer()
    record["seq"], record["sim_time_us"], record["mode"] = 7, 123_000, 4
    measurement = np.arange(MEASUREMENT.size, dtype=float)
    record["measurement"] = measurement
    record["ch_e"] = np.full(6, -1.5)
    decoded = CONTROL.decode(record.encode((np.ones(3), (), np.zeros(2))))
    assert (decoded["seq"], decoded["sim_time_us"], decoded["mode"]) == (7, 123_000, 4)
    np.testing.assert_array_equal(decoded["measurement"], measurement)
    np.testing.assert_array_equal(decoded["ch_e"], np.full(6, -1.5))
    np.testing.assert_array_equal(decoded["reference"], np.zeros(REFERENCE.size))
    np.testing.assert_array_equal(decoded["theta_f_phi"], np.ones(3))
    assert decoded["measurement"][MEASUREMENT.euler_rad].tolist() == [6.0, 7.0, 8.0]
    internals = record.block(tuple(f"ch_{name}" for name in CHANNEL_INTERNALS))
    table = np.arange(6.0 * len(CHANNEL_INTERNALS)).reshape(6, -1)  # channels x internals
    internals[...] = table.T
    decoded = CONTROL.decode(record.encode(((), (), ())))
    for i, name in enumerate(CHANNEL_INTERNALS):
        np.testing.assert_array_equal(decoded[f"ch_{name}"], table[:, i])
    with pytest.raises(ValueError, match="not consecutive"):
        record.block(("measurement", "reference"))
    with pytest.raises(ValueError, match="takes 3 sequences"):
        record.encode(())
    with pytest.raises(KeyError):
        STATE.buffer()["no_such_field"] = 1.0


def test_a_field_read_at_its_offset_is_the_decoded_field():
    """Readers that need a few fields (the Foxglove view) read them at ``offset``."""
    import struct

    from contracts.telemetry import STATE

    rng = np.random.default_rng(5)
    for schema in (STATE, CONTROL):
        record = schema.buffer()
        for name, kind, count in schema.fields:
            record[name] = rng.normal(size=count or None) if kind == "f8" else \
                rng.integers(0, 1000, size=count or None)
        payload = record.encode(tuple(rng.normal(size=2) for _ in schema.sequences))
        decoded = schema.decode(payload)
        for name, kind, count in schema.fields:
            for i in range(count or 1):
                (value,) = struct.unpack_from("<" + {"f8": "d", "i8": "q", "u8": "Q"}[kind],
                                              payload, schema.offset(name, i))
                assert value == (decoded[name][i] if count else decoded[name]), name
        assert [a.tobytes() for a in schema.sequence_arrays(payload)] == \
            [decoded[name].tobytes() for name in schema.sequences]


def test_records_decoded_many_at_once_are_those_decoded_one_by_one():
    """A log read back decodes its control records at once (``decode_many``): the same
    numbers, bit for bit, as ``decode`` gives each; a payload that does not fit is refused
    as ``decode`` refuses it."""
    rng = np.random.default_rng(3)
    record = CONTROL.buffer()
    payloads = []
    for k in range(50):
        for name, kind, count in CONTROL.fields:
            if kind == "f8":
                record[name] = np.where(rng.random(count or ()) < 0.1, np.nan,
                                        rng.normal(size=count or None))
        record["seq"], record["sim_time_us"], record["mode"] = k, 10_000 * k, k % 7
        payloads.append(record.encode(tuple(rng.normal(size=rng.integers(0, 5))
                                            for _ in CONTROL.sequences)))
    rows, sequences = CONTROL.decode_many(payloads)
    for row, seqs, payload in zip(rows, sequences, payloads, strict=True):
        one = CONTROL.decode(payload)
        for name, _kind, _count in CONTROL.fields:
            assert np.asarray(row[name]).tobytes() == np.asarray(one[name]).tobytes(), name
        for name, values in zip(CONTROL.sequences, seqs, strict=True):
            assert values.tobytes() == one[name].tobytes(), name
    for bad in (payloads[0][:-8], payloads[0] + b"\0" * 8, b"\xff" * 4 + payloads[0][4:]):
        with pytest.raises(ValueError):
            CONTROL.decode(bad)
        with pytest.raises(ValueError):
            CONTROL.decode_many([payloads[1], bad])
