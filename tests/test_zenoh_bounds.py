"""What a querier can queue in a vehicle process is bounded (real Zenoh sessions on
loopback, no vehicle loop answering): past MAX_PENDING_REQUESTS the next request is
refused at once as busy, and a payload over MAX_REQUEST_BYTES is refused unread."""

from __future__ import annotations

import json
import time

from contracts.telemetry import vehicle_key
from contracts.zenoh_link import (
    MAX_PENDING_REQUESTS,
    MAX_REQUEST_BYTES,
    TelemetryNode,
    ZenohOptions,
    open_session,
)
from ground.processes import free_tcp_port


def _answers(replies) -> list[dict]:
    out = []
    for reply in replies:
        if reply.ok is not None:
            out.append(json.loads(reply.ok.payload.to_bytes()))
        else:
            out.append(json.loads(reply.err.payload.to_bytes()))
    return out


def test_pending_requests_and_payload_sizes_are_bounded():
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    node = TelemetryNode(ZenohOptions(listen=[endpoint]), 1, "sitl", log=lambda text: None)
    node.serve("perturb")
    asker = open_session(ZenohOptions(connect=[endpoint]))
    key = vehicle_key(1, "sitl", "perturb")
    try:
        deadline = time.monotonic() + 5.0
        while node.requests.qsize() == 0 and time.monotonic() < deadline:  # route up
            asker.get(key, payload=b"{}", timeout=0.05)
        pending = [asker.get(key, payload=json.dumps({"kind": "wind", "n": i}).encode(),
                             timeout=2.0) for i in range(MAX_PENDING_REQUESTS + 5)]
        deadline = time.monotonic() + 5.0
        while node.requests.qsize() < MAX_PENDING_REQUESTS and time.monotonic() < deadline:
            time.sleep(0.01)
        assert node.requests.qsize() == MAX_PENDING_REQUESTS  # no more than the bound
        busy = [a for replies in pending[-5:] for a in _answers(replies)]
        assert busy and all(a["error"].startswith("busy:") for a in busy)
        while not node.requests.empty():  # the loop's turn: answer them
            node.requests.get_nowait().reply(True)
        big = _answers(asker.get(key, payload=b" " * (MAX_REQUEST_BYTES + 1), timeout=2.0))
        assert big and "is over" in big[0]["error"]
    finally:
        asker.close()
        node.close()
