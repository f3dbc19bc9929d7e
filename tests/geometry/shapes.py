"""Shapes shared by the geometry tests: grids drawn as text, the real maps' occupied cells after
the default filter, and the checks of an extruded solid."""

from __future__ import annotations

import functools
import io

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import Config
from scan2terrain.exporters.meshfile import stl_bytes
from scan2terrain.geometry.contacts import SPLIT_MAX
from scan2terrain.geometry.mesh import Mesh, is_watertight
from scan2terrain.geometry.outlines import Polygon
from scan2terrain.readers import read_map_yaml
from scan2terrain.steps import classify, filter_occupancy
from scan2terrain.types import OCCUPIED, Pose2D
from tests.fixtures import MAPS


def grid(text: str) -> NDArray[np.bool_]:
    """A grid drawn as text, top row first (as it looks): ``#`` occupied, ``.`` free."""
    rows = [r.strip() for r in text.strip().splitlines()]
    return np.flipud(np.array([[c == "#" for c in r] for r in rows], dtype=bool))


@functools.cache
def default_filtered(name: str) -> tuple[NDArray[np.bool_], float, Pose2D]:
    """A fixture map's occupied cells after classification and the default filter, as
    ``map2world`` computes them (steps.classify, steps.filter_occupancy)."""
    meta, g = read_map_yaml(MAPS[name])
    trinary = classify(g, meta.mode, meta.occupied_thresh, meta.free_thresh)
    occupied = filter_occupancy(trinary, Config()) == OCCUPIED
    return occupied, g.resolution, g.origin


def volume(mesh: Mesh) -> float:
    """Signed volume (divergence theorem): positive when faces wind outwards."""
    v = mesh.vertices[mesh.faces]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def welded_watertight(mesh: Mesh) -> bool:
    """trimesh's verdict on the STL bytes, where vertices are welded by position (as Gazebo's
    assimp does): every edge in exactly two faces, consistently wound."""
    import trimesh

    loaded = trimesh.load(io.BytesIO(stl_bytes(mesh)), file_type="stl", force="mesh")
    assert isinstance(loaded, trimesh.Trimesh)
    return bool(loaded.is_watertight and loaded.is_winding_consistent)


def check_solid(mesh: Mesh, polygons: list[Polygon], height: float, base: float) -> None:
    assert is_watertight(mesh)
    assert welded_watertight(mesh)
    area = sum(p.area() for p in polygons)
    # Vertices at diagonal contacts move a hair into their own material (SPLIT_MAX each),
    # which takes at most a sliver of SPLIT_MAX times the two edges there off the volume.
    points = np.unique(np.concatenate([r for p in polygons for r in p.rings()]), axis=0)
    contacts = sum(len(r) for p in polygons for r in p.rings()) - len(points)
    longest = max(
        float(np.abs(np.diff(r, axis=0)).max(initial=0)) for p in polygons for r in p.rings()
    )
    slack = contacts * 2 * SPLIT_MAX * longest * height
    assert area * height - slack - 1e-9 <= volume(mesh) <= area * height * (1 + 1e-9) + 1e-9
    z = mesh.vertices[:, 2]
    assert set(np.unique(z).tolist()) <= {base, base + height}
    # Walls: two triangles per outline edge; every face has area.
    edges = sum(len(r) for p in polygons for r in p.rings())
    assert len(mesh.faces) >= 2 * edges + 2
    v = mesh.vertices[mesh.faces]
    assert (np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1) > 0).all()
    # Walls face out: the outward normal of each wall quad points away from the material (the
    # right of the outline edge), caps face up at the top and down at the bottom.
    normals = mesh.normals()
    top = (v[:, :, 2] == base + height).all(axis=1)
    bottom = (v[:, :, 2] == base).all(axis=1)
    assert np.allclose(normals[top], [0, 0, 1]) and np.allclose(normals[bottom], [0, 0, -1])
