"""Figures like the paper's: references vs outputs, sliding surfaces, adaptive parameters,
motor commands. Written as PNG with matplotlib's non-interactive backend."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from autopilot.control.sliding_mode import TEL_ES  # noqa: E402
from contracts.frames import altitude_m  # noqa: E402
from contracts.vectors import CHANNELS  # noqa: E402
from ground.record.run_files import RunRecord  # noqa: E402
from ground.report.metrics import AXES, axis_error  # noqa: E402
from ground.scenario.scenario_file import Scenario  # noqa: E402

UNITS = {"x": "m", "y": "m", "z": "m", "phi": "rad", "theta": "rad", "psi": "rad"}


@dataclass(frozen=True)
class Marks:
    """What happened when, drawn on every time plot: perturbation windows (shaded, from
    the time each took effect to its end) and events (thin lines), in the plots' time."""

    windows: tuple[tuple[float, float, str], ...] = ()  # start, end [s], what
    events: tuple[tuple[float, str], ...] = ()  # t [s], what

    def draw(self, fig: plt.Figure) -> None:
        for ax in fig.axes:
            for start, end, _what in self.windows:
                ax.axvspan(start, end, color="C1", alpha=0.15, lw=0)
            for t, _what in self.events:
                ax.axvline(t, color="C2", lw=0.7, alpha=0.8)


NO_MARKS = Marks()


def _save(fig: plt.Figure, path: Path, top_in: float = 0.45, hgap_in: float = 0.3,
          marks: Marks = NO_MARKS) -> Path:
    """Margins fixed in inches (room for tick labels, axis labels and titles) instead of
    ``tight_layout``, which draws every figure twice: the report's figures take half the
    time. ``top_in``: room above the axes (a suptitle needs more); ``hgap_in``: between
    rows (titles or x labels on every row need more); ``marks``: perturbations and events
    on every axis (all of them plot against time)."""
    marks.draw(fig)
    width_in, height_in = fig.get_size_inches()
    rows, cols = fig.axes[0].get_subplotspec().get_gridspec().get_geometry()
    left_in, right_in, bottom_in, wgap_in = 1.0, 0.2, 0.5, 1.1
    axes_w_in = (width_in - left_in - right_in - (cols - 1) * wgap_in) / cols
    axes_h_in = (height_in - bottom_in - top_in - (rows - 1) * hgap_in) / rows
    fig.subplots_adjust(left=left_in / width_in, right=1 - right_in / width_in,
                        bottom=bottom_in / height_in, top=1 - top_in / height_in,
                        wspace=wgap_in / axes_w_in, hspace=hgap_in / axes_h_in)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _value_and_error(row: Any, t: np.ndarray, lines: tuple, error: np.ndarray,
                     ylabel: str, error_label: str, transient_s: float) -> None:
    """One row of a two-column figure: the values on the left (each ``(y, style, width,
    label)``), their error on the right with the end of the transient marked."""
    for y, style, width, label in lines:
        row[0].plot(t, y, style, lw=width, label=label)
    row[0].set_ylabel(ylabel)
    row[1].plot(t, error, "C3", lw=1.0)
    row[1].set_ylabel(error_label)
    row[1].axvline(transient_s, color="0.6", lw=0.8, ls=":")


def _label_columns(fig: Any, plots: Any, title: str) -> None:
    plots[0, 0].legend(loc="upper right", fontsize=8)
    plots[-1, 0].set_xlabel("t [s]")
    plots[-1, 1].set_xlabel("t [s]")
    fig.suptitle(title)


def plot_tracking(record: RunRecord, scenario: Scenario, out_dir: Path,
                  marks: Marks = NO_MARKS) -> Path:
    axes = scenario.axes
    fig, plots = plt.subplots(len(axes), 2, figsize=(11, 2.2 * len(axes)), squeeze=False)
    t = record.time_s
    for row, axis in enumerate(axes):
        _, meas_index = AXES[axis]
        output = record.true_state[:, meas_index]
        error = axis_error(record, axis)
        reference = output + error
        shown = altitude_m if axis == "z" else (lambda v: v)  # altitude up, as people read it
        label = "altitude" if axis == "z" else axis
        _value_and_error(plots[row], t, ((shown(reference), "k--", 1.0, "reference"),
                                         (shown(output), "C0", 1.2, record.controller)),
                         error, f"{label} [{UNITS[axis]}]", f"e_{axis} [{UNITS[axis]}]",
                         scenario.transient_s)
    _label_columns(fig, plots, f"{scenario.name}: {record.controller} on the "
                               f"{record.plant} plant")
    return _save(fig, out_dir / "tracking.png", top_in=0.55, marks=marks)


def plot_sliding(record: RunRecord, out_dir: Path, marks: Marks = NO_MARKS) -> Path:
    fig, ax = plt.subplots(figsize=(9, 3.5))
    for ch, name in enumerate(CHANNELS):
        series = record.channel_telemetry[:, ch, TEL_ES]
        if np.all(np.isnan(series)):
            continue
        ax.plot(record.time_s, series, lw=1.0, label=f"e_s {name}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("sliding surface e_s")
    ax.legend(ncol=3, fontsize=8)
    ax.set_title(f"Sliding surfaces ({record.controller})")
    return _save(fig, out_dir / "sliding.png", marks=marks)


def plot_adaptive(record: RunRecord, out_dir: Path, marks: Marks = NO_MARKS) -> Path | None:
    if not record.theta_f:
        return None
    fig, plots = plt.subplots(2, 2, figsize=(11, 6))
    for ch in range(3):
        ax = plots.flat[ch]
        theta = record.theta_f[ch]
        if theta.shape[1]:
            ax.plot(record.time_s, theta - theta[0], lw=0.8)
        ax.set_title(f"theta_f {CHANNELS[ch]} (change from identified)", fontsize=9)
        ax.set_xlabel("t [s]")
    ax = plots.flat[3]
    for ch, name in enumerate(CHANNELS):
        g = record.theta_g[:, ch]
        if np.all(np.isnan(g)):
            continue
        ax.plot(record.time_s, g / g[0], lw=1.0, label=name)
    ax.set_title("theta_g / initial", fontsize=9)
    ax.legend(ncol=3, fontsize=8)
    ax.set_xlabel("t [s]")
    return _save(fig, out_dir / "adaptive.png", top_in=0.3, hgap_in=0.75, marks=marks)


def plot_motors(record: RunRecord, out_dir: Path, marks: Marks = NO_MARKS) -> Path:
    fig, ax = plt.subplots(figsize=(9, 3.5))
    for i in range(4):
        ax.plot(record.time_s, record.motor_commands[:, i], lw=0.8, label=f"motor {i + 1}")
    ax.set_ylim(-0.05, 1.05)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("command W_i / W_max")
    ax.legend(ncol=4, fontsize=8)
    ax.set_title(f"Motor commands ({record.controller})")
    return _save(fig, out_dir / "motors.png", marks=marks)


def plot_estimation(record: RunRecord, scenario: Scenario, out_dir: Path,
                    marks: Marks = NO_MARKS) -> Path:
    """What the vehicle believed against what was: position, velocity and attitude, the
    estimate over the truth, and the error beside each."""
    rows = (("north", 0, "m"), ("east", 1, "m"), ("altitude", 2, "m"), ("v north", 3, "m/s"),
            ("v east", 4, "m/s"), ("roll", 6, "rad"), ("pitch", 7, "rad"), ("yaw", 8, "rad"))
    fig, plots = plt.subplots(len(rows), 2, figsize=(11, 1.9 * len(rows)), squeeze=False)
    t = record.time_s
    for row, (label, index, unit) in enumerate(rows):
        truth, estimate = record.truth[:, index], record.measurement[:, index]
        if index == 2:
            truth, estimate = altitude_m(truth), altitude_m(estimate)
        error = estimate - truth
        if index >= 6:
            error = (error + np.pi) % (2 * np.pi) - np.pi
        _value_and_error(plots[row], t, ((truth, "k--", 1.0, "truth"),
                                         (estimate, "C0", 1.1, "estimate")),
                         error, f"{label} [{unit}]", f"error [{unit}]", scenario.transient_s)
    _label_columns(fig, plots, f"{scenario.name}: onboard estimate against the simulator's "
                               "truth")
    return _save(fig, out_dir / "estimation.png", top_in=0.55, marks=marks)


def plot_run(record: RunRecord, scenario: Scenario, out_dir: Path,
             marks: Marks = NO_MARKS) -> list[Path]:
    paths = [plot_tracking(record, scenario, out_dir, marks),
             plot_sliding(record, out_dir, marks), plot_motors(record, out_dir, marks)]
    if record.truth is not None:
        paths.append(plot_estimation(record, scenario, out_dir, marks))
    adaptive = plot_adaptive(record, out_dir, marks)
    if adaptive is not None:
        paths.append(adaptive)
    return paths
