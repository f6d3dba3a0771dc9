"""``ivfm rehearse`` as a person runs it: the shipped quad X 500 (its airframe file's own
CMDF_ACC_MAX) through the default profile's lockstep flights (go, exit 0), its page
rendered by headless Chromium, and an airframe with 0.2 s motors judged no-go on the
right checks. The real-time timing flight is left out of the pinned verdict: what it
measures is how busy the machine is (docs/rehearsal.md)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from tests.once import once

pytestmark = pytest.mark.process

ROOT = Path(__file__).parents[2]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
GO_GREEN = np.array([0x1a, 0x7f, 0x37]) / 255.0  # the verdict's background (rehearsal.py)


def ivfm(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ground.cli", *argv], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def x500_rehearsal(tmp_path_factory, worker_id):
    """The rehearsal both tests below read, flown once in the test run (tests/once.py)."""
    folder, done = once(tmp_path_factory, worker_id, "x500-rehearsal", _rehearse_x500)
    return folder / "x500", subprocess.CompletedProcess(done["args"], done["returncode"],
                                                        done["stdout"], done["stderr"])


def _rehearse_x500(folder: Path) -> dict:
    shipped = ROOT / "ground/rehearsal/profiles/default.toml"
    profile = tomllib.loads(shipped.read_text())
    # The lockstep flights, and of the real-time ones the setpoint loss: its ground station
    # (a real MAVLink client) switches to OFFBOARD, streams and stops; its event windows
    # are seconds wide. The timing figures of the others depend on the machine's load.
    profile["flight"] = [{**f, "scenario": str(shipped.parent / f["scenario"])}
                         for f in profile["flight"]
                         if not f.get("realtime") or "setpoint-loss" in f["scenario"]]
    (folder / "pinned.toml").write_text(tomli_w.dumps(profile))
    out = folder / "x500"
    done = ivfm("rehearse", "--airframe", "quad-x-500", "--profile",
                str(folder / "pinned.toml"), "--out", str(out), cwd=ROOT)
    return {"args": done.args, "returncode": done.returncode, "stdout": done.stdout,
            "stderr": done.stderr}


def test_the_x500_rehearsal_is_a_go(x500_rehearsal):
    out, done = x500_rehearsal
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.startswith("rehearsal of quad-x-500: GO (17 of 17 static checks, "
                                  "7 of 7 flights passed")
    result = json.loads((out / "rehearsal.json").read_text())
    assert result["verdict"] == "GO" and result["model"] == "shipped quad-x-500.json"
    assert result["parameters_set"] == {"CMDF_ACC_MAX": 20.0}  # the airframe file's own
    assert "parameters set: CMDF_ACC_MAX = 20" in (out / "rehearsal.html").read_text()
    flights = {f["name"]: f for f in result["flights"]}
    assert all(f["passed"] for f in flights.values())
    assert set(flights) == {"takeoff-hold-land", "tracking", "wind", "weak-motor",
                            "gps-loss", "geofence", "setpoint-loss"}
    # The progress line names each flight as it starts.
    for name in flights:
        assert f"] {name} (" in done.stderr
    for f in flights.values():  # each run folder kept, to open with ivfm report
        kept = {p.name for p in Path(f["run_dir"]).iterdir()}
        # a passed flight's tracking figure (the page shows it), the rest on request
        assert {"metrics.json", "tracking.png"} <= kept and "report.html" not in kept
        assert not kept & {"sliding.png", "motors.png", "estimation.png"}
    # Beside the real-time flight, the reference sleeper over the autopilot's loop (12 s of
    # flight, 100 Hz): its figures next to the autopilot's misses, in every output. What it
    # counted depends on the machine's load, so only its shape is pinned.
    assert all("reference" not in f for n, f in flights.items() if n != "setpoint-loss")
    beside = flights["setpoint-loss"]
    ref = beside["reference"]
    assert ref["source"] in ("cyclictest", "built-in") and ref["period_ms"] == 10.0
    assert ref["window"] == "the autopilot's loop" and 10.0 < ref["window_s"] < 13.0
    assert 0.8 * ref["window_s"] / 0.01 < ref["wakeups"] <= ref["window_s"] / 0.01 + 2
    assert isinstance(ref["lost_periods"], int) and isinstance(beside["deadline_misses"], int)
    assert beside["machine"].startswith("in the same ")
    md = (out / "rehearsal.md").read_text()
    assert (f"| setpoint-loss | {beside['deadline_misses']} | {beside['steps_held']} | "
            f"{ref['lost_periods']} | ") in md
    assert "<table id='reference'>" in (out / "rehearsal.html").read_text()
    # The airframe's parameter is the one flown, and the one in QGroundControl's file.
    assert "1\t1\tCMDF_ACC_MAX\t20.0\t9" in (out / "parameters.params").read_text()


@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium is not installed (Debian: "
                    "apt-get install chromium; .ci/run installs it where it may)")
def test_the_rehearsal_page_renders_in_headless_chromium(x500_rehearsal, tmp_path):
    """What a person sees: Chromium renders the page (no network) and the screenshot shows
    the green GO banner and the tracking figures under it."""
    import matplotlib.image

    out, done = x500_rehearsal
    assert done.returncode == 0, done.stderr
    shot = tmp_path / "rehearsal.png"
    subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
                    "--hide-scrollbars", "--window-size=1200,1500", f"--screenshot={shot}",
                    (out / "rehearsal.html").as_uri()],
                   capture_output=True, timeout=60, check=True)
    image = matplotlib.image.imread(shot)[:, :, :3]
    assert image.shape[:2] == (1500, 1200)
    green = np.all(np.abs(image - GO_GREEN) < 0.02, axis=2)
    # The banner (about 150 x 75 px of solid green) at the top left, where one looks first;
    # the "pass" words below are the same green, in thin strokes.
    assert green[:250, :400].sum() > 8000
    assert not np.any(np.all(np.abs(image - (0xc6 / 255, 0x28 / 255, 0x28 / 255)) < 0.02,
                             axis=2))  # no red anywhere: nothing failed
    assert (image.std(axis=(0, 1)) > 0.05).all()  # tables and text, not a blank page


def test_slow_motors_are_a_no_go_on_the_right_checks(tmp_path):
    """0.2 s motors: the static lag check fails, and the hover with a weakened motor is
    lost; the other static checks pass."""
    data = tomllib.loads((ROOT / "contracts/airframes/quad-x-500.toml").read_text())
    data["name"] = "slow-motors"
    for rotor in data["rotor"]:
        rotor["time_constant_s"] = 0.2
    airframe = tmp_path / "slow-motors.toml"
    airframe.write_text(tomli_w.dumps(data))
    profile = tmp_path / "weak-motor-only.toml"
    flights = ROOT / "ground/rehearsal/profiles/flights"
    profile.write_text(f'name = "weak-motor-only"\n[airframe]\n'
                       f'motor_time_constant_max_s = 0.05\nthrust_to_weight_min = 1.5\n'
                       f'[[flight]]\nscenario = "{flights / "weak-motor.toml"}"\n')
    out = tmp_path / "out"
    done = ivfm("rehearse", "--airframe", str(airframe), "--profile", str(profile),
                "--out", str(out), cwd=tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "no model of this airframe: identifying one on it" in done.stderr
    result = json.loads((out / "rehearsal.json").read_text())
    assert result["verdict"] == "NO-GO"
    failed_static = [o["message"] for o in result["static"] if not o["passed"]]
    assert failed_static == ["motor time constant 0.2 s > limit 0.05 s (rotor 1)"]
    (flight,) = result["flights"]
    assert flight["name"] == "weak-motor" and not flight["passed"]
    failed = {o["name"] for o in flight["outcomes"] if not o["passed"]}
    assert {"axes.x.max_abs <= 0.5", "axes.y.max_abs <= 0.5"} <= failed
    # A failed flight's folder holds every figure and its page, for the diagnosis.
    run_dir = Path(flight["run_dir"])
    assert {"tracking.png", "sliding.png", "motors.png", "adaptive.png",
            "report.html"} <= {p.name for p in run_dir.iterdir()}
