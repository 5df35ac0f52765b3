"""The package's shape: layers that import only downwards, no import cycles, no service that
imports the simulator or the tools, and each default defined once."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from schemas import MissionGoal
from services.mission_controller.controller import ControlParams
from services.mission_controller.service import Settings as ControllerSettings

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("schemas", "services")
SERVICES = ("calibration", "camera_planner", "frame_source", "ir_transmitter",
            "mission_controller", "monitor", "pose_estimator", "ros2_bridge", "sim",
            "vertex_extractor", "viz")
#: pure algorithm modules (compiled kernels: no bus, no settings) that another service may
#: reuse: the vertex extractor's shape test (``shape.py``) fits the pose estimator's planar pose
SHARED_ALGORITHMS = {"services.pose_estimator.p4p"}


def _module(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, top_level_only: bool) -> set[str]:
    """Project modules imported by ``path`` (at module level only, if asked)."""
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    out: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return {m for m in out if m.split(".")[0] in PACKAGES}


def _graph(top_level_only: bool) -> dict[str, set[str]]:
    files = {_module(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}
    # a module's own parent packages are imported before it anyway: not an edge
    return {m: {i for i in _imports(p, top_level_only)
                if i in files and i != m and not m.startswith(i + ".")}
            for m, p in files.items()}


def test_no_import_cycles_at_module_level():
    graph = _graph(top_level_only=True)
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        path.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                pytest.fail("import cycle: " + " -> ".join([*path[path.index(n):], n]))
            if n not in state:
                visit(n)
        path.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


@pytest.mark.parametrize("layer,forbidden", [
    ("schemas", ("services",)),
    ("services.core", ("services.runtime", "services.tools",
                       *(f"services.{s}" for s in SERVICES))),
    ("services.runtime", ("services.tools", *(f"services.{s}" for s in SERVICES))),
])
def test_layers_import_only_downwards(layer: str, forbidden: tuple[str, ...]):
    bad = [(m, i) for m, deps in _graph(top_level_only=False).items()
           if m == layer or m.startswith(layer + ".") for i in deps
           if any(i == f or i.startswith(f + ".") for f in forbidden)]
    assert not bad, bad


def test_no_service_imports_the_simulator_another_service_or_the_tools():
    bad = []
    for m, deps in _graph(top_level_only=False).items():
        parts = m.split(".")
        if len(parts) < 2 or parts[0] != "services" or parts[1] not in SERVICES:
            continue
        for i in deps:
            ip = i.split(".")
            other = len(ip) > 1 and ip[1] in SERVICES and ip[1] != parts[1] and \
                i not in SHARED_ALGORITHMS
            if other or (len(ip) > 1 and ip[1] == "tools"):
                bad.append((m, i))
    assert not bad, bad


def test_the_shared_algorithms_stay_pure():
    graph = _graph(top_level_only=False)
    for module in SHARED_ALGORITHMS:
        impure = [i for i in graph[module]
                  if not (i == "services.core" or i.startswith("services.core."))]
        assert not impure, (module, impure)


def test_every_package_names_its_public_surface():
    missing = [str(p.relative_to(ROOT)) for pkg in PACKAGES
               for p in (ROOT / pkg).rglob("__init__.py")
               if "__all__" not in p.read_text() and '"""' not in p.read_text()]
    assert not missing, missing


def test_the_goal_tolerance_is_defined_once():
    """The controller's parameter model holds the default; the service's settings inherit it
    and a mission goal without a tolerance leaves it to the controller."""
    default = ControlParams.model_fields["goal_tolerance_m"].default
    assert ControllerSettings.model_fields["goal_tolerance_m"].default == default
    assert ControllerSettings().part(ControlParams) == ControlParams()
    assert MissionGoal(waypoints=[(0.6, 0.0)]).tolerance_m is None
    for name, field in ControlParams.model_fields.items():
        assert ControllerSettings.model_fields[name].default == field.default, name
