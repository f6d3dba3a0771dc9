"""Telemetry batches: the records of a span of sim time in one put (contracts/telemetry.py
pack_batch / unpack_batch, contracts/telemetry_node.py). The format round-trips and
refuses what does not parse or what its sender does not publish; a node sends its
records per span of sim time, its JSON records after the batch before them, a full
batch at once, a stale one after a span of wall time, the last one on close (real Zenoh
sessions on loopback)."""

from __future__ import annotations

import struct
import threading
import time

import pytest

from contracts.telemetry import (
    CONTROL,
    MIRROR_ATTACHMENT,
    STATE,
    pack_batch,
    unbatched,
    unpack_batch,
    vehicle_key,
)
from contracts.telemetry_node import BATCH_MAX_RECORDS, TelemetryNode
from contracts.zenoh_link import ZenohOptions, open_session
from ground.run.children import free_tcp_port

AP_BATCH = "ivfm/vehicle/1/autopilot/batch"
CONTROL_KEY = "ivfm/vehicle/1/autopilot/control"
MIRROR_KEY = "mavlink/1/1/HIL_ACTUATOR_CONTROLS"


def _records() -> list[tuple[str, bytes, bytes | None]]:
    control = CONTROL.buffer()
    out = []
    for seq in range(5):
        control["seq"], control["sim_time_us"] = seq, seq * 10_000
        out.append((CONTROL_KEY, control.encode(((1.0,), (), (2.0, 3.0))), None))
        out.append((MIRROR_KEY, bytes([0xFD, seq]) + b"frame",
                    MIRROR_ATTACHMENT.pack(seq, seq * 10_000)))
    return out


def _pack(records) -> bytes:
    keys = list(dict.fromkeys(k for k, _, _ in records))
    return pack_batch(keys, [keys.index(k) for k, _, _ in records], [p for _, p, _ in records],
                      [a or b"" for _, _, a in records])


def test_a_batch_gives_back_its_records_in_order_with_their_attachments():
    records = _records()
    assert unpack_batch(AP_BATCH, _pack(records)) == records
    assert unbatched(AP_BATCH, _pack(records), None) == records
    assert unbatched(CONTROL_KEY, b"payload", None) == [(CONTROL_KEY, b"payload", None)]


@pytest.mark.parametrize("mangle, reason", [
    (lambda b: b"IVB2" + b[4:], "does not start with IVB1"),
    (lambda b: b[:-1], "records take"),
    (lambda b: b + b"\x00", "records take"),
    (lambda b: b[:5], "does not parse"),
    (lambda b: b[:9], "is not one its sender publishes"),  # cut inside its first key
    (lambda b: b[:4] + struct.pack("<H", 2000) + b[6:], "keys is over"),
])
def test_a_batch_that_does_not_parse_is_refused_saying_why(mangle, reason):
    with pytest.raises(ValueError, match=reason):
        unpack_batch(AP_BATCH, mangle(_pack(_records())))


@pytest.mark.parametrize("key", [
    "ivfm/vehicle/2/autopilot/control",  # another vehicle's
    "ivfm/vehicle/1/sitl/state",  # the other process's
    "mavlink/2/1/HEARTBEAT",  # a mirror of another vehicle
    "ivfm/vehicle/1/autopilot/batch",  # a batch inside a batch
])
def test_a_batch_holding_keys_its_sender_does_not_publish_is_refused(key):
    with pytest.raises(ValueError, match="refused"):
        unpack_batch(AP_BATCH, _pack([(key, b"x", None)]))
    # The simulator's batches carry only its own mirror frames (component 51: the
    # readings it sent, --log-sensors), never the autopilot's.
    with pytest.raises(ValueError, match="not one its sender publishes"):
        unpack_batch("ivfm/vehicle/1/sitl/batch", _pack([(MIRROR_KEY, b"\xfd", None)]))
    with pytest.raises(ValueError, match="not one its sender publishes"):
        unpack_batch("ivfm/vehicle/1/sitl/batch",
                     _pack([("mavlink/2/51/HIL_SENSOR", b"\xfd", None)]))
    own = [("mavlink/1/51/HIL_SENSOR", b"\xfd", b"attached")]
    assert unpack_batch("ivfm/vehicle/1/sitl/batch", _pack(own)) == own


def test_a_key_index_past_the_table_and_an_empty_batch_are_refused():
    good = _pack([(CONTROL_KEY, b"x", None)])
    at = 4 + 2 + 2 + len(CONTROL_KEY) + 4  # magic, key count, key, record count
    with pytest.raises(ValueError, match="names key 3 of 1"):
        unpack_batch(AP_BATCH, good[:at] + struct.pack("<H", 3) + good[at + 2:])
    with pytest.raises(ValueError, match="1-65535 records"):
        pack_batch([CONTROL_KEY], [], [], [])


class _Heard:
    """What a subscriber on loopback hears of a node's keys, in order."""

    def __init__(self, endpoint: str) -> None:
        self.session = open_session(ZenohOptions(connect=[endpoint]))
        self.puts: list[tuple[str, bytes]] = []
        self.route_up = False
        self.lock = threading.Lock()
        self.sub = self.session.declare_subscriber("ivfm/vehicle/**", self._on)

    def _on(self, sample) -> None:
        key = str(sample.key_expr)
        with self.lock:
            if key.endswith("/probe"):  # the route is up
                self.route_up = True
            else:
                self.puts.append((key, sample.payload.to_bytes()))

    def wait(self, count: int, timeout_s: float = 5.0) -> list[tuple[str, bytes]]:
        deadline = time.monotonic() + timeout_s
        while len(self.puts) < count and time.monotonic() < deadline:
            time.sleep(0.005)
        with self.lock:
            return list(self.puts)

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


def _route(node: TelemetryNode, ear: _Heard) -> None:
    """Until the node's puts reach the ear (a key outside the contract goes on its own)."""
    probe = node.publisher("probe")
    deadline = time.monotonic() + 5.0
    while not ear.route_up and time.monotonic() < deadline:
        probe.put(b"{}")
        time.sleep(0.02)
    assert ear.route_up


@pytest.fixture
def node_and_ear():
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    node = TelemetryNode(ZenohOptions(listen=[endpoint], batch_s=0.02), 1, "sitl",
                         log=lambda text: None)
    ear = _Heard(endpoint)
    _route(node, ear)
    yield node, ear
    ear.close()
    node.close()


def _state(seq: int) -> bytes:
    record = STATE.buffer()
    record["seq"], record["sim_time_us"] = seq, seq * 10_000
    return record.encode()


def test_a_node_sends_a_span_of_sim_time_in_one_put_and_json_after_it(node_and_ear):
    node, ear = node_and_ear
    state = node.publisher("state")
    state_key = vehicle_key(1, "sitl", "state")
    for seq in range(5):  # 0, 10, 20, 30, 40 ms of sim time; the span is 20 ms
        state.put(_state(seq))
        node.end_step(seq * 10_000)
    time.sleep(0.1)
    heard = ear.wait(3)
    assert [k for k, _ in heard] == ["ivfm/vehicle/1/sitl/batch"] * 3  # at 0, 20, 40 ms
    assert [[STATE.decode(p)["seq"] for _, p, _ in unpack_batch(k, b)] for k, b in heard] \
        == [[0], [1, 2], [3, 4]]
    state.put(_state(5))  # waits for its span ...
    node.status(50_000, force=True)  # ... unless a JSON record follows it
    heard = ear.wait(5)[3:]
    assert [k for k, _ in heard] == ["ivfm/vehicle/1/sitl/batch", "ivfm/vehicle/1/sitl/status"]
    assert unpack_batch(*heard[0])[0][0] == state_key
    assert state.count == 6 and node.counts()[state_key] == 6


def test_a_full_batch_goes_at_once_and_a_stale_one_after_a_span_of_wall_time(node_and_ear):
    node, ear = node_and_ear
    state = node.publisher("state")
    for seq in range(BATCH_MAX_RECORDS):  # no end of step: sim time stands still
        state.put(_state(seq))
    before_s = time.monotonic()  # no later than the next record comes
    state.put(_state(BATCH_MAX_RECORDS))
    node.flush_stale(before_s)  # younger than a span (20 ms) of wall time: it waits
    node.flush_stale(before_s + 0.019)
    heard = ear.wait(1)
    assert len(heard) == 1 and len(unpack_batch(*heard[0])) == BATCH_MAX_RECORDS
    time.sleep(0.05)
    assert len(ear.wait(1)) == 1
    node.flush_stale(time.monotonic() + 0.02)  # a span later
    assert len(unpack_batch(*ear.wait(2)[1])) == 1


def test_close_sends_what_waits_and_a_zero_span_sends_each_record_alone():
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    for batch_s, expected in ((0.02, ["ivfm/vehicle/1/sitl/batch"]),
                              (0.0, ["ivfm/vehicle/1/sitl/state"] * 2)):
        node = TelemetryNode(ZenohOptions(listen=[endpoint], batch_s=batch_s), 1, "sitl",
                             log=lambda text: None)
        ear = _Heard(endpoint)
        try:
            _route(node, ear)
            state = node.publisher("state")
            state.put(_state(0))
            state.put(_state(1))
            node.close()
            assert [k for k, _ in ear.wait(len(expected))] == expected
        finally:
            ear.close()
            node.close()


def test_a_vehicle_batches_a_span_of_20_ms_in_real_time_and_100_ms_in_lockstep():
    """In lockstep nothing waits on a record but the logger, and each put costs both
    sides: five times fewer of them. A span given on the command line holds in both."""
    import autopilot.__main__ as autopilot_main
    import sitl.__main__ as sitl_main
    from contracts.zenoh_link import zenoh_options_from_args

    for module in (sitl_main, autopilot_main):
        parse = module.build_parser().parse_args
        assert zenoh_options_from_args(parse([])).batch_s == 0.1  # lockstep by default
        assert zenoh_options_from_args(parse(["--lockstep"])).batch_s == 0.1
        assert zenoh_options_from_args(parse(["--realtime"])).batch_s == 0.02
        for mode in ("--lockstep", "--realtime"):
            given = parse([mode, "--telemetry-batch-ms", "40"])
            assert zenoh_options_from_args(given).batch_s == 0.04
            assert zenoh_options_from_args(
                parse([mode, "--telemetry-batch-ms", "0"])).batch_s == 0.0
