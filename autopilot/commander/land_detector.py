"""Land detection: on the ground means low, still and not asked to lift off (pure)."""

from __future__ import annotations

LANDED_ALTITUDE_M = 0.05  # the plant's ground is z = 0
LANDED_SPEED_MPS = 0.1


class LandDetector:
    """Whether the vehicle is on the ground, and since when (sim time)."""

    def __init__(self) -> None:
        self.landed = True
        self.landed_since_s: float | None = 0.0

    def update(self, sim_t_s: float, altitude_m: float, down_speed_mps: float,
               lifting_off: bool) -> str | None:
        """Take one sample; "landed" or "airborne" when the state changes, else None."""
        on_ground = (altitude_m < LANDED_ALTITUDE_M and abs(down_speed_mps) < LANDED_SPEED_MPS
                     and not lifting_off)
        if on_ground and not self.landed:
            self.set(True, sim_t_s)
            return "landed"
        if not on_ground and self.landed:
            self.set(False, sim_t_s)
            return "airborne"
        return None

    def set(self, landed: bool, sim_t_s: float) -> None:
        """Declare the state (arming restarts the landed timer; a scenario starts flying)."""
        self.landed = landed
        self.landed_since_s = sim_t_s if landed else None

    def landed_for_s(self, sim_t_s: float) -> float:
        """How long the vehicle has been on the ground (0 in the air)."""
        if not self.landed or self.landed_since_s is None:
            return 0.0
        return sim_t_s - self.landed_since_s
