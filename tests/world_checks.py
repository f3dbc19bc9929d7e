"""Checks of written worlds shared by the command tests: the ground Gazebo's own code builds
(:mod:`tests.gazebo_harness`) against a map or a DEM, and a world folder's files normalised for
comparing two runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scan2terrain.readers.world import SIMULATORS
from scan2terrain.types import OccupancyGrid
from scan2terrain.world.folder import Result
from tests.gazebo_harness import probe_world, terrain_height

#: bag2world's options for a sensor fixed at the origin.
STATIONARY = ["--pose", "0", "0", "0", "0", "0", "0"]

#: The wall height of the map worlds :func:`check_world` compares (m).
H = 2.0


def uniform(data: np.ndarray, radius: int = 1) -> np.ndarray:
    """Cells whose (2 radius + 1)^2 neighbourhood holds one value (border cells excluded)."""
    h, w = data.shape
    core = data[radius : h - radius, radius : w - radius]
    same = np.ones(core.shape, dtype=bool)
    for dr in range(-radius, radius + 1):
        for dc in range(-radius, radius + 1):
            same &= data[radius + dr : h - radius + dr, radius + dc : w - radius + dc] == core
    out = np.zeros(data.shape, dtype=bool)
    out[radius : h - radius, radius : w - radius] = same
    return out


def cell_centres(grid: OccupancyGrid) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.indices(grid.shape, dtype=np.float64)
    return grid.origin.transform((cols + 0.5) * grid.resolution, (rows + 0.5) * grid.resolution)


def check_world(
    result: Result,
    reference: OccupancyGrid,
    tmp: Path,
    *,
    radius: int = 1,
    unknown_level: float = 0.0,
) -> dict[str, int]:
    """Compare every world in ``result`` with ``reference`` (map frame); return cells checked."""
    checked: dict[str, int] = {}
    expected_of = {100: H, 0: 0.0, -1: unknown_level}
    mask = uniform(reference.data, radius)
    x, y = cell_centres(reference)
    for w in result.worlds:
        sim = w.placement.simulator
        assert sim in SIMULATORS
        version, probes = probe_world(w.world, [w.models], tmp / f"probe_{sim}")
        assert version  # parsed strictly by SDFormat
        (col,) = [p for p in probes if p.kind == "collision"]
        visuals = [p for p in probes if p.kind == "visual"]
        assert len(visuals) == 1 and visuals[0].textures == 3 and visuals[0].blends == 2
        if sim == "gz":
            # gz-sim rendering places the visual by <pos> alone; it must match the collision.
            assert visuals[0].pos == pytest.approx(col.pose[:3])
        ox, oy = w.placement.offset
        got = terrain_height(col, x[mask] - ox, y[mask] - oy, sim)
        assert isinstance(got, np.ndarray)
        want = np.vectorize(expected_of.get)(reference.data[mask])
        bad = np.abs(got - want) > 0.01 * H
        assert not bad.any(), (
            f"{sim}: {bad.sum()} of {mask.sum()} cells off, e.g. map cell "
            f"{np.argwhere(mask)[bad][0]} want {want[bad][0]} got {got[bad][0]}"
        )
        checked[sim] = int(mask.sum())
    return checked


def ground(result: Result, tmp: Path, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Ground height at world (x, y) in the one world of ``result``, as gz-common builds it."""
    (w,) = result.worlds
    sim = w.placement.simulator
    assert sim in SIMULATORS
    version, probes = probe_world(w.world, [w.models], tmp / f"probe_{sim}")
    assert version  # parsed strictly by SDFormat
    (col,) = [p for p in probes if p.kind == "collision"]
    (vis,) = [p for p in probes if p.kind == "visual"]
    if sim == "gz":
        assert vis.pos == pytest.approx(col.pose[:3])
    got = terrain_height(col, x, y, sim)
    assert isinstance(got, np.ndarray)
    return got


def normalised_outputs(out: Path, source: Path) -> dict[str, bytes]:
    """Every output file, keyed by its path with the model names replaced by ``MODEL``, and
    with the names that depend on the input (model names, the input's file name) replaced in
    text files; PNG images as their decoded pixels (the bytes depend on zlib)."""
    models = sorted((p.name for p in (out / "models").iterdir()), key=len, reverse=True)
    base = min(models, key=len)

    def norm(text: str) -> str:
        for name in models:
            text = text.replace(name, name.replace(base, "MODEL"))
        return text.replace(source.name, "SOURCE")

    files: dict[str, bytes] = {}
    for p in sorted(out.rglob("*")):
        if not p.is_file():
            continue
        key = norm(str(p.relative_to(out)))
        if p.suffix == ".png":
            with Image.open(p) as im:
                files[key] = im.mode.encode() + repr(im.size).encode() + im.tobytes()
        elif p.suffix in (".sdf", ".world", ".config", ".yaml"):
            files[key] = norm(p.read_text()).encode()
        else:
            files[key] = p.read_bytes()
    return files
