"""What a command module loads when it is imported: the heavy libraries and our compiled modules
are deferred to the functions that use them (pyproject.toml's banned-module-level-imports, which
ruff enforces), so a world made of a map loads no numba, and one made of a cloud no bag reader."""

from __future__ import annotations

import subprocess
import sys

import pytest

HEAVY = ("numba", "rosbags", "mcap", "gtsam", "small_gicp", "scipy", "open3d", "laspy", "PIL")


@pytest.mark.parametrize(
    "module",
    [
        "scan2terrain.cli",
        "scan2terrain.commands.maps",
        "scan2terrain.commands.dem",
        "scan2terrain.commands.voxels",
        "scan2terrain.commands.scans",
        "scan2terrain.commands.replay",
    ],
)
def test_importing_a_command_loads_no_heavy_library(module: str) -> None:
    code = f"import sys, {module}; print(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "", f"{module} loads {done.stdout.strip()}"
