"""Which measured signals each channel's fuzzy model takes as inputs (its regressors).

Shared by the flight controller, which evaluates the models, and the offline
identification, which fits them; docs/mathematics.md gives the equations.
"""

from __future__ import annotations

# The one place that says which regressors each channel's f uses (docs/mathematics.md).
CHANNEL_REGRESSORS: dict[str, tuple[str, ...]] = {
    "phi": ("theta_rate_rad_s", "psi_rate_rad_s", "w_r_rad_s"),
    "theta": ("phi_rate_rad_s", "psi_rate_rad_s", "w_r_rad_s"),
    "psi": ("phi_rate_rad_s", "theta_rate_rad_s"),
}


def current_column_name(name: str) -> str:
    """The name a column has today: files written before 0.5 wrote rad/s as ``_rps``."""
    return name.replace("_rps2", "_rad_s2").replace("_rps", "_rad_s")
