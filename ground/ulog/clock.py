"""A PX4 log's signals on one clock: the armed, airborne spans (vehicle_status armed and
vehicle_land_detected not landed), trimmed at both ends and cut at gaps in any signal; a
uniform grid over each; the attitude by slerp, the rates linearly, the Euler angles, rates
and (from PX4's derivative of the body rates) accelerations of the ZYX convention
(contracts/frames.py), row by row.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import make_interp_spline
from scipy.spatial.transform import Rotation, Slerp

from autopilot.trajectories import abs_reach, tail_reach
from ground.ulog.read import ARMED_VALUE, PX4Log, Series, ULogError

# Left out at the start and the end of each airborne span: the take-off (ground effect;
# ivfm identify --log skips 2 s likewise) and the landing (the land detector says landed
# a second or more after the touch-down).
DEFAULT_TRIM_S = (2.0, 2.0)
MAX_RATE_HZ = 100.0  # the default clock: the body rates' own, at most the control rate here
MIN_SPAN_S = 1.0  # shorter airborne pieces are left out
# Logged times are whole microseconds: an instant within half of one of a sample is at it
# (the grid's sums of periods round).
TIME_TOLERANCE_S = 0.5e-6

# -- airborne spans ------------------------------------------------------------------------

@dataclass(frozen=True)
class Spans:
    """The armed, airborne time of a log [s since its start], trimmed."""

    spans: tuple[tuple[float, float], ...]
    airborne_s: float  # before trimming
    armed_s: float
    ends_airborne: bool  # the log stops with the vehicle in the air (cut short?)


def _state_at(series: Series, t: np.ndarray, predicate) -> np.ndarray:
    """The state in force at each instant (False before the first sample)."""
    idx = np.searchsorted(series.time_s, t, side="right") - 1
    state = predicate(series.values[np.clip(idx, 0, None), 0])
    return np.where(idx >= 0, state, False)


def _intervals(t: np.ndarray, state: np.ndarray, end_s: float) -> list[tuple[float, float]]:
    """The intervals where ``state`` (given at the change times ``t``) holds."""
    out: list[tuple[float, float]] = []
    for k in np.flatnonzero(state):
        a, b = float(t[k]), float(t[k + 1]) if k + 1 < len(t) else end_s
        if out and out[-1][1] == a:
            out[-1] = (out[-1][0], b)
        elif b > a:
            out.append((a, b))
    return out


def airborne_spans(log: PX4Log, trim_s: tuple[float, float] = DEFAULT_TRIM_S) -> Spans:
    """The spans where the vehicle was armed and the land detector said not landed,
    each trimmed by ``trim_s`` (start, end; no end trim where the log ends in the air)."""
    armed = log.series("armed")
    landed = log.series("landed")
    armed_value = ARMED_VALUE[armed.source.topic]
    end_s = log.duration_s
    t = np.union1d(armed.time_s, landed.time_s)
    is_armed = _state_at(armed, t, lambda v: v == armed_value)
    in_air = is_armed & ~_state_at(landed, t, lambda v: v != 0)
    armed_spans = _intervals(t, is_armed, end_s)
    air = _intervals(t, in_air, end_s)
    # A span the log ends in has no landing to trim, and keeps its last sample (the grid
    # is half-open [a, b)).
    ends = [(b + TIME_TOLERANCE_S, 0.0) if b >= end_s else (b, trim_s[1]) for _a, b in air]
    trimmed = tuple((a + trim_s[0], b - trim_end) for (a, _b), (b, trim_end) in
                    zip(air, ends, strict=True) if b - a > trim_s[0] + trim_end)
    return Spans(trimmed, sum(b - a for a, b in air), sum(b - a for a, b in armed_spans),
                 bool(air) and air[-1][1] >= end_s)


def _cut_at_gaps(spans: Sequence[tuple[float, float]], series: Sequence[Series],
                 min_span_s: float) -> list[tuple[float, float]]:
    """The spans within every series' samples, cut where one has a gap (5 of its own
    intervals, at least 0.05 s): nothing is interpolated across a dropout."""
    pieces = list(spans)
    for s in series:
        if len(s.time_s) < 2:
            return []
        limit = max(5.0 * s.interval_s(), 0.05)
        gaps = np.flatnonzero(np.diff(s.time_s) > limit)
        holes = [(s.time_s[g], s.time_s[g + 1]) for g in gaps]
        cut = []
        for a, b in pieces:
            a, b = max(a, float(s.time_s[0])), min(b, float(s.time_s[-1]) + TIME_TOLERANCE_S)
            for h0, h1 in holes:
                if h1 <= a or h0 >= b:
                    continue
                if h0 > a:
                    cut.append((a, float(h0)))
                a = max(a, float(h1))
            if b > a:
                cut.append((a, b))
        pieces = cut
    return [(a, b) for a, b in pieces if b - a >= min_span_s]


def _grid(spans: Sequence[tuple[float, float]], anchor: Series, period_s: float
          ) -> list[np.ndarray]:
    """Uniform instants per span, starting on the anchor's first sample in it (so a log
    sampled at the grid's rate is taken at its own samples)."""
    out = []
    for a, b in spans:
        k = np.searchsorted(anchor.time_s, a, side="left")
        start = float(anchor.time_s[k]) if k < len(anchor.time_s) else a
        n = int(math.ceil((b - start) / period_s - 1e-9))  # the instants before b
        if n >= 2:
            out.append(start + period_s * np.arange(n))
    return out


def _check_finite(series: Series, spans: Sequence[tuple[float, float]], path: Path) -> None:
    """Every sample that a span's instants are taken from is a finite number."""
    for a, b in spans:
        i0 = max(0, int(np.searchsorted(series.time_s, a, side="right")) - 1)
        i1 = int(np.searchsorted(series.time_s, b, side="left")) + 1
        block = series.values[i0:i1]
        bad = np.argwhere(~np.isfinite(block))
        if bad.size:
            row, col = bad[0]
            raise ULogError(
                f"{path}: {series.source.topic}.{series.fields[col]} is "
                f"{block[row, col]} at {series.time_s[i0 + row]:.3f} s, inside the "
                f"airborne span {a:.2f}-{b:.2f} s")


# -- kinematics ------------------------------------------------------------------------------

def euler_from_quaternions(q: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (N, 3) of quaternions (N, 4) [w, x, y, z]:
    contracts.frames.euler_from_quat, row by row."""
    w, x, y, z = q.T
    phi = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    theta = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    psi = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.column_stack([phi, theta, psi])


def _euler_terms(euler: np.ndarray) -> tuple[np.ndarray, ...]:
    cphi, sphi = np.cos(euler[:, 0]), np.sin(euler[:, 0])
    ctheta = np.cos(euler[:, 1])
    ctheta = np.copysign(np.maximum(np.abs(ctheta), 1e-6), ctheta)
    return cphi, sphi, ctheta, np.sin(euler[:, 1]) / ctheta


def euler_rates(euler: np.ndarray, body_rates: np.ndarray) -> np.ndarray:
    """[phi', theta', psi'] (N, 3) from body rates [p, q, r]:
    contracts.frames.euler_rates_from_body_rates, row by row."""
    cphi, sphi, ctheta, ttheta = _euler_terms(euler)
    p, q, r = body_rates.T
    return np.column_stack([p + (q * sphi + r * cphi) * ttheta, q * cphi - r * sphi,
                            (q * sphi + r * cphi) / ctheta])


def euler_accelerations(euler: np.ndarray, rates: np.ndarray, body_rates: np.ndarray,
                        body_acc: np.ndarray) -> np.ndarray:
    """d/dt of the Euler rates: E(phi, theta) w' + (dE/dt) w, with E the map of
    :func:`euler_rates` and ``rates`` the Euler rates."""
    cphi, sphi, ctheta, ttheta = _euler_terms(euler)
    p, q, r = body_rates.T
    phi_dot, theta_dot = rates[:, 0], rates[:, 1]
    out = euler_rates(euler, body_acc)
    a = q * sphi + r * cphi  # its phi-derivative is q cphi - r sphi
    da = phi_dot * (q * cphi - r * sphi)
    sec2 = 1.0 / (ctheta * ctheta)
    out[:, 0] += da * ttheta + a * sec2 * theta_dot
    out[:, 1] += -phi_dot * (q * sphi + r * cphi)
    out[:, 2] += da / ctheta + a * ttheta / ctheta * theta_dot
    return out


@dataclass(frozen=True)
class Kinematics:
    """Attitude, Euler rates and (when logged) accelerations on the common clock."""

    pieces: list[np.ndarray]  # the instants, one array per span piece
    euler_rad: list[np.ndarray]
    euler_rate_rad_s: list[np.ndarray]
    body_rates: list[np.ndarray]
    euler_acc_rad_s2: list[np.ndarray] | None  # None: the log has no acceleration
    sources: dict[str, str]


def _slerp(series: Series, t: np.ndarray, path: Path) -> np.ndarray:
    """The attitude quaternions [w, x, y, z] at ``t`` by spherical interpolation."""
    i0 = max(0, int(np.searchsorted(series.time_s, t[0], side="right")) - 1)
    i1 = int(np.searchsorted(series.time_s, t[-1], side="left")) + 1
    q = series.values[i0:i1]
    norms = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 0.01)
    if bad.size:
        raise ULogError(f"{path}: vehicle_attitude.q is not a unit quaternion at "
                        f"{series.time_s[i0 + bad[0]]:.3f} s (norm {norms[bad[0]]:.4g})")
    if len(q) == 1:
        return np.repeat(q / norms[:, None], len(t), axis=0)
    rotations = Rotation.from_quat(q[:, [1, 2, 3, 0]])  # scipy: scalar last
    times = series.time_s[i0:i1]
    xyzw = Slerp(times, rotations)(np.clip(t, times[0], times[-1])).as_quat()
    return xyzw[:, [3, 0, 1, 2]]


def _linear(series: Series, t: np.ndarray) -> np.ndarray:
    return make_interp_spline(series.time_s, series.values, k=1, axis=0)(t)


def held(series: Series, t: np.ndarray) -> np.ndarray:
    """The last sample at or before each instant."""
    return series.values[np.searchsorted(series.time_s, t + TIME_TOLERANCE_S,
                                         side="right") - 1]


def kinematics(log: PX4Log, spans: Sequence[tuple[float, float]], period_s: float | None,
               also: Sequence[Series] = ()) -> tuple[Kinematics, float]:
    """The attitude signals on the common clock over ``spans`` (cut at the gaps of these
    and of ``also``), and the clock's period."""
    attitude = log.series("attitude")
    rates = log.series("rates")
    found = log.source("acceleration")
    acceleration = log.series("acceleration") if found is not None else None
    if period_s is None:
        interval = rates.interval_s() if len(rates.time_s) > 1 else 1.0 / MAX_RATE_HZ
        period_s = max(round(interval, 6), 1.0 / MAX_RATE_HZ)
    used = [attitude, rates, *also] + ([acceleration] if acceleration is not None else [])
    pieces = _cut_at_gaps(spans, used, max(MIN_SPAN_S, 3 * period_s))
    for s in used:
        _check_finite(s, pieces, log.path)
    grid = _grid(pieces, rates, period_s)
    euler, euler_rate, body, acc = [], [], [], []
    for t in grid:
        e = euler_from_quaternions(_slerp(attitude, t, log.path))
        w = _linear(rates, t)
        er = euler_rates(e, w)
        euler.append(e)
        euler_rate.append(er)
        body.append(w)
        if acceleration is not None:
            acc.append(euler_accelerations(e, er, w, _linear(acceleration, t)))
    sources = {"attitude": attitude.label, "rates": rates.label}
    if acceleration is not None:
        sources["acceleration"] = acceleration.label
    return Kinematics(grid, euler, euler_rate, body, acc if acceleration is not None else None,
                      sources), period_s


def flight_reach(log: PX4Log, trim_s: tuple[float, float] = DEFAULT_TRIM_S
                 ) -> tuple[float, float, float] | None:
    """How far the airborne flight reached: roll/pitch attitude [rad], roll/pitch rate and
    yaw rate [rad/s], each the smaller side at the coverage tails (as the coverage check
    counts a rate); None when the log cannot say."""
    try:
        spans = airborne_spans(log, trim_s).spans
        kin, _period = kinematics(log, spans, None)
    except ULogError:
        return None
    if not kin.pieces:
        return None
    euler = np.concatenate(kin.euler_rad)
    rates = np.concatenate(kin.euler_rate_rad_s)
    return (min(abs_reach(euler[:, 0]), abs_reach(euler[:, 1])),
            min(tail_reach(rates[:, 0]), tail_reach(rates[:, 1])), tail_reach(rates[:, 2]))
