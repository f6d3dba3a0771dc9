"""What ground tools send the vehicle: position and attitude setpoints, the sticks of
MANUAL_CONTROL (RC overrides in the ArduPilot flavour), a Follow Me target, and the
ground station's heartbeat.

Each input is checked before anything changes, and stamped on the link clock, where the
stream failsafes (autopilot/commander/failsafe.py) look for it. A streamed setpoint is
flown at once in a mode that follows setpoints, else kept for when one is entered.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from autopilot.commander.failsafe import LinkWatch, Stream
from autopilot.commander.rc import RcInput
from autopilot.flight_tasks.follow import FollowTargetTask
from autopilot.flight_tasks.setpoints import checked_attitude_target, checked_position_setpoint
from autopilot.flight_tasks.shaping import Setpoint
from autopilot.flight_tasks.sticks import Sticks
from autopilot.flight_tasks.task import TaskState


@dataclass(eq=False)
class ToolInputs:
    """The input streams of one vehicle: ``follows_setpoints`` says whether its current
    mode flies a streamed setpoint as it arrives; ``say`` queues a STATUSTEXT."""

    links: LinkWatch
    state: TaskState
    follow: FollowTargetTask
    flavour: str
    follows_setpoints: Callable[[], bool]
    say: Callable[[str, int], None]
    # Copter: a target outside GUIDED is ignored (GCS_MAVLink_Copter returns unless the
    # mode is a guided one), not kept for later nor counted as a stream.
    targets_in_guided_only: bool = False

    def _ignored(self) -> bool:
        return self.targets_in_guided_only and not self.follows_setpoints()

    def __post_init__(self) -> None:
        self.rc = RcInput()  # the ArduPilot flavour's channels (autopilot/commander/rc.py)

    def gcs_heartbeat(self, link_t_s: float) -> None:
        """A ground station's HEARTBEAT; said when it ends a loss."""
        if self.links.gcs_heartbeat(link_t_s):
            self.say("ground station link regained", 5)

    def streaming(self, stream: Stream, link_t_s: float) -> bool:
        """Whether ``stream`` was heard within its timeout (COM_OF_LOSS_T / COM_RC_LOSS_T);
        in the ArduPilot flavour the sticks are the RC channels, there while overridden."""
        if self.flavour == "ardupilot" and stream is Stream.MANUAL:
            return self.rc.sticks_present
        return self.links.streaming(stream, link_t_s, self.state.parameters)

    def watched(self, stream: Stream | None) -> Stream | None:
        """The stream whose loss is the stream failsafe: in the ArduPilot flavour the
        radio failsafe (rc.RcPilot) watches the sticks instead."""
        if self.flavour == "ardupilot" and stream is Stream.MANUAL:
            return None
        return stream

    def position_setpoint(self, link_t_s: float, setpoint: Setpoint) -> None:
        """A local NED setpoint (NaN for what the tool left out); checked before anything
        changes. Per axis group a position (velocity and acceleration then feed-forward)
        or a velocity; a yaw or a yaw rate (docs/mavlink.md)."""
        checked = checked_position_setpoint(setpoint)
        if self._ignored():
            return
        self.links.setpoint_heard(link_t_s)
        self.state.stream_position(link_t_s, checked)
        if self.follows_setpoints():
            self.state.apply_streamed()

    def attitude_setpoint(self, link_t_s: float, quaternion: tuple | None,
                          thrust: float | None) -> None:
        """An attitude setpoint, thrust as the flavour reads it (setpoints.py)."""
        target = checked_attitude_target(quaternion, thrust, self.flavour,
                                         self.state.parameters["MPC_TKO_SPEED"])
        if self._ignored():
            return
        self.links.setpoint_heard(link_t_s)
        self.state.streamed = target
        if self.follows_setpoints():
            self.state.apply_streamed()

    def manual_input(self, link_t_s: float, sticks: Sticks) -> None:
        """MANUAL_CONTROL's sticks (checked by sticks.sticks_from_manual_control)."""
        self.links.manual_heard_s = link_t_s
        self.state.sticks = sticks

    def rc_override(self, link_t_s: float, channels: list[int]) -> None:
        """RC_CHANNELS_OVERRIDE's (or MANUAL_CONTROL's) 18 channels, checked by
        RcInput.override; the commander reads sticks and the mode switch off them."""
        self.rc.override(link_t_s, channels, self.state.parameters)

    def follow_target(self, position_ned_m: np.ndarray,
                      velocity_ned_mps: np.ndarray | None) -> None:
        """A FOLLOW_TARGET report in local NED (None: no velocity given), stamped with the
        sim time it arrived at; refused (RefusedError) and ignored when out of range."""
        self.follow.report(self.state.sim_t_s, position_ned_m, velocity_ned_mps)
