"""The setuptools build of one RRG Python package for colcon's ament_python build (docs/colcon.md).

Each of rrg_sim, rrg_estimator, rrg_planner and rrg_hw_bridge carries a ``package.xml``, a
``setup.cfg``, a ``resource/<package>`` marker and a ``setup.py`` that hands its own directory to
``setup_package`` here. Everything else comes from the repository's ``pyproject.toml``, the one
place it is written down: the version, the package data, and the console scripts (the
``[project.scripts]`` whose module lies in the package: the ones pip installs, node executables
included). The package's directory is the Python package itself, so it is mapped as
``package_dir={name: "."}``; its ``setup.py`` is a build script, not a module, and is left out of
the install. colcon's ``--symlink-install`` cannot link such a package and falls back to a full
install (``_Develop``).

Run by colcon with the interpreter that runs colcon; needs setuptools only (and the standard
library's ``tomllib``, Python >= 3.11).
"""

from __future__ import annotations

import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py
from setuptools.command.develop import develop

#: The repository: this file lies in <repository>/scripts/.
REPO = Path(__file__).resolve().parents[1]


def pyproject() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text())


def in_package(module: str, name: str) -> bool:
    """Whether the dotted ``module`` is ``name`` or one of its submodules."""
    return module == name or module.startswith(name + ".")


def console_scripts(name: str, project: dict | None = None) -> list[str]:
    """``[project.scripts]`` entries whose module lies in package ``name``, as setuptools'
    ``console_scripts`` (``exe = module:function``)."""
    scripts = (project or pyproject())["project"].get("scripts", {})
    return [
        f"{exe} = {target}"
        for exe, target in sorted(scripts.items())
        if in_package(target.partition(":")[0].strip(), name)
    ]


def package_data(name: str, project: dict | None = None) -> dict[str, list[str]]:
    """``[tool.setuptools.package-data]`` entries of package ``name`` and its subpackages."""
    data = (project or pyproject())["tool"]["setuptools"].get("package-data", {})
    return {pkg: list(globs) for pkg, globs in data.items() if in_package(pkg, name)}


def manifest_name(package_dir: Path) -> str:
    """The ``<name>`` of ``package_dir/package.xml``."""
    return ET.parse(package_dir / "package.xml").getroot().findtext("name").strip()


class _BuildPy(build_py):
    """build_py without the package's own ``setup.py``, which sits in the package directory
    (``package_dir={name: "."}``) but is a build script, not a module of the package."""

    def find_package_modules(self, package, package_dir):
        modules = super().find_package_modules(package, package_dir)
        return [m for m in modules if not ("." not in package and m[1] == "setup")]


class _Develop(develop):
    """develop without ``--editable``. colcon's ``--symlink-install`` links each package's
    directory into the build space under its package name, which a package whose directory is
    the package itself (``package_dir={name: "."}``) defeats; without the option colcon falls
    back to a full install (as it does with setuptools releases whose develop lacks it)."""

    user_options = [o for o in develop.user_options if o[0] != "editable"]
    boolean_options = [o for o in develop.boolean_options if o != "editable"]


def setup_package(package_dir: str | Path) -> None:
    """setuptools' ``setup()`` for the RRG Python package in ``package_dir`` (the directory that
    holds its ``setup.py``, ``package.xml`` and ``__init__.py``)."""
    package_dir = Path(package_dir).resolve()
    name = package_dir.name
    if manifest_name(package_dir) != name:
        raise SystemExit(f"{package_dir}/package.xml does not name {name}")
    project = pyproject()
    meta = project["project"]
    setup(
        name=name,
        version=meta["version"],
        description=f"{name}: part of {meta['description']}",
        license="Apache-2.0",
        python_requires=meta.get("requires-python"),
        packages=[name] + [f"{name}.{sub}" for sub in find_packages(str(package_dir))],
        package_dir={name: "."},
        package_data=package_data(name, project),
        data_files=[
            ("share/ament_index/resource_index/packages", [f"resource/{name}"]),
            (f"share/{name}", ["package.xml"]),
        ],
        # The Python dependencies are the pip project's (pyproject.toml, pinned by
        # scripts/constraints.txt); the ROS ones are package.xml's exec_depends.
        install_requires=[],
        zip_safe=False,
        entry_points={"console_scripts": console_scripts(name, project)},
        cmdclass={"build_py": _BuildPy, "develop": _Develop},
    )
