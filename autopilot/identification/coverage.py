"""Does the identification data cover the envelope the model will fly?

A fuzzy model is fitted on the range its data spans; flown outside it, the Gaussians'
tails and the consequents extrapolate. The paper's f_theta takes the roll rate as input:
identified on data whose roll rate stayed under 0.5 rad/s, it was flown at 1 rad/s and
tracked pitch six times worse than roll (docs/reproducing.md). So the data's reach is
checked against the envelope, per signal and per side, before a model is written.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from autopilot.identification.dataset import Dataset
from autopilot.trajectories import COVERAGE_TAIL, abs_reach
from contracts.airframe_file import Envelope

ATTITUDES = ("phi_rad", "theta_rad")


class SignalCoverage(NamedTuple):
    """How far one signal of the data reaches against what the envelope needs."""

    column: str
    need: float  # the envelope
    low: float  # the data's COVERAGE_TAIL quantile
    high: float  # the data's 1 - COVERAGE_TAIL quantile
    # A rate must reach -need and +need (a model input, extrapolated past its data); an
    # attitude only |angle| >= need (it sets the thrust the vehicle flies at, either way).
    magnitude: float | None = None  # attitudes: the 1 - 2 COVERAGE_TAIL quantile of |x|

    @property
    def reach(self) -> float:
        """The reach as a fraction of the envelope (>= 1: covered)."""
        if self.magnitude is not None:
            return self.magnitude / self.need
        return min(-self.low, self.high) / self.need

    @property
    def covered(self) -> bool:
        return self.reach >= 1.0


def coverage(dataset: Dataset, envelope: Envelope, split: float = 0.5
             ) -> list[SignalCoverage]:
    """Each checked signal's reach in the rows that identify (the first ``split``): roll
    and pitch angles and rates, and the yaw rate."""
    n_ident = max(1, int(round(split * dataset.n_rows)))
    needs = {"phi_rad": envelope.attitude_rad, "theta_rad": envelope.attitude_rad,
             "phi_rate_rad_s": envelope.rate_rad_s, "theta_rate_rad_s": envelope.rate_rad_s,
             "psi_rate_rad_s": envelope.yaw_rate_rad_s}
    out = []
    for column, need in needs.items():
        data = dataset.columns[column][:n_ident]
        low, high = np.quantile(data, [COVERAGE_TAIL, 1.0 - COVERAGE_TAIL])
        magnitude = abs_reach(data) if column in ATTITUDES else None
        out.append(SignalCoverage(column, float(need), float(low), float(high), magnitude))
    return out


def format_coverage(report: list[SignalCoverage]) -> str:
    """A table of the reach, one row per signal."""
    tail = f"{100 * COVERAGE_TAIL:g} %"
    lines = [f"Coverage of the envelope (the identification data's {tail} and "
             f"{100 - 100 * COVERAGE_TAIL:g} % quantiles)",
             f"{'signal':<18}{'envelope':>10}{'low':>10}{'high':>10}{'|x|':>10}  covered"]
    for c in report:
        magnitude = "" if c.magnitude is None else f"{c.magnitude:.3f}"
        lines.append(f"{c.column:<18}{c.need:>10.3f}{c.low:>10.3f}{c.high:>10.3f}"
                     f"{magnitude:>10}  {'yes' if c.covered else f'no ({100 * c.reach:.0f} %)'}")
    lines.append("(a rate must reach the envelope on both sides, an attitude either way)")
    return "\n".join(lines)


def coverage_metadata(envelope: Envelope, report: list[SignalCoverage]) -> dict:
    """What a model file records of its envelope and the data's reach."""
    return {"envelope": {"attitude_rad": envelope.attitude_rad,
                         "rate_rad_s": envelope.rate_rad_s,
                         "yaw_rate_rad_s": envelope.yaw_rate_rad_s},
            "coverage": {c.column: [round(c.low, 6), round(c.high, 6)] for c in report},
            "covered": all(c.covered for c in report)}
