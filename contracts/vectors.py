"""Flat vector layouts the processes exchange, each defined once with named fields.

* the **measurement** the controller reads each step (the simulator link decodes it, the
  in-process plant produces it, control records carry it);
* the **reference** the controller tracks (the reference generator and the setpoint
  shaper write it, control records carry it);
* the simulator's **truth** state (the plant derives it, the simulator's sensors read it
  and its samples carry it, truth records keep it in this order).

Python code indexes by name (``m[MEASUREMENT.position_ned_m]``); numba-compiled code,
which cannot take slice objects from globals, uses the integer offsets below, derived
from the same tables.
"""

from __future__ import annotations


class Layout:
    """Named, contiguous slices of a flat float vector: ``layout.field`` is a slice."""

    def __init__(self, name: str, **sizes: int) -> None:
        self.name = name
        self.fields: tuple[str, ...] = tuple(sizes)
        self._start: dict[str, int] = {}
        offset = 0
        for field, size in sizes.items():
            self._start[field] = offset
            setattr(self, field, slice(offset, offset + size))
            offset += size
        self.size = offset

    def start(self, field: str) -> int:
        """Offset of ``field``'s first value."""
        return self._start[field]

    def __repr__(self) -> str:
        return f"Layout({self.name!r}, size {self.size})"


# Position and velocity NED, ZYX Euler angles and their rates (not body rates), SI.
MEASUREMENT = Layout("measurement", position_ned_m=3, velocity_ned_mps=3, euler_rad=3,
                     euler_rate_rad_s=3)
MEASUREMENT_SIZE = MEASUREMENT.size
MEAS_POS = MEASUREMENT.start("position_ned_m")
MEAS_VEL = MEASUREMENT.start("velocity_ned_mps")
MEAS_EULER = MEASUREMENT.start("euler_rad")
MEAS_EULER_RATE = MEASUREMENT.start("euler_rate_rad_s")
MEAS_Z = MEAS_POS + 2  # NED: down is positive
MEAS_VZ = MEAS_VEL + 2
MEAS_YAW = MEAS_EULER + 2

# The plant's state as the simulator reports it: position and velocity NED, attitude
# (quaternion body FRD -> NED, ZYX Euler angles, their rates), body rates FRD, rotor
# speeds [rad/s]; the order of the truth record (contracts/telemetry.py STATE).
TRUTH = Layout("truth", position_ned_m=3, velocity_ned_mps=3, quaternion=4, euler_rad=3,
               euler_rate_rad_s=3, body_rate_rad_s=3, rotor_rad_s=4)
TRUTH_POS = TRUTH.start("position_ned_m")
TRUTH_VEL = TRUTH.start("velocity_ned_mps")
TRUTH_QUAT = TRUTH.start("quaternion")
TRUTH_EULER = TRUTH.start("euler_rad")
TRUTH_EULER_RATE = TRUTH.start("euler_rate_rad_s")
TRUTH_BODY_RATE = TRUTH.start("body_rate_rad_s")
TRUTH_ROTOR = TRUTH.start("rotor_rad_s")

# Position NED and its two derivatives, then Euler angles and their two derivatives (the
# latter ignored for roll and pitch when the position loop sets them).
REFERENCE = Layout("reference", position_ned_m=3, velocity_ned_mps=3, accel_ned_mps2=3,
                   euler_rad=3, euler_rate_rad_s=3, euler_accel_rad_s2=3)
REF_SIZE = REFERENCE.size
REF_POS = REFERENCE.start("position_ned_m")
REF_VEL = REFERENCE.start("velocity_ned_mps")
REF_ACC = REFERENCE.start("accel_ned_mps2")
REF_EULER = REFERENCE.start("euler_rad")
REF_EULER_RATE = REFERENCE.start("euler_rate_rad_s")
REF_EULER_ACC = REFERENCE.start("euler_accel_rad_s2")

# The controller's six channels, in the order of its per-channel arrays and records.
CHANNELS = ("phi", "theta", "psi", "z", "x", "y")
ATTITUDE_CHANNELS = CHANNELS[:3]  # the channels whose drift f is identified

# One channel's internals each control step, in the order of the controller's telemetry
# rows (autopilot/control/sliding_mode.py writes them; control records carry them).
CHANNEL_INTERNALS = ("ref", "y", "e", "e_s", "e_eps", "f_hat", "u_eq", "u_s", "v",
                     "theta_g_channel")
