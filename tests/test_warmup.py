"""After the warm-up (scripts/setup.sh runs it), the commands compile no numba kernel: every
signature they use is in numba's cache."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import FIXTURES

RUN = """
import sys, tempfile
from scan2terrain.cli import main
from scan2terrain.warmup import dispatchers
F = sys.argv[1]
with tempfile.TemporaryDirectory() as t:
    for args in (
        ["cloud2world", F + "/clouds/pc_hdl32_scan_pcd_ply_twin/251370668.pcd", "-o", t + "/a"],
        ["bag2world", F + "/bags/bag1_fuse_tb3_sim_scan_odom", "-o", t + "/b"],
        ["bag2world", F + "/bags/bag1_embark_luminar_pointcloud", "-o", t + "/c",
         "--topic", "/luminar_pointcloud", "--pose", "0", "0", "0", "0", "0", "0",
         "--resolution", "0.2"],
        ["octree2world", F + "/octomap/scan.dat.bz2", "-o", t + "/d", "--resolution", "0.2"],
        ["cloud2world", F + "/clouds/pc_laz_autzen_trim/autzen_trim.laz", "-o", t + "/e",
         "--stream", "--resolution", "2", "--grid", "height"],
        ["map2world", F + "/maps/map_tb3_world_mapsaver/map.yaml", "-o", t + "/f",
         "--simplify", "0.05"],
    ):
        assert main([*args, "-q"]) == 0, args
misses = {d.__name__: dict(d.stats.cache_misses) for d in dispatchers() if d.stats.cache_misses}
print(misses)
"""


def test_commands_after_the_warm_up_compile_nothing() -> None:
    py = sys.executable
    subprocess.run([py, "-m", "scan2terrain.warmup"], check=True, capture_output=True)
    done = subprocess.run(
        [py, "-c", RUN, str(FIXTURES)], check=True, capture_output=True, text=True
    )
    assert done.stdout.strip() == "{}", done.stdout  # kernels compiled in this process
    from scan2terrain.warmup import cold

    assert not cold()


def test_every_kernel_module_is_listed() -> None:
    """A new kernel module must join KERNEL_MODULES, or the warm-up would leave it cold."""
    from scan2terrain.warmup import KERNEL_MODULES

    src = Path(__file__).resolve().parent.parent / "src"
    jitted = {
        ".".join(p.relative_to(src).with_suffix("").parts)
        for p in src.rglob("*.py")
        if "njit(" in p.read_text()
    }
    jitted.discard("scan2terrain.octree._kernels")  # its serial set is built from the others
    assert jitted <= set(KERNEL_MODULES), jitted - set(KERNEL_MODULES)


def test_a_cold_cache_is_announced_in_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from scan2terrain import warmup
    from scan2terrain.cli import main

    monkeypatch.setattr(warmup, "cold", lambda: True)
    tree = str(FIXTURES / "octomap/geb079.bt")
    assert main(["octree2world", tree, "-o", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len([line for line in err if "compiling the numba kernels" in line]) == 1
    assert main(["octree2world", tree, "-o", str(tmp_path / "b"), "-q"]) == 0
    assert capsys.readouterr().err == ""


NO_BLAS_PROBE = """
import sys
import numpy as np
from scan2terrain.cli import main
F, out = sys.argv[1], sys.argv[2]
assert main(["cloud2world", F + "/clouds/pc_hdl32_scan_pcd_ply_twin/251370668.pcd", "-o",
             out + "/a", "-q"]) == 0
assert main(["octree2world", F + "/octomap/geb079.bt", "-o", out + "/b", "-q"]) == 0
print("scipy.linalg" in sys.modules)
import numba
dot = numba.njit(lambda a, b: np.dot(a, b))  # BLAS still works where asked for
print(dot(np.ones(3), np.arange(3.0)))
"""


def test_kernels_run_without_numbas_blas_probe_importing_scipy(tmp_path: Path) -> None:
    """numba's numpy support probes for BLAS by importing scipy.linalg (80 ms a process); the
    kernels use no BLAS, so commands that run them import none, and np.dot still compiles."""
    done = subprocess.run(
        [sys.executable, "-c", NO_BLAS_PROBE, str(FIXTURES), str(tmp_path)],
        check=True,
        capture_output=True,
        text=True,
    )
    assert done.stdout.split() == ["False", "3.0"], done.stdout


NO_BAG_PROBE = """
import sys
from scan2terrain.cli import main
F, out = sys.argv[1], sys.argv[2]
assert main(["octree2world", F + "/octomap/scan.dat.bz2", "-o", out + "/a", "-q",
             "--resolution", "0.2"]) == 0
print(sorted(m for m in ("rosbags", "mcap") if m in sys.modules))
"""


def test_commands_without_a_bag_import_no_bag_reader(tmp_path: Path) -> None:
    """rosbags costs about 60 ms to import: a scan file's command (whose scan counts are the
    same type as a bag's) reads no bag, so it imports none."""
    done = subprocess.run(
        [sys.executable, "-c", NO_BAG_PROBE, str(FIXTURES), str(tmp_path)],
        check=True,
        capture_output=True,
        text=True,
    )
    assert done.stdout.split() == ["[]"], done.stdout


@pytest.mark.parametrize(("given", "expected"), [(None, "PASSIVE"), ("ACTIVE", "ACTIVE")])
def test_openmp_threads_wait_passively_unless_the_user_chose(
    given: str | None, expected: str
) -> None:
    """Spinning OpenMP threads made two threads slower than one while another process held a
    core; the kernels' numba sets passive waits before OpenMP loads, and leaves a user's
    choice alone."""
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if given is not None:
        env["OMP_WAIT_POLICY"] = given
    probe = "import os, scan2terrain.octree.tree; print(os.environ['OMP_WAIT_POLICY'])"
    done = subprocess.run(
        [sys.executable, "-c", probe], env=env, check=True, capture_output=True, text=True
    )
    assert done.stdout.strip() == expected


@pytest.mark.parametrize("args", [["--parts", "bogus"], ["--parts"], ["extra"]])
def test_warmup_refuses_unknown_arguments_in_one_line(
    args: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    from scan2terrain.warmup import main

    assert main(args) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("usage: python -m scan2terrain.warmup")
    assert main(["--help"]) == 0
