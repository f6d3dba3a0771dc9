"""Airframe files: the shipped ones, every check with the field it names, and the signs of
the effectiveness matrix rotor by rotor for "+", PX4's quad X and an asymmetric H."""

from __future__ import annotations

import copy
import math
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from autopilot.control.mixer import mix
from contracts.airframe import (
    PAPER,
    airframe_by_name,
    airframe_from_spec,
    attitude_drift,
    controller_inputs,
    hover_rotor_speeds,
    max_thrust_n,
    rotor_speeds,
)
from contracts.airframe_file import AirframeError, parse_airframe, read_airframe
from sitl import dynamics
from tests.airframes import PlusNumbers, plus_numbers

AIRFRAMES = Path(__file__).parents[2] / "contracts" / "airframes"


def _rotor(x: float, y: float, spin: str, k: float = 1e-5) -> dict:
    return {"position_m": [x, y, 0.0], "spin": spin, "thrust_coeff_ns2": k,
            "moment_coeff_nms2": 1.6e-7, "max_rad_s": 1000.0, "time_constant_s": 0.03,
            "inertia_kgm2": 6e-5}


def _frame(*rotors: dict) -> dict:
    return {"name": "test", "mass_kg": 1.5,
            "inertia_kgm2": [[0.02, 0.0, 0.0], [0.0, 0.02, 0.0], [0.0, 0.0, 0.04]],
            "linear_drag_nspm": 0.2, "command_map": "speed", "rotor": list(rotors)}


A = 0.175
# PX4's quad X motor order: 1 front right ccw, 2 rear left ccw, 3 front left cw, 4 rear
# right cw.
QUAD_X = _frame(_rotor(A, A, "ccw"), _rotor(-A, -A, "ccw"), _rotor(A, -A, "cw"),
                _rotor(-A, A, "cw"))
PLUS = _frame(_rotor(A, 0, "cw"), _rotor(0, A, "ccw"), _rotor(-A, 0, "cw"), _rotor(0, -A, "ccw"))
# H frame, front arms wider than the rear ones and a heavier front pair of props.
H_FRAME = _frame(_rotor(0.20, 0.25, "ccw", 1.2e-5), _rotor(-0.15, -0.18, "ccw"),
                 _rotor(0.20, -0.25, "cw", 1.2e-5), _rotor(-0.15, 0.18, "cw"))

# Sign of (roll, pitch, yaw) torque from one rotor's extra thrust: a rotor on the right
# (y > 0) rolls left (negative), one in front pitches the nose up, a ccw rotor yaws the
# nose right (positive), as PX4's airframe reference draws them.
SIGNS = {
    "plus": [(0, +1, -1), (-1, 0, +1), (0, -1, -1), (+1, 0, +1)],
    "quad_x": [(-1, +1, +1), (+1, -1, +1), (+1, +1, -1), (-1, -1, -1)],
    "h_frame": [(-1, +1, +1), (+1, -1, +1), (+1, +1, -1), (-1, -1, -1)],
}


def test_the_shipped_airframes_are_the_papers_the_realistic_one_and_a_quad_x():
    assert PlusNumbers(1.2, 0.18, 0.18, 0.09, 0.23, 54.2e-6, 1.1e-6, 1.32e-3, 500.0, 0.0,
                       0.0) == plus_numbers("paper")
    assert PlusNumbers(1.5, 0.0215, 0.0215, 0.0380, 0.225, 1.22e-5, 1.9e-7, 6.0e-5,
                       1100.0, 0.02, 0.25) == plus_numbers("realistic")
    files = [p.name for p in resources.files("contracts").joinpath("airframes").iterdir()]
    assert {"paper.toml", "realistic.toml", "quad-x-500.toml"} <= set(files)


@pytest.mark.parametrize("name, frame", [("plus", PLUS), ("quad_x", QUAD_X),
                                         ("h_frame", H_FRAME)])
def test_each_rotor_rolls_pitches_and_yaws_the_way_the_convention_says(name, frame):
    effectiveness = parse_airframe(copy.deepcopy(frame)).effectiveness()
    for i, expected in enumerate(SIGNS[name]):
        assert effectiveness[0, i] > 0, (name, i + 1)  # every rotor lifts
        got = tuple(int(np.sign(round(v, 15))) for v in effectiveness[1:, i])
        assert got == expected, (name, f"rotor {i + 1}", got, expected)


def test_the_paper_inputs_are_its_rotor_map_exactly():
    """U_z = sum T_i, U_phi = T4 - T2, U_theta = T1 - T3, U_psi = d (W2^2 + W4^2 - W1^2 -
    W3^2), W_r = W1 - W2 + W3 - W4: the paper's map, and the effectiveness matrix with the
    arm on the torques."""
    from contracts.airframe import residual_rotor_speed

    n = plus_numbers("paper")
    w = np.array([410.0, 395.0, 402.0, 388.0])
    t = n.thrust_coeff_ns2 * w**2
    by_hand = (t.sum(), t[3] - t[1], t[0] - t[2],
               n.drag_coeff_nms2 * (w[1]**2 + w[3]**2 - w[0]**2 - w[2]**2))
    np.testing.assert_allclose(controller_inputs(w, np.ones(4), PAPER), by_hand, rtol=1e-14)
    np.testing.assert_allclose(read_airframe("paper").effectiveness() @ w**2,
                               (by_hand[0], n.arm_m * by_hand[1], n.arm_m * by_hand[2],
                                by_hand[3]), rtol=1e-12)
    assert residual_rotor_speed(w, PAPER) == w[0] - w[1] + w[2] - w[3]
    np.testing.assert_allclose(PAPER.input_gains, (n.arm_m / n.ixx_kgm2,
                                                   n.arm_m / n.iyy_kgm2, 1 / n.izz_kgm2))


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(mass=1), "unknown field(s) mass"),
    (lambda d: d.pop("mass_kg"), "mass_kg is required"),
    (lambda d: d.update(mass_kg=-1.0), "mass_kg must be a number in [0.001, 1000]"),
    (lambda d: d.update(mass_kg=math.nan), "mass_kg must be a number in [0.001, 1000]"),
    (lambda d: d.update(mass_kg="1.5"), "mass_kg must be a number"),
    (lambda d: d.update(command_map="pwm"), "command_map must be one of speed, thrust"),
    (lambda d: d["inertia_kgm2"][0].__setitem__(1, 0.01), "inertia_kgm2 must be symmetric"),
    (lambda d: d["inertia_kgm2"][2].__setitem__(2, -0.04), "must be positive definite"),
    (lambda d: d.update(inertia_kgm2=[0.02, 0.02, 0.04]), "must be a 3x3 matrix"),
    (lambda d: d["rotor"][1].update(spin="left"), 'rotor[2].spin must be "cw" or "ccw"'),
    (lambda d: d["rotor"][2].pop("max_rad_s"), "rotor[3]: max_rad_s required"),
    (lambda d: d["rotor"][3].update(max_rad_s=math.inf),
     "rotor[4].max_rad_s must be a number in (0, 100000]"),
    (lambda d: d["rotor"][0].update(position_m=[0.1, 0.1]), "rotor[1].position_m must be"),
    (lambda d: d["rotor"][0].update(diameter_m=0.25), "rotor[1]: unknown field(s) diameter_m"),
    (lambda d: d.update(rotor=[]), "rotor must be a list"),
    (lambda d: [r.update(position_m=[0.0, 0.0, 0.0]) for r in d["rotor"]],
     "rank deficient"),
    (lambda d: d.update(mass_kg=50.0), "cannot fly"),
    # Enough thrust in all (4 x 10 N against 26.5 N) but the rear rotors, which carry
    # most of the weight of a centre of mass this far back, top out first: 25.5 N.
    (lambda d: (d.update(mass_kg=2.7), [r.update(position_m=[r["position_m"][0] + 0.1,
                                                             r["position_m"][1], 0.0])
                                        for r in d["rotor"]]), "without torque"),
])
def test_bad_airframe_files_are_refused_naming_the_field(change, message):
    data = copy.deepcopy(QUAD_X)
    change(data)
    with pytest.raises(AirframeError, match=None) as info:
        parse_airframe(data, "airframe file my.toml")
    assert message in str(info.value) and "my.toml" in str(info.value), str(info.value)


def test_files_by_path_and_bad_paths(tmp_path):
    text = resources.files("contracts").joinpath("airframes", "paper.toml").read_text()
    (tmp_path / "mine.toml").write_text(text.replace('name = "paper"', 'name = "mine"'))
    mine = str(tmp_path / "mine.toml")
    assert read_airframe(mine).fingerprint() == read_airframe("paper").fingerprint()
    np.testing.assert_array_equal(airframe_by_name(mine).mixing, PAPER.mixing)
    assert tomllib.loads(text)["name"] == "paper"
    (tmp_path / "broken.toml").write_text("mass_kg = [")
    with pytest.raises(AirframeError, match="not TOML"):
        read_airframe(str(tmp_path / "broken.toml"))
    with pytest.raises(AirframeError, match="no such file"):
        read_airframe(str(tmp_path / "absent.toml"))
    with pytest.raises(AirframeError, match="unknown airframe 'quad'; shipped: paper"):
        read_airframe("quad")
    (tmp_path / "unnamed.toml").write_text(
        "\n".join(line for line in text.splitlines() if not line.startswith("name =")))
    assert read_airframe(str(tmp_path / "unnamed.toml")).name == "unnamed"  # the file's stem


@pytest.mark.parametrize("fidelity", ["paper", "rigid-body"])
def test_one_rotors_extra_thrust_turns_the_plant_the_way_the_convention_says(fidelity):
    """The plant, rotor by rotor, on the paper's "+" airframe (the signs of SIGNS)."""
    n = plus_numbers("paper")
    hover = math.sqrt(n.mass_kg * 9.81 / (4 * n.thrust_coeff_ns2))
    for i, expected in enumerate(SIGNS["plus"]):
        w = np.full(4, hover)
        w[i] += 20.0
        if fidelity == "paper":
            state = np.zeros(dynamics.PAPER_STATE_SIZE)
            state[dynamics.PAPER_ROTOR:] = w
            accel = dynamics.paper_derivative(state, w, PAPER, dynamics.no_disturbance())[9:12]
        else:
            state = np.zeros(dynamics.RIGID_STATE_SIZE)
            state[6] = 1.0
            state[dynamics.RIGID_ROTOR:] = w
            accel = dynamics.rigid_body_derivative(state, w, PAPER,
                                                   dynamics.no_disturbance())[10:13]
        got = tuple(int(np.sign(round(a, 12))) for a in accel)
        assert got == expected, (fidelity, f"rotor {i + 1}", got)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("name, frame", [("plus", PLUS), ("quad_x", QUAD_X),
                                         ("h_frame", H_FRAME)])
def test_the_mixer_raises_the_rotors_that_turn_the_vehicle_the_way_asked(name, frame, axis):
    """A small roll, pitch or yaw demand over hover: each rotor moves the way the
    convention says it turns the vehicle (SIGNS), rotor by rotor."""
    af = airframe_from_spec(parse_airframe(copy.deepcopy(frame)))
    weight = af.mass_kg * 9.81
    demand = [0.0, 0.0, 0.0]
    demand[axis] = 0.05 if axis < 2 else 0.002
    moved = mix(weight, *demand, af) - mix(weight, 0.0, 0.0, 0.0, af)
    for i, signs in enumerate(SIGNS[name]):
        if signs[axis] == 0:
            assert abs(moved[i]) < 1e-9, (name, axis, i + 1, moved)
        elif name != "h_frame" or axis == 2:
            assert np.sign(moved[i]) == signs[axis], (name, axis, i + 1, moved)
    # On the asymmetric H a roll or pitch demand also moves the rotors that have no arm
    # along it (to cancel the other torques); the rotors that do, move the way they turn.
    if name == "h_frame" and axis < 2:
        achieved = controller_inputs(rotor_speeds(mix(weight, *demand, af), af), np.ones(4),
                                     af)
        np.testing.assert_allclose(achieved, [weight, *demand], rtol=1e-9, atol=1e-12)


def _extra_thrust_accel(spec_dict: dict, fidelity: str, rotor: int) -> np.ndarray:
    """Angular acceleration one rotor's extra speed adds, over equal rotor speeds."""
    model = airframe_from_spec(parse_airframe(copy.deepcopy(spec_dict)))
    dist = dynamics.no_disturbance()

    def accel(w: np.ndarray) -> np.ndarray:
        if fidelity == "paper":
            state = np.zeros(dynamics.PAPER_STATE_SIZE)
            state[dynamics.PAPER_ROTOR:] = w
            return dynamics.paper_derivative(state, w, model, dist)[9:12]
        state = np.zeros(dynamics.RIGID_STATE_SIZE)
        state[6] = 1.0
        state[dynamics.RIGID_ROTOR:] = w
        return dynamics.rigid_body_derivative(state, w, model, dist)[10:13]

    base = np.full(4, hover_rotor_speeds(model)[0])
    more = base.copy()
    more[rotor] += 30.0
    return accel(more) - accel(base)


@pytest.mark.parametrize("fidelity", ["paper", "rigid-body"])
@pytest.mark.parametrize("name, frame", [("plus", PLUS), ("quad_x", QUAD_X),
                                         ("h_frame", H_FRAME)])
def test_the_plant_turns_each_frame_rotor_by_rotor_the_way_the_convention_says(name, frame,
                                                                               fidelity):
    for i, expected in enumerate(SIGNS[name]):
        got = tuple(int(np.sign(round(a, 12))) for a in _extra_thrust_accel(frame, fidelity, i))
        assert got == expected, (name, fidelity, f"rotor {i + 1}", got)


@pytest.mark.parametrize("fidelity", ["paper", "rigid-body"])
def test_an_x_frame_flies_the_same_whatever_order_its_rotors_are_listed_in(fidelity):
    """PX4's order, and the same vehicle with its rotors listed in another order and the
    motor commands remapped to match: the same flight."""
    from sitl.plant import Plant

    order = [2, 0, 3, 1]  # file position -> PX4 motor
    shuffled = copy.deepcopy(QUAD_X)
    shuffled["rotor"] = [QUAD_X["rotor"][m] for m in order]
    commands = np.array([0.62, 0.55, 0.60, 0.57])  # per PX4 motor: rolls, pitches, yaws
    flights = []
    for frame, cmd in ((QUAD_X, commands), (shuffled, commands[order])):
        plant = Plant(parse_airframe(copy.deepcopy(frame)), fidelity,
                      position_ned_m=(0.0, 0.0, -10.0))
        plant.set_motor_commands(cmd)
        plant.advance(1.0)
        flights.append(plant.true_measurement())
    assert np.max(np.abs(flights[0][6:9])) > 0.05  # it did turn
    np.testing.assert_allclose(flights[0], flights[1], rtol=1e-9, atol=1e-12)


def test_the_thrust_command_map_gives_thrust_in_proportion_to_the_command():
    from sitl.plant import Plant

    frame = copy.deepcopy(QUAD_X)
    frame["command_map"] = "thrust"
    for rotor in frame["rotor"]:
        rotor["time_constant_s"] = 0.0  # the rotor at its command at once
    plant = Plant(parse_airframe(frame), "rigid-body", position_ned_m=(0.0, 0.0, -10.0))
    plant.set_motor_commands(np.full(4, 0.25))
    plant.advance(0.001)
    thrust = dynamics.rotor_wrench(plant.state().rotor_rad_s, np.ones(4), plant.model)[0]
    assert thrust == pytest.approx(0.25 * 4 * 1e-5 * 1000.0**2, rel=1e-9)  # c T_max


def test_the_shipped_quad_x_hovers_level_on_equal_hover_commands():
    from sitl.plant import Plant

    spec = read_airframe("quad-x-500")
    hover = hover_rotor_speeds(airframe_from_spec(spec))
    plant = Plant(spec, "rigid-body", position_ned_m=(0.0, 0.0, -10.0), rotor_rad_s=hover)
    plant.set_motor_commands(hover / spec.rotors[0].max_rad_s)
    plant.advance(2.0)
    m = plant.true_measurement()
    assert abs(m[2] + 10.0) < 1e-6 and np.max(np.abs(m[6:12])) < 1e-9, m


def _full_inertia_x() -> dict:
    frame = copy.deepcopy(QUAD_X)
    frame["inertia_kgm2"] = [[0.021, 0.002, -0.001], [0.002, 0.026, 0.0015],
                             [-0.001, 0.0015, 0.041]]
    return frame


def test_the_nominal_drift_is_the_papers_for_a_diagonal_inertia_and_newton_euler_else():
    n = plus_numbers("paper")
    p, q, r, w_r = 0.7, -1.3, 0.9, 25.0
    f = attitude_drift(p, q, r, n.rotor_inertia_kgm2 * w_r, PAPER)
    a1, a2 = (n.iyy_kgm2 - n.izz_kgm2) / n.ixx_kgm2, n.rotor_inertia_kgm2 / n.ixx_kgm2
    a3, a4 = (n.izz_kgm2 - n.ixx_kgm2) / n.iyy_kgm2, n.rotor_inertia_kgm2 / n.iyy_kgm2
    np.testing.assert_allclose(f[:2], (a1 * q * r - a2 * q * w_r, a3 * p * r + a4 * p * w_r),
                               rtol=1e-14)
    assert f[2] == 0.0  # Ixx = Iyy: nothing to identify on yaw, exactly
    af = airframe_from_spec(parse_airframe(_full_inertia_x()))
    omega, h_r = np.array([p, q, r]), 0.03
    expected = -np.linalg.solve(af.inertia_kgm2, np.cross(
        omega, af.inertia_kgm2 @ omega + [0.0, 0.0, h_r]))
    np.testing.assert_allclose(attitude_drift(p, q, r, h_r, af), expected, rtol=1e-12)


@pytest.mark.parametrize("name, frame", [("quad_x", QUAD_X), ("h_frame", H_FRAME),
                                         ("full_inertia_x", _full_inertia_x())])
def test_each_input_accelerates_its_own_axis_only(name, frame):
    """What the controller assumes, phi'' = f_phi + b1 U_phi etc., on the rigid-body plant:
    at rest, the mixer's rotor speeds for (weight, U) give angular acceleration b * U, the
    other axes untouched, products of inertia included."""
    for rotor in frame["rotor"]:
        rotor["time_constant_s"] = 0.0
    af = airframe_from_spec(parse_airframe(copy.deepcopy(frame)))
    weight = af.mass_kg * 9.81
    for axis, u in ((0, 0.4), (1, -0.3), (2, 0.01)):
        demand = np.zeros(3)
        demand[axis] = u
        w = rotor_speeds(mix(weight, *demand, af), af)
        state = np.zeros(dynamics.RIGID_STATE_SIZE)
        state[6] = 1.0
        state[dynamics.RIGID_ROTOR:] = w
        accel = dynamics.rigid_body_derivative(state, w, af, dynamics.no_disturbance())
        np.testing.assert_allclose(accel[10:13], af.input_gains * demand, rtol=1e-9,
                                   atol=1e-9 * abs(af.input_gains[axis] * u))
        assert accel[5] == pytest.approx(0.0, abs=1e-9)  # the weight carried


def test_max_thrust_and_hover_of_the_shipped_quad_x():
    af = airframe_by_name("quad-x-500")
    assert max_thrust_n(af) == pytest.approx(4 * 8.55e-6 * 1000.0**2, rel=1e-12)
    assert max_thrust_n(af) / (af.mass_kg * 9.81) == pytest.approx(1.743, abs=1e-3)
    np.testing.assert_allclose(hover_rotor_speeds(af), math.sqrt(2.0 * 9.81 / (4 * 8.55e-6)),
                               rtol=1e-12)


@pytest.mark.parametrize("table, message", [
    ({"CMDF_ACC_MAX": "fast"}, "parameters.CMDF_ACC_MAX must be a finite number"),
    ({"CMDF_ACC_MAX": float("nan")}, "must be a finite number"),
    ({"CMDF_ACC_MAX": True}, "must be a finite number"),
    ({"A_NAME_FAR_TOO_LONG": 1.0}, "is not a parameter name"),
])
def test_bad_parameter_tables_are_refused(table, message):
    from contracts.airframe_file import AirframeError, parse_airframe

    data = tomllib.loads((AIRFRAMES / "quad-x-500.toml").read_text())
    data["parameters"] = table
    with pytest.raises(AirframeError, match=message):
        parse_airframe(data, "airframe file mine.toml")


def test_airframe_parameters_are_defaults_that_scenarios_and_the_command_line_override():
    """The quad X 500's own CMDF_ACC_MAX reaches the flight; a scenario's or the command
    line's value wins; a name the table does not have is refused, naming the file."""
    import dataclasses

    from autopilot.parameters import airframe_parameters
    from ground.run.flights import Overrides, plan_flight
    from ground.scenario.scenario_file import scenario_by_name

    assert airframe_parameters(read_airframe("quad-x-500")) == {"CMDF_ACC_MAX": 20.0}
    assert airframe_parameters(read_airframe("paper")) == {}
    scenario = scenario_by_name("x500-position-sine")
    assert plan_flight(scenario).parameters["CMDF_ACC_MAX"] == 20.0
    assert plan_flight(scenario, Overrides(parameters={"CMDF_ACC_MAX": 9.0})
                       ).parameters["CMDF_ACC_MAX"] == 9.0
    mine = dataclasses.replace(scenario, parameters={"CMDF_ACC_MAX": 12.0})
    assert plan_flight(mine).parameters["CMDF_ACC_MAX"] == 12.0
    assert plan_flight(scenario_by_name("position-sine")).parameters["CMDF_ACC_MAX"] == 8.0


def test_an_unknown_parameter_in_an_airframe_file_is_refused_where_it_is_used(tmp_path):
    from autopilot.parameters import airframe_parameters

    text = (AIRFRAMES / "quad-x-500.toml").read_text().replace(
        "CMDF_ACC_MAX = 20.0", "NOT_A_PARAM = 1.0")
    path = tmp_path / "mine.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match="mine.toml: parameters: unknown parameter"):
        airframe_parameters(read_airframe(str(path), controllable=False))
