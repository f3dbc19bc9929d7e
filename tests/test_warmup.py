"""After the warm-up (scripts/setup.sh runs it), the commands compile no numba kernel: every
signature they use is in numba's cache."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.fixtures import FIXTURES, GEB079, HDL_PCD, ROOT

NOTE = (
    "scan2terrain: compiling numba kernels into numba's cache (once; 30 s to 2 minutes on 2 "
    "cores; `python -m scan2terrain.warmup` compiles them all ahead)"
)

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

    src = ROOT / "src"
    jitted = {
        ".".join(p.relative_to(src).with_suffix("").parts)
        for p in src.rglob("*.py")
        if "njit(" in p.read_text()
    }
    jitted.discard("scan2terrain.octree._kernels")  # its serial set is built from the others
    assert jitted <= set(KERNEL_MODULES), jitted - set(KERNEL_MODULES)


def test_compiling_is_announced_when_it_starts_and_timed_when_done(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The note comes when numba compiles something during the command (here a kernel that is
    in no cache), and a last line says how long compiling took; -q says neither."""
    import numba

    from scan2terrain.cli import main
    from scan2terrain.commands import voxels

    real = voxels.octree2world

    def compiling(*args: Any, **kwargs: Any) -> Any:
        numba.njit(lambda x: x + 1)(1)  # a new function each call: compiled each time
        return real(*args, **kwargs)

    monkeypatch.setattr(voxels, "octree2world", compiling)
    tree = str(GEB079)
    assert main(["octree2world", tree, "-o", str(tmp_path / "a")]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "numba" in line]
    assert notes[0] == NOTE and len(notes) == 2, notes
    assert re.fullmatch(
        r"scan2terrain: compiled numba kernels in [\d.]+ s; later runs load them from the cache",
        notes[1],
    )
    assert main(["octree2world", tree, "-o", str(tmp_path / "b"), "-q"]) == 0
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(voxels, "octree2world", real)  # compiles nothing: says nothing
    assert main(["octree2world", tree, "-o", str(tmp_path / "c")]) == 0
    assert capsys.readouterr().err == ""


CACHE_PATHS = """
import json
from scan2terrain.warmup import dispatchers
print(json.dumps({d.__module__: d._cache._cache_path for d in dispatchers()}))
"""
#: Kernel modules a cloud2world run on a PCD file does not use (ray boxes, streamed tiles, LAS,
#: outlines): nothing of theirs in the cache must not make it announce compiling.
UNUSED_BY_CLOUD2WORLD = ("_raybox", "_tile_kernels", "_las_kernels", "_outline_kernels")


def _cache_paths(env: dict[str, str]) -> dict[str, Path]:
    done = subprocess.run(
        [sys.executable, "-c", CACHE_PATHS], env=env, check=True, capture_output=True, text=True
    )
    return {module: Path(path) for module, path in json.loads(done.stdout).items()}


def test_a_command_that_compiles_nothing_says_nothing_of_compiling(tmp_path: Path) -> None:
    """cloud2world said "first run: compiling the numba kernels ... (about 30 s)" on every run
    while a kernel module it never uses had nothing in numba's cache (a ``pip install -e .``
    without the warm-up): runs of 2 s that compiled nothing. A cache holding the warm-up's
    kernels but those modules': no note."""
    py = sys.executable
    subprocess.run([py, "-m", "scan2terrain.warmup"], check=True, capture_output=True)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    warm, fresh = _cache_paths(dict(os.environ)), _cache_paths(env)
    for module, folder in warm.items():
        stem = module.rsplit(".", 1)[-1]
        if stem not in UNUSED_BY_CLOUD2WORLD:
            fresh[module].mkdir(parents=True, exist_ok=True)
            for f in folder.glob(f"{stem}.*.nb[ic]"):
                shutil.copy2(f, fresh[module])
    pcd = HDL_PCD
    done = subprocess.run(
        [py, "-m", "scan2terrain.cli", "cloud2world", pcd, "-o", tmp_path / "w"],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0 and done.stderr == "", done.stderr


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
