"""Voxel meshes (--geometry voxels): closed, 2-manifold, exact, checked with trimesh (an
independent reader that welds equal positions, as STL readers do)."""

from __future__ import annotations

from typing import TypedDict

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from scan2terrain.geometry.voxel_mesh import (
    SPLIT,
    SPLIT_MAX,
    TooManyChunks,
    TooManyTriangles,
    VoxelChunk,
    mesh_voxels,
)


def _edges_used_twice(chunk: VoxelChunk) -> bool:
    f = chunk.mesh.faces
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, count = np.unique(e, axis=0, return_counts=True)
    return bool((count == 2).all())


def _check(keys: np.ndarray, r: float = 1.0, chunk: int | None = None) -> list[VoxelChunk]:
    chunks = mesh_voxels(keys, r, chunk_cells=chunk)
    assert sum(c.voxels for c in chunks) == len(keys)
    volume = area = 0.0
    for c in chunks:
        assert _edges_used_twice(c), c.index
        m = trimesh.Trimesh(c.mesh.vertices, c.mesh.faces, process=True)  # welds positions
        assert m.is_watertight and m.is_winding_consistent, c.index
        assert m.volume > 0  # outward normals
        volume += m.volume
        area += m.area
    # Exact up to the hair moves at edge and corner contacts: no vertex moves farther than the
    # hair, so the volume changes by at most the hair times the surface's area.
    hair = min(SPLIT * r, SPLIT_MAX)
    assert abs(volume - len(keys) * r**3) <= hair * area + 1e-9
    return chunks


def _cells_around(keys: np.ndarray) -> np.ndarray:
    """Every voxel of the keys' bounding box grown by one."""
    axes = [np.arange(a, b) for a, b in zip(keys.min(0) - 1, keys.max(0) + 2, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def _inside(chunks: list[VoxelChunk], points: np.ndarray) -> np.ndarray:
    inside = np.zeros(len(points), bool)
    for c in chunks:
        m = trimesh.Trimesh(c.mesh.vertices, c.mesh.faces, process=True)
        inside |= m.contains(points)
    return inside


@pytest.mark.parametrize(
    "keys",
    [
        [[0, 0, 0]],
        [[0, 0, 0], [1, 0, 0]],
        [[0, 0, 0], [1, 1, 0]],  # along an edge only
        [[0, 0, 0], [1, 1, 1]],  # at a corner only
        [[0, 0, 0], [1, 1, 0], [1, 0, 1], [0, 1, 1]],  # a checkerboard: four corner contacts
        # two voxels meeting along an edge under a common roof (a pinched saddle)
        [[0, 0, 0], [1, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]],
        [[x, y, z] for x in range(3) for y in range(3) for z in range(3) if (x, y, z) != (1, 1, 1)],
    ],
)
def test_hand_made_sets_are_closed_manifold_and_exact(keys: list[list[int]]) -> None:
    k = np.array(keys)
    chunks = _check(k)
    lo, hi = k.min(0) - 1, k.max(0) + 2
    grid = np.stack(
        np.meshgrid(*[np.arange(a, b) for a, b in zip(lo, hi, strict=True)], indexing="ij"), -1
    )
    cells = grid.reshape(-1, 3)
    occupied = {tuple(v) for v in k}
    expect = np.array([tuple(c) in occupied for c in cells])
    assert (_inside(chunks, cells + 0.5) == expect).all()


@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.integers(2, 6),
    st.floats(0.2, 0.8),
    st.sampled_from([None, 1, 2, 3]),
)
def test_random_voxel_sets(seed: int, side: int, fill: float, chunk: int | None) -> None:
    rng = np.random.default_rng(seed)
    keys = np.argwhere(rng.random((side, side, side)) < fill) - rng.integers(-3, 3, 3)
    if len(keys) == 0:
        return
    chunks = _check(keys, 0.1, chunk)
    # Voxelised back: the centres of occupied voxels are inside, the others outside.
    lo, hi = keys.min(0) - 1, keys.max(0) + 2
    cells = np.stack(
        np.meshgrid(*[np.arange(a, b) for a, b in zip(lo, hi, strict=True)], indexing="ij"), -1
    )
    cells = cells.reshape(-1, 3)
    occupied = {tuple(v) for v in keys}
    expect = np.array([tuple(c) in occupied for c in cells])
    assert (_inside(chunks, (cells + 0.5) * 0.1) == expect).all()


def test_greedy_merging_and_chunks() -> None:
    block = np.argwhere(np.ones((10, 10, 10), bool))
    one = _check(block, 0.05)
    assert len(one) == 1 and len(one[0].mesh.faces) == 12  # a cube: 2 triangles a side
    cut = _check(block, 0.05, chunk=4)
    assert len(cut) == 27 and [c.index for c in cut] == sorted(c.index for c in cut)
    assert sum(c.voxels for c in cut) == 1000


def test_origin_resolution_labels_and_budget() -> None:
    keys = np.array([[0, 0, 0], [1, 0, 0]])
    (c,) = mesh_voxels(keys, 0.5, origin=(10.0, 20.0, 30.0))
    assert c.mesh.vertices.min(0).tolist() == [10.0, 20.0, 30.0]
    assert c.mesh.vertices.max(0).tolist() == [11.0, 20.5, 30.5]
    (labelled,) = mesh_voxels(keys, 1.0, labels=np.array([3, 7]))
    assert set(labelled.face_labels.tolist()) == {3, 7}  # not merged across labels
    assert len(labelled.mesh.faces) > len(c.mesh.faces)
    with pytest.raises(TooManyTriangles) as err:
        mesh_voxels(keys, 1.0, max_triangles=5)
    assert err.value.count == 12


class _BadOptions(TypedDict, total=False):
    chunk_cells: int


@pytest.mark.parametrize(
    ("keys", "kwargs", "match"),
    [
        (np.zeros((2, 2), int), {}, "shape"),
        (np.zeros((2, 3)), {}, "integer"),
        (np.zeros((2, 3), int), {}, "unique"),
        (np.zeros((1, 3), int), {"chunk_cells": 0}, "chunk_cells"),
    ],
)
def test_bad_arguments(keys: np.ndarray, kwargs: _BadOptions, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        mesh_voxels(keys, 1.0, **kwargs)


def test_empty_and_deterministic() -> None:
    assert mesh_voxels(np.zeros((0, 3), int), 1.0) == []
    rng = np.random.default_rng(3)
    keys = np.argwhere(rng.random((8, 8, 8)) < 0.5)
    a = mesh_voxels(keys, 0.05, chunk_cells=3)
    b = mesh_voxels(keys[rng.permutation(len(keys))], 0.05, chunk_cells=3)
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x.mesh.vertices, y.mesh.vertices)
        assert np.array_equal(x.mesh.faces, y.mesh.faces)


def test_too_many_chunks_is_refused_before_meshing() -> None:
    keys = np.argwhere(np.ones((4, 4, 4), bool))
    with pytest.raises(TooManyChunks) as err:
        mesh_voxels(keys, 1.0, chunk_cells=1, max_chunks=10)
    assert err.value.count == 64
    assert len(mesh_voxels(keys, 1.0, chunk_cells=2, max_chunks=8)) == 8


def test_sparse_lookups_give_the_same_meshes(monkeypatch: pytest.MonkeyPatch) -> None:
    """Chunks too large for the dense tables (bitmaps, point tables, chunk counts) take sorted
    lookups instead: the same meshes, byte for byte."""
    from scan2terrain.geometry import _voxel_lattice, voxel_mesh

    rng = np.random.default_rng(7)
    keys = np.argwhere(rng.random((14, 12, 10)) < 0.45)
    labels = rng.integers(0, 3, len(keys))
    dense = mesh_voxels(keys, 0.1, chunk_cells=6, labels=labels)
    monkeypatch.setattr(_voxel_lattice, "DENSE_MAX", 0)
    monkeypatch.setattr(_voxel_lattice, "DENSE_UNIQUE_MAX", 0)
    monkeypatch.setattr(voxel_mesh, "DENSE_CHUNKS_MAX", 0)
    sparse = mesh_voxels(keys, 0.1, chunk_cells=6, labels=labels)
    assert len(dense) == len(sparse) > 1
    for a, b in zip(dense, sparse, strict=True):
        assert a.index == b.index
        assert np.array_equal(a.mesh.vertices, b.mesh.vertices)
        assert np.array_equal(a.mesh.faces, b.mesh.faces)
        assert np.array_equal(a.face_labels, b.face_labels)


# --- every triangle faces out of the solid ---------------------------------------------------


def _inward(chunk: VoxelChunk, keys: np.ndarray, r: float, chunk_cells: int | None) -> np.ndarray:
    """The chunk's triangles whose normal points into the solid: each triangle lies (up to the
    hair moves) on one lattice plane, on exposed voxel faces; its normal along that plane's axis
    must point from the occupied voxel to the empty one at the triangle's centre (taken on the
    unmoved positions, so a sliver's centre is still inside its face)."""
    k = np.asarray(keys, np.int64)
    if chunk_cells is not None:
        k = k[(np.floor_divide(k, chunk_cells) == chunk.index).all(axis=1)]
    tri = (chunk.mesh.vertices / r)[chunk.mesh.faces]  # lattice units, (F, 3, 3)
    # Lattice and half-lattice points moved by a hair (< 0.02) go back; a spine's points stay.
    half = np.round(tri * 2) / 2
    exact = np.where(np.abs(tri - half) < 0.02, half, tri)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    near = np.round(tri)
    on_plane = (near[:, 0] == near[:, 1]) & (near[:, 1] == near[:, 2])
    on_plane &= (np.abs(tri - near) < 0.02).all(axis=1)
    assert (on_plane.sum(axis=1) == 1).all()  # one plane per triangle, no degenerate one
    axis = np.argmax(on_plane, axis=1)
    rows = np.arange(len(tri))
    exact_normal = np.cross(exact[:, 1] - exact[:, 0], exact[:, 2] - exact[:, 0])
    assert (exact_normal[rows, axis] != 0).all()
    plane = near[rows, 0, axis].astype(np.int64)
    cell = np.floor(exact.mean(axis=1)).astype(np.int64)
    below, above = cell.copy(), cell.copy()
    below[rows, axis] = plane - 1
    above[rows, axis] = plane
    lo: NDArray[np.int64] = k.min(0) - 1
    span: NDArray[np.int64] = k.max(0) - k.min(0) + 3

    def code(c: NDArray[np.int64]) -> NDArray[np.int64]:
        c = c - lo
        codes: NDArray[np.int64] = (c[:, 0] * span[1] + c[:, 1]) * span[2] + c[:, 2]
        return codes

    occupied_below = np.isin(code(below), code(k))
    assert (occupied_below != np.isin(code(above), code(k))).all()  # on an exposed face
    outward = np.where(occupied_below, 1, -1)
    return np.flatnonzero(normal[rows, axis] * outward <= 0)


def _long_bars(seed: int, side: int, p: float, dots: float, length: int = 150) -> np.ndarray:
    """Bars of voxels 50 to 150 long side by side in a ``side`` x ``side`` section (edge
    contacts all along where two bars are diagonal neighbours), with scattered voxels."""
    rng = np.random.default_rng(seed)
    parts = [np.zeros((0, 3), np.int64)]
    for a in range(side):
        for b in range(side):
            if rng.random() < p:
                t = np.arange(rng.integers(0, length // 3), rng.integers(2 * length // 3, length))
                parts.append(np.column_stack([np.full(len(t), a), t, np.full(len(t), b)]))
    parts.append(np.argwhere(rng.random((side, length, side)) < dots))
    keys = np.unique(np.concatenate(parts), axis=0)
    return keys[:, rng.permutation(3)]


def test_the_long_rectangle_of_the_issue_faces_out() -> None:
    """A bar's top face 71 voxels long whose far edge holds the midpoints of a diagonal contact:
    a fan from the near corner turned three slivers over."""
    keys = np.array(
        [(0, j, 0) for j in range(71)]
        + [(1, j, 1) for j in range(71)]
        + [(0, 71, 0), (0, 71, 1), (1, 71, 1)]
    )
    for r in (0.05, 1.0):
        for chunk in _check(keys, r):
            assert len(_inward(chunk, keys, r, None)) == 0


@pytest.mark.parametrize(
    ("side", "p", "dots", "chunk"),
    [(2, 0.6, 0.01, None), (3, 0.5, 0.01, None), (4, 0.3, 0.02, None), (4, 0.4, 0.02, 128)],
)
def test_every_triangle_faces_out_of_the_solid(
    side: int, p: float, dots: float, chunk: int | None
) -> None:
    """Seeded random sets full of long faces and edge contacts (the hair moves at 5 cm voxels
    are the largest, 1% of a voxel): no triangle turns over, and each mesh stays closed,
    2-manifold and exact."""
    for seed in range(40):
        keys = _long_bars(seed, side, p, dots)
        for c in _check(keys, 0.05, chunk):
            bad = _inward(c, keys, 0.05, chunk)
            assert len(bad) == 0, (seed, c.mesh.vertices[c.mesh.faces[bad[:3]]])
