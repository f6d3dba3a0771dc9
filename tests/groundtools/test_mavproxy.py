"""MAVProxy (PyPI ``MAVProxy``) at its prompt, as a person types, flies the real processes.

The autopilot runs its ArduPilot-Copter flavour, the one MAVProxy's mode names know.
"""

from __future__ import annotations

import math
import os
import re
import sys
import time
from pathlib import Path

import pexpect
import pytest

from autopilot.copter_parameters import ardupilot_parameters
from contracts.frames import DEFAULT_HOME
from tests.harness import start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool]

MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
MODULES = "param,ftp,arm,mode,cmdlong,misc"  # what the flow needs; no GUI modules


class Prompt:
    def __init__(self, port: int, workdir: Path, modules: str = MODULES) -> None:
        workdir.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, HOME=str(workdir), TERM="dumb", PYTHONUNBUFFERED="1",
                   MPLBACKEND="Agg")
        env.pop("DISPLAY", None)
        self.child = pexpect.spawn(
            str(MAVPROXY), [f"--master=udpin:127.0.0.1:{port}", "--no-state",
                            f"--default-modules={modules}"],
            cwd=str(workdir), env=env, encoding="utf-8", codec_errors="replace", timeout=30,
            echo=False)
        self.child.logfile_read = open(workdir / "mavproxy.log", "w")  # noqa: SIM115

    def type(self, line: str, *expect: str, timeout_s: float = 15.0) -> None:
        """Type a line at the prompt and wait for each pattern in turn."""
        self.child.sendline(line)
        for pattern in expect:
            self.child.expect(pattern, timeout=timeout_s)

    def wait_for_gps_lock(self, timeout_s: float = 30.0) -> None:
        """Telemetry flowing: a Copter streams nothing until asked (SRn_* 0), and MAVProxy
        asks (REQUEST_DATA_STREAM) every 15 s for the vehicles it has seen, so up to 15 s
        after it first hears one; it says "GPS lock" at the first GPS_RAW_INT with a fix.
        That may come while an earlier expect searches past it (pexpect drops what
        precedes a match: a clean-clone CI run timed out so, the lock printed before
        "Loaded 5 waypoints"), so what MAVProxy printed so far is looked at first."""
        log = self.child.logfile_read
        log.flush()
        if "GPS lock at" in Path(log.name).read_text(errors="replace"):
            return
        self.child.expect(r"GPS lock at", timeout=timeout_s)

    def relative_altitude_m(self) -> float:
        self.type("status GLOBAL_POSITION_INT", r"relative_alt : (-?\d+)")
        return int(self.child.match.group(1)) / 1000.0

    def close(self) -> None:
        if self.child.isalive():
            self.child.sendeof()  # Ctrl-D: MAVProxy's own clean exit
            try:
                self.child.expect(pexpect.EOF, timeout=10)
            except pexpect.TIMEOUT:
                self.child.terminate(force=True)
        self.child.close()
        self.child.logfile_read.close()


def _param_line(name: str, value: float) -> str:
    """What ``param show NAME`` prints: the name, spaces, the value and no more digits.
    Not up to the line's end: ``print`` writes the text and its newline apart, and
    MAVProxy rewrites its prompt between other writes, here while it still retried the
    refused PARAM_SET: "ATT_LAM          9.0GUIDED> " in a CI run that then timed out."""
    return rf"{re.escape(name)}\s+{re.escape(repr(float(value)))}(?![0-9])"


def test_mavproxy_arms_takes_off_tunes_a_gain_and_lands(tmp_path):
    procs = start_processes(tmp_path, autopilot_args=["--flavour", "ardupilot"])
    prompt = Prompt(procs.gcs_port, tmp_path / "mavproxy")
    try:
        prompt.child.expect(r"online system 1", timeout=40)
        # Parameters download by themselves (FTP is declined, then the parameter protocol).
        start = time.monotonic()
        prompt.child.expect(rf"Received {len(ardupilot_parameters())} parameters", timeout=40)
        assert "FTP: request timed out" not in prompt.child.before
        assert time.monotonic() - start < 10
        prompt.wait_for_gps_lock()
        prompt.type("mode GUIDED", r"Got COMMAND_ACK: DO_SET_MODE: ACCEPTED")
        prompt.type("arm throttle", r"Got COMMAND_ACK: COMPONENT_ARM_DISARM: ACCEPTED",
                    r"(?<!DIS)ARMED")
        prompt.type("takeoff 2", r"Got COMMAND_ACK: NAV_TAKEOFF: ACCEPTED")
        deadline = time.monotonic() + 20
        altitude = prompt.relative_altitude_m()
        while abs(altitude - 2.0) > 0.15 and time.monotonic() < deadline:
            time.sleep(0.5)
            altitude = prompt.relative_altitude_m()
        assert abs(altitude - 2.0) <= 0.15
        # Read a controller gain, set it in flight, read it back.
        prompt.type("param show ATT_LAM", _param_line("ATT_LAM", 8.0))
        prompt.type("param watch ATT_LAM")
        prompt.type("param set ATT_LAM 9", r"> ATT_LAM=9\.000000")  # the vehicle's echo
        prompt.type("param show ATT_LAM", _param_line("ATT_LAM", 9.0))
        # A bad value is refused by the vehicle and the old one stays.
        prompt.type("param set ATT_LAM 1e9", r"Param write denied \(ATT_LAM\): 1e\+09 is outside")
        prompt.type("param show ATT_LAM", _param_line("ATT_LAM", 9.0))
        prompt.type("mode LAND", r"Mode LAND")
        prompt.child.expect(r"DISARMED", timeout=30)
        assert prompt.relative_altitude_m() < 0.1
    finally:
        prompt.close()
        procs.stop()


MISSION = """QGC WPL 110
0	1	0	16	0	0	0	0	47.397742	8.545594	488.000000	1
1	0	3	22	0	0	0	0	0.000000	0.000000	5.000000	1
2	0	3	16	0	1	0	0	47.397900	8.545594	5.000000	1
3	0	3	16	2	1	0	0	47.397900	8.545800	6.000000	1
4	0	3	20	0	0	0	0	0.000000	0.000000	0.000000	1
"""


def test_mavproxy_loads_and_lists_a_mission(tmp_path):
    """``wp load`` sends a QGC WPL file item by item; ``wp list`` reads it back, the same."""
    procs = start_processes(tmp_path, autopilot_args=["--flavour", "ardupilot"])
    workdir = tmp_path / "mavproxy"
    workdir.mkdir()
    (workdir / "mission.txt").write_text(MISSION)
    prompt = Prompt(procs.gcs_port, workdir, modules="wp,mode,misc")
    try:
        prompt.child.expect(r"online system 1", timeout=40)
        prompt.type("wp load mission.txt", r"Loaded 5 waypoints from mission.txt",
                    r"Sent all 5 waypoints")
        # It prints each item it read: command frame lat lon alt p1..p4 cur auto.
        item_line = r"\d+ \d+ -?[\d.]+ -?[\d.]+ [^\r\n]*auto=1\r?\n"
        prompt.type("wp list", r"Requesting 5 waypoints", rf"(?:{item_line}){{5}}")
        listed = [line for line in prompt.child.match.group(0).splitlines() if line]
    finally:
        prompt.close()
        procs.stop()
    assert len(listed) == 5, listed
    for ours, theirs in zip(MISSION.splitlines()[1:], listed, strict=True):
        a = ours.split("\t")
        command, frame, lat, lon, alt, p1, p2, p3, p4 = (
            theirs.replace("=", " ").split()[i] for i in (0, 1, 2, 3, 4, 6, 8, 10, 12))
        assert (int(command), int(frame)) == (int(a[3]), int(a[2])), (ours, theirs)
        assert [float(v) for v in (p1, p2, p3, p4, lat, lon, alt)] == pytest.approx(
            [float(v) for v in a[4:11]], abs=1e-6), (ours, theirs)


def test_mavproxy_wp_save_round_trips_and_auto_flies_the_loaded_mission(tmp_path):
    """Copter's way, as MAVProxy's users fly it: ``wp load`` of a QGC WPL 110 file whose
    item 0 is home, ``wp save`` writes the same file back (home from the vehicle), then
    GUIDED arm and take-off, ``mode auto``: the waypoints are reached in turn (MAVProxy
    says each new MISSION_CURRENT), numbered after home, and the RTL item brings the
    vehicle home and down."""
    procs = start_processes(tmp_path, autopilot_args=["--flavour", "ardupilot"])
    workdir = tmp_path / "mavproxy"
    workdir.mkdir()
    (workdir / "mission.txt").write_text(MISSION)
    prompt = Prompt(procs.gcs_port, workdir, modules="wp,mode,misc,arm,cmdlong")
    try:
        prompt.child.expect(r"online system 1", timeout=40)
        prompt.type("wp load mission.txt", r"Loaded 5 waypoints from mission.txt",
                    r"Sent all 5 waypoints")
        prompt.type("wp save saved.txt", r"Saved 5 waypoints to saved.txt")
        saved = (workdir / "saved.txt").read_text().splitlines()
        assert saved[0] == "QGC WPL 110"
        for ours, theirs in zip(MISSION.splitlines()[1:], saved[1:], strict=True):
            a, b = ours.split("\t"), theirs.split("\t")
            assert [int(v) for v in (b[0], b[2], b[3], b[11])] == \
                [int(v) for v in (a[0], a[2], a[3], a[11])], (ours, theirs)
            assert [float(v) for v in b[4:11]] == pytest.approx(
                [float(v) for v in a[4:11]], abs=1e-6), (ours, theirs)
        prompt.wait_for_gps_lock()  # telemetry streams once MAVProxy has asked for them
        prompt.type("mode GUIDED", r"Got COMMAND_ACK: DO_SET_MODE: ACCEPTED")
        prompt.type("arm throttle", r"Got COMMAND_ACK: COMPONENT_ARM_DISARM: ACCEPTED",
                    r"(?<!DIS)ARMED")
        prompt.type("takeoff 5", r"Got COMMAND_ACK: NAV_TAKEOFF: ACCEPTED")
        deadline = time.monotonic() + 30
        while prompt.relative_altitude_m() < 4.7 and time.monotonic() < deadline:
            time.sleep(0.5)
        start = time.monotonic()
        prompt.type("mode AUTO", r"Got COMMAND_ACK: DO_SET_MODE: ACCEPTED")
        for seq in (2, 3, 4):  # the take-off item (1) is done at 5 m already
            prompt.child.expect(rf"waypoint {seq}\r?\n", timeout=60)
        prompt.type("status MISSION_ITEM_REACHED", r"seq : 3")  # item 3 reached, then RTL
        prompt.child.expect(r"DISARMED", timeout=90)  # RTL: home, landed, disarmed
        flown_s = time.monotonic() - start
        prompt.type("status GLOBAL_POSITION_INT",
                    r"lat : (-?\d+), lon : (-?\d+), alt : -?\d+, relative_alt : (-?\d+)")
        lat_e7, lon_e7, relative_mm = (int(g) for g in prompt.child.match.groups())
    finally:
        prompt.close()
        procs.stop()
    north, east, _ = DEFAULT_HOME.ned_from_geodetic(lat_e7 * 1e-7, lon_e7 * 1e-7,
                                                    DEFAULT_HOME.alt_amsl_m)
    assert math.hypot(north, east) < 1.0 and relative_mm < 100
    assert flown_s < 90
