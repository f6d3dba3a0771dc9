"""Mixer: invert the rotor map (docs/mathematics.md), saturating with roll/pitch authority first."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from contracts.airframe import Airframe


@njit(cache=True)
def mix(
    u_z: float, u_phi: float, u_theta: float, u_psi: float, af: Airframe
) -> np.ndarray:
    """Normalised motor commands c_i = W_i / W_max in [0, 1] for the wanted forces.

    Squared speeds W_i^2 = a +- r/p -+ y with a = U_z/4b, r = U_phi/2b, p = U_theta/2b,
    y = U_psi/4d. When they do not fit in [0, W_max^2]: roll/pitch are scaled to fit,
    thrust then moves to make room for them, and yaw gets what is left (as PX4's mixer
    gives up yaw first).
    """
    b, d = af.thrust_coeff_ns2, af.drag_coeff_nms2
    top = af.rotor_max_rad_s * af.rotor_max_rad_s
    a = u_z / (4.0 * b)
    r = u_phi / (2.0 * b)
    p = u_theta / (2.0 * b)
    y = u_psi / (4.0 * d)
    a = min(max(a, 0.0), top)
    spread = max(abs(r), abs(p))
    # Roll/pitch must fit between 0 and top around the collective: above, the collective
    # gives way (attitude first); below, roll/pitch shrink rather than the collective
    # rising, so a vehicle asked to descend does not climb on attitude demands.
    room = min(a, top / 2.0) if a < spread else top / 2.0
    if spread > room:
        scale = room / spread
        r *= scale
        p *= scale
        spread = room
    a = min(max(a, spread), top - spread)
    # Yaw must keep every rotor in [0, top]: rotors 1, 3 carry -y, rotors 2, 4 carry +y.
    y_low = max(a + abs(p) - top, -(a - abs(r)))
    y_high = min(a - abs(p), top - a - abs(r))
    y = min(max(y, y_low), y_high)
    out = np.empty(4)
    out[0] = a + p - y
    out[1] = a - r + y
    out[2] = a - p - y
    out[3] = a + r + y
    for i in range(4):
        out[i] = math.sqrt(min(max(out[i], 0.0), top)) / af.rotor_max_rad_s
    return out
