"""Walls as one watertight triangle mesh extruded from outlines (the files: exporters.meshfile).

Frames and units: vertices are in the MAP frame, metres, z up. Faces wind counter-clockwise seen
from outside (right-hand normals point out of the solid).

:func:`extrude` builds, per polygon (:class:`scan2terrain.geometry.outlines.Polygon`), a prism:
each outline edge becomes one wall quad (two triangles) and the polygon, holes included, is
triangulated once for the top and once for the bottom cap, using only the outline's own
vertices, so every boundary edge of a cap is exactly a wall quad's edge (no T-junctions) and
every edge of the mesh belongs to exactly two faces. Where rings touch at a point (a diagonal
contact of two cells) the point has one vertex per sector of material around it, each moved a
hair into its own sector (:data:`SPLIT`): the mesh stays 2-manifold there even for readers that
merge vertices by position (STL holds no indices; trimesh and Gazebo's assimp weld equal
positions), and the solids stand about a millimetre apart instead of sharing a vertical line.

Caps: convex polygons without holes (most wall pieces: rectangles) take a fan; the others go to
earcut, on points moved by a tiny deterministic jitter (:func:`_jitter`), because outlines are
full of exactly collinear points (the corners of staircases) on which ear clipping gets stuck and
drops points. Its output is then checked and, where needed, repaired locally (:class:`_Cap`):
slivers flipped away, T-junctions split, runs of slivers ear-clipped anew. Polygons with many
holes (speckled grids), and those whose earcut output is beyond repair, are cut into tiles first
(:func:`~scan2terrain.geometry._cap_tiles.tiled_cap`); a polygon that still cannot be
triangulated along its own edges raises. Every face has area: on a grid, at least half
a square cell (an eighth for simplified outlines).

Why mapbox-earcut: the caps are polygons with holes (up to thousands of vertices) and earcut is
the small, fast, widely used ear-clipping triangulator (Mapbox's C++ header behind a thin
binding: numpy in and out, no other dependency, a 77 kB wheel). Constrained Delaunay libraries
would need less repair but are either large (CGAL) or not free to use (Triangle).

"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from scan2terrain.geometry.caps import _caps
from scan2terrain.geometry.contacts import SharedPoints
from scan2terrain.geometry.outlines import Polygon, flatten

__all__ = ["Mesh", "boxes_mesh", "extrude", "is_watertight"]


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh.

    Attributes
    ----------
    vertices : float64 array, shape (V, 3)
        Map frame, metres, z up.
    faces : int64 array, shape (F, 3)
        Vertex indices, counter-clockwise seen from outside.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]

    def normals(self) -> NDArray[np.float64]:
        """Unit normal of each face, float64 (F, 3) (zero for a face without area)."""
        v = self.vertices[self.faces]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        unit: NDArray[np.float64] = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        return unit


def extrude(polygons: list[Polygon], height: float, base: float = 0.0) -> Mesh:
    """Walls from ``base`` to ``base + height`` over the polygons, as one watertight mesh.

    Parameters
    ----------
    polygons : list of Polygon
        Map frame, metres; valid polygons (simple rings, holes inside, not overlapping, rings
        touching at most at vertices), such as
        :func:`~scan2terrain.geometry.outlines.trace` or
        :func:`~scan2terrain.geometry.outlines.simplify` return.
    height : float
        Wall height, metres, > 0.
    base : float
        z of the bottom caps, metres.

    Returns
    -------
    Mesh
        Vertices: every ring vertex at ``base`` (in ring order, polygon by polygon, exterior
        then holes), then the same at ``base + height``. Faces: two per outline edge (walls),
        then the top caps, then the bottom caps. :func:`is_watertight` holds.

    Notes
    -----
    Where rings meet at a point (a diagonal contact) the mesh needs one vertex per *sector* of
    material there, not one per ring: a hole touching its own exterior leaves the exterior's
    corner along the hole's edge (see :mod:`~scan2terrain.geometry.outlines`), so a sector
    lies between one ring's outgoing edge and, counter-clockwise, another ring's incoming edge.
    Each sector uses the vertex that ends its incoming edge, for both walls and for the cap
    triangles inside it, so every vertical edge has exactly two wall faces.

    Raises
    ------
    ValueError
        If ``height`` is not positive and finite, ``base`` not finite, or a polygon cannot be
        triangulated into exactly its area (it is not valid).
    """
    if not (height > 0 and math.isfinite(height)):
        raise ValueError(f"height must be a positive number of metres, got {height}")
    if not math.isfinite(base):
        raise ValueError(f"base must be a finite number of metres, got {base}")
    if not polygons:
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    rings = flatten(polygons)
    xy = rings.xy
    n = len(xy)
    vertices = np.empty((2 * n, 3))
    vertices[:n, :2] = xy
    vertices[n:, :2] = xy
    vertices[:n, 2] = base
    vertices[n:, 2] = base + height
    nxt = rings.next_vertex()
    prv = np.empty(n, dtype=np.int64)
    prv[nxt] = np.arange(n, dtype=np.int64)
    shared = SharedPoints(xy, nxt, prv)
    # Edge k runs from vertex k to nxt[k]; at a shared point it starts at its sector's vertex.
    a = np.arange(n, dtype=np.int64)
    sector = shared.sector_of_edges()
    a[shared.members] = sector
    vertices[sector, :2] += shared.split(sector, nxt, prv)
    vertices[sector + n, :2] = vertices[sector, :2]
    b = nxt
    # Material is left of a -> b, so outside is to the right: (a, b, b') and (a, b', a') wind
    # counter-clockwise seen from there.
    walls = np.stack([a, b, b + n, a, b + n, a + n], axis=1).reshape(-1, 3)
    caps = _caps(xy, rings.start, rings.owner, shared)
    top = caps + n
    bottom = caps[:, ::-1]
    return Mesh(vertices, np.concatenate([walls, top, bottom]).astype(np.int64))


def boxes_mesh(boxes: NDArray[np.float64], height: float, base: float = 0.0) -> Mesh:
    """Upright boxes as one mesh: 8 vertices and 12 triangles each (outward, counter-clockwise).

    ``boxes`` (K, 5): centre x, y, size x, size y (metres, along the box's axes), yaw (radians),
    as :func:`scan2terrain.exporters.sdf.boxes_model_sdf` takes them; each from ``base`` to
    ``base + height``. Neighbouring boxes keep their shared faces (a visual, not a solid).
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 5)
    k = len(b)
    sx = np.array([-0.5, 0.5, 0.5, -0.5])
    sy = np.array([-0.5, -0.5, 0.5, 0.5])
    c, s = np.cos(b[:, 4:5]), np.sin(b[:, 4:5])
    u, v = sx[None, :] * b[:, 2:3], sy[None, :] * b[:, 3:4]
    x = b[:, 0:1] + c * u - s * v  # (K, 4) corners, counter-clockwise from above
    y = b[:, 1:2] + s * u + c * v
    ring = np.stack([x, y], axis=-1)
    low = np.concatenate([ring, np.full((k, 4, 1), base)], axis=-1)
    high = np.concatenate([ring, np.full((k, 4, 1), base + height)], axis=-1)
    vertices = np.concatenate([low, high], axis=1).reshape(-1, 3)
    # Per box: bottom (seen from below), top, and the four sides.
    local = np.array(
        [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]]
        + [[i, (i + 1) % 4, (i + 1) % 4 + 4] for i in range(4)]
        + [[i, (i + 1) % 4 + 4, i + 4] for i in range(4)],
        dtype=np.int64,
    )
    faces = (local[None, :, :] + 8 * np.arange(k, dtype=np.int64)[:, None, None]).reshape(-1, 3)
    return Mesh(vertices, faces)


def is_watertight(mesh: Mesh) -> bool:
    """Every edge is used by exactly two faces, once in each direction, and no face repeats a
    vertex: a closed, consistently oriented 2-manifold (combinatorially)."""
    f = np.asarray(mesh.faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        return False
    if ((f < 0) | (f >= len(mesh.vertices))).any():
        return False
    if ((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])).any():
        return False
    v = len(mesh.vertices)
    a = f.reshape(-1)
    b = f[:, [1, 2, 0]].reshape(-1)
    directed = np.sort(a * v + b)
    if (directed[1:] == directed[:-1]).any():
        return False  # a directed edge twice: inconsistent orientation or more than two faces
    reverse = np.sort(b * v + a)
    return bool(np.array_equal(directed, reverse))
