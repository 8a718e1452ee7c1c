"""colcon's ament_python build of rrg_fake_hw (docs/colcon.md): the metadata is
pyproject.toml's, read by scripts/ament_setup.py. A build script, not a module of the package."""

import runpy
from pathlib import Path

if __name__ == "__main__":  # run by colcon; importing rrg_fake_hw.setup does nothing
    here = Path(__file__).resolve().parent
    runpy.run_path(str(here.parent / "scripts" / "ament_setup.py"))["setup_package"](here)
