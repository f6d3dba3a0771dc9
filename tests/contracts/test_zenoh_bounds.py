"""What a querier can queue in a vehicle process is bounded (real Zenoh sessions on
loopback, no vehicle loop answering): past MAX_PENDING_REQUESTS the next request is
refused at once as busy, and a payload over MAX_REQUEST_BYTES is refused unread."""

from __future__ import annotations

import json
import time

from contracts.telemetry import vehicle_key
from contracts.telemetry_node import MAX_PENDING_REQUESTS, MAX_REQUEST_BYTES, TelemetryNode
from contracts.zenoh_link import ZenohOptions, open_session
from ground.run.children import free_tcp_port


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


def test_a_refused_request_says_why_and_a_defect_is_an_internal_error():
    """Request.refuse, as both vehicle loops use it: a ValueError's reason goes back to the
    asker; any other exception (a defect in a handler) is refused as an internal error
    instead of ending the loop. Both are said in the process's log."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    said: list[str] = []
    node = TelemetryNode(ZenohOptions(listen=[endpoint]), 1, "sitl", log=lambda text: None)
    node.serve("perturb")
    asker = open_session(ZenohOptions(connect=[endpoint]))
    key = vehicle_key(1, "sitl", "perturb")
    try:
        answers = []
        for exc in (ValueError("unknown perturbation kind 'x'"), TypeError("unhashable")):
            replies = None
            deadline = time.monotonic() + 5.0
            while node.requests.qsize() == 0 and time.monotonic() < deadline:  # route up
                replies = asker.get(key, payload=b'{"kind": "x"}', timeout=2.0)
                time.sleep(0.02)
            node.requests.get_nowait().refuse(exc, said.append)
            while not node.requests.empty():  # asked again while the route came up
                node.requests.get_nowait().refuse(exc, lambda text: None)
            answers.append(_answers(replies)[0])
        assert answers[0] == {"ok": False, "error": "unknown perturbation kind 'x'"}
        assert answers[1] == {"ok": False, "error": "internal error: TypeError"}
        assert said == ["refused perturb request: unknown perturbation kind 'x'",
                        "refused perturb request on an internal error: "
                        "TypeError('unhashable')"]
    finally:
        asker.close()
        node.close()
