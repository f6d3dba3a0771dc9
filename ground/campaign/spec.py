"""Campaign files and their draws (pure: no I/O but reading the file).

A campaign flies many randomized variants of one or more scenarios with several
controllers. Each *draw* is one set of values taken from the campaign's distributions,
flown by every controller (paired: same plant, same perturbations, same seeds), so that
controllers are compared draw by draw. Draw ``i`` is taken from a generator seeded with
``(campaign seed, i)`` alone: any draw can be made again without the others, and adding
runs to a campaign keeps the draws it had.

An identification campaign (``kind = "identification"``) instead identifies the models
on ``runs`` excitation seeds (the campaign's seed, then each run's index) at each of its
``clusters`` counts, a full grid, and compares IVFM with T1FM on their validation data.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from contracts.toml_tables import check_fields, number
from ground.scenario.scenario_file import scenario_by_name

KINDS = ("flights", "identification")
HOW = ("inprocess", "processes")
CONTROLLERS = ("ivfc", "t1fc", "smc", "pid")
MAX_RUNS = 100_000
# What a draw can vary, and the range each may take (checked when the file is read).
FLIGHT_FACTORS = {
    "mass_scale": (0.5, 2.0),  # the plant's mass, whole run (simulator perturbation)
    "inertia_scale": (0.5, 2.0),  # the plant's inertia I
    "jr_scale": (0.5, 2.0),  # the rotors' inertia Jr
    "motor_efficiency": (0.3, 1.0),  # each motor's, drawn per motor
    "wind_mps": (0.0, 20.0),  # a steady horizontal wind of this speed, direction uniform
    "gust_mps": (0.0, 20.0),  # one 2 s gust of this peak, at a uniform time, direction uniform
    "kick_scale": (0.0, 3.0),  # the scenario's kicks scaled
    "perturbation_scale": (0.0, 3.0),  # the scenario's mass / inertia / Jr steps scaled
    "sensor_seed": (0, 2**31 - 1),  # the simulator's sensors and link loss
    "identification_seed": (0, 2**31 - 1),  # the model flown: identified with this seed
}
IDENTIFICATION_FACTORS: dict[str, tuple[float, float]] = {}  # a grid: seeds x clusters
CLUSTER_RANGE = (2, 8)
INTEGER_FACTORS = {"sensor_seed", "identification_seed"}


@dataclass(frozen=True)
class Distribution:
    """``uniform = [low, high]``, ``normal = [mean, sd]`` (clipped to the factor's range),
    ``integers = [low, high]`` (both included), ``choice = [a, b, ...]`` or ``value = x``."""

    kind: str
    args: tuple[float, ...]

    def draw(self, rng: np.random.Generator, low: float, high: float) -> float:
        if self.kind == "uniform":
            return float(rng.uniform(*self.args))
        if self.kind == "normal":
            return float(np.clip(rng.normal(*self.args), low, high))
        if self.kind == "integers":
            return int(rng.integers(int(self.args[0]), int(self.args[1]) + 1))
        if self.kind == "choice":
            return self.args[int(rng.integers(len(self.args)))]
        return self.args[0]


@dataclass(frozen=True)
class Campaign:
    name: str
    description: str
    kind: str
    scenarios: tuple[str, ...]
    controllers: tuple[str, ...]
    runs: int  # draws per scenario
    seed: int
    how: str
    plant: str | None
    factors: dict[str, Distribution] = field(default_factory=dict)
    source: Path | None = None
    clusters: tuple[int, ...] = ()  # identification: the cluster counts of the grid

    @property
    def tasks(self) -> int:
        if self.kind == "identification":
            return self.runs * len(self.clusters)
        return self.runs * len(self.scenarios) * len(self.controllers)

    def draw(self, index: int) -> dict[str, float]:
        """The values of draw ``index`` (the same whatever else is drawn)."""
        rng = np.random.default_rng([self.seed, index])
        ranges = IDENTIFICATION_FACTORS if self.kind == "identification" else FLIGHT_FACTORS
        values: dict[str, float] = {}
        for name in sorted(self.factors):  # a fixed order: the file's order may change
            low, high = ranges[name]
            if name == "motor_efficiency":
                for motor in range(1, 5):
                    values[f"motor_efficiency_{motor}"] = self.factors[name].draw(rng, low, high)
            else:
                values[name] = self.factors[name].draw(rng, low, high)
            if name in ("wind_mps", "gust_mps"):
                values[name.replace("_mps", "_direction_rad")] = float(
                    rng.uniform(0.0, 2 * math.pi))
            if name == "gust_mps":
                values["gust_start_fraction"] = float(rng.uniform(0.2, 0.8))
        return values


def _distribution(name: str, data: Any, low: float, high: float, where: str) -> Distribution:
    if not isinstance(data, dict) or len(data) != 1:
        raise ValueError(f"{where}.{name} must be one of {{uniform = [low, high]}}, "
                         "{normal = [mean, sd]}, {integers = [low, high]}, "
                         "{choice = [...]}, {value = x}")
    (kind, args), = data.items()
    integer = name in INTEGER_FACTORS
    if kind == "value":
        args = [args]
    if kind not in ("uniform", "normal", "integers", "choice", "value") or \
            not isinstance(args, list) or not args:
        raise ValueError(f"{where}.{name}: unknown distribution {kind!r} or no values")
    numbers = tuple(number(a, f"{where}.{name}.{kind}") for a in args)
    if kind in ("uniform", "normal", "integers") and len(numbers) != 2:
        raise ValueError(f"{where}.{name}.{kind} takes two numbers, got {len(numbers)}")
    if kind == "normal":
        if not 0 <= numbers[1] <= (high - low):
            raise ValueError(f"{where}.{name}.normal: sd {numbers[1]:g} out of [0, "
                             f"{high - low:g}]")
        if not low <= numbers[0] <= high:
            raise ValueError(f"{where}.{name}.normal: mean {numbers[0]:g} out of "
                             f"[{low:g}, {high:g}]")
    else:
        for n in numbers:
            if not low <= n <= high:
                raise ValueError(f"{where}.{name}: {n:g} is out of [{low:g}, {high:g}]")
        if kind in ("uniform", "integers") and numbers[0] > numbers[1]:
            raise ValueError(f"{where}.{name}.{kind}: low {numbers[0]:g} above high "
                             f"{numbers[1]:g}")
    if integer and kind not in ("integers", "choice", "value"):
        raise ValueError(f"{where}.{name} is a whole number: use integers, choice or value")
    if integer and any(n != int(n) for n in numbers):
        raise ValueError(f"{where}.{name} takes whole numbers")
    if integer:
        numbers = tuple(int(n) for n in numbers)
    return Distribution(kind, numbers)


def parse_campaign(data: dict[str, Any], where: str = "campaign",
                   source: Path | None = None) -> Campaign:

    known = {"name", "description", "kind", "scenarios", "controllers", "runs", "seed", "how",
             "plant", "draw", "clusters"}
    check_fields(data, known, where)
    name = data.get("name", source.stem if source else "campaign")
    if not isinstance(name, str) or not name.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"{where}: name must be letters, digits, '-' or '_', got {name!r}")
    kind = data.get("kind", "flights")
    if kind not in KINDS:
        raise ValueError(f"{where}: kind must be one of {', '.join(KINDS)}, got {kind!r}")
    runs = data.get("runs")
    if isinstance(runs, bool) or not isinstance(runs, int) or not 1 <= runs <= MAX_RUNS:
        raise ValueError(f"{where}: runs must be a whole number in [1, {MAX_RUNS}], got "
                         f"{runs!r}")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise ValueError(f"{where}: seed must be a whole number >= 0, got {seed!r}")
    how = data.get("how", "inprocess")
    if how not in HOW:
        raise ValueError(f"{where}: how must be one of {', '.join(HOW)}, got {how!r}")
    scenarios: tuple[str, ...] = ()
    controllers: tuple[str, ...] = ()
    if kind == "flights":
        scenarios = _names(data.get("scenarios"), f"{where}.scenarios")
        for s in scenarios:
            scenario_by_name(s if not source or not (source.parent / s).is_file()
                             else str(source.parent / s))
        controllers = _names(data.get("controllers", ["ivfc", "t1fc"]),
                             f"{where}.controllers")
        bad = [c for c in controllers if c not in CONTROLLERS]
        if bad:
            raise ValueError(f"{where}.controllers: unknown {', '.join(bad)}; known: "
                             f"{', '.join(CONTROLLERS)}")
        if len(set(controllers)) != len(controllers):
            raise ValueError(f"{where}.controllers: each controller once")
    clusters: tuple[int, ...] = ()
    if kind == "identification":
        raw = data.get("clusters", [5])
        low, high = CLUSTER_RANGE
        if not isinstance(raw, list) or not raw or not all(
                isinstance(c, int) and not isinstance(c, bool) and low <= c <= high
                for c in raw) or len(set(raw)) != len(raw):
            raise ValueError(f"{where}: clusters must be a list of distinct whole numbers in "
                             f"[{low}, {high}], got {raw!r}")
        clusters = tuple(raw)
    elif "clusters" in data:
        raise ValueError(f"{where}: clusters is for identification campaigns")
    plant = data.get("plant")
    if plant is not None and plant not in ("paper", "rigid-body"):
        raise ValueError(f"{where}: plant must be paper or rigid-body, got {plant!r}")
    draw = data.get("draw", {})
    if not isinstance(draw, dict):
        raise ValueError(f"{where}.draw must be a table")
    ranges = IDENTIFICATION_FACTORS if kind == "identification" else FLIGHT_FACTORS
    unknown = sorted(set(draw) - set(ranges))
    if unknown:
        raise ValueError(f"{where}.draw: unknown factor(s) {', '.join(unknown)}; known: "
                         f"{', '.join(ranges)}")
    factors = {n: _distribution(n, d, *ranges[n], f"{where}.draw") for n, d in draw.items()}
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ValueError(f"{where}: description must be text")
    return Campaign(name, description, kind, scenarios, controllers, runs, seed, how, plant,
                    factors, source, clusters)


def _names(value: Any, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not value or \
            not all(isinstance(v, str) and v for v in value):
        raise ValueError(f"{where} must be a non-empty list of names")
    return tuple(value)


CAMPAIGN_DIR = Path(__file__).parent / "shipped"


def shipped_campaigns() -> list[str]:
    folder = CAMPAIGN_DIR
    return sorted(p.stem for p in folder.glob("*.toml"))


def read_campaign(name_or_path: str | Path) -> Campaign:
    """A shipped campaign by name, or a campaign file; ValueError naming what is wrong."""
    path = Path(name_or_path)
    if not path.is_file():
        shipped = CAMPAIGN_DIR / f"{name_or_path}.toml"
        if not shipped.is_file():
            raise ValueError(f"no campaign {str(name_or_path)!r}: not a file, nor one of "
                             f"{', '.join(shipped_campaigns())}")
        path = shipped
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not TOML: {exc}") from None
    return parse_campaign(data, str(path), path)
