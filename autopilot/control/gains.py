"""A sliding-mode channel's gains, read from the parameter table (autopilot/parameters.py)."""

from __future__ import annotations

from typing import NamedTuple


class ChannelGains(NamedTuple):
    """One sliding-mode channel's gains, in the form the compiled law takes."""

    lam: float
    gam: float
    eps: float
    eta_f: float
    eta_g: float
    w_f: float
    w_g: float
    g0: float  # absolute lower bound of theta_g
    g_max: float  # absolute upper bound of theta_g


def channel_gains(params: dict[str, float], group: str, g_initial: float,
                  adaptive: bool = True) -> ChannelGains:
    """Gains of one channel; a non-adaptive controller sets both adaptation rates to 0."""
    return ChannelGains(
        lam=params[f"{group}_LAM"],
        gam=params[f"{group}_GAM"],
        eps=params[f"{group}_EPS"],
        eta_f=params[f"{group}_ETA_F"] if adaptive else 0.0,
        eta_g=params[f"{group}_ETA_G"] if adaptive else 0.0,
        w_f=params[f"{group}_WF"],
        w_g=params[f"{group}_WG"],
        g0=params[f"{group}_G0"] * g_initial,
        g_max=g_initial / params[f"{group}_G0"],
    )
