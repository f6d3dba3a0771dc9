"""What a PX4 log holds for identification (``ivfm ulog info``): the firmware and vehicle,
how long it flew, where each signal is and how often it was logged, how far the flight
reached against an airframe's envelope, and what it lacks for ``ivfm identify --ulog`` and
``ivfm airframe from-ulog``."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from autopilot.identification.coverage import SignalCoverage, coverage, format_coverage
from autopilot.trajectories import COVERAGE_TAIL, abs_reach
from contracts.airframe import airframe_from_spec
from contracts.airframe_file import AirframeSpec, Envelope, envelope_of
from ground.ulog.airframe_draft import hover_thrust, layout, rotors_from_log
from ground.ulog.clock import DEFAULT_TRIM_S, airborne_spans, kinematics
from ground.ulog.identification import DEFAULT_CUTOFF_HZ, identification_data_of
from ground.ulog.read import (
    CA_AIRFRAMES,
    IDENTIFICATION_SIGNALS,
    SIGNALS,
    PX4Log,
    ULogError,
    check_quad_log,
    mav_type_name,
    missing_message,
    read_log,
    rotor_count,
)

REACH_SIGNALS = ("phi_rad", "theta_rad", "phi_rate_rad_s", "theta_rate_rad_s",
                 "psi_rate_rad_s")


@dataclass
class SignalInfo:
    signal: str
    label: str | None  # where it was found, None: missing
    rate_hz: float | None = None
    samples: int = 0


@dataclass
class LogInfo:
    path: Path
    version: str
    hardware: str
    duration_s: float
    vehicle: list[str]
    signals: list[SignalInfo]
    parameters: list[str]
    armed_s: float | None = None
    airborne_s: float | None = None
    spans: tuple[tuple[float, float], ...] = ()
    ends_airborne: bool = False
    reach: list[SignalCoverage] | None = None  # against the envelope (--airframe)
    ranges: dict[str, tuple[float, float, float, float]] | None = None  # min, tails, max
    reach_rows: int = 0
    lacks_identification: list[str] = field(default_factory=list)
    lacks_draft: list[str] = field(default_factory=list)
    draft_refused: str | None = None
    warnings: list[str] = field(default_factory=list)


def _signals(log: PX4Log) -> list[SignalInfo]:
    out = []
    for signal in SIGNALS:
        if signal == "nav_state":
            continue
        if log.source(signal) is None:
            out.append(SignalInfo(signal, None))
            continue
        s = log.series(signal)
        interval = s.interval_s()
        out.append(SignalInfo(signal, s.label, 1.0 / interval if np.isfinite(interval)
                              and interval > 0 else None, len(s.time_s)))
    return out


def _vehicle(log: PX4Log) -> list[str]:
    p = log.parameters
    out = [f"MAV_TYPE {mav_type_name(p.get('MAV_TYPE'))}"]
    if "CA_AIRFRAME" in p:
        out.append(f"CA_AIRFRAME {int(p['CA_AIRFRAME'])} "
                   f"({CA_AIRFRAMES.get(int(p['CA_AIRFRAME']), 'unknown')})")
    count, where = rotor_count(log)
    out.append(f"{count} rotors ({where})" if count is not None else f"rotors: {where}")
    if "SYS_AUTOSTART" in p:
        out.append(f"SYS_AUTOSTART {int(p['SYS_AUTOSTART'])}")
    return out


def _parameters(log: PX4Log, info: LogInfo) -> list[str]:
    out = []
    factor = log.parameter("thrust_model_factor")
    out.append(f"{factor[0]} {factor[1]:g}" if factor else
               "no THR_MDL_FAC (the airframe's command map is taken)")
    hover = hover_thrust(log)
    if hover is not None:
        out.append(f"hover thrust {hover[0]:.3f} ({hover[1]})")
    else:
        info.lacks_draft.append("a hover thrust (hover_thrust_estimate or MPC_THR_HOVER)")
    try:
        rotors = rotors_from_log(log)
    except ULogError as exc:
        info.draft_refused = str(exc).removeprefix(f"{log.path}: ")
    else:
        if rotors is None:
            info.lacks_draft.append("rotor positions and spins (no CA_ROTOR* parameters: PX4 "
                               "before 1.13)")
        else:
            out.append(f"rotor geometry: {layout(rotors)}, CA_ROTOR0-3 "
                       + ", ".join(f"({r.position_m[0]:g}, {r.position_m[1]:g}) {r.spin}"
                                   if r.position_m and r.spin else "incomplete"
                                   for r in rotors))
    if log.topic("esc_status") is not None:
        out.append("esc_status logged (rotor speeds)")
    return out


def _raw_ranges(columns: dict[str, np.ndarray]) -> dict[str, tuple[float, float, float, float]]:
    out = {}
    for name, values in columns.items():
        low, high = np.quantile(values, [COVERAGE_TAIL, 1.0 - COVERAGE_TAIL])
        out[name] = (float(values.min()), float(low), float(high), float(values.max()))
    return out


def log_info(path: str | Path, airframe: AirframeSpec | None = None,
             envelope: Envelope | None = None, trim_s: tuple[float, float] = DEFAULT_TRIM_S
             ) -> LogInfo:
    """What the log at ``path`` holds for identification; ULogError only for a file that
    is not a readable ULog (everything else is reported as lacking)."""
    log = read_log(path)
    hardware = str(log.ulog.msg_info_dict.get("ver_hw", "unknown hardware"))
    info = LogInfo(log.path, log.version(), hardware, log.duration_s, _vehicle(log),
                   _signals(log), [], warnings=list(log.warnings))
    info.parameters = _parameters(log, info)
    missing = [s.signal for s in info.signals if s.label is None]
    for signal in IDENTIFICATION_SIGNALS:
        if signal in missing:
            info.lacks_identification.append(missing_message(signal).removeprefix(
                "the log has no "))
    try:
        check_quad_log(log)
    except ULogError as exc:
        info.lacks_identification.append(str(exc).removeprefix(f"{log.path}: "))
    if "armed" in missing or "landed" in missing:
        return info
    spans = airborne_spans(log, trim_s)
    info.armed_s, info.airborne_s = spans.armed_s, spans.airborne_s
    info.spans, info.ends_airborne = spans.spans, spans.ends_airborne
    if not spans.spans:
        info.lacks_identification.append(
            f"an airborne span longer than {trim_s[0] + trim_s[1]:g} s")
        return info
    if "attitude" in missing or "rates" in missing:
        return info
    need = envelope or (envelope_of(airframe) if airframe is not None else None)
    if airframe is not None and not info.lacks_identification:
        try:
            data = identification_data_of(log, airframe_from_spec(airframe), None,
                                        DEFAULT_CUTOFF_HZ, trim_s, None)
        except ULogError as exc:
            info.lacks_identification.append(str(exc).removeprefix(f"{log.path}: "))
        else:
            info.reach = coverage(data.dataset, need)
            info.reach_rows = data.dataset.n_rows
            return info
    try:
        kin, _period = kinematics(log, spans.spans, None)
    except ULogError as exc:
        info.lacks_identification.append(str(exc).removeprefix(f"{log.path}: "))
        return info
    if not kin.pieces:
        info.lacks_identification.append("an airborne span without gaps in the attitude")
        return info
    euler = np.concatenate(kin.euler_rad)
    rates = np.concatenate(kin.euler_rate_rad_s)
    columns = {"phi_rad": euler[:, 0], "theta_rad": euler[:, 1],
               "phi_rate_rad_s": rates[:, 0], "theta_rate_rad_s": rates[:, 1],
               "psi_rate_rad_s": rates[:, 2]}
    info.reach_rows = len(euler)
    if need is not None:
        half = max(1, round(0.5 * len(euler)))
        needs = dict(zip(REACH_SIGNALS, (need.attitude_rad, need.attitude_rad, need.rate_rad_s,
                                         need.rate_rad_s, need.yaw_rate_rad_s), strict=True))
        info.reach = []
        for name in REACH_SIGNALS:
            values = columns[name][:half]
            low, high = np.quantile(values, [COVERAGE_TAIL, 1.0 - COVERAGE_TAIL])
            magnitude = abs_reach(values) if name in ("phi_rad", "theta_rad") else None
            info.reach.append(SignalCoverage(name, needs[name], float(low), float(high),
                                             magnitude))
    else:
        info.ranges = _raw_ranges(columns)
    return info


def format_info(info: LogInfo) -> str:
    lines = [f"{info.path}: PX4 {info.version}, {info.hardware}, {info.duration_s:.1f} s",
             f"vehicle: {', '.join(info.vehicle)}"]
    if info.airborne_s is not None:
        kept = sum(b - a for a, b in info.spans)
        lines.append(f"flight: armed {info.armed_s:.1f} s, airborne {info.airborne_s:.1f} s; "
                     f"{kept:.1f} s in {len(info.spans)} span"
                     f"{'s' if len(info.spans) != 1 else ''} after trimming"
                     + ("; the log ends in the air (cut short?)" if info.ends_airborne else ""))
    lines.append("signals:")
    for s in info.signals:
        if s.label is None:
            lines.append(f"  {s.signal:<13} missing: {missing_message(s.signal).split(': ', 1)[1]}")
        else:
            rate = f"{s.rate_hz:7.1f} Hz" if s.rate_hz is not None else "        "
            lines.append(f"  {s.signal:<13} {rate}  {s.label} ({s.samples} samples)")
    lines.append("parameters: " + "; ".join(info.parameters))
    if info.reach is not None:
        lines.append(f"reach in the identification half of {info.reach_rows} airborne "
                     "samples:")
        lines.append(format_coverage(info.reach))
    elif info.ranges is not None:
        lines.append(f"reach over {info.reach_rows} airborne samples (no --airframe: no "
                     "envelope to judge against):")
        lines.append(f"{'signal':<18}{'min':>10}{'0.5 %':>10}{'99.5 %':>10}{'max':>10}")
        for name, (lo, q0, q1, hi) in info.ranges.items():
            lines.append(f"{name:<18}{lo:>10.3f}{q0:>10.3f}{q1:>10.3f}{hi:>10.3f}")
    covered = info.reach is None or all(c.covered for c in info.reach)
    if info.lacks_identification:
        lines.append("identification (ivfm identify --ulog): cannot, the log lacks "
                     + "; ".join(info.lacks_identification))
    elif info.reach is not None and not covered:
        lines.append("identification (ivfm identify --ulog): the flight does not cover the "
                     "envelope (see above): refused unless --allow-narrow or a smaller "
                     "--envelope")
    elif info.reach is None:
        lines.append("identification (ivfm identify --ulog): every signal is there; give "
                     "--airframe to judge the reach against its envelope")
    else:
        lines.append("identification (ivfm identify --ulog): ready, the flight covers the "
                     "envelope")
    if info.draft_refused:
        lines.append(f"draft airframe (ivfm airframe from-ulog): refused: {info.draft_refused}")
    elif info.lacks_draft:
        lines.append("draft airframe (ivfm airframe from-ulog): the log lacks "
                     + "; ".join(info.lacks_draft) + " (marked TO_FILL, with the inertia)")
    else:
        lines.append("draft airframe (ivfm airframe from-ulog): geometry and hover thrust "
                     "read; the inertia (and top speed, unless ESC rpm) to fill")
    lines += [f"warning: {w}" for w in info.warnings]
    return "\n".join(lines)
