"""Failsafes timed on the link clock: the ground station's heartbeat, the offboard
setpoint stream and manual control (PX4's COM_DL_LOSS_T / NAV_DLL_ACT, COM_OF_LOSS_T /
COM_OBL_ACT and COM_RC_LOSS_T / NAV_RCL_ACT).
Pure: the vehicle calls it with the link clock and carries out the action it names."""

from __future__ import annotations

from contracts.modes import FlightMode

# NAV_DLL_ACT: what ground-station loss does (PX4's numbers).
GCS_LOSS_ACTIONS: dict[int, FlightMode | None] = {0: None, 1: FlightMode.HOLD,
                                                  2: FlightMode.RTL, 3: FlightMode.LAND}


# NAV_RCL_ACT: what the loss of manual control does in a manual mode.
MANUAL_LOSS_ACTIONS: dict[int, FlightMode] = {1: FlightMode.HOLD, 2: FlightMode.RTL,
                                              3: FlightMode.LAND}


def offboard_loss_action(com_obl_act: float) -> FlightMode:
    """COM_OBL_ACT: 0 lands, otherwise hold."""
    return FlightMode.LAND if com_obl_act == 0 else FlightMode.HOLD


class LinkWatch:
    """When the ground station and the setpoint stream were last heard (link clock)."""

    def __init__(self) -> None:
        self.gcs_heard_s: float | None = None
        self.gcs_lost = False
        self.setpoint_heard_s: float | None = None
        self.manual_heard_s: float | None = None

    def gcs_heartbeat(self, link_t_s: float) -> bool:
        """A ground station heartbeat; True if it ends a loss."""
        self.gcs_heard_s = link_t_s
        regained, self.gcs_lost = self.gcs_lost, False
        return regained

    def gcs_lost_now(self, link_t_s: float, timeout_s: float) -> bool:
        """True once, when the ground station has been silent for ``timeout_s``."""
        if (self.gcs_heard_s is not None and not self.gcs_lost
                and link_t_s - self.gcs_heard_s > timeout_s):
            self.gcs_lost = True
            return True
        return False

    def setpoint_heard(self, link_t_s: float) -> None:
        self.setpoint_heard_s = link_t_s

    def setpoints_streaming(self, link_t_s: float, timeout_s: float) -> bool:
        return self.setpoint_heard_s is not None and \
            link_t_s - self.setpoint_heard_s <= timeout_s

    def manual_streaming(self, link_t_s: float, timeout_s: float) -> bool:
        return self.manual_heard_s is not None and link_t_s - self.manual_heard_s <= timeout_s
