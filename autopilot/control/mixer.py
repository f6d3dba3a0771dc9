"""Mixer: the airframe's inverse input map with saturation priorities (docs/mathematics.md).

Like PX4's multirotor mixer: roll and pitch come first, the collective moves to make room
for them, and yaw gets what is left. Any quadrotor geometry: the rotors enter through
``Airframe.mixing`` (W_i^2 per unit of U_z, U_phi, U_theta, U_psi).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from contracts.airframe import Airframe


@njit(cache=True)
def mix(
    u_z: float, u_phi: float, u_theta: float, u_psi: float, af: Airframe
) -> np.ndarray:
    """Normalised motor commands c_i in [0, 1] (the airframe's command map) for the
    wanted inputs.

    W_i^2 = t_i U_z + rp_i + y_i with t, rp, y the mixing matrix's thrust, roll/pitch and
    yaw parts; each must stay in [0, W_max,i^2]. When they do not fit: roll/pitch are
    scaled to fit at some collective (and, below it, shrink rather than the collective
    rising, so a vehicle asked to descend does not climb on attitude demands); the
    collective then moves into the range that fits them; yaw is limited to what keeps
    every rotor in range.
    """
    m = af.mixing
    top = af.max_rad_s * af.max_rad_s
    t = m[:, 0]
    rp = m[:, 1] * u_phi + m[:, 2] * u_theta
    thrust = max(u_z, 0.0)
    # The collective must be at least `need` for no rotor to go below 0.
    need = 0.0
    for i in range(4):
        need = max(need, -rp[i] / t[i])
    if need > 0.0:
        scale = 1.0
        for i in range(4):
            # At collective `need`, rotor i sits at t_i need + rp_i, within its top?
            used = t[i] * need + rp[i]
            if used > top[i]:
                scale = min(scale, top[i] / used)
        scale = min(scale, thrust / need)
        if scale < 1.0:
            rp *= scale
            need *= scale
    room = math.inf
    for i in range(4):
        room = min(room, (top[i] - rp[i]) / t[i])
    thrust = min(max(thrust, need), room)
    w2 = t * thrust + rp
    y_low, y_high = -math.inf, math.inf
    for i in range(4):
        k = m[i, 3]
        if k > 0.0:
            y_low = max(y_low, -w2[i] / k)
            y_high = min(y_high, (top[i] - w2[i]) / k)
        elif k < 0.0:
            y_low = max(y_low, (top[i] - w2[i]) / k)
            y_high = min(y_high, -w2[i] / k)
    yaw = min(max(u_psi, y_low), y_high)
    out = np.empty(4)
    for i in range(4):
        x = min(max(w2[i] + m[i, 3] * yaw, 0.0), top[i])
        out[i] = x / top[i] if af.thrust_command_map else math.sqrt(x) / af.max_rad_s[i]
    return out
