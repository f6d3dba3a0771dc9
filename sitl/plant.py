"""The plant as an object: fixed-step RK4 dynamics, a rotor model and perturbations.

Pure: no I/O and no clocks. Time advances only when ``advance`` is called, so the same
calls give the same trajectory bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from contracts.airframe import Airframe, airframe_from_spec, rotor_speeds
from contracts.airframe_file import AirframeSpec
from contracts.compiled import Resolved
from contracts.frames import (
    body_rates_from_euler_rates,
    euler_from_quat,
    euler_rates_from_body_rates,
    quat_from_euler,
)
from contracts.perturbations import Perturbations
from contracts.vectors import (
    MEASUREMENT,
    TRUTH,
    TRUTH_BODY_RATE,
    TRUTH_EULER,
    TRUTH_EULER_RATE,
    TRUTH_POS,
    TRUTH_QUAT,
    TRUTH_ROTOR,
    TRUTH_VEL,
)
from sitl import dynamics

# A state's numbers in one array (contracts/vectors.py TRUTH): a state the plant gives has
# its vectors as views of it.
STATE_POSITION, STATE_VELOCITY, STATE_QUATERNION, STATE_EULER = (
    TRUTH_POS, TRUTH_VEL, TRUTH_QUAT, TRUTH_EULER)
STATE_EULER_RATE, STATE_BODY_RATE, STATE_ROTOR, STATE_SIZE = (
    TRUTH_EULER_RATE, TRUTH_BODY_RATE, TRUTH_ROTOR, TRUTH.size)


@njit(cache=True)
def derive_state(fidelity: int, raw: np.ndarray, rotor_at: int, out: np.ndarray) -> None:
    """The state's numbers (STATE_*) of the integrator's ``raw`` state, into ``out``: the
    paper's model integrates Euler rates, and reports the body rates a gyro would see (a
    receiver that converts them back recovers the same Euler rates); the rigid body
    integrates a quaternion and body rates."""
    for i in range(6):
        out[STATE_POSITION + i] = raw[i]
    if fidelity == dynamics.FIDELITY_PAPER:
        for i in range(6):
            out[STATE_EULER + i] = raw[6 + i]  # Euler angles, then their rates
        out[STATE_BODY_RATE:STATE_BODY_RATE + 3] = body_rates_from_euler_rates(
            raw[6], raw[7], raw[9], raw[10], raw[11])
        out[STATE_QUATERNION:STATE_QUATERNION + 4] = quat_from_euler(raw[6], raw[7], raw[8])
    else:
        for i in range(4):
            out[STATE_QUATERNION + i] = raw[6 + i]
        euler = euler_from_quat(out[STATE_QUATERNION:STATE_QUATERNION + 4])
        out[STATE_EULER:STATE_EULER + 3] = euler
        for i in range(3):
            out[STATE_BODY_RATE + i] = raw[10 + i]
        out[STATE_EULER_RATE:STATE_EULER_RATE + 3] = euler_rates_from_body_rates(
            euler[0], euler[1], raw[10], raw[11], raw[12])
    for i in range(4):
        out[STATE_ROTOR + i] = raw[rotor_at + i]


def state_of(time_s: float, values: np.ndarray) -> VehicleState:
    """The state whose numbers (STATE_*) are ``values``, its vectors views of them."""
    return VehicleState(time_s, values[STATE_POSITION:STATE_POSITION + 3],
                        values[STATE_VELOCITY:STATE_VELOCITY + 3],
                        values[STATE_EULER:STATE_EULER + 3],
                        values[STATE_EULER_RATE:STATE_EULER_RATE + 3],
                        values[STATE_BODY_RATE:STATE_BODY_RATE + 3],
                        values[STATE_QUATERNION:STATE_QUATERNION + 4],
                        values[STATE_ROTOR:STATE_ROTOR + 4], values)


@dataclass
class VehicleState:
    """Everything the plant knows, in NED/FRD SI units."""

    time_s: float
    position_ned_m: np.ndarray
    velocity_ned_mps: np.ndarray
    euler_rad: np.ndarray
    euler_rate_rad_s: np.ndarray
    body_rate_rad_s: np.ndarray
    quaternion: np.ndarray
    rotor_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(4))
    # All of it in one array (STATE_*), when the vectors are views of one (``state_of``).
    values: np.ndarray | None = field(default=None, repr=False, compare=False)

    def numbers(self) -> np.ndarray:
        """The state's numbers in one array (STATE_*): its own, or gathered."""
        if self.values is not None:
            return self.values
        return np.concatenate([np.asarray(v, dtype=np.float64) for v in (
            self.position_ned_m, self.velocity_ned_mps, self.quaternion, self.euler_rad,
            self.euler_rate_rad_s, self.body_rate_rad_s, self.rotor_rad_s)])


class Plant:
    """A quadrotor integrated with fixed-step RK4; rotor commands are held between calls."""

    def __init__(
        self,
        airframe: Airframe | AirframeSpec,
        fidelity: str = "paper",
        step_s: float = 0.001,
        position_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        euler_rad: tuple[float, float, float] = (0.0, 0.0, 0.0),
        rotor_rad_s: float | np.ndarray = 0.0,
        ground_contact: bool = False,
    ) -> None:
        if fidelity not in dynamics.FIDELITIES:
            known = ", ".join(dynamics.FIDELITIES)
            raise ValueError(f"unknown plant fidelity {fidelity!r}; known: {known}")
        if not (math.isfinite(step_s) and 1e-5 <= step_s <= 0.05):
            raise ValueError(f"plant step_s must be in [1e-5, 0.05] s, got {step_s!r}")
        if isinstance(airframe, AirframeSpec):
            airframe = airframe_from_spec(airframe)
        self.nominal_model: Airframe = airframe
        self.fidelity = fidelity
        self._fidelity_code = dynamics.FIDELITIES[fidelity]
        self.step_s = step_s
        self.ground_contact = ground_contact
        self.time_s = 0.0
        self._steps_done = 0
        self.perturbations = Perturbations()
        self._model = airframe
        self._disturbance = dynamics.no_disturbance()
        if self._fidelity_code == dynamics.FIDELITY_PAPER:
            self._state = np.zeros(dynamics.PAPER_STATE_SIZE)
            self._state[6:9] = euler_rad
            self._rotor_at = dynamics.PAPER_ROTOR
        else:
            self._state = np.zeros(dynamics.RIGID_STATE_SIZE)
            self._state[6:10] = quat_from_euler(*euler_rad)
            self._rotor_at = dynamics.RIGID_ROTOR
        self._state[0:3] = position_ned_m
        self._state[self._rotor_at:self._rotor_at + 4] = rotor_rad_s
        self._command_rad_s = np.broadcast_to(np.asarray(rotor_rad_s, dtype=float), 4).copy()
        # Typed once, not each step (the airframe is a namedtuple: slow to type).
        self._integrate = Resolved(dynamics.rk4_integrate)
        self._rotor_speeds = Resolved(rotor_speeds)

    @property
    def model(self) -> Airframe:
        """The vehicle as currently perturbed (what the dynamics integrate)."""
        return self._model

    def set_perturbations(self, perturbations: Perturbations) -> None:
        """Replace the active perturbations; validated when the object was built."""
        self._model = dynamics.perturbed_model(
            self.nominal_model, perturbations.mass_scale, perturbations.inertia_scale,
            perturbations.rotor_inertia_scale)
        dist = dynamics.no_disturbance()
        dist[dynamics.DIST_FORCE:dynamics.DIST_FORCE + 3] = perturbations.force_ned_n
        dist[dynamics.DIST_TORQUE:dynamics.DIST_TORQUE + 3] = perturbations.torque_frd_nm
        dist[dynamics.DIST_WIND:dynamics.DIST_WIND + 3] = perturbations.wind_ned_mps
        dist[dynamics.DIST_EFFICIENCY:] = perturbations.motor_efficiency
        self._disturbance = dist
        self.perturbations = perturbations

    def set_motor_commands(self, commands: np.ndarray) -> None:
        """Normalised motor commands c_i in [0, 1] -> rotor speed commands through the
        airframe's command map (``contracts.airframe.rotor_speeds``)."""
        c = np.asarray(commands, dtype=float)
        if c.shape != (4,) or not all(map(math.isfinite, c.tolist())):
            raise ValueError(f"motor commands must be 4 finite numbers, got {commands!r}")
        self._command_rad_s = self._rotor_speeds(c, self._model)

    def advance(self, duration_s: float) -> None:
        """Integrate for a whole number of plant steps with the commands held."""
        n_steps = round(duration_s / self.step_s)
        if n_steps < 1 or abs(n_steps * self.step_s - duration_s) > 1e-9:
            raise ValueError(
                f"duration {duration_s} s is not a whole number of {self.step_s} s plant steps"
            )
        self._state = self._integrate(
            self._fidelity_code,
            self._state,
            self._command_rad_s,
            self._model,
            self._disturbance,
            self.step_s,
            n_steps,
            self.ground_contact,
        )
        self._steps_done += n_steps
        self.time_s = self._steps_done * self.step_s

    @property
    def raw_state(self) -> np.ndarray:
        return self._state.copy()

    def true_measurement(self) -> np.ndarray:
        """The controller's measurement (``contracts.vectors.MEASUREMENT``) of the true
        state: what a perfect sensor suite would give (in-process runs fly on it)."""
        s = self._state
        out = np.empty(MEASUREMENT.size)
        out[MEASUREMENT.position_ned_m] = s[0:3]
        out[MEASUREMENT.velocity_ned_mps] = s[3:6]
        if self._fidelity_code == dynamics.FIDELITY_PAPER:
            out[MEASUREMENT.euler_rad] = s[6:9]
            out[MEASUREMENT.euler_rate_rad_s] = s[9:12]
        else:
            euler = euler_from_quat(s[6:10])
            out[MEASUREMENT.euler_rad] = euler
            out[MEASUREMENT.euler_rate_rad_s] = euler_rates_from_body_rates(
                euler[0], euler[1], s[10], s[11], s[12])
        return out

    def state(self) -> VehicleState:
        """The state now, its vectors views of one new array (nobody writes into it)."""
        values = np.empty(STATE_SIZE)
        derive_state(self._fidelity_code, self._state, self._rotor_at, values)
        return state_of(self.time_s, values)
