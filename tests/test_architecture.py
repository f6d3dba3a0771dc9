"""The import direction of the architecture, checked on every module's syntax tree.

``lint-imports`` (the contracts in pyproject.toml, run by .ci/run) checks the same rules on
grimp's import graph, indirect chains included. This test reads every ``import`` and
``from ... import`` node of every module itself (those inside functions too, where several
modules import lazily; relative imports resolved; ``importlib.import_module`` and
``__import__`` of a literal name counted), so a rule holds even for an import that only
runs on one path.
"""

from __future__ import annotations

import ast
import graphlib
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("contracts", "sitl", "autopilot", "ground")
PURE_CORES = ("autopilot.control", "autopilot.models", "autopilot.estimation",
              "autopilot.commander", "autopilot.navigator", "autopilot.flight_tasks")


@dataclass(frozen=True)
class Rule:
    name: str
    importers: tuple[str, ...]  # these packages (and their modules) ...
    forbidden: tuple[str, ...]  # ... never import these (or their modules) ...
    except_importers: tuple[str, ...] = ()  # ... unless the importer is in one of these


RULES = (
    Rule("1. contracts imports nothing from sitl, autopilot, ground",
         ("contracts",), ("sitl", "autopilot", "ground")),
    Rule("2a. sitl and autopilot never import ground", ("sitl", "autopilot"), ("ground",)),
    Rule("2b. sitl never imports autopilot", ("sitl",), ("autopilot",)),
    Rule("2c. autopilot never imports sitl", ("autopilot",), ("sitl",)),
    Rule("3. offline identification is not on the flight path",
         ("autopilot", "sitl"), ("autopilot.identification",),
         except_importers=("autopilot.identification",)),
    Rule("4. the MAVLink server is not imported by the vehicle's logic",
         ("autopilot.commander", "autopilot.navigator", "autopilot.flight_tasks",
          "autopilot.control", "autopilot.models", "autopilot.estimation"),
         ("autopilot.mavlink",)),
    Rule("5. pure cores have no process I/O", PURE_CORES,
         ("zenoh", "socket", "selectors", "subprocess", "autopilot.process")),
)


# ground/'s packages from the top down; siblings in one layer never import each other
# (pyproject.toml's import-linter contract 6 says the same on grimp's graph).
GROUND_LAYERS = (("cli",), ("rehearsal",), ("check", "campaign"), ("run",),
                 ("report", "identify", "telemetry", "uplink", "ulog"), ("record",), ("scenario",))


@dataclass(frozen=True)
class Import:
    importer: str  # the module that imports
    imported: str  # a module (or a module's attribute) it names
    path: Path
    line: int

    def __str__(self) -> str:
        return f"{self.importer} -> {self.imported} ({self.path}:{self.line})"


def within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def module_name(root: Path, path: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _literal_import_call(node: ast.Call) -> str | None:
    """The name in ``importlib.import_module("x")`` or ``__import__("x")``."""
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    if (name in ("import_module", "__import__") and node.args
            and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
        return node.args[0].value
    return None


def imports_of(root: Path, path: Path) -> list[Import]:
    """Every import in the file at any depth: for ``from a.b import c``, both ``a.b`` and
    ``a.b.c`` (c may be a module)."""
    importer = module_name(root, path)
    package = importer.split(".") if path.name == "__init__.py" else importer.split(".")[:-1]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            names = [module] + [f"{module}.{alias.name}" for alias in node.names
                                if alias.name != "*"]
        elif isinstance(node, ast.Call) and (name := _literal_import_call(node)):
            names = [name]
        found += [Import(importer, name, path, node.lineno) for name in names]
    return found


def all_imports(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> list[Import]:
    found = []
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            found += imports_of(root, path)
    return found


def violations(rule: Rule, imports: list[Import]) -> list[Import]:
    return [imp for imp in imports
            if any(within(imp.importer, p) for p in rule.importers)
            and not any(within(imp.importer, p) for p in rule.except_importers)
            and any(within(imp.imported, p) for p in rule.forbidden)]


def ground_layer(module: str) -> tuple[int, str] | None:
    """(layer index from the top, package) of a module in one of ground's packages."""
    parts = module.split(".")
    if len(parts) < 2 or parts[0] != "ground":
        return None
    return next(((i, parts[1]) for i, layer in enumerate(GROUND_LAYERS) if parts[1] in layer),
                None)


def layer_violations(imports: list[Import]) -> list[Import]:
    """Imports of a higher layer, or of a sibling in the same layer."""
    broken = []
    for imp in imports:
        here, there = ground_layer(imp.importer), ground_layer(imp.imported)
        if here and there and (there[0] < here[0] or (there[0] == here[0]
                                                      and there[1] != here[1])):
            broken.append(imp)
    return broken


@pytest.fixture(scope="module")
def imports() -> list[Import]:
    return all_imports()


def test_every_package_is_read_with_its_lazy_imports(imports):
    importers = {imp.importer for imp in imports}
    for package in PACKAGES:
        assert package in importers or any(within(m, package) for m in importers), package
    # autopilot/__main__.py imports the process loop inside main(): seen.
    assert any(imp.importer == "autopilot.__main__" and imp.imported == "autopilot.process.loop"
               for imp in imports)


@pytest.mark.parametrize("rule", RULES, ids=[r.name.split(".")[0] for r in RULES])
def test_import_rule_holds(rule, imports):
    broken = violations(rule, imports)
    assert not broken, f"{rule.name}:\n" + "\n".join(f"  {imp}" for imp in broken)


BAD_TREE = {
    "contracts/__init__.py": "",
    "contracts/frames.py": "def late():\n    from ground.cli.main import main\n    return main\n",
    "sitl/__init__.py": "",
    "sitl/server.py": "import importlib\nLOOP = importlib.import_module('autopilot.process')\n",
    "autopilot/__init__.py": "",
    "autopilot/identification/__init__.py": "from . import identify\n",
    "autopilot/identification/identify.py": "import numpy\n",
    "autopilot/navigator/__init__.py": "",
    "autopilot/navigator/runner.py": (
        "class Runner:\n"
        "    def step(self):\n"
        "        from ..identification import identify\n"
        "        from autopilot.mavlink.server import MavlinkServer\n"
        "        import socket\n"
        "        return identify, MavlinkServer, socket\n"),
    "ground/__init__.py": "",
    "ground/cli/main.py": "from autopilot.identification.identify import numpy\n",
}


def test_the_checker_finds_crafted_bad_imports_inside_functions(tmp_path):
    """A tree that breaks rules 1, 2b, 3, 4 and 5 inside functions and through relative and
    importlib imports; identification importing itself and ground importing it are allowed."""
    for name, text in BAD_TREE.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    imports = all_imports(tmp_path)
    broken = {rule.name.split(".")[0]: sorted({(i.importer, i.imported, i.line)
                                               for i in violations(rule, imports)})
              for rule in RULES}
    assert broken == {
        "1": [("contracts.frames", "ground.cli.main", 2),
              ("contracts.frames", "ground.cli.main.main", 2)],
        "2a": [],
        "2b": [("sitl.server", "autopilot.process", 2)],
        "2c": [],
        "3": [("autopilot.navigator.runner", "autopilot.identification", 3),
              ("autopilot.navigator.runner", "autopilot.identification.identify", 3)],
        "4": [("autopilot.navigator.runner", "autopilot.mavlink.server", 4),
              ("autopilot.navigator.runner", "autopilot.mavlink.server.MavlinkServer", 4)],
        "5": [("autopilot.navigator.runner", "socket", 5)],
    }


# -- no import cycle, no oversized class or module -----------------------------------------

MAX_CLASS_LINES = 300
MAX_MODULE_LINES = 450


def project_modules(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> dict[str, Path]:
    return {module_name(root, path): path for package in packages
            for path in sorted((root / package).rglob("*.py"))}


def module_graph(imports: list[Import], modules: dict[str, Path]) -> dict[str, set[str]]:
    """importer -> the project modules it imports (``from a import b`` names module ``a.b``
    when that is a module, else ``a``); every import counts, TYPE_CHECKING ones too."""
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for imp in imports:
        target = imp.imported
        while target and target not in modules:
            target = target.rpartition(".")[0]
        if target and target != imp.importer:
            graph[imp.importer].add(target)
    return graph


def import_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the graph (its modules in order, the first repeated), or None."""
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as exc:
        return list(exc.args[1])
    return None


def test_grounds_packages_import_only_the_layers_below_them(imports):
    assert {p for layer in GROUND_LAYERS for p in layer} == {
        p.name for p in (ROOT / "ground").iterdir() if (p / "__init__.py").exists()}
    broken = layer_violations(imports)
    assert not broken, "\n".join(f"  {imp}" for imp in broken)


def test_the_layer_check_sees_an_import_upwards_and_between_siblings(tmp_path):
    tree = {"ground/__init__.py": "", "ground/record/__init__.py": "",
            "ground/record/files.py": "def late():\n    from ground.run.flights import fly\n",
            "ground/check/__init__.py": "from ground.campaign import spec\n",
            "ground/run/flights.py": "from ground.record import files\n"}
    for name, text in tree.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    broken = {(i.importer, i.imported) for i in layer_violations(all_imports(tmp_path,
                                                                             ("ground",)))}
    assert broken == {("ground.record.files", "ground.run.flights"),
                      ("ground.record.files", "ground.run.flights.fly"),
                      ("ground.check", "ground.campaign"),
                      ("ground.check", "ground.campaign.spec")}


def test_no_import_cycle_anywhere_type_checking_imports_included(imports):
    cycle = import_cycle(module_graph(imports, project_modules()))
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_finder_sees_a_cycle_made_only_of_type_checking_imports(tmp_path):
    tree = {"ground/__init__.py": "", "ground/a.py": "from ground.b import B\n",
            "ground/b.py": ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                            "    from ground.a import A\n"),
            "ground/c.py": "from ground import a\n"}
    for name, text in tree.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    modules = project_modules(tmp_path, ("ground",))
    cycle = import_cycle(module_graph(all_imports(tmp_path, ("ground",)), modules))
    assert cycle is not None and set(cycle) == {"ground.a", "ground.b"}


def oversized(modules: dict[str, Path]) -> list[str]:
    found = []
    for name, path in modules.items():
        text = path.read_text()
        if text.count("\n") > MAX_MODULE_LINES:
            found.append(f"module {name}: {text.count(chr(10))} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_CLASS_LINES:
                    found.append(f"class {name}.{node.name}: {lines} lines")
    return found


def test_no_class_over_300_lines_and_no_module_over_450():
    assert oversized(project_modules()) == []


def test_the_size_check_sees_a_long_class(tmp_path):
    (tmp_path / "ground").mkdir()
    (tmp_path / "ground/big.py").write_text("class Big:\n" + "    x = 1\n" * 300)
    assert oversized(project_modules(tmp_path, ("ground",))) == ["class ground.big.Big: 301 lines"]
