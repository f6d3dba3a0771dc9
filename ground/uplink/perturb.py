"""Perturbation injection: the ground station's Python API (``ivfm ground perturb`` uses it).

Requests are acknowledged Zenoh queries to the process that applies the kind (plant,
sensor and link kinds to the simulator, reference kicks to the autopilot). A request is
checked here first, with the same validator the vehicle uses, and the vehicle's answer
(the entry with its sim-time window, or the error) is returned or raised::

    with PerturbationClient() as ground:
        ground.uplink.perturb(1, "wind", start_s="now", duration_s=5, ned_mps=[3, 0, 0])
        ground.uplink.perturb(1, "kick", start_s=8.0, end_s=8.5, phi_rad=0.25)
"""

from __future__ import annotations

import json
import time
from typing import Any

import zenoh

from contracts.perturbations import KINDS, parse_request
from contracts.telemetry import DEFAULT_GROUND_ENDPOINT, SITL, check_vehicle_id, vehicle_key
from contracts.zenoh_link import ZenohOptions, open_session


class PerturbationError(RuntimeError):
    """The vehicle refused a request, or could not be reached; the message says which."""


class PerturbationClient:
    def __init__(self, options: ZenohOptions | None = None,
                 session: zenoh.Session | None = None, timeout_s: float = 5.0) -> None:
        self._own = session is None
        self.session = session or open_session(
            options or ZenohOptions(connect=[DEFAULT_GROUND_ENDPOINT]))
        self.timeout_s = timeout_s

    def __enter__(self) -> PerturbationClient:
        return self

    def __exit__(self, *_exc: Any) -> None:
        self.close()

    def close(self) -> None:
        if self._own:
            self.session.close()

    def perturb(self, vehicle: int, kind: str, start_s: float | str = "now",
                end_s: float | None = None, duration_s: float | None = None,
                id: str | None = None, **params: Any) -> dict[str, Any]:
        request: dict[str, Any] = {"kind": kind, "start_s": start_s, **params}
        if end_s is not None:
            request["end_s"] = end_s
        if duration_s is not None:
            request["duration_s"] = duration_s
        if id is not None:
            request["id"] = id
        return self.send(vehicle, request)

    def send(self, vehicle: int, request: dict[str, Any]) -> dict[str, Any]:
        """Validate, route by kind and send one "add" request; the vehicle's answer."""
        entry = parse_request({k: v for k, v in request.items() if k != "op"})
        return self.query(vehicle, KINDS[entry.kind].target, "perturb",
                          {"op": "add", **request})

    def clear(self, vehicle: int, target: str, id: str | None = None) -> dict[str, Any]:
        body: dict[str, Any] = {"op": "clear"}
        if id is not None:
            body["id"] = id
        return self.query(vehicle, target, "perturb", body)

    def list(self, vehicle: int, target: str) -> list[dict[str, Any]]:
        return self.query(vehicle, target, "perturb", {"op": "list"})["perturbations"]

    def start(self, vehicle: int) -> dict[str, Any]:
        """Release a simulator started with ``--hold``."""
        return self.query(vehicle, SITL, "start", {})

    def wait_for(self, vehicle: int, process: str, timeout_s: float | None = None) -> None:
        """Until the process's liveliness token is visible (it is up and reachable)."""
        key = vehicle_key(check_vehicle_id(vehicle), process)
        deadline = time.monotonic() + (timeout_s or self.timeout_s)
        while time.monotonic() < deadline:
            if any(r.ok is not None for r in self.session.liveliness().get(key, timeout=0.5)):
                return
            time.sleep(0.1)
        raise PerturbationError(f"vehicle {vehicle}'s {process} is not reachable over zenoh "
                                f"(no liveliness token {key})")

    def query(self, vehicle: int, process: str, topic: str,
              body: dict[str, Any]) -> dict[str, Any]:
        key = vehicle_key(check_vehicle_id(vehicle), process, topic)
        payload = json.dumps(body, allow_nan=False).encode()
        deadline = time.monotonic() + self.timeout_s
        while True:  # a vehicle just started may not be routed to us yet: ask again
            for reply in self.session.get(key, payload=payload, timeout=self.timeout_s):
                if reply.ok is not None:
                    return json.loads(reply.ok.payload.to_bytes())
                error = reply.err.payload.to_bytes()
                try:
                    message = json.loads(error).get("error", error.decode())
                except ValueError:
                    message = error.decode(errors="replace")
                raise PerturbationError(f"vehicle {vehicle} {process} refused: {message}")
            if time.monotonic() >= deadline:
                raise PerturbationError(f"no answer from vehicle {vehicle}'s {process} on "
                                        f"{key} within {self.timeout_s:g} s")
            time.sleep(0.02)
