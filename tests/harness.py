"""Start the simulator and autopilot as real processes and talk to them as a ground tool."""

from __future__ import annotations

import math
import os
import socket
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

os.environ["MAVLINK20"] = "1"  # before pymavlink picks its dialect: MAVLink 2, as tools use

from pymavlink import mavutil  # noqa: E402

mavutil.set_dialect("common")
from autopilot.mavlink.link import kernel_drops  # noqa: E402
from contracts.mavlink import StatustextAssembler  # noqa: E402
from ground.run.loader import ForkedProcess, ProcessLoader  # noqa: E402

GCS_SYSID = 255


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port claimed for this test's processes and tools (ground/run/children.py)."""
    from ground.run.children import free_port as claimed_port

    return claimed_port(kind)


_LOADER: list[ProcessLoader] = []


def process_loader() -> ProcessLoader:
    """The loader the vehicles of this test process are forked from (contracts/zygote.py):
    a flight's processes start without loading their imports and compiled code again. It
    ends with the test process (end of its input)."""
    if not _LOADER or not _LOADER[0].alive:
        _LOADER[:] = [ProcessLoader(("sitl", "autopilot"))]
    return _LOADER[0]


@dataclass
class Processes:
    sim_port: int
    gcs_port: int  # where the test's ground tool listens
    vehicle_port: int  # the autopilot's own ground-link port
    log_dir: Path
    sim_args: list[str] = field(default_factory=list)
    autopilot_args: list[str] = field(default_factory=list)
    sim: ForkedProcess | None = None
    autopilot: ForkedProcess | None = None

    def start_sim(self) -> None:
        """``python -m sitl``, forked by this test process's loader (``process_loader``);
        a restart appends to the same log."""
        self.sim = process_loader().start(
            "sitl", ["--port", str(self.sim_port), *self.sim_args], self.log_dir / "sitl.log")

    def start_autopilot(self) -> None:
        self.autopilot = process_loader().start(
            "autopilot", ["--sim", f"127.0.0.1:{self.sim_port}",
                          "--gcs", f"127.0.0.1:{self.gcs_port}",
                          "--gcs-bind", str(self.vehicle_port), "--api", "none",
                          "--api-bind", "0", *self.autopilot_args],
            self.log_dir / "autopilot.log")

    def wait_for(self, what: str, said: Callable[[], bool], idle_s: float = 30.0) -> None:
        """Until ``said()``, for as long as the processes start: a fixed wait failed beside
        busy work, where loading the compiled code took the simulator over 30 s
        (ground/run/children.py, ``StartingDeadline``). A process that exits meanwhile
        fails the test with both logs."""
        from ground.run.loader import StartingDeadline

        started = {name: proc for name, proc in (("sitl", self.sim),
                                                 ("autopilot", self.autopilot)) if proc}
        deadline = StartingDeadline({name: p.pid for name, p in started.items()}, idle_s)
        while not said():
            exited = [name for name, proc in started.items() if proc.poll() is not None]
            why = (f"({', '.join(exited)} exited)" if exited else
                   deadline.expired(f"the {what}"))
            if why is not None:
                raise AssertionError(f"no {what} {why}\nsitl log:\n{self.sim_log()}\n"
                                     f"autopilot log:\n{self.autopilot_log()}")
            time.sleep(0.05)

    def wait_listening(self) -> None:
        """Until the simulator listens, then its port: it binds port 0 and says which one.
        A port picked here and bound there could be taken in between (a parallel test's
        outgoing connection took one: "Address already in use")."""
        self.wait_for("listening simulator", lambda: "listening on tcp" in self.sim_log())
        line = next(ln for ln in self.sim_log().splitlines() if "listening on tcp" in ln)
        self.sim_port = int(line.split("listening on tcp 127.0.0.1:", 1)[1].split()[0])

    def wait_connected(self) -> None:
        """Until the autopilot has connected to the simulator."""
        self.wait_for("connection to the simulator",
                      lambda: "connected to the simulator" in self.autopilot_log())

    def sim_log(self) -> str:
        path = self.log_dir / "sitl.log"
        return path.read_text() if path.exists() else ""

    def autopilot_log(self) -> str:
        path = self.log_dir / "autopilot.log"
        return path.read_text() if path.exists() else ""

    def stop(self) -> None:
        for proc in (self.autopilot, self.sim):
            if proc is not None and proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(5)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()


def start_processes(log_dir: Path, sim_args: list[str] | None = None,
                    autopilot_args: list[str] | None = None) -> Processes:
    """Simulator and autopilot in real time at 100 Hz, the vehicle on the ground."""
    # The paper's airframe unless a test names one: the tests' figures were measured on it
    # (the processes' own default is the quad X 500; tests/autopilot/test_default_vehicle.py).
    sim_args, autopilot_args = list(sim_args or []), list(autopilot_args or [])
    for args in (sim_args, autopilot_args):
        if "--airframe" not in args:
            args += ["--airframe", "paper"]
    # Sleep to each control step, not spin the last 0.5 ms: no test of these processes
    # asserts jitter, and spinning took 2-3 % of a CPU per flight from the tests
    # beside it (CI flies four at a time). Jitter is measured by tests/benchmarks/soak.py.
    if "--spin-us" not in autopilot_args:
        autopilot_args += ["--spin-us", "0"]
    procs = Processes(0, free_port(), free_port(), log_dir,
                      ["--realtime", "--plant", "rigid-body", *sim_args],
                      ["--realtime", *autopilot_args])
    procs.start_sim()  # on a port of its own choosing (a restart takes the same one)
    procs.wait_listening()
    procs.start_autopilot()
    procs.wait_connected()
    return procs


class GroundTool:
    """A pymavlink ground station: heartbeats, and waiting for what the vehicle says."""

    def __init__(self, port: int, signing_key: bytes | None = None) -> None:
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}",
                                               source_system=GCS_SYSID, source_component=190)
        if signing_key is not None:
            self.conn.setup_signing(signing_key, sign_outgoing=True)
        self.texts: list[str] = []  # whole texts
        self.completed_text: str | None = None  # the one the last message completed
        self._assembler = StatustextAssembler()
        self.last_heartbeat_s = 0.0
        self.heartbeats = True

    @property
    def mav(self):
        return self.conn.mav

    def pump(self, timeout_s: float = 0.05):
        """Receive one message (or None); keeps our 1 Hz heartbeat going."""
        now = time.monotonic()
        if self.heartbeats and now - self.last_heartbeat_s >= 1.0:
            self.last_heartbeat_s = now
            self.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS,
                                    mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        msg = self.conn.recv_match(blocking=True, timeout=timeout_s)
        self.completed_text = None
        if msg is not None and msg.get_type() == "STATUSTEXT":
            text = self._assembler.add(msg)  # chunks reassembled, as QGC and MAVSDK do
            if text is not None:
                self.texts.append(text)
                self.completed_text = text
        return msg

    def drain(self) -> int:
        """Read what waits in the socket, as a tool that comes back to its link does: one
        that has not read for seconds has a full receive buffer, and the kernel drops the
        answer to its next request (a fence download after a MAVSDK example timed out so,
        beside busy work). How many messages were read."""
        count = 0
        while self.conn.recv_match(blocking=False) is not None:
            count += 1
        return count

    def wait(self, predicate: Callable, timeout_s: float = 10.0, what: str = "",
             also: Callable[[], None] | None = None):
        """The first message for which predicate(msg) holds; fails after timeout_s."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if also is not None:
                also()
            msg = self.pump()
            if msg is not None and predicate(msg):
                return msg
        raise AssertionError(f"timed out after {timeout_s} s waiting for {what or predicate}; "
                             f"status texts: {self.texts[-8:]}; datagrams the kernel dropped "
                             f"for want of buffer at the tool: {kernel_drops(self.conn.port)}")

    def wait_type(self, kind: str, timeout_s: float = 10.0, cond: Callable | None = None,
                  also: Callable[[], None] | None = None):
        return self.wait(lambda m: m.get_type() == kind and (cond is None or cond(m)),
                         timeout_s, kind, also)

    def wait_text(self, fragment: str, timeout_s: float = 10.0,
                  also: Callable[[], None] | None = None) -> str:
        for text in self.texts:
            if fragment in text:
                return text
        self.wait(lambda m: self.completed_text is not None and fragment in self.completed_text,
                  timeout_s, f"STATUSTEXT '{fragment}'", also)
        return self.completed_text

    def command(self, command: int, *params: float, timeout_s: float = 5.0):
        """COMMAND_LONG to the vehicle; returns its COMMAND_ACK."""
        p = list(params) + [0.0] * (7 - len(params))
        self.mav.command_long_send(1, 1, command, 0, *p)
        return self.wait_type("COMMAND_ACK", timeout_s, lambda m: m.command == command)

    def connect(self, timeout_s: float = 30.0):
        """Wait for the vehicle's heartbeat and a healthy simulator link."""
        self.wait_type("HEARTBEAT", timeout_s, lambda m: m.get_srcComponent() == 1)
        return self.wait_type("SYS_STATUS", timeout_s,
                              lambda m: m.onboard_control_sensors_health & 0x20)

    def position(self):
        return self.wait_type("LOCAL_POSITION_NED")

    def heartbeat(self):
        return self.wait_type("HEARTBEAT", cond=lambda m: m.get_srcComponent() == 1)

    def armed(self) -> bool:
        return bool(self.heartbeat().base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    def send_position_setpoint(self, x: float, y: float, z: float, yaw: float = 0.0,
                               type_mask: int = 0x9F8) -> None:
        self.mav.set_position_target_local_ned_send(
            0, 1, 1, mavutil.mavlink.MAV_FRAME_LOCAL_NED, type_mask, x, y, z, 0.0, 0.0, 0.0,
            0.0, 0.0, 0.0, yaw, 0.0)

    def close(self) -> None:
        self.conn.close()


def px4_mode(main: int, sub: int = 0) -> tuple[float, float, float]:
    """DO_SET_MODE params for a PX4 custom mode."""
    return float(mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub)


def is_nan(value: float) -> bool:
    return isinstance(value, float) and math.isnan(value)
