"""The simulator on Zenoh: its truth state each sample (sent in batches), each perturbation
as it starts and ends, its status (at most once a second, and a final one with the link's
latency), and the requests it serves (``perturb``, ``start``), queued for the loop to take.
"""

from __future__ import annotations

import queue
from collections.abc import Callable
from typing import Any

import numpy as np

from contracts import SITL
from contracts.mavlink import SIMULATOR_COMPID
from contracts.perturbation_effects import PLANT_EFFECTS
from contracts.perturbations import Perturbation, Perturbations
from contracts.telemetry import STATE, json_record
from contracts.telemetry_node import PERTURBATIONS_OFF, Request, TelemetryNode
from contracts.vectors import TRUTH
from contracts.zenoh_link import ZenohOptions
from sitl.link import LinkStats
from sitl.plant import VehicleState

# STATE record fields that are the plant's truth (contracts/vectors.py TRUTH, in its
# order; then the motor commands, then the plant effects).
STATE_FROM_PLANT = TRUTH.fields


class SimulatorTelemetry:
    """The simulator's Zenoh node and its publications. The perturbation service answers
    every query with an error unless ``serve_perturbations`` (a vehicle started by hand is
    never blown or kicked by whoever reaches it)."""

    def __init__(self, options: ZenohOptions, vehicle_id: int, serve_perturbations: bool,
                 log: Callable[[str], None]) -> None:
        self.node = TelemetryNode(options, vehicle_id, SITL, log)
        self._state_pub = self.node.publisher("state")
        self._event_pub = self.node.publisher("perturbation")
        self.node.serve("perturb", None if serve_perturbations else PERTURBATIONS_OFF)
        self.node.serve("start")
        self._state_record = STATE.buffer()  # one record, refilled each sample
        # Its counters and its truth and motor commands each in one view, filled in one
        # assignment; the plant effects refilled when they change (replaced whole: frozen).
        self._head = self._state_record.run(("seq", "sim_time_us"))
        self._truth = self._state_record.run((*STATE_FROM_PLANT, "motor_commands"))
        self._effects_of: Perturbations | None = None

    def next_request(self, wait_s: float = 0.0) -> Request | None:
        """The oldest request not yet taken, or None (asked each sample: no exception
        raised when there is none); ``wait_s``: up to this long for one to come."""
        requests = self.node.requests
        if wait_s <= 0.0 and requests.empty():
            return None
        try:
            return requests.get(timeout=wait_s) if wait_s > 0.0 else requests.get_nowait()
        except queue.Empty:
            return None

    def publish_state(self, time_us: int, state: VehicleState, active: Perturbations,
                      motor_commands: np.ndarray) -> None:
        """The truth at ``time_us``: the plant's state, the plant changes in force and the
        motor commands applied."""
        if not self.node.enabled:
            return
        record = self._state_record
        self._head[:] = (self._state_pub.count, time_us)
        truth = self._truth
        truth[:TRUTH.size] = state.numbers()
        truth[TRUTH.size:] = motor_commands
        if active is not self._effects_of:
            self._effects_of = active
            for name in PLANT_EFFECTS:
                record[name] = getattr(active, name)
        self._state_pub.put(record.encode())
        self.node.end_step(time_us)

    def mirror_readings(self, time_us: int, sensor_frame: bytes,
                        gps_frame: bytes | None) -> None:
        """The HIL_SENSOR and HIL_GPS frames of the sample at ``time_us`` as sent, into
        the MAVLink mirror (``mavlink/V/51/HIL_SENSOR``): what a PX4 log keeps as
        sensor_combined and sensor_gps."""
        node = self.node
        node.mirror(node.vehicle, SIMULATOR_COMPID, "HIL_SENSOR", sensor_frame, time_us)
        if gps_frame is not None:
            node.mirror(node.vehicle, SIMULATOR_COMPID, "HIL_GPS", gps_frame, time_us)

    def publish_event(self, time_us: int, event: str, entry: Perturbation) -> None:
        """A perturbation that started or ended at ``time_us``."""
        self._event_pub.put(json_record(self._event_pub.count, time_us, event=event,
                                        **entry.to_request()))

    def status(self, time_us: int, stats: LinkStats, started: bool) -> None:
        """The link's counters, at most once a second of wall time: a ground station sees
        the simulator alive even while sim time stands still."""
        self.node.flush_stale()
        if self.node.status_due():  # asked each sample: gather nothing till then
            self.node.status(time_us, **_status_fields(stats, started))

    def close(self, time_us: int, stats: LinkStats, started: bool) -> None:
        """The final status, with the latency of the autopilot's answers; then the session
        closes."""
        self.node.status(time_us, final=True, **_status_fields(stats, started),
                         latency=_latency_summary(stats))
        self.node.close()


def _status_fields(stats: LinkStats, started: bool) -> dict[str, Any]:
    return {"samples_sent": stats.samples_sent,
            "commands_received": stats.commands_received,
            "refused": stats.bad_messages,
            "periods_without_command": stats.periods_without_command,
            "started": started}


def _latency_summary(stats: LinkStats) -> dict[str, float]:
    h = stats.latency
    if h.n == 0:
        return {}
    return {"p50_ms": h.percentile(50) * 1e3, "p99_ms": h.percentile(99) * 1e3,
            "max_ms": h.max_s * 1e3}
