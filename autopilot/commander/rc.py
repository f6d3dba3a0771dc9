"""RC as a ground tool sends it (the ArduPilot flavour): RC_CHANNELS_OVERRIDE and
MANUAL_CONTROL onto 18 channels, read as ArduPilot Copter reads them (pure: the link
clock is passed in).

There is no simulated receiver: the channels are what the ground tool overrides, 0 where
it overrides nothing. Copter's rules (libraries/GCS_MAVLink/GCS_Common.cpp,
libraries/RC_Channel):

* per channel of RC_CHANNELS_OVERRIDE: 65535 leaves the channel as it is, 0 releases it;
  for channels 9-18 0 also leaves it and 65534 releases it. An override lasts
  RC_OVERRIDE_TIME after the last one for its channel (negative: until released).
* MANUAL_CONTROL is the same override on channels 1-4: y roll and r yaw as
  1500 + v / 2, x pitch reversed (1500 - x / 2: forward is low PWM), z throttle 1000 + z;
  INT16_MAX releases that channel.
* the sticks: roll 1, pitch 2, throttle 3, yaw 4 (1000-2000 us around 1500); in the
  modes whose throttle is a climb rate Copter's deadzone THR_DZ around mid stick.
* the mode switch on FLTMODE_CH: six PWM bands, a band held for 200 ms is a position,
  and a new position (not the first one seen) selects FLTMODEn.
* the radio failsafe: overrides in force but none received for 1 s
  (FS_RADIO_RC_OVERRIDE_TIMEOUT_MS), or the throttle below FS_THR_VALUE three frames in a
  row; cleared by three good frames.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Protocol

from autopilot.commander.failsafe import FailsafeDecision, FailsafeView, decide, radio_loss_action
from autopilot.flight_tasks.sticks import Sticks
from autopilot.flight_tasks.task import TaskState
from autopilot.refusal import RefusedError
from contracts.modes import FlightMode, mode_from_custom

CHANNELS = 18
IGNORE = 0xFFFF  # UINT16_MAX: leave the channel as it is
RELEASE_HIGH = 0xFFFE  # UINT16_MAX - 1: release channels 9-18
PWM_MIN_US, PWM_MAX_US = 800, 2200  # an override outside is refused (Copter takes any)
STICK_MID_US, STICK_HALF_US = 1500, 500
THROTTLE_LOW_US = 1000
INT16_MAX = 0x7FFF  # MANUAL_CONTROL: release this axis
# Copter's mode switch bands: the upper edge of positions 1-5 [us]; above: position 6.
MODE_SWITCH_EDGES_US = (1230, 1360, 1490, 1620, 1749)
MODE_SWITCH_VALID_US = (900, 2200)  # exclusive: a pulse outside is an error, ignored
SWITCH_DEBOUNCE_S = 0.2  # SWITCH_DEBOUNCE_TIME_MS
RADIO_OVERRIDE_TIMEOUT_S = 1.0  # FS_RADIO_RC_OVERRIDE_TIMEOUT_MS (Copter 4.5, 4.6)
LOW_THROTTLE_FRAMES = 3  # FS_COUNTER
ROLL, PITCH, THROTTLE, YAW = 0, 1, 2, 3


def switch_position(pwm_us: int) -> int | None:
    """The mode switch position (0-5) of a pulse, None if the pulse is an error."""
    low, high = MODE_SWITCH_VALID_US
    if not low < pwm_us < high:
        return None
    return sum(pwm_us > edge for edge in MODE_SWITCH_EDGES_US)


def manual_control_channels(x: int, y: int, z: int, r: int) -> list[int]:
    """MANUAL_CONTROL's axes as an RC_CHANNELS_OVERRIDE of channels 1-4 (0 releases,
    IGNORE elsewhere), checked: x, y, r in [-1000, 1000], z in [0, 1000], or INT16_MAX."""
    for name, value, low in (("x", x, -1000), ("y", y, -1000), ("z", z, 0),
                             ("r", r, -1000)):
        if value != INT16_MAX and not low <= value <= 1000:
            raise RefusedError(f"manual control {name} {value} is outside [{low}, 1000]")
    out = [IGNORE] * CHANNELS
    for channel, value, pwm in ((ROLL, y, STICK_MID_US + y / 2),
                                (PITCH, x, STICK_MID_US - x / 2),
                                (THROTTLE, z, THROTTLE_LOW_US + z),
                                (YAW, r, STICK_MID_US + r / 2)):
        out[channel] = 0 if value == INT16_MAX else round(pwm)
    return out


def _inverse_deadband(value: float, width: float) -> float:
    """The value that sticks.deadband(., width) turns back into ``value``: the stick
    tasks apply their own deadband (MPC_HOLD_DZ); Copter's THR_DZ replaces it."""
    if value == 0.0:
        return 0.0
    return math.copysign(width + (1.0 - width) * abs(value), value)


def sticks_from_channels(pwm: Sequence[int], throttle_deadzone: float | None,
                         hold_deadband: float) -> Sticks:
    """Channels 1-4 as the stick tasks read sticks (sticks.py): roll right, pitch low
    forward, throttle 1000-2000 as 0-1, yaw right; an absent channel centred.
    ``throttle_deadzone`` (THR_DZ / 1000 of the throttle range, None: none) is the band
    around mid stick that holds the altitude, in place of ``hold_deadband``."""
    def centred(channel: int) -> float:
        if not pwm[channel]:
            return 0.0
        return min(1.0, max(-1.0, (pwm[channel] - STICK_MID_US) / STICK_HALF_US))

    throttle = 0.5
    if pwm[THROTTLE]:
        throttle = min(1.0, max(0.0, (pwm[THROTTLE] - THROTTLE_LOW_US) / 1000.0))
        if throttle_deadzone is not None:
            half = min(0.999, 2.0 * throttle_deadzone)  # of the -1..1 stick range
            s = 2.0 * throttle - 1.0
            s = 0.0 if abs(s) <= half else math.copysign((abs(s) - half) / (1.0 - half), s)
            throttle = 0.5 + 0.5 * _inverse_deadband(s, hold_deadband)
    return Sticks(forward=-centred(PITCH), right=centred(ROLL), throttle=throttle,
                  yaw=centred(YAW))


class RcInput:
    """The 18 channels a ground tool overrides, with their expiry, the mode switch and
    the radio failsafe's inputs (link clock)."""

    def __init__(self) -> None:
        self.values = [0] * CHANNELS  # the override of each channel, 0 none
        self.set_s: list[float] = [0.0] * CHANNELS  # when each was last overridden
        # What the vehicle sees now [us], 0 no channel (Commander.rc_channels_pwm).
        self.pwm: tuple[int, ...] = (0,) * CHANNELS
        self.heard_s: float | None = None  # the last override frame
        self.low_throttle = 0  # frames in a row below FS_THR_VALUE (Copter's counter)
        self.failsafe = False
        self._switch: int | None = None  # the mode switch's established position
        self._bounce: tuple[int, float] | None = None  # (position, since) not yet taken

    def override(self, link_t_s: float, raw: Sequence[int], p: Mapping[str, float]) -> None:
        """RC_CHANNELS_OVERRIDE's 18 values (MANUAL_CONTROL's through
        manual_control_channels): all checked before any is taken."""
        if len(raw) != CHANNELS:
            raise RefusedError(f"RC override needs {CHANNELS} channels, got {len(raw)}")
        wanted: list[tuple[int, int]] = []
        for i, value in enumerate(raw):
            if value == IGNORE or (i >= 8 and value == 0):
                continue
            if i >= 8 and value == RELEASE_HIGH:
                value = 0
            if value and not PWM_MIN_US <= value <= PWM_MAX_US:
                raise RefusedError(f"RC override channel {i + 1}: {value} is outside "
                                   f"[{PWM_MIN_US}, {PWM_MAX_US}] us")
            wanted.append((i, value))
        for i, value in wanted:
            self.values[i], self.set_s[i] = value, link_t_s
        if wanted:
            self.heard_s = link_t_s
        self.refresh(link_t_s, p["RC_OVERRIDE_TIME"])
        throttle = self.pwm[THROTTLE]
        if throttle and throttle < p["FS_THR_VALUE"]:
            self.low_throttle = min(LOW_THROTTLE_FRAMES, self.low_throttle + 1)
        elif wanted:
            self.low_throttle = max(0, self.low_throttle - 1)

    def refresh(self, link_t_s: float, timeout_s: float) -> None:
        """Expire the overrides older than ``timeout_s`` (RC_OVERRIDE_TIME)."""
        if timeout_s >= 0:
            for i in range(CHANNELS):
                if self.values[i] and link_t_s - self.set_s[i] >= timeout_s:
                    self.values[i] = 0
        self.pwm = tuple(self.values)

    @property
    def active(self) -> bool:
        """Some channel is overridden (Copter's has_active_overrides)."""
        return any(self.pwm)

    @property
    def sticks_present(self) -> bool:
        """The throttle channel has a value: the stick modes have a pilot."""
        return self.pwm[THROTTLE] != 0

    def radio_lost(self, link_t_s: float) -> bool:
        """Overrides in force but none received for 1 s, or a low throttle: the radio
        failsafe's trigger (Copter's read_radio and set_throttle_and_failsafe)."""
        if self.low_throttle >= LOW_THROTTLE_FRAMES:
            return True
        return self.active and self.heard_s is not None and \
            link_t_s - self.heard_s >= RADIO_OVERRIDE_TIMEOUT_S

    def radio_back(self, link_t_s: float) -> bool:
        """The failsafe is over: frames arriving with a good throttle."""
        return self.low_throttle == 0 and self.heard_s is not None and \
            link_t_s - self.heard_s < RADIO_OVERRIDE_TIMEOUT_S

    def mode_switch(self, link_t_s: float, channel: int) -> int | None:
        """The mode switch's new position (0-5) on FLTMODE_CH (1-based, 0 none), once a
        band change has held SWITCH_DEBOUNCE_S; None otherwise. The first position seen
        changes nothing (the switch where the tool found it)."""
        if not 1 <= channel <= CHANNELS or not self.pwm[channel - 1]:
            self._switch = self._bounce = None  # no receiver: the switch is gone
            return None
        position = switch_position(self.pwm[channel - 1])
        if position is None:
            return None
        if self._switch is None:
            self._switch = position
            return None
        if position == self._switch:
            self._bounce = None
            return None
        if self._bounce is None or self._bounce[0] != position:
            # From the frame that brought it: Copter reads the switch every loop.
            self._bounce = (position, self.set_s[channel - 1])
            return None
        if link_t_s - self._bounce[1] < SWITCH_DEBOUNCE_S:
            return None
        self._switch, self._bounce = position, None
        return position


class RcVehicle(Protocol):
    """What the RC pilot reads of the vehicle and asks of it (the commander provides)."""

    armed: bool
    mode: FlightMode
    flavour: str

    def set_mode(self, mode: FlightMode, link_t_s: float) -> None:
        """Enter ``mode`` as a tool asks for it (its needs checked first)."""
        ...

    def say(self, text: str, severity: int = 6) -> None: ...

    def failsafe_view(self) -> FailsafeView: ...

    def apply_failsafe(self, decision: FailsafeDecision | None) -> None:
        """The one way a failsafe changes the vehicle."""
        ...


# The modes whose throttle is a climb rate: Copter's THR_DZ applies in them.
CLIMB_THROTTLE_MODES = (FlightMode.ALTCTL, FlightMode.POSCTL, FlightMode.HOLD)


class RcPilot:
    """What the channels do, each service of the links (the MAVLink server calls it in
    the ArduPilot flavour, after the link failsafes; link clock): overrides expire,
    the sticks follow the channels, the mode switch selects FLTMODEn, the radio
    failsafe (FS_THR_ENABLE) starts or ends."""

    def __init__(self, vehicle: RcVehicle, rc: RcInput, state: TaskState) -> None:
        self.vehicle, self.rc, self.state = vehicle, rc, state

    def check(self, link_t_s: float) -> None:
        v, rc, state = self.vehicle, self.rc, self.state
        p = state.parameters
        had_sticks = rc.sticks_present
        rc.refresh(link_t_s, p["RC_OVERRIDE_TIME"])
        state.loiter_sticks = rc.sticks_present
        if rc.sticks_present:
            climbs = v.mode in CLIMB_THROTTLE_MODES
            state.sticks = sticks_from_channels(
                rc.pwm, p["THR_DZ"] / 1000.0 if climbs else None, p["MPC_HOLD_DZ"])
        elif had_sticks:
            state.sticks = Sticks()  # centred: hold, hover
        position = rc.mode_switch(link_t_s, int(p["FLTMODE_CH"]))
        if position is not None:
            number = int(p[f"FLTMODE{position + 1}"])
            try:
                mode = mode_from_custom(v.flavour, number)
                if mode is None:
                    raise RefusedError(f"mode {number} is not built")
                v.set_mode(mode, link_t_s)
            except RefusedError as exc:
                v.say(f"mode switch position {position + 1}: {exc}", 4)
        if not rc.failsafe:
            if p["FS_THR_ENABLE"] and v.armed and rc.radio_lost(link_t_s):
                rc.failsafe = True
                v.apply_failsafe(decide("Radio Failsafe",
                                        radio_loss_action(p["FS_THR_ENABLE"], v.mode),
                                        v.failsafe_view()))
        elif rc.radio_back(link_t_s):
            rc.failsafe = False
            v.say("Radio Failsafe Cleared", 4)
