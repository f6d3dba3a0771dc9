"""One page per run: ``report.html`` beside ``metrics.json``, self-contained (figures
inline, no network), written by ``ivfm run`` and ``ivfm report``.

What a person reads first comes first: how the run was flown and whether its
expectations held; then the metrics per axis, the events and perturbations on a
timeline, a top view of the path with the planned legs, and the figures, every time
plot marked with the perturbation windows (shaded) and the events (lines).
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import Any

import numpy as np

from ground.report.figures import Marks, plt

FIGURES = ("tracking", "estimation", "sliding", "adaptive", "motors")
_STYLE = """
body { font-family: sans-serif; margin: 1.5em 2em; color: #222; max-width: 1250px; }
h1 { margin-bottom: 0.2em; } h2 { margin-top: 1.4em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.5em 0; }
td, th { border: 1px solid #ccc; padding: 3px 9px; text-align: right; }
th { background: #eee; } td:first-child, th:first-child { text-align: left; }
.verdict { display: inline-block; padding: 0.5em 1.2em; font-size: 1.6em; color: white;
           font-weight: bold; border-radius: 4px; }
.ok { background: #1a7f37; } .bad { background: #c62828; } .none { background: #777; }
.pass { color: #1a7f37; font-weight: bold; } .fail { color: #c62828; font-weight: bold; }
tr.failed td { background: #fdecea; }
img { max-width: 100%; border: 1px solid #ddd; margin: 0.3em 0; }
.timeline td:nth-child(2), .timeline td:nth-child(3) { text-align: left; }
"""


def marks_of(metrics: dict[str, Any], sim_time_us: np.ndarray, time_s: np.ndarray) -> Marks:
    """Perturbation windows and events in the figures' time (the reference time, which
    starts when the vehicle began to track)."""
    offset_s = float(sim_time_us[0]) / 1e6 - float(time_s[0]) if len(time_s) else 0.0
    started: dict[str, tuple[float, str]] = {}
    windows = []
    end_s = float(time_s[-1]) if len(time_s) else 0.0
    for e in metrics.get("perturbations_applied", []):
        t = e["sim_time_us"] / 1e6 - offset_s
        what = f"{e['kind']} {e['id']}"
        if e["event"] == "start":
            started[e["id"]] = (t, what)
        elif e["id"] in started:
            begin, what = started.pop(e["id"])
            windows.append((begin, t, what))
    windows += [(begin, end_s, what) for begin, what in started.values()]
    events = tuple((e["t_s"] - offset_s, _event_text(e)) for e in metrics.get("events", [])
                   if e["kind"] != "mode")
    return Marks(tuple(windows), events)


def _event_text(e: dict[str, Any]) -> str:
    return " ".join(str(e[k]) for k in ("kind", "mode", "text") if e.get(k))


def _png(path: Path) -> str:
    return base64.b64encode(path.read_bytes()).decode()


def path_figure(measurement: np.ndarray, reference: np.ndarray,
                planned_ned: np.ndarray | None) -> str:
    """A top view (north up, east right) of the path flown, the reference and the
    planned legs, as inline PNG data."""
    fig, ax = plt.subplots(figsize=(5.5, 5.0))
    ax.plot(reference[:, 1], reference[:, 0], "k--", lw=1.0, label="reference")
    ax.plot(measurement[:, 1], measurement[:, 0], "C0", lw=1.3, label="flown")
    if planned_ned is not None and len(planned_ned):
        ax.plot(planned_ned[:, 1], planned_ned[:, 0], "o:", color="C1", ms=5, lw=1.0,
                label="planned")
    ax.plot([0], [0], "s", color="C2", ms=7, label="home")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8, loc="best")
    ax.set_title("Path, seen from above")
    fig.subplots_adjust(left=0.15, right=0.97, bottom=0.1, top=0.92)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    plt.close(fig)
    return base64.b64encode(buffer.getvalue()).decode()


def run_page(run_dir: Path, metrics: dict[str, Any], run: dict[str, Any], marks: Marks,
             path_png: str | None, outcomes: list[tuple[str, bool, str]] | None) -> str:
    """The page's HTML. ``outcomes``: the scenario's expectations (name, held, measured),
    None when it has none."""
    e = html.escape
    name = metrics.get("scenario", run.get("scenario", "run"))
    if outcomes is None:
        verdict, css = "no expectations", "none"
    elif all(ok for _, ok, _ in outcomes):
        verdict, css = "expectations held", "ok"
    else:
        verdict, css = f"{sum(not ok for _, ok, _ in outcomes)} expectation(s) failed", "bad"
    if metrics.get("diverged"):
        verdict, css = "diverged", "bad"
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>{e(name)}: {e(verdict)}"
        f"</title><style>{_STYLE}</style></head><body>",
        f"<h1>{e(name)}</h1>",
        f"<div class='verdict {css}' id='verdict'>{e(verdict)}</div>",
        f"<p>{e(str(run.get('controller', '')))} on the {e(str(run.get('plant', '')))} plant, "
        f"airframe {e(str(run.get('airframe', '')))}, {e(str(run.get('mode', '')))} at "
        f"{run.get('rate_hz', '')} Hz, {e(str(metrics.get('sensors', 'ideal')))} sensors, "
        f"flying on {e(str(metrics.get('state_source', 'auto')))}, seed "
        f"{metrics.get('seed', 0)}. Folder <code>{e(str(run_dir))}</code>.</p>"]
    if outcomes is not None:
        parts.append("<h2>Expectations</h2><table id='expectations'><tr><th>expectation</th>"
                     "<th>result</th><th>measured</th></tr>")
        parts += [f"<tr{'' if ok else ' class=failed'}><td>{e(n)}</td><td>"
                  f"{'<span class=pass>held</span>' if ok else '<span class=fail>FAILED</span>'}"
                  f"</td><td>{e(text)}</td></tr>" for n, ok, text in outcomes]
        parts.append("</table>")
    axes = metrics.get("axes", {})
    if axes:
        parts.append("<h2>Tracking</h2><table id='metrics'><tr><th>axis</th><th>RMSE</th>"
                     "<th>MSE</th><th>max |e|</th></tr>")
        parts += [f"<tr><td>{e(axis)}</td><td>{_num(m.get('rmse'))}</td><td>"
                  f"{_num(m.get('mse'))}</td><td>{_num(m.get('max_abs'))}</td></tr>"
                  for axis, m in axes.items()]
        parts.append("</table>")
        control = metrics.get("control", {})
        extra = [(k, control[k]) for k in ("effort_mean_sum_c2", "chattering_per_s",
                                           "saturated_fraction") if k in control]
        if extra:
            parts.append("<p>" + "; ".join(f"{e(k.replace('_', ' '))} {_num(v)}"
                                           for k, v in extra) + "</p>")
    parts.append("<h2>Timeline</h2>")
    rows = sorted([(t, "perturbation", f"{w} (until {end:.2f} s)") for t, end, w in
                   marks.windows] + [(t, "event", w) for t, w in marks.events])
    if rows:
        parts.append("<table class='timeline' id='timeline'><tr><th>t [s]</th><th>what</th>"
                     "<th></th></tr>")
        parts += [f"<tr><td>{t:.2f}</td><td>{e(kind)}</td><td>{e(w)}</td></tr>"
                  for t, kind, w in rows]
        parts.append("</table><p>On the figures: perturbation windows shaded orange, events "
                     "as green lines (times from the start of tracking).</p>")
    else:
        parts.append("<p>No perturbations and no events.</p>")
    if path_png:
        parts.append(f"<h2>Path</h2><img id='path' alt='path from above' "
                     f"src='data:image/png;base64,{path_png}'>")
    for figure in FIGURES:
        png = run_dir / f"{figure}.png"
        if png.is_file():
            parts.append(f"<h2>{figure.capitalize()}</h2><img alt='{figure}' "
                         f"src='data:image/png;base64,{_png(png)}'>")
    parts.append("<p>Open the log (<code>*.mcap</code>) in Foxglove with the layout "
                 "<code>ivfm-sitl.foxglove-layout.json</code> shipped with ivfm-sitl "
                 "(docs/telemetry.md).</p></body></html>")
    return "\n".join(parts) + "\n"


def _num(value: Any) -> str:
    if value is None:
        return "-"
    try:
        return f"{float(value):.4g}"
    except (TypeError, ValueError):
        return html.escape(str(value))
