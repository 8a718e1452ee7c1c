"""RRG in a lab's ROS 2 workspace (docs/colcon.md): each Python package carries ament_python
metadata (package.xml, setup.py, setup.cfg, resource marker) whose dependencies are the ones its
code imports, the vendored interface subsets carry COLCON_IGNORE, and a `colcon build` of a copy
of the repository against the pip-installed ROS 2 installs packages whose node starts from the
install space and answers."""

from __future__ import annotations

import ast
import json
import os
import re
import runpy
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from catkin_pkg.package import parse_package
from repo_layout import NODE_MODULES, PACKAGES, PYPROJECT

ROOT = Path(__file__).resolve().parents[2]
#: The vendored interface subsets (scripts/setup_ros.sh builds them into the venv).
VENDORED = (
    "rrg_hw_bridge/interfaces/control_msgs",
    "rrg_hw_bridge/interfaces/wam_msgs",
    "rrg_hw_bridge/interfaces/wam_srvs",
    "rrg_hw_bridge/interfaces/bhand_srvs",
    "rrg_common/interfaces/tf2_msgs",
)
#: What a copy of the repository leaves out without git (hidden, generated or outside git).
GENERATED = (".*", "*.egg-info", "build", "install", "log", "bags", "results", "__pycache__")
#: The ROS packages of the pip-installed ROS 2 (the venv is its ament prefix).
ROS_INDEX = Path(sys.prefix) / "share" / "ament_index" / "resource_index" / "packages"
AMENT_SETUP = runpy.run_path(str(ROOT / "scripts" / "ament_setup.py"))


def _imported_top_levels(pkg: str) -> set[str]:
    """The top-level names that the modules of ``pkg`` import (absolute imports, lazy too)."""
    names = set()
    for path in (ROOT / pkg).rglob("*.py"):
        if path == ROOT / pkg / "setup.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                names.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                names.add(node.module.split(".")[0])
    return names


# ------------------------------------------------------------------ metadata (fast)
@pytest.mark.parametrize("pkg", PACKAGES)
def test_each_python_package_carries_ament_python_metadata(pkg):
    manifest = parse_package(str(ROOT / pkg / "package.xml"))  # validates format 3 as well
    assert manifest.package_format == 3
    assert manifest.name == pkg
    assert manifest.get_build_type() == "ament_python"
    assert manifest.version == PYPROJECT["project"]["version"]
    assert (ROOT / pkg / "resource" / pkg).is_file()
    assert (ROOT / pkg / "__init__.py").is_file()  # the directory is the Python package
    cfg = (ROOT / pkg / "setup.cfg").read_text()
    assert f"install_scripts=$base/lib/{pkg}" in cfg  # where ros2 run looks
    assert f"script_dir=$base/lib/{pkg}" in cfg


def test_rrg_msgs_is_an_ament_cmake_package():
    manifest = parse_package(str(ROOT / "rrg_msgs" / "package.xml"))
    assert (manifest.name, manifest.get_build_type()) == ("rrg_msgs", "ament_cmake")


@pytest.mark.parametrize("pkg", PACKAGES)
def test_exec_depends_are_the_ros_and_rrg_packages_the_code_imports(pkg):
    """package.xml's exec_depends (less rosdep's python3-* keys) are exactly the ROS packages and
    the other RRG packages that the package's modules import."""
    manifest = parse_package(str(ROOT / pkg / "package.xml"))
    declared = {d.name for d in manifest.exec_depends if not d.name.startswith("python3-")}
    ros = set(os.listdir(ROS_INDEX)) | set(PACKAGES)
    imported = {name for name in _imported_top_levels(pkg) if name in ros} - {pkg}
    assert {"rclpy", "rrg_msgs", "std_msgs"} <= ros  # the index is not vacuous
    assert sorted(declared) == sorted(imported)


@pytest.mark.parametrize("path", VENDORED)
def test_vendored_interfaces_carry_colcon_ignore_and_the_pip_setup_builds_them(path):
    assert (ROOT / path / "package.xml").is_file()
    assert (ROOT / path / "COLCON_IGNORE").is_file()
    setup_ros = (ROOT / "scripts" / "setup_ros.sh").read_text()
    assert re.search(rf"^build_interfaces {re.escape(path)} ", setup_ros, re.M)


def test_every_vendored_interface_package_is_listed():
    """A package.xml anywhere inside the Python packages is one of VENDORED (so a new vendored
    subset gets its COLCON_IGNORE and its test)."""
    found = {
        p.parent.relative_to(ROOT).as_posix()
        for pkg in PACKAGES
        for p in (ROOT / pkg).rglob("package.xml")
        if p.parent != ROOT / pkg
    }
    assert sorted(found) == sorted(VENDORED)


def test_the_node_executables_are_pyprojects_console_scripts_split_by_package():
    """Every node module has a main() and a [project.scripts] entry (what pip installs); the
    per-package builds install every entry, and every package-data entry, exactly once."""
    from rrg_bringup.graph import NODES

    assert set(NODES.values()) <= set(NODE_MODULES)
    scripts = PYPROJECT["project"]["scripts"]
    targets = set(scripts.values())
    for module in NODE_MODULES:
        assert f"{module}:main" in targets, module
        path = ROOT.joinpath(*module.split(".")).with_suffix(".py")
        tree = ast.parse(path.read_text())
        assert any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in tree.body)
    per_package = [s for pkg in PACKAGES for s in AMENT_SETUP["console_scripts"](pkg)]
    assert sorted(per_package) == sorted(f"{exe} = {target}" for exe, target in scripts.items())
    # and pyproject's package data, each entry to the package that holds it
    data = [item for pkg in PACKAGES for item in AMENT_SETUP["package_data"](pkg).items()]
    assert sorted(data) == sorted(PYPROJECT["tool"]["setuptools"]["package-data"].items())


def test_importing_a_packages_setup_py_does_nothing():
    """The setup.py in each package directory is importable as a module (pip's install of the
    package directory holds it too), and importing it runs no setup()."""
    import importlib

    for pkg in PACKAGES:
        assert importlib.import_module(f"{pkg}.setup").__name__ == f"{pkg}.setup"


# ------------------------------------------------------------------ colcon build (slow)
def _copy_repository(dest: Path) -> None:
    """The repository's files (git's tracked and untracked-but-not-ignored ones, so a work tree
    is copied as it would be committed), or, without git, the tree less generated folders."""
    try:
        out = subprocess.run(
            ["git", "-C", str(ROOT), "ls-files", "-z", "--cached", "--others"]
            + ["--exclude-standard"],
            capture_output=True,
            check=True,
            timeout=60,
        ).stdout
        files = [f for f in out.decode().split("\0") if f and (ROOT / f).is_file()]
    except (OSError, subprocess.SubprocessError):
        files = []
    if not files:
        shutil.copytree(
            ROOT,
            dest,
            symlinks=True,
            ignore=shutil.ignore_patterns(*GENERATED),
        )
        return
    for f in files:
        (dest / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / f, dest / f, follow_symlinks=False)


#: Run in the install space's environment (bash, install/setup.bash sourced): where the modules
#: and executables resolve, found as ros2 run finds them (the ament index, lib/<package>/<exe>).
PROBE = """
import importlib, json, sys
from ament_index_python.packages import get_package_prefix
modules = ["rrg_sim", "rrg_estimator.ros.estimator_node", "rrg_planner.ros.planner_node",
           "rrg_hw_bridge.ros.bridge_node", "rrg_models.objects"]
print(json.dumps({
    "files": {m: importlib.import_module(m).__file__ for m in modules},
    "prefix": get_package_prefix("rrg_estimator"),
}))
"""


@pytest.mark.slow
def test_colcon_builds_the_repository_and_a_node_runs_from_the_install_space(tmp_path, ros_domain):
    """`colcon build` of a copy of the repository against the pip-installed ROS 2 (the venv is
    the underlay: its rrg_msgs and vendored interfaces are the ones scripts/setup_ros.sh built,
    as a lab's would be its own), then the estimator node started as ros2 run starts it, from
    the install space, in a domain of its own: it joins the graph, its service answers, and it
    stops cleanly on SIGINT. (rrg_msgs builds with colcon too, with the cmake arguments in
    docs/colcon.md, but its C++ build takes minutes on 2 cores: not in the suite.)"""
    from ros_testing import RosClient, ros_env, stop_process

    colcon = Path(sys.executable).with_name("colcon")
    assert colcon.exists(), "colcon is missing: scripts/setup.sh installs it"
    src, ws = tmp_path / "src" / "rrg", tmp_path / "ws"
    src.mkdir(parents=True)
    ws.mkdir()
    _copy_repository(src)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("COLCON", "PYTHONPATH"))}
    env.update(
        AMENT_PREFIX_PATH=sys.prefix,  # the underlay: the pip-installed ROS 2 (no setup.bash)
        CMAKE_PREFIX_PATH=sys.prefix,
        COLCON_HOME=str(tmp_path / "colcon_home"),  # no user defaults or mixins
    )

    # the vendored subsets are not packages to colcon, even when pointed at them
    listed = subprocess.run(
        [str(colcon), "list", "--names-only", "--base-paths", str(src)]
        + [str(src / v) for v in VENDORED],
        cwd=ws,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert listed.returncode == 0, listed.stderr
    assert sorted(listed.stdout.split()) == sorted([*PACKAGES, "rrg_msgs"])

    build = subprocess.run(
        [str(colcon), "build", "--base-paths", str(src), "--packages-ignore", "rrg_msgs"]
        + ["--event-handlers", "console_direct-", "console_cohesion+"],
        cwd=ws,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        timeout=600,
    )
    assert build.returncode == 0, build.stdout[-4000:]
    assert f"{len(PACKAGES)} packages finished" in build.stdout

    install = ws / "install"
    site = Path("lib") / f"python{sys.version_info.major}.{sys.version_info.minor}"
    for pkg in PACKAGES:
        prefix = install / pkg
        assert (prefix / "share/ament_index/resource_index/packages" / pkg).is_file()
        assert (prefix / "share" / pkg / "package.xml").is_file()
        installed = prefix / site / "site-packages" / pkg
        # every module of the source's packages (directories with __init__.py), and no setup.py
        source = {
            p.relative_to(src / pkg).as_posix()
            for p in (src / pkg).rglob("*.py")
            if (p.parent / "__init__.py").is_file() and p != src / pkg / "setup.py"
        }
        assert {p.relative_to(installed).as_posix() for p in installed.rglob("*.py")} == source
        # pyproject's package data
        for package, globs in AMENT_SETUP["package_data"](pkg).items():
            base = Path(*package.split(".")[1:])
            for pattern in globs:
                wanted = sorted(p.relative_to(src / pkg) for p in (src / pkg / base).glob(pattern))
                assert wanted, pattern
                got = sorted(p.relative_to(installed) for p in (installed / base).glob(pattern))
                assert got == wanted
        # the package's executables, where ros2 run looks (none: no lib/<package> at all)
        lib = prefix / "lib" / pkg
        exes = {p.name for p in lib.iterdir()} if lib.is_dir() else set()
        assert exes == {s.split(" = ")[0] for s in AMENT_SETUP["console_scripts"](pkg)}

    def in_install_space(*cmd: str) -> list[str]:
        """``cmd`` run by bash with the install space's setup.bash sourced."""
        return ["bash", "-c", 'source "$0/setup.bash" && exec "$@"', str(install), *cmd]

    probe = subprocess.run(
        in_install_space(sys.executable, "-c", PROBE),
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert probe.returncode == 0, probe.stderr
    found = json.loads(probe.stdout.strip().splitlines()[-1])
    for module, file in found["files"].items():
        assert Path(file).is_relative_to(install), (module, file)
    exe = Path(found["prefix"]) / "lib" / "rrg_estimator" / "rrg-estimator-node"
    assert exe.is_relative_to(install) and os.access(exe, os.X_OK)

    node_env = {**ros_env(ros_domain), **{k: env[k] for k in ("AMENT_PREFIX_PATH", "COLCON_HOME")}}
    node_env.pop("PYTHONPATH", None)
    log_path = tmp_path / "estimator.log"
    with log_path.open("w") as log:
        node = subprocess.Popen(
            in_install_space(str(exe), "--ros-args", "-p", "marker_count:=50"),
            env=node_env,
            stdout=log,
            stderr=subprocess.STDOUT,
            cwd=tmp_path,
        )
    client = None
    try:
        from rrg_msgs.srv import GetBelief

        client = RosClient(node_env, name="rrg_colcon_test")

        get_belief = client.node.create_client(GetBelief, "/rrg/get_belief")
        client.wait_for_services([get_belief], [node], timeout_s=60)
        assert client.spin_until(
            lambda: ("estimator", "/rrg") in client.node.get_node_names_and_namespaces(), 30
        ), client.node.get_node_names_and_namespaces()
        answer = None
        for _ in range(5):  # a server that has just started may drop a first response
            answer = client.try_call(get_belief, GetBelief.Request(), timeout_s=5)
            if answer is not None:
                break
        assert answer is not None, "get_belief did not answer"
        assert answer.error_code == GetBelief.Response.NO_BELIEF
        # the node's process is the install space's executable (bash exec'd it)
        cmdline = Path(f"/proc/{node.pid}/cmdline").read_bytes().split(b"\0")
        assert str(exe).encode() in cmdline, cmdline
    finally:
        if client is not None:
            client.close()
        status = stop_process(node)
    text = log_path.read_text()
    assert status == 0, text
    assert "Traceback" not in text, text
