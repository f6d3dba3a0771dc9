"""report.html: one self-contained page per run (ground/report/run_page.py), read as a person
reads it, and rendered by headless Chromium."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ground.report.run_page import marks_of
from ground.report.run_report import report

SHORT_RUN = Path(__file__).parents[1] / "data" / "short-run"  # a 1 s lockstep run's folder
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
NO_EXPECTATIONS_GREY = np.array([0x77, 0x77, 0x77]) / 255.0  # the short run has none


@pytest.fixture()
def short_run(tmp_path) -> Path:
    folder = tmp_path / "short-run"
    shutil.copytree(SHORT_RUN, folder)
    report(folder)
    return folder


def test_the_page_is_self_contained_with_the_runs_numbers(short_run):
    page = (short_run / "report.html").read_text()
    assert not re.search(r"(src|href)=['\"]?(https?:|//)", page)  # nothing from a network
    assert page.count("data:image/png;base64,") >= 3  # tracking, sliding, motors (inline)
    metrics = __import__("json").loads((short_run / "metrics.json").read_text())
    for axis, m in metrics["axes"].items():
        assert f"<td>{axis}</td><td>{float(m['rmse']):.4g}</td>" in page


def test_perturbation_windows_and_events_are_placed_in_the_figures_time():
    metrics = {"perturbations_applied": [
        {"sim_time_us": 12_500_000, "event": "start", "id": "jr", "kind": "rotor_inertia"},
        {"sim_time_us": 14_500_000, "event": "end", "id": "jr", "kind": "rotor_inertia"},
        {"sim_time_us": 15_500_000, "event": "start", "id": "w", "kind": "wind"}],
        "events": [{"kind": "mode", "t_s": 0.5, "mode": "OFFBOARD"},
                   {"kind": "failsafe", "t_s": 16.5, "mode": "LAND"}]}
    # Tracking began 0.5 s into the sim: the figures' time is 0.5 s behind sim time.
    marks = marks_of(metrics, np.array([500_000, 20_500_000]), np.array([0.0, 20.0]))
    assert marks.windows == ((12.0, 14.0, "rotor_inertia jr"), (15.0, 20.0, "wind w"))
    assert marks.events == ((16.0, "failsafe LAND"),)  # mode changes are on the timeline


@pytest.mark.process
@pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium is not installed (Debian: "
                    "apt-get install chromium; .ci/run installs it where it may)")
def test_the_page_renders_in_headless_chromium(tmp_path):
    """What a person sees: the verdict at the top (grey: the short run's scenario has no
    expectations) and figures under it."""
    import matplotlib.image

    folder = tmp_path / "short-run"
    shutil.copytree(SHORT_RUN, folder)
    report(folder)
    shot = tmp_path / "page.png"
    subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
                    "--disable-background-networking", "--hide-scrollbars",
                    "--window-size=1200,1600", f"--screenshot={shot}",
                    (folder / "report.html").as_uri()],
                   capture_output=True, timeout=60, check=True)
    image = matplotlib.image.imread(shot)[:, :, :3]
    assert image.shape[:2] == (1600, 1200)
    banner = np.all(np.abs(image - NO_EXPECTATIONS_GREY) < 0.02, axis=2)
    assert banner[:250, :500].sum() > 8000  # the verdict banner, top left
    assert (image[800:].std(axis=(0, 1)) > 0.05).all()  # figures below, not a blank page


@pytest.mark.process
def test_a_report_without_figures_loads_no_compiled_code_and_no_matplotlib(tmp_path):
    """The report after every ``ivfm run`` and ``ivfm check`` run: numba's first call in a
    process loads its registries (0.3-0.5 s, most of what the report cost), so its numbers
    come from numpy alone; matplotlib (0.4 s of CPU) loads only for figures. A fresh
    interpreter, as the command is after a flight."""
    folder = tmp_path / "short-run"
    shutil.copytree(SHORT_RUN, folder)
    code = ("import sys; from pathlib import Path; "
            "from ground.report.run_report import report; "
            f"report(Path({str(folder)!r}), figures=False); "
            "print('numba.np.arraymath' in sys.modules, 'matplotlib' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, cwd=Path(__file__).parents[2])
    assert (folder / "metrics.json").exists()
    # numba.np.arraymath: loaded with numba's registries
    assert done.stdout.strip() == "False False"
