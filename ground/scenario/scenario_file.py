"""Scenario files (TOML): reference, perturbation schedule, plant, controller, duration.

The paper's scenarios (docs/scenarios.md) ship as files in ``ground/scenario/shipped``;
``ivfm run`` takes one of their names or the path of a user's file. docs/scenarios.md
describes the format; every field is checked and an error names the file and the field.
"""

from __future__ import annotations

import functools
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from autopilot.control.factory import CONTROLLERS
from autopilot.navigator.plan_file import read_plan
from autopilot.parameters import validate_parameters
from autopilot.trajectories import ENVELOPE_OPTIONS, Reference
from contracts.airframe import PAPER_SPEC, airframe_from_spec
from contracts.airframe_file import AirframeSpec, envelope_of, read_airframe
from contracts.atomic_file import write_atomic
from contracts.frames import DEFAULT_HOME, Home
from contracts.mavlink import STATE_SOURCES, mavlink
from contracts.perturbations import (
    Perturbation,
    Perturbations,
    kick_at,
    parse_schedule,
    plant_perturbations_at,
)
from contracts.toml_tables import check_fields, number, subtable
from ground.scenario.expectations import Expectations, parse_expectations
from ground.scenario.ground_station import GroundStationPlan, parse_ground_station
from sitl.dynamics import FIDELITIES
from sitl.sensors import read_profile

SCENARIO_DIR = Path(__file__).parent / "shipped"
AXES = ("x", "y", "z", "phi", "theta", "psi")
_TOP = {"name", "description", "duration_s", "axes", "transient_s", "reference", "plant",
        "controller", "perturbation", "mission", "expect", "ground_station"}


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    reference: Reference
    axes: tuple[str, ...]
    transient_s: float
    duration_s: float = 20.0
    perturbations: tuple[Perturbation, ...] = ()
    controller: str = "ivfc"
    plant: str = "paper"
    airframe: AirframeSpec = PAPER_SPEC  # [plant] airframe, read once with the file
    sensors: str = "ideal"  # the simulator's sensor profile (sitl/sensor_profiles)
    state_source: str = "auto"  # what the autopilot flies on (contracts.mavlink.STATE_SOURCES)
    parameters: dict[str, float] = field(default_factory=dict)
    model_path: Path | None = None
    source: Path | None = None
    plan: Path | None = None  # a QGroundControl .plan flown in AUTO.MISSION from the ground
    expect: Expectations = field(default_factory=Expectations)  # what must hold (checks)
    home: Home = DEFAULT_HOME  # where on Earth the local frame is ([plant] home)
    # A ground tool on the vehicle's ground link during the run (ground/scenario/ground_station.py).
    ground_station: GroundStationPlan | None = None
    # An excitation whose [reference] names no envelope flies the airframe's ([envelope]).
    envelope_from_airframe: bool = False

    def on_airframe(self, airframe: AirframeSpec) -> Scenario:
        """This scenario as flown on ``airframe``: an excitation that names no envelope
        takes the airframe file's (or the paper's, when it names none)."""
        if not self.envelope_from_airframe:
            return self
        envelope = dict(zip(ENVELOPE_OPTIONS, envelope_of(airframe), strict=True))
        return replace(self, reference=replace(self.reference, **envelope))

    @property
    def mission_items(self) -> tuple:
        """The plan's mission items (empty without a plan)."""
        if self.plan is None:
            return ()

        return read_plan(self.plan)[mavlink.MAV_MISSION_TYPE_MISSION]

    def plant_perturbations_at(self, t_s: float) -> Perturbations:
        return plant_perturbations_at(self.perturbations, t_s)

    def kick_at(self, t_s: float) -> tuple[float, float]:
        return kick_at(self.perturbations, t_s)


def load_scenario(path: Path) -> Scenario:
    """Read and check a scenario file; ValueError names the file and the field."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"cannot read scenario {path}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"scenario {path} is not valid TOML: {exc}") from None
    try:
        return _scenario(data, path)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"scenario {path}: {exc}") from None


def _scenario(data: dict[str, Any], path: Path) -> Scenario:

    check_fields(data, _TOP, "scenario")
    name = _text(data, "name", path.stem)
    duration = _positive(data, "duration_s", 20.0, 3600.0)
    transient = float(data.get("transient_s", 0.0))
    if not 0.0 <= transient < duration:
        raise ValueError(f"transient_s must be in [0, duration_s), got {transient!r}")
    axes = data.get("axes", ["x", "y", "z", "psi"])
    if not isinstance(axes, list) or not axes or any(a not in AXES for a in axes):
        raise ValueError(f"axes must be a list drawn from {', '.join(AXES)}, got {axes!r}")
    plan = _plan(_table(data, "mission"), path)
    ref = _table(data, "reference")
    ref_fields = {f.name for f in fields(Reference)}
    check_fields(ref, ref_fields, "reference")
    if plan is not None:
        if ref:
            raise ValueError("a scenario flies a [mission] or a [reference], not both")
        ref = {"kind": "hover", "altitude_m": 0.0}  # the mission starts on the ground
    if "kind" not in ref:
        raise ValueError("reference needs a kind")
    reference = Reference(**{k: v if k == "kind" else float(v) for k, v in ref.items()})
    envelope_from_airframe = (reference.kind == "excitation"
                              and not set(ref) & set(ENVELOPE_OPTIONS))
    plant = _table(data, "plant")
    check_fields(plant, {"fidelity", "airframe", "sensors", "home"}, "plant")
    fidelity = plant.get("fidelity", "paper")
    airframe = plant.get("airframe", "paper")
    sensors = plant.get("sensors", "ideal")
    home = _home(plant.get("home"))
    if not isinstance(sensors, str):
        raise ValueError("plant.sensors must be a profile name or a .toml path")
    if sensors.endswith(".toml") or "/" in sensors:
        sensors = str(path.parent / sensors)  # a file beside the scenario, as the model
    try:
        read_profile(sensors)
    except ValueError as exc:
        raise ValueError(f"plant.sensors: {exc}") from None
    if fidelity not in FIDELITIES:
        raise ValueError(f"plant.fidelity must be one of {', '.join(FIDELITIES)}")
    try:
        airframe = read_airframe(airframe)
        airframe_from_spec(airframe)  # flies: its numbers make a model
    except ValueError as exc:
        raise ValueError(f"plant.airframe: {exc}") from None
    ctrl = _table(data, "controller")
    controller = ctrl.get("name", "ivfc")
    if controller not in CONTROLLERS:
        raise ValueError(f"controller.name must be one of {', '.join(CONTROLLERS)}")
    params = ctrl.get("parameters", {})
    if not isinstance(params, dict):
        raise ValueError("controller.parameters must be a table NAME = value")
    validate_parameters(params)
    state_source = ctrl.get("state_source", "auto")
    if state_source not in STATE_SOURCES:
        raise ValueError(f"controller.state_source must be one of {', '.join(STATE_SOURCES)}")
    model = ctrl.get("model")
    model_path = (path.parent / model) if isinstance(model, str) else None
    if model is not None and model_path is None:
        raise ValueError("controller.model must be a path (relative to the scenario file)")
    check_fields(ctrl, {"name", "parameters", "model", "state_source"}, "controller")
    perturbations = parse_schedule(data.get("perturbation", []))
    ground_station = parse_ground_station(data.get("ground_station"), duration)
    if ground_station is not None and ground_station.offboard_at_s is not None and \
            (plan is not None or reference.kind != "hover"):
        raise ValueError("ground_station.offboard_at_s streams a hover point: the scenario's "
                         "reference must be kind = \"hover\"")
    expect = parse_expectations(data.get("expect"), tuple(axes), duration)
    if expect.sections & {"estimation"} and state_source != "estimator":
        raise ValueError("expect.estimation: the scenario does not fly on the estimator "
                         "(controller.state_source = \"estimator\")")
    if expect.sections & {"path"} and plan is None:
        raise ValueError("expect.path: the scenario flies no [mission]")
    return Scenario(name=name, description=_text(data, "description", ""),
                    reference=reference, axes=tuple(axes), transient_s=transient,
                    duration_s=duration, perturbations=perturbations, controller=controller,
                    plant=fidelity, airframe=airframe, sensors=sensors,
                    state_source=state_source,
                    parameters={k: float(v) for k, v in params.items()},
                    model_path=model_path, source=path, plan=plan, expect=expect, home=home,
                    ground_station=ground_station,
                    envelope_from_airframe=envelope_from_airframe).on_airframe(airframe)


def _home(value: Any) -> Home:
    """[plant] home = [latitude deg, longitude deg, altitude m AMSL]."""
    if value is None:
        return DEFAULT_HOME
    if not (isinstance(value, list) and len(value) == 3 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise ValueError(f"plant.home must be [latitude, longitude, altitude AMSL], got "
                         f"{value!r}")
    try:
        return Home.checked(*(float(v) for v in value))
    except ValueError as exc:
        raise ValueError(f"plant.home: {exc}") from None


def _plan(mission: dict[str, Any], path: Path) -> Path | None:
    """[mission] plan = "file.plan" (beside the scenario), read and checked now."""

    check_fields(mission, {"plan"}, "mission")
    if not mission:
        return None
    name = mission.get("plan")
    if not isinstance(name, str):
        raise ValueError("mission.plan must be the path of a .plan file")
    plan = path.parent / name
    if not read_plan(plan)[0]:
        raise ValueError(f"mission.plan: {plan} has no mission items")
    return plan


def _text(data: dict[str, Any], key: str, default: str) -> str:
    value = data.get(key, default)
    if not isinstance(value, str):
        raise ValueError(f"{key} must be text, got {value!r}")
    return value


def _positive(data: dict[str, Any], key: str, default: float, high: float) -> float:
    return number(data.get(key, default), key, 0.0, high, low_open=True)


def _table(data: dict[str, Any], key: str) -> dict[str, Any]:
    return subtable(data, key, f"[{key}]")


PAPER_SCENARIOS = ("attitude-sine", "attitude-hold", "position-sine", "attitude-jr-10",
                   "attitude-jr-15", "attitude-jr-20", "position-kick")


def shipped_names() -> list[str]:
    """The shipped scenarios' names (no file is parsed), the paper's seven first."""
    found = sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))
    return [n for n in PAPER_SCENARIOS if n in found] + [n for n in found
                                                          if n not in PAPER_SCENARIOS]


@functools.cache
def _shipped(name: str) -> Scenario:
    return load_scenario(SCENARIO_DIR / f"{name}.toml")


def shipped_scenarios() -> dict[str, Scenario]:
    """Every shipped scenario, each parsed on first use (not at import)."""
    return {name: _shipped(name) for name in shipped_names()}


def scenario_by_name(name: str) -> Scenario:
    """A shipped scenario by name (that file alone is read), or a scenario file by path."""
    if name in shipped_names():
        return _shipped(name)
    if name.endswith(".toml") or "/" in name:
        return load_scenario(Path(name))
    known = ", ".join(shipped_names())
    raise ValueError(f"unknown scenario {name!r}; known scenarios: {known} (or a .toml file)")


def scenario_from_dict(data: dict[str, Any], file: Path, base_dir: Path) -> Scenario:
    """A scenario given as a dict (the scenario file's tables), written to ``file`` as TOML
    and read back with every check; the files it names are relative to ``base_dir``."""
    import copy

    import tomli_w

    data = copy.deepcopy(data)
    for table, key in (("mission", "plan"), ("controller", "model"), ("plant", "sensors")):
        value = data.get(table, {}).get(key) if isinstance(data.get(table), dict) else None
        if isinstance(value, str) and (table != "plant" or value.endswith(".toml")
                                       or "/" in value):
            data[table][key] = str((Path(base_dir) / value).resolve())
    file = Path(file)
    file.parent.mkdir(parents=True, exist_ok=True)
    try:
        write_atomic(file, tomli_w.dumps(data))
    except TypeError as exc:
        raise ValueError(f"scenario {data.get('name', '?')}: not a TOML table: {exc}") from None
    return load_scenario(file)
