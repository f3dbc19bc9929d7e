"""Occupied voxels as exact, 2-manifold triangle meshes, one per chunk (``--geometry voxels``).

Frames and units: a voxel is given by its integer lattice coordinates ``(i, j, k)`` and fills
``[i, i+1) x [j, j+1) x [k, k+1)`` times ``resolution`` metres, plus ``origin``; vertices are in
metres, z up; faces wind counter-clockwise seen from outside (normals point out of the solid).

The steps, each vectorised over a chunk's voxels (no Python loop per voxel or per face):

1. Chunks. Voxels are grouped in cubes of ``chunk_cells`` voxels a side; each chunk is meshed on
   its own, as if the others were empty (chunks on every core, in threads), so every chunk's
   mesh is closed (two chunks meet in coincident faces, which a physics engine treats as two
   touching solids).
2. Exposed faces: a voxel face whose neighbour (same chunk) is not occupied.
3. Rectangles: in each plane (face direction, layer) the face cells are merged into runs
   along the plane's first axis, and runs of equal extent in consecutive rows into rectangles
   (greedy meshing; faces of different ``labels``, e.g. colours, are never merged).
4. No T-junctions: every rectangle corner that lies inside another rectangle's edge is inserted
   into that edge, so the two faces that share a stretch of edge share all of its vertices. A
   rectangle is then a convex polygon with collinear points: a fan from a corner whose two edges
   hold no inserted point (n - 2 triangles), else a fan from its centre; a rectangle more than
   ``SPINE_RATIO`` times longer than wide with a point moved by step 5 on its boundary, from
   points on its midline (:mod:`._voxel_spine`: a far fan apex would let the move turn a
   triangle over).
5. 2-manifold where voxels touch only along an edge or at a corner: a lattice vertex gets one
   copy per *sheet* of surface around it, from the occupancy of the 8 voxels around it
   (:func:`sheet_tables`: the surface faces around each of its 6 half-edges are paired, those of
   the same voxel together when 4 meet, and the sheets are the cycles that pairing makes). A
   vertex with more than one sheet moves each copy by ``SPLIT`` of a voxel (at most
   ``SPLIT_MAX`` m) toward its sheet's voxels and away from its empty ones: solids touching at an
   edge or corner stand a hair apart, and readers that weld equal positions (STL holds no
   indices) still see every edge used by exactly two faces. Every other vertex is exact.

So the mesh encloses exactly the occupied voxels (a voxel centre is inside it iff the voxel is
occupied), and its volume is the voxel count times a voxel's volume, up to the hair moves.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from scan2terrain.geometry._voxel_contacts import (
    Diagonals,
    _diagonals,
    sheet_tables,
)
from scan2terrain.geometry._voxel_lattice import CodeSet, _Lattice, lex_order, unique_rows
from scan2terrain.geometry._voxel_spine import SPINE_RATIO, spine_triangles
from scan2terrain.geometry.mesh import Mesh

__all__ = ["SPLIT", "SPLIT_MAX", "TooManyChunks", "TooManyTriangles", "VoxelChunk", "mesh_voxels"]


#: How far the copies of a vertex where solids touch only at an edge or a corner move apart:
#: this fraction of a voxel, at most ``SPLIT_MAX`` metres (0.5 mm at 5 cm voxels).
SPLIT = 0.01


SPLIT_MAX = 1e-3


#: The six face directions: (axis, sign); in-plane axes (u, v) make (u, v, axis) right-handed.
_DIRS = ((0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1))


_UV = {0: (1, 2), 1: (2, 0), 2: (0, 1)}


class TooManyTriangles(ValueError):
    """The meshes would hold more triangles than allowed (``count`` says how many)."""

    def __init__(self, count: int, limit: int) -> None:
        super().__init__(f"{count} triangles, more than the limit of {limit}")
        self.count = count
        self.limit = limit


class TooManyChunks(ValueError):
    """The voxels span more chunks than allowed (``count`` says how many); raised before any
    chunk is meshed."""

    def __init__(self, count: int, limit: int) -> None:
        super().__init__(f"{count} chunks, more than the limit of {limit}")
        self.count = count
        self.limit = limit


@dataclass(frozen=True)
class VoxelChunk:
    """The mesh of one chunk.

    Attributes
    ----------
    index : tuple of 3 ints
        The chunk's position on the chunk lattice (voxel coordinate // chunk_cells).
    mesh : Mesh
        Vertices in metres, faces counter-clockwise from outside.
    face_labels : int64 array, shape (F,)
        The label of the voxel face each triangle comes from (all 0 without labels).
    voxels : int
        Occupied voxels in the chunk.
    """

    index: tuple[int, int, int]
    mesh: Mesh
    face_labels: NDArray[np.int64]
    voxels: int


def mesh_voxels(
    keys: NDArray[np.integer],
    resolution: float,
    *,
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
    chunk_cells: int | None = None,
    labels: NDArray[np.integer] | None = None,
    max_triangles: int | None = None,
    max_chunks: int | None = None,
) -> list[VoxelChunk]:
    """Mesh the voxels at integer coordinates ``keys`` (N, 3), unique, into one closed mesh per
    chunk of ``chunk_cells`` voxels a side (None: one chunk), chunks in lattice order.

    ``labels`` (N,) keeps faces of different labels in different rectangles (and is reported
    per triangle). Raises :class:`TooManyTriangles` as soon as the meshes so far hold more than
    ``max_triangles`` triangles, :class:`TooManyChunks` before any meshing when the voxels span
    more than ``max_chunks`` chunks; ``ValueError`` for bad arguments.
    """
    k = np.asarray(keys)
    if k.ndim != 2 or k.shape[1] != 3 or not np.issubdtype(k.dtype, np.integer):
        raise ValueError(f"keys must be an integer array of shape (N, 3), got {k.shape} {k.dtype}")
    if not (resolution > 0 and np.isfinite(resolution)):
        raise ValueError(f"resolution must be > 0, got {resolution}")
    if chunk_cells is not None and chunk_cells < 1:
        raise ValueError(f"chunk_cells must be >= 1, got {chunk_cells}")
    if len(k) == 0:
        return []
    lab = np.zeros(len(k), np.int64) if labels is None else np.asarray(labels, np.int64)
    if lab.shape != (len(k),):
        raise ValueError(f"labels must have shape ({len(k)},), got {lab.shape}")
    span = k.max(axis=0).astype(np.float64) - k.min(axis=0) + 3
    if float(np.prod(span)) >= 2.0**62:
        raise ValueError("keys span too large a range")
    # Chunks on the original lattice (so they do not depend on the other voxels), meshed one
    # at a time: memory is bounded by the largest chunk, not by the whole map. Each chunk sorts
    # its own voxels (one answer, whatever the input order).
    chunk_keys, chunk_of = _chunks(k, chunk_cells)
    if max_chunks is not None and len(chunk_keys) > max_chunks:
        raise TooManyChunks(len(chunk_keys), max_chunks)
    by_chunk = np.argsort(chunk_of, kind="stable")
    bounds = np.searchsorted(chunk_of[by_chunk], np.arange(len(chunk_keys) + 1))
    hair = min(SPLIT, SPLIT_MAX / resolution)
    out: list[VoxelChunk] = []
    total = 0

    def one(c: int) -> VoxelChunk:
        members = by_chunk[bounds[c] : bounds[c + 1]]
        index = (int(chunk_keys[c, 0]), int(chunk_keys[c, 1]), int(chunk_keys[c, 2]))
        return _mesh_chunk(k[members], lab[members], index, resolution, origin, hair)

    # Chunks on every core (numpy releases the GIL in its sorts and loops); results in chunk
    # order, so the meshes do not depend on the number of threads.
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        for chunk in pool.map(one, range(len(chunk_keys))):
            total += len(chunk.mesh.faces)
            if max_triangles is not None and total > max_triangles:
                raise TooManyTriangles(total, max_triangles)
            out.append(chunk)
    return out


#: Largest box of chunks whose voxels are counted per chunk in a dense table (else sorted).
DENSE_CHUNKS_MAX = 1 << 24


def _chunks(
    k: NDArray[np.integer], chunk_cells: int | None
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The chunks the voxels fall in, in lattice order, and each voxel's chunk: through a count
    per chunk of the bounding box when that box is small (one pass, no sort of the voxels)."""
    if chunk_cells is None:
        return np.zeros((1, 3), np.int64), np.zeros(len(k), np.int64)
    chunk3 = np.floor_divide(k.astype(np.int64), int(chunk_cells))
    lo = chunk3.min(axis=0)
    chunk3 -= lo
    dims = chunk3.max(axis=0) + 1
    if float(np.prod(dims.astype(np.float64))) > DENSE_CHUNKS_MAX:
        keys, _, chunk_of = unique_rows(chunk3)
        return keys + lo, chunk_of
    code = (chunk3[:, 0] * dims[1] + chunk3[:, 1]) * dims[2] + chunk3[:, 2]
    present = np.flatnonzero(np.bincount(code, minlength=int(np.prod(dims))))
    dense_id = np.zeros(int(np.prod(dims)), np.int64)
    dense_id[present] = np.arange(len(present))
    keys = np.stack(np.unravel_index(present, tuple(int(d) for d in dims)), axis=1)
    return keys.astype(np.int64) + lo, dense_id[code]


def _mesh_chunk(
    k: NDArray[np.integer],
    lab: NDArray[np.int64],
    index: tuple[int, int, int],
    resolution: float,
    origin: tuple[float, float, float],
    hair: float,
) -> VoxelChunk:
    lo = k.min(axis=0).astype(np.int64)
    vox = k.astype(np.int64) - lo + 1  # >= 1: every neighbour is >= 0
    dims = vox.max(axis=0) + 2
    grid = _Lattice(vox, dims)  # sorts the voxels (x, then y, then z)
    if (np.diff(grid.codes) == 0).any():
        raise ValueError("keys must be unique")
    faces = _exposed_faces(grid, lab[grid.order])
    rects = _rectangles(faces)
    diag = _diagonals(grid, hair)
    polys = _polygons(rects, grid, diag)
    vertices, faces_, labels = _triangles(polys, grid, diag, hair)
    xyz = (vertices + (lo - 1)) * resolution + np.asarray(origin, np.float64)
    return VoxelChunk(index, Mesh(xyz, faces_), labels, len(k))


@dataclass
class _Faces:
    group: NDArray[np.int64]  #: plane id (direction, layer, label), dense
    direction: NDArray[np.int64]  #: index into _DIRS
    layer: NDArray[np.int64]
    u: NDArray[np.int64]
    v: NDArray[np.int64]
    label: NDArray[np.int64]


def _exposed_faces(grid: _Lattice, labels: NDArray[np.int64]) -> _Faces:
    parts: list[tuple[int, NDArray[np.int64]]] = []
    for d, (axis, sign) in enumerate(_DIRS):
        step = np.zeros(3, np.int64)
        step[axis] = sign
        exposed = ~grid.occupied(grid.vox + step)
        parts.append((d, np.flatnonzero(exposed)))
    direction = np.concatenate([np.full(len(i), d, np.int64) for d, i in parts])
    which = np.concatenate([i for _, i in parts])
    vox = grid.vox[which]
    axis = np.array([a for a, _ in _DIRS])[direction]
    sign = np.array([s for _, s in _DIRS])[direction]
    ua = np.array([_UV[a][0] for a, _ in _DIRS])[direction]
    va = np.array([_UV[a][1] for a, _ in _DIRS])[direction]
    rows = np.arange(len(vox))
    layer = vox[rows, axis] + (sign > 0)
    label = labels[which]
    _, _, group = unique_rows(np.stack([direction, layer, label - label.min()], axis=1))
    return _Faces(group, direction, layer, vox[rows, ua], vox[rows, va], label)


@dataclass
class _Rects:
    group: NDArray[np.int64]
    direction: NDArray[np.int64]
    layer: NDArray[np.int64]
    label: NDArray[np.int64]
    u0: NDArray[np.int64]  #: lattice lines bounding the rectangle: cells u0..u1-1, v0..v1-1
    u1: NDArray[np.int64]
    v0: NDArray[np.int64]
    v1: NDArray[np.int64]


def _rectangles(f: _Faces) -> _Rects:
    """Greedy rectangles per plane: runs along one in-plane axis, then runs of equal extent in
    consecutive rows merged; each plane keeps whichever of its two axes gives fewer."""
    along_u = _runs_merged(f.group, f.u, f.v)
    along_v = _runs_merged(f.group, f.v, f.u)
    n_groups = int(f.group.max()) + 1
    rects_u = np.bincount(along_u[0], minlength=n_groups)
    use_v = np.bincount(along_v[0], minlength=n_groups) < rects_u
    keep_u = ~use_v[along_u[0]]
    keep_v = use_v[along_v[0]]
    g = np.concatenate([along_u[0][keep_u], along_v[0][keep_v]])
    first = np.concatenate([along_u[1][keep_u], along_v[1][keep_v]])
    u0 = np.concatenate([along_u[2][keep_u], along_v[4][keep_v]])
    u1 = np.concatenate([along_u[3][keep_u], along_v[5][keep_v]])
    v0 = np.concatenate([along_u[4][keep_u], along_v[2][keep_v]])
    v1 = np.concatenate([along_u[5][keep_u], along_v[3][keep_v]])
    o = lex_order((u0, v0, g))  # a deterministic order
    f0 = first[o]
    return _Rects(g[o], f.direction[f0], f.layer[f0], f.label[f0], u0[o], u1[o], v0[o], v1[o])


def _runs_merged(
    group: NDArray[np.int64], x: NDArray[np.int64], y: NDArray[np.int64]
) -> tuple[NDArray[np.int64], ...]:
    """Runs along x in each (group, y) row, then runs of equal [x0, x1) in consecutive rows
    merged: (group, a face of it, x0, x1, y0, y1) per rectangle."""
    order = lex_order((x, y, group))
    g, xs, ys = group[order], x[order], y[order]
    new_run = np.ones(len(g), bool)
    new_run[1:] = (g[1:] != g[:-1]) | (ys[1:] != ys[:-1]) | (xs[1:] != xs[:-1] + 1)
    start = np.flatnonzero(new_run)
    end = np.append(start[1:], len(g))
    rg, ry, rx0, rx1, first = g[start], ys[start], xs[start], xs[end - 1] + 1, order[start]
    o = lex_order((ry, rx1, rx0, rg))
    rg, ry, rx0, rx1, first = rg[o], ry[o], rx0[o], rx1[o], first[o]
    new_rect = np.ones(len(rg), bool)
    new_rect[1:] = (
        (rg[1:] != rg[:-1])
        | (rx0[1:] != rx0[:-1])
        | (rx1[1:] != rx1[:-1])
        | (ry[1:] != ry[:-1] + 1)
    )
    s = np.flatnonzero(new_rect)
    e = np.append(s[1:], len(rg))
    return rg[s], first[s], rx0[s], rx1[s], ry[s], ry[e - 1] + 1


@dataclass
class _Polygons:
    """Each rectangle's boundary: corners and inserted points, counter-clockwise from outside."""

    start: NDArray[np.int64]  #: offset of each polygon's first point
    size: NDArray[np.int64]  #: points per polygon
    points: NDArray[np.int64]  #: (P, 3) lattice points (shifted coordinates; midpoints: -1)
    midpoint: NDArray[np.int64]  #: (P,) index into the diagonals' midpoints, -1 for lattice points
    #: (P,) a face incident to each lattice point, as the index (0..7, ``x + 2y + 4z``) of
    #: its occupied voxel in the 2x2x2 block around the point, times 8, plus its empty voxel's
    block: NDArray[np.int64]
    fan: NDArray[np.int64]  #: per polygon: index (0..size-1) of the fan corner, -1: centre
    centre: NDArray[np.float64]  #: (R, 3) polygon centres (lattice units)
    label: NDArray[np.int64]
    triangle_count: NDArray[np.int64]
    lo: NDArray[np.int64]  #: (R, 2) the rectangle's corner (u0, v0)
    hi: NDArray[np.int64]  #: (R, 2) and (u1, v1)
    direction: NDArray[np.int64]  #: (R,) index into _DIRS
    layer: NDArray[np.int64]  #: (R,)


def _to3d(
    direction: NDArray[np.int64],
    layer: NDArray[np.int64],
    u: NDArray[np.int64],
    v: NDArray[np.int64],
) -> NDArray[np.int64]:
    out = np.empty((len(direction), 3), np.int64)
    flat = out.reshape(-1)
    row = 3 * np.arange(len(direction))
    flat[row + _AXES[direction, 0]] = layer
    flat[row + _AXES[direction, 1]] = u
    flat[row + _AXES[direction, 2]] = v
    return out


#: Per face direction: its axis and in-plane axes (u, v).
_AXES = np.array([(axis, *_UV[axis]) for axis, _ in _DIRS], np.int64)


_OTHER = np.array([[1, 2], [0, 2], [0, 1]])


def _edge_tables() -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Per (face direction, rectangle edge 0..3): the axis the edge runs along; the quadrant of
    the rectangle's faces' voxels around the edge's line (0..3, the line's two other axes in
    order, 1 where the voxel is on the line's high side); and the same as a block index
    (``x + 2y + 4z``) in the 2x2x2 block around a point of the edge, the along axis left 0.
    Edge 0 runs at v = v0 along u, 1 at u = u1 along v, 2 at v = v1, 3 at u = u0."""
    along = np.zeros((6, 4), np.int64)
    quadrant = np.zeros((6, 4), np.int64)
    block = np.zeros((6, 4), np.int64)
    for d, (axis, sign) in enumerate(_DIRS):
        ua, va = _UV[axis]
        for e, (run, side, high) in enumerate(((ua, va, 1), (va, ua, 0), (ua, va, 0), (va, ua, 1))):
            high_side = {axis: 1 if sign < 0 else 0, side: high}
            a, b = _OTHER[run]
            along[d, e] = run
            quadrant[d, e] = high_side[a] + 2 * high_side[b]
            block[d, e] = (high_side[a] << a) + (high_side[b] << b)
    return along, quadrant, block


_EDGE_ALONG, _EDGE_QUADRANT, _EDGE_BLOCK = _edge_tables()


def _polygons(r: _Rects, grid: _Lattice, diag: Diagonals) -> _Polygons:
    n = len(r.u0)
    rep = np.repeat
    # Corners counter-clockwise in (u, v): (u0,v0) (u1,v0) (u1,v1) (u0,v1); edge e runs from
    # corner e to corner e+1. Negative directions are reversed at the end.
    cu = np.stack([r.u0, r.u1, r.u1, r.u0], axis=1)
    cv = np.stack([r.v0, r.v0, r.v1, r.v1], axis=1)
    corners = _to3d(rep(r.direction, 4), rep(r.layer, 4), cu.ravel(), cv.ravel()).reshape(n, 4, 3)
    # Each rectangle edge: its line, the quadrant its faces' voxels are in, and its span.
    ef = corners.reshape(-1, 3)
    et = np.roll(corners, -1, axis=1).reshape(-1, 3)
    ea = _EDGE_ALONG[r.direction].ravel()
    k = np.arange(len(ea))
    oa, ob = _OTHER[ea, 0], _OTHER[ea, 1]
    quadrant = _EDGE_QUADRANT[r.direction].ravel()
    lo = 2 * np.minimum(ef[k, ea], et[k, ea])
    hi = 2 * np.maximum(ef[k, ea], et[k, ea])
    # Points inserted into edges (doubled coordinates along the edge): the rectangle corners
    # strictly inside an edge, on the line the edge runs along (a corner matters only on the
    # lines its rectangle has an edge along: the faces that share a stretch of a line are the
    # ones with an edge along it); the diagonals' midpoints on their line and quadrant (only
    # faces of that voxel take them).
    c_edge, c_along = _corners_inside(grid, ef, et, ea)
    c_count = np.bincount(c_edge, minlength=len(ea))
    w = 2 * int(grid.dims.max()) + 4
    e_key = _line_key(ea, 2 * ef[k, oa], 2 * ef[k, ob], w)
    m_key = _line_key(diag.line[:, 0], diag.line[:, 1], diag.line[:, 2], w)
    m_key = m_key * 4 + diag.line[:, 3]
    # Only the edges on a line that holds a midpoint look for them (few lines do).
    d_max = int(grid.dims.max())
    line_id = (ea * d_max + ef[k, oa]) * d_max + ef[k, ob]
    mid_line = (diag.line[:, 0] * d_max + diag.line[:, 1] // 2) * d_max + diag.line[:, 2] // 2
    ask = np.flatnonzero(CodeSet(mid_line, 3 * d_max * d_max).contains(line_id))
    m_first = np.zeros(len(ea), np.int64)
    m_count = np.zeros(len(ea), np.int64)
    m_first[ask], m_count[ask], m_order = _between(
        m_key, diag.along, e_key[ask] * 4 + quadrant[ask], lo[ask], hi[ask], w
    )
    # The inserted points of each edge, in the order the edge runs.
    count = c_count + m_count
    ins_edge = np.concatenate([c_edge, rep(k, m_count)])
    m_at = m_order[_ranges(m_first, m_count)]
    ins_along = np.concatenate([c_along, diag.along[m_at]])
    ins_mid = np.concatenate([np.full(len(c_edge), -1, np.int64), m_at])
    ascending = et[k, ea] > ef[k, ea]
    key = np.where(ascending[ins_edge], ins_along, -ins_along)
    o = lex_order((key, ins_edge))
    ins_edge, ins_along, ins_mid = ins_edge[o], ins_along[o], ins_mid[o]
    inserted = count.reshape(n, 4)
    size = 4 + inserted.sum(axis=1)
    free_corner = (inserted == 0) & (np.roll(inserted, 1, axis=1) == 0)  # edges e-1 and e
    has_free = free_corner.any(axis=1)
    corner_idx = np.argmax(free_corner, axis=1)
    # The point sequence: corner 0, edge 0's points in order from corner 0, corner 1, ...
    per_edge = 1 + count
    total = int(per_edge.sum())
    edge_of = rep(k, per_edge)
    pos = np.arange(total) - rep(np.cumsum(per_edge) - per_edge, per_edge)
    is_corner = pos == 0
    points = np.empty((total, 3), np.int64)
    midpoint = np.full(total, -1, np.int64)
    points[is_corner] = ef
    ins = ~is_corner
    p = ef[ins_edge].copy()
    p[np.arange(len(ins_edge)), ea[ins_edge]] = ins_along // 2
    p[ins_mid >= 0] = -1
    points[ins] = p
    midpoint[ins] = ins_mid
    rect_of = edge_of // 4
    lattice = midpoint < 0
    block = np.zeros(total, np.int64)
    # A lattice point's face: its edge's face cell nearest to it, in the block around the point
    # (the edge's quadrant, and along the edge on the point's high side unless at the far end).
    e_lat = edge_of[lattice]
    a_lat = ea[e_lat]
    along = points[lattice][np.arange(len(e_lat)), a_lat]
    below_end = along < hi[e_lat] // 2
    occupied_at = _EDGE_BLOCK.ravel()[4 * r.direction[e_lat // 4] + e_lat % 4] + (
        below_end << a_lat
    )
    block[lattice] = occupied_at * 9 + _NORMAL_STEP[r.direction[rect_of[lattice]]]
    start = np.cumsum(size) - size
    # Negative directions wind clockwise in (u, v): reverse each polygon, keeping its start.
    neg = np.array([s for _, s in _DIRS])[r.direction] < 0
    within = np.arange(total) - rep(start, size)
    src = np.where(
        rep(neg, size), rep(start, size) + (rep(size, size) - within) % rep(size, size),
        np.arange(total),
    )  # fmt: skip
    points, midpoint, block = points[src], midpoint[src], block[src]
    corner_pos = np.concatenate(
        [np.zeros((n, 1), np.int64), np.cumsum(per_edge.reshape(n, 4), axis=1)[:, :3]], axis=1
    )
    fan_pos = corner_pos[np.arange(n), corner_idx]
    fan_pos = np.where(neg, (size - fan_pos) % size, fan_pos)
    fan = np.where(has_free, fan_pos, -1)
    tri = np.where(has_free, size - 2, size)
    centre = (corners[:, 0] + corners[:, 2]) / 2.0
    lo_uv = np.column_stack([r.u0, r.v0])
    hi_uv = np.column_stack([r.u1, r.v1])
    return _Polygons(
        start, size, points, midpoint, block, fan, centre, r.label, tri, lo_uv, hi_uv,
        r.direction, r.layer,
    )  # fmt: skip


def _corners_inside(
    grid: _Lattice, ef: NDArray[np.int64], et: NDArray[np.int64], ea: NDArray[np.int64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The rectangle corners strictly inside each edge (from ``ef`` to ``et``, along axis
    ``ea``) on that edge's line: (edge, doubled coordinate along it), edges ascending and each
    edge's points ascending. A corner is marked on the lines of its rectangle's two edges; each
    edge then looks up the lattice points between its ends."""
    strides = grid.strides
    size = 3 * int(np.prod(grid.dims.astype(np.float64)))
    marks = np.concatenate([grid.encode(ef) * 3 + ea, grid.encode(et) * 3 + ea])
    marked = CodeSet(marks, size)
    rows = np.arange(len(ea))
    lo = np.minimum(ef[rows, ea], et[rows, ea])
    inside = np.maximum(ef[rows, ea], et[rows, ea]) - lo - 1
    edge = np.repeat(rows, inside)
    along = _ranges(lo + 1, inside)
    base = (grid.encode(ef) - ef[rows, ea] * strides[ea]) * 3 + ea  # the line, at 0 along it
    hit = marked.contains(base[edge] + along * (3 * strides[ea[edge]]))
    return edge[hit], 2 * along[hit]


def _line_key(
    axis: NDArray[np.int64] | int, a: NDArray[np.int64], b: NDArray[np.int64], w: int
) -> NDArray[np.int64]:
    """One int64 per lattice line (axis, its two other coordinates, doubled, < w)."""
    key: NDArray[np.int64] = (axis * w + a) * w + b
    return key


def _between(
    key: NDArray[np.int64],
    along: NDArray[np.int64],
    q_key: NDArray[np.int64],
    lo: NDArray[np.int64],
    hi: NDArray[np.int64],
    w: int,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """For each query (line ``q_key``, span ``lo``..``hi``), the points (``key``, ``along``)
    strictly inside it: the first one's position in the returned order, and their count."""
    top = max(int(key.max(initial=0)), int(q_key.max(initial=0))) + 1
    if float(top) * w < 2.0**62:  # line keys and positions pack into one int64 as they are
        p_code = key * w + along
        q_ids = q_key
    else:  # pragma: no cover - lattices wider than OctoMap's 2^16 keys a side
        _, _, ids = unique_rows(np.concatenate([key, q_key])[:, None])
        p_code = ids[: len(key)] * w + along
        q_ids = ids[len(key) :]
    order = np.argsort(p_code, kind="stable")
    sorted_code = p_code[order]
    first = np.searchsorted(sorted_code, q_ids * w + lo, side="right")
    last = np.searchsorted(sorted_code, q_ids * w + hi, side="left")
    return first, np.maximum(last - first, 0), order


def _ranges(first: NDArray[np.int64], count: NDArray[np.int64]) -> NDArray[np.int64]:
    """Concatenated ``arange(first[i], first[i] + count[i])``."""
    total = int(count.sum())
    starts = np.repeat(first - (np.cumsum(count) - count), count)
    out: NDArray[np.int64] = starts + np.arange(total)
    return out


#: Per face direction, the step in the block index from a face's occupied voxel to its empty
#: one (its outward normal, x + 2y + 4z).
_NORMAL_STEP = np.array([sign * (1 << axis) for axis, sign in _DIRS], np.int64)


def _in_plane2(
    p: _Polygons, pts: NDArray[np.int64], polys: NDArray[np.int64], diag: Diagonals
) -> NDArray[np.int64]:
    """The in-plane (u, v) of the points ``pts`` of the polygons ``polys`` (in that order),
    doubled, where they lie before any move: lattice points as they are, midpoints from their
    diagonal's line."""
    doubled = 2 * p.points[pts]
    mid = p.midpoint[pts]
    at = np.flatnonzero(mid >= 0)
    line = diag.line[mid[at]]
    t = line[:, 0]
    doubled[at, t] = diag.along[mid[at]]
    doubled[at, _OTHER[t, 0]] = line[:, 1]
    doubled[at, _OTHER[t, 1]] = line[:, 2]
    axes = _AXES[p.direction[np.repeat(polys, p.size[polys])]]
    rows = np.arange(len(pts))
    return np.column_stack([doubled[rows, axes[:, 1]], doubled[rows, axes[:, 2]]])


def _triangles(
    p: _Polygons, grid: _Lattice, diag: Diagonals, hair: float
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """The chunk's vertices (lattice units, shifted), triangles and each triangle's label."""
    sheet_of, n_sheets, direction = sheet_tables()
    n_poly = len(p.size)
    lattice = p.midpoint < 0
    # Lattice points: one vertex per (point, sheet), the sheet from the 8 voxels around.
    # The 8 voxels around each distinct point (a point is in 4 to 6 polygons).
    pts = p.points[lattice]
    u_code, u_of = grid.unique(grid.encode(pts))
    u_pts = grid.decode(u_code)
    u_pattern = np.zeros(len(u_code), np.int64)
    for i in range(8):
        off = np.array([i & 1, i >> 1 & 1, i >> 2 & 1]) - 1  # voxel (0, 0, 0) is at point - 1
        u_pattern |= grid.occupied(u_pts + off).astype(np.int64) << i
    pattern = u_pattern[u_of]
    sheet = sheet_of.reshape(256, 64)[pattern, p.block[lattice]].astype(np.int64)
    if (sheet < 0).any():  # pragma: no cover - a face always separates occupied from empty
        raise AssertionError("a polygon point is not on the surface")
    sheet = np.where(n_sheets[pattern] > 1, sheet, 0)
    # One vertex per (point, sheet) used, in that order.
    key = u_of * 4 + sheet
    used_key = np.zeros(4 * len(u_code), bool)
    used_key[key] = True
    n_lattice = int(used_key.sum())
    lid = (np.cumsum(used_key) - 1)[key]
    v_key = np.flatnonzero(used_key)
    v_point, v_sheet = v_key // 4, v_key % 4
    v_pattern = u_pattern[v_point]
    split = (n_sheets[v_pattern] > 1)[:, None]
    lattice_xyz = u_pts[v_point] + np.where(split, direction[v_pattern, v_sheet] * hair, 0.0)
    vid = np.empty(len(p.points), np.int64)
    vid[lattice] = lid
    # Midpoints of diagonal edges: the ones used, in their order.
    used, mid_id = np.unique(p.midpoint[~lattice], return_inverse=True)
    vid[~lattice] = n_lattice + mid_id.reshape(-1)
    # Long rectangles with a moved point (a split vertex or a midpoint) on their boundary: a
    # fan could turn a triangle over there, a spine cannot (_voxel_spine.py).
    ext = p.hi - p.lo
    spine = ext.max(axis=1) > SPINE_RATIO * ext.min(axis=1)
    long_ = np.flatnonzero(spine)
    if len(long_):
        vertex_moved = np.concatenate([split[:, 0], np.ones(len(used), bool)])
        moved = vertex_moved[vid[_ranges(p.start[long_], p.size[long_])]].astype(np.int64)
        spine[long_] = np.add.reduceat(moved, np.cumsum(p.size[long_]) - p.size[long_]) > 0
    spine_polys = np.flatnonzero(spine)
    pts = _ranges(p.start[spine_polys], p.size[spine_polys])
    # Polygon centres (fans from the centre).
    use_centre = (p.fan < 0) & ~spine
    centre_vid = np.full(n_poly, -1, np.int64)
    centre_vid[use_centre] = n_lattice + len(used) + np.arange(int(use_centre.sum()))
    spines = spine_triangles(
        spine_polys, p.size, _in_plane2(p, pts, spine_polys, diag), vid[pts], p.lo, p.hi,
        np.array([s for _, s in _DIRS])[p.direction] < 0,
        n_lattice + len(used) + int(use_centre.sum()),
    )  # fmt: skip
    sp_axes = _AXES[p.direction[spines.poly_of_point]]
    spine_xyz = np.empty((len(spines.uv), 3))
    rows = np.arange(len(spines.uv))
    spine_xyz[rows, sp_axes[:, 0]] = p.layer[spines.poly_of_point]
    spine_xyz[rows, sp_axes[:, 1]] = spines.uv[:, 0]
    spine_xyz[rows, sp_axes[:, 2]] = spines.uv[:, 1]
    vertices = np.concatenate([lattice_xyz, diag.xyz[used], p.centre[use_centre], spine_xyz])
    # Triangles: fans from a corner (n - 2) or from the centre (n); then the spines'.
    tri_count = np.where(spine, 0, p.triangle_count)
    poly_of_tri = np.repeat(np.arange(n_poly), tri_count)
    j = np.arange(int(tri_count.sum())) - np.repeat(np.cumsum(tri_count) - tri_count, tri_count)
    size, start, fan = p.size[poly_of_tri], p.start[poly_of_tri], p.fan[poly_of_tri]
    corner_fan = fan >= 0
    a = np.where(corner_fan, vid[start + np.maximum(fan, 0)], centre_vid[poly_of_tri])
    b_local = np.where(corner_fan, (fan + 1 + j) % size, j % size)
    c_local = np.where(corner_fan, (fan + 2 + j) % size, (j + 1) % size)
    tris = np.column_stack([a, vid[start + b_local], vid[start + c_local]]).astype(np.int64)
    tris = np.concatenate([tris, spines.triangles])
    return vertices, tris, p.label[np.concatenate([poly_of_tri, spines.poly_of_triangle])]
