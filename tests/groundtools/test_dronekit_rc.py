"""DroneKit-Python (PyPI ``dronekit2``) flies the ArduPilot flavour on channel overrides,
as its own channel_overrides example does with ArduPilot Copter SITL: the real
processes, the real client, ``vehicle.channels.overrides`` on the ground link."""

from __future__ import annotations

import threading
import time

import pytest

from tests.harness import start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool]


class Sticks:
    """The overrides a pilot holds: re-sent at 10 Hz, as a ground station's joystick does
    (an override lasts RC_OVERRIDE_TIME; the radio failsafe starts after 1 s without)."""

    def __init__(self, vehicle, channels: dict[str, int]) -> None:
        self.vehicle, self.channels = vehicle, dict(channels)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def set(self, **channels: int) -> None:
        """Channels by number (``ch3=1800``)."""
        self.channels.update({name[2:]: pwm for name, pwm in channels.items()})
        self.vehicle.channels.overrides = self.channels

    def _run(self) -> None:
        while not self._stop.wait(0.1):
            self.vehicle.channels.overrides = self.channels

    def release(self) -> None:
        self._stop.set()
        self._thread.join()
        self.vehicle.channels.overrides = {}


def _wait(what, timeout_s: float, every_s: float = 0.05) -> None:
    deadline = time.monotonic() + timeout_s
    while not what():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(every_s)


def test_dronekit_flies_alt_hold_and_switches_mode_on_channel_overrides(tmp_path):
    from dronekit import VehicleMode, connect

    procs = start_processes(tmp_path, autopilot_args=["--flavour", "ardupilot"])
    vehicle = connect(f"udpin:127.0.0.1:{procs.gcs_port}", wait_ready=False,
                      source_system=255, heartbeat_timeout=30)
    sticks = None
    try:
        vehicle.wait_ready("parameters", "armed", "mode", "attitude", timeout=60)
        assert vehicle.parameters["FLTMODE_CH"] == 5
        # Throttle low, sticks centred, the mode switch in position 6 (FLTMODE6: STABILIZE).
        sticks = Sticks(vehicle, {"1": 1500, "2": 1500, "3": 1000, "4": 1500, "5": 1800})
        time.sleep(0.3)  # a few frames: the switch's position is where it was found
        vehicle.mode = VehicleMode("ALT_HOLD")
        _wait(lambda: vehicle.mode.name == "ALT_HOLD", 5)
        deadline = time.monotonic() + 30  # until the simulator's state is there
        while not vehicle.armed:
            assert time.monotonic() < deadline, "never armed"
            vehicle.armed = True
            time.sleep(0.2)
        sticks.set(ch3=1800)  # climb: 0.83 m/s (THR_DZ 100, then PX4's expo)
        _wait(lambda: vehicle.location.global_relative_frame.alt > 3.0, 15)
        sticks.set(ch3=1500)  # centred: hold the altitude
        time.sleep(2.0)
        held = []
        for _ in range(25):  # 5 s
            held.append(vehicle.location.global_relative_frame.alt)
            time.sleep(0.2)
        print(f"ALT_HOLD: altitude {min(held):.3f} .. {max(held):.3f} m over 5 s")
        assert min(held) > 3.0 and max(held) - min(held) < 0.05  # measured: 1-2 mm
        assert vehicle.mode.name == "ALT_HOLD" and vehicle.armed
        # Position 5 of the switch: FLTMODE5 is LOITER in Copter SITL.
        sticks.set(ch5=1700)
        _wait(lambda: vehicle.mode.name == "LOITER", 5)
        sticks.release()
        sticks = None
        time.sleep(2.0)  # released, not lost: no radio failsafe
        assert vehicle.mode.name == "LOITER" and vehicle.armed
        vehicle.mode = VehicleMode("LAND")
        _wait(lambda: not vehicle.armed, 40, every_s=0.2)
        assert vehicle.location.global_relative_frame.alt < 0.2
    finally:
        if sticks is not None:
            sticks.release()
        vehicle.close()
        procs.stop()
