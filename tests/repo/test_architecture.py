"""The package structure (design §1): one-way dependencies, no import cycles, no node importing
another node, and ROS-free cores. Read from the source with ``ast``; nothing is imported."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from repo_layout import NODE_MODULES, PACKAGES

ROOT = Path(__file__).resolve().parents[2]
#: The packages each package may import besides itself, from the bottom up: the robot's models;
#: the plumbing every node shares; the simulators, and the bridge that stands in for them on a
#: real robot (it knows the robot's models, never a simulator); the belief; the search over the
#: belief; the emulated drivers (the MuJoCo world behind the real drivers' protocols); the tools
#: on the planner (bags, experiments, onboarding); and bringup, the launcher and the benchmarks,
#: on top of everything.
BASE = {"rrg_models", "rrg_common"}
ALLOWED = {
    "rrg_models": set(),
    "rrg_common": {"rrg_models"},
    "rrg_sim": BASE,
    "rrg_hw_bridge": BASE,
    "rrg_estimator": BASE | {"rrg_sim"},
    "rrg_planner": BASE | {"rrg_sim", "rrg_estimator"},
    "rrg_fake_hw": BASE | {"rrg_sim", "rrg_hw_bridge"},
    "rrg_bags": BASE | {"rrg_sim", "rrg_estimator", "rrg_planner"},
    "rrg_experiments": BASE | {"rrg_sim", "rrg_estimator", "rrg_planner"},
    "rrg_onboarding": BASE | {"rrg_sim", "rrg_estimator", "rrg_planner", "rrg_experiments"},
    "rrg_bringup": BASE
    | {
        "rrg_sim",
        "rrg_estimator",
        "rrg_planner",
        "rrg_hw_bridge",
        "rrg_fake_hw",
        "rrg_bags",
        "rrg_experiments",
    },
}
#: Sub-packages and modules that may use rclpy (nodes, their clients and the shared plumbing).
ROS_PARTS = ("ros",)
#: Packages that are ROS tools throughout: the launcher and its benchmarks, and the bags.
ROS_PACKAGES = ("rrg_bringup", "rrg_bags")
ROS_MODULES = (
    "rrg_sim.executor.executor_node",
    "rrg_sim.executor.robot_client",
    "rrg_planner.client",
)
#: Bag tools that read and write MCAP without rclpy are ROS-free too, but may sit under bags/.
ROS_LIBRARIES = (
    "rclpy",
    "rrg_msgs",
    "std_msgs",
    "sensor_msgs",
    "geometry_msgs",
    "diagnostic_msgs",
    "visualization_msgs",
    "builtin_interfaces",
    "rcl_interfaces",
    "std_srvs",
    "action_msgs",
    "trajectory_msgs",
    "control_msgs",
    "bhand_srvs",
)


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if path == ROOT / pkg / "setup.py":  # colcon's build script (docs/colcon.md)
                continue
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            mods[name] = path
    return mods


MODULES = _modules()


def _imports(name: str) -> set[str]:
    """Every module name an import statement of ``name`` names (resolved, any depth, lazy ones
    too)."""
    path = MODULES[name]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                base = base[: len(base) - node.level + (path.name == "__init__.py")]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            out.add(module)
            out.update(f"{module}.{alias.name}" for alias in node.names)
    return out


def _internal(imported: set[str], own: str) -> set[str]:
    """The project modules among ``imported`` (a name resolves to its longest known prefix)."""
    deps = set()
    for name in imported:
        while name and name not in MODULES:
            name = name.rpartition(".")[0]
        if name and name != own and not own.startswith(name + "."):
            deps.add(name)
    return deps


GRAPH = {name: _internal(_imports(name), name) for name in MODULES}


def _is_ros(name: str) -> bool:
    parts = name.split(".")
    return (
        parts[0] in ROS_PACKAGES
        or any(p in ROS_PARTS for p in parts[1:])
        or name in ROS_MODULES
        or parts[-1].endswith("_node")
        or parts[-1].endswith("_cli")
    )  # command-line front ends may start ROS tools


def test_the_module_list_is_complete():
    assert len(MODULES) > 80
    assert "rrg_planner.closed_loop" in MODULES and "rrg_estimator.tracker" in MODULES


def test_no_import_cycles():
    """Tarjan's strongly connected components of the import graph are all single modules."""
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    assert cycles == []


def test_a_self_import_cycle_is_detected():
    """The cycle finder is not vacuous: a two-module cycle added to the graph is found."""
    a, b = "rrg_models.poses", "rrg_models.config"  # poses imports config
    assert b in GRAPH[a]
    saved = set(GRAPH[b])
    GRAPH[b].add(a)
    try:
        with pytest.raises(AssertionError):
            test_no_import_cycles()
    finally:
        GRAPH[b] = saved


@pytest.mark.parametrize("name", sorted(MODULES))
def test_dependencies_run_one_way(name):
    """Each module imports only its own package and the packages ALLOWED below it: never
    upward."""
    own = name.split(".")[0]
    upward = sorted(d for d in GRAPH[name] if d.split(".")[0] not in ALLOWED[own] | {own})
    assert upward == []


def _reachable(name: str) -> set[str]:
    """Every project module ``name`` imports, directly or through others."""
    seen, todo = set(), [name]
    while todo:
        for dep in GRAPH[todo.pop()] - seen:
            seen.add(dep)
            todo.append(dep)
    return seen


@pytest.mark.parametrize("name", sorted(n for n in MODULES if n.startswith("rrg_hw_bridge.")))
def test_the_bridge_imports_no_simulator(name):
    """The bridge runs a real robot on the robot's models (rrg_models) and the shared plumbing
    (rrg_common), never on a simulator's code, directly or through another module."""
    simulators = sorted(
        d for d in _reachable(name) if d.split(".")[0] in ("rrg_sim", "rrg_fake_hw")
    )
    assert simulators == []


#: A node module wires a ROS-free core to topics, services and actions (design §1, as
#: ros2/examples' nodes): at most this many lines, and no function over FUNCTION_MAX_LINES.
NODE_MAX_LINES = 450
FUNCTION_MAX_LINES = 80


@pytest.mark.parametrize("name", NODE_MODULES)
def test_node_modules_are_thin(name):
    path = MODULES[name]
    tree = ast.parse(path.read_text())
    long_functions = sorted(
        (f.name, f.end_lineno - f.lineno + 1)
        for f in ast.walk(tree)
        if isinstance(f, ast.FunctionDef | ast.AsyncFunctionDef)
        and f.end_lineno - f.lineno + 1 > FUNCTION_MAX_LINES
    )
    assert (len(path.read_text().splitlines()) <= NODE_MAX_LINES, long_functions) == (True, [])


@pytest.mark.parametrize("name", sorted(n for n in MODULES if n.endswith("_node")))
def test_no_node_imports_another_node(name):
    assert sorted(d for d in GRAPH[name] if d.endswith("_node")) == []


@pytest.mark.parametrize("name", sorted(n for n in MODULES if not _is_ros(n)))
def test_cores_are_ros_free(name):
    """A core module imports no ROS library and no ROS-side module (so, transitively, no rclpy)."""
    ros_libraries = sorted(m for m in _imports(name) if m.split(".")[0] in ROS_LIBRARIES)
    ros_modules = sorted(d for d in GRAPH[name] if _is_ros(d))
    assert (ros_libraries, ros_modules) == ([], [])


def test_module_names_are_unique():
    """Files are named for what they hold: no two modules share a file name."""
    seen: dict[str, str] = {}
    clashes = []
    for name, path in MODULES.items():
        if path.name in ("__init__.py", "config.py"):  # config.py: each package's own parameters
            continue
        if path.name in seen:
            clashes.append((seen[path.name], name))
        seen[path.name] = name
    assert clashes == []


def test_the_architecture_docs_layers_are_the_codes():
    """docs/architecture.md's table of layers is what scripts/architecture_picture.py computes
    from the imports now (run the script after a change that moves an import across
    packages)."""
    import runpy

    script = runpy.run_path(str(ROOT / "scripts" / "architecture_picture.py"))
    assert script["main"](["--check"]) == 0
    edges, _ = script["package_graph"]()
    floors = script["floors"](edges)
    assert floors["rrg_models"] == 1 and floors["rrg_bringup"] == max(floors.values())
    assert floors["rrg_hw_bridge"] <= floors["rrg_sim"]
    assert set(edges) == set(PACKAGES)
