"""SDF primitive shapes and extruded polylines as triangles, in the shape's own frame.

What :mod:`.world` turns each ``<geometry>`` into (the collision pose is applied there). Every
function returns ``(vertices, triangles, note)``: float64 (V, 3) metres, int64 (T, 3) indices,
and what the part line says about the approximation. Faces wind counter-clockwise seen from
outside where the shape has an outside.

* box: 8 vertices, 12 triangles, exact.
* cylinder (axis z, centred) and capsule (cylinder of ``length`` plus two half spheres): lathed
  with ``N`` segments around (vertices on the surface, so the chords lie inside it). ``N`` is the
  smallest multiple of 8, at least 256, whose chord error is under :data:`CHORD_TOLERANCE`
  (1 mm), at most :data:`MAX_SEGMENTS`; the note says the bound.
* sphere and ellipsoid: an icosphere (icosahedron split ``k`` times, vertices pushed onto the
  sphere), ``k`` the smallest whose largest distance between a face and the sphere is under
  1 mm, at most :data:`MAX_ICOSPHERE_LEVEL`; an ellipsoid scales the unit icosphere by its radii
  (the bound is the sphere's error times the largest radius).
* plane: what each simulator's physics builds. gz-physics' dartsim has no plane shape: it makes
  a 2100 m cube whose top face is the plane (``dartsim/src/SDFFeatures.cc``, ``ConstructPlane``:
  "This number was taken from osrf/gazebo"), centred on the collision origin, ``<size>``
  ignored. Gazebo Classic's ODE plane is infinite and is not placed by the collision pose:
  ``n . p = z`` with the SDF ``<normal>`` in the WORLD frame and ``z`` the collision's world
  height (``gazebo/physics/ode/ODEPlaneShape.cc``, ``CreatePlane``); it is cut here to a
  :data:`PLANE_SIDE` square around the collision's position projected onto it, so beams hit it
  up to about 1 km away.
* polyline: extruded as gz-common's ``MeshManager::CreateExtrudedPolyline`` builds it for gz-sim
  and Classic alike (see :func:`polyline`).
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
from numpy.typing import NDArray

#: Largest distance (metres) between a curved surface and its triangles we aim for.
CHORD_TOLERANCE = 1e-3
#: Segments around a cylinder or capsule: at least this many, more when the radius needs them.
MIN_SEGMENTS = 256
#: ... and at most this many (a cylinder of radius over 3.4 km then exceeds the tolerance).
MAX_SEGMENTS = 8192
#: Subdivisions of the icosahedron at most (level 8: 1,310,720 triangles).
MAX_ICOSPHERE_LEVEL = 8
#: Side (metres) of gz-physics' plane cube, and of the square that stands for ODE's plane.
PLANE_SIDE = 2100.0
#: gz-common merges polyline points closer than this (``CreateExtrudedPolyline``'s ``tol``).
POLYLINE_TOLERANCE = 1e-4

Shape = tuple[NDArray[np.float64], NDArray[np.int64], str]


class ShapeError(ValueError):
    """A shape's numbers cannot be triangulated; the message says why (the caller names the
    file and the element)."""


def millimetres(metres: float) -> str:
    """A length as the part lines print it."""
    return f"{metres * 1e3:.3g} mm"


# --------------------------------------------------------------------------- box


def box(size: NDArray[np.float64]) -> Shape:
    """An axis-aligned box of ``size`` (x, y, z) metres centred on the origin."""
    corners = np.array(
        [[x, y, z] for z in (-0.5, 0.5) for y in (-0.5, 0.5) for x in (-0.5, 0.5)],
        dtype=np.float64,
    )
    faces = np.array(
        [
            [0, 2, 1], [1, 2, 3],  # z-
            [4, 5, 6], [5, 7, 6],  # z+
            [0, 1, 4], [1, 5, 4],  # y-
            [2, 6, 3], [3, 6, 7],  # y+
            [0, 4, 2], [2, 4, 6],  # x-
            [1, 3, 5], [3, 7, 5],  # x+
        ],
        dtype=np.int64,
    )  # fmt: skip
    return corners * np.asarray(size, dtype=np.float64), faces, "exact"


# --------------------------------------------------------------------------- lathed shapes


def _segments(radius: float, per_quad: float = 1.0) -> tuple[int, float]:
    """Segments around a circle of ``radius`` and the chord error they leave (metres).

    ``per_quad`` is how many sagittas a face can be off (2 for a sphere's quads, whose centre
    misses in both directions)."""
    n = MIN_SEGMENTS
    while n < MAX_SEGMENTS and per_quad * radius * (1 - math.cos(math.pi / n)) > CHORD_TOLERANCE:
        n *= 2
    return n, per_quad * radius * (1 - math.cos(math.pi / n))


def _lathe(radii: NDArray[np.float64], heights: NDArray[np.float64], n: int) -> Shape:
    """The surface swept by the profile (``radii[k]``, ``heights[k]``) around z, from a pole
    (radius 0) at ``heights[0]`` to a pole at ``heights[-1]``, ``n`` segments around. Rings
    between the poles have positive radii."""
    rings = len(radii) - 2
    angle = 2 * math.pi * np.arange(n) / n
    ring_xy = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    vertices = np.empty((2 + rings * n, 3))
    vertices[0] = (0.0, 0.0, heights[0])
    vertices[1] = (0.0, 0.0, heights[-1])
    body = vertices[2:].reshape(rings, n, 3)
    body[:, :, :2] = radii[1:-1, None, None] * ring_xy[None]
    body[:, :, 2] = heights[1:-1, None]
    j = np.arange(n)
    nxt = (j + 1) % n
    first = 2 + j
    last = 2 + (rings - 1) * n + j
    bottom = np.stack([np.zeros(n, dtype=np.int64), 2 + nxt, first], axis=1)
    top = np.stack([np.ones(n, dtype=np.int64), last, 2 + (rings - 1) * n + nxt], axis=1)
    k = np.arange(rings - 1)[:, None]
    a = 2 + k * n + j  # ring k, segment j
    b = 2 + k * n + nxt
    c = a + n  # ring k + 1
    d = b + n
    sides = np.stack([np.stack([a, b, d], -1), np.stack([a, d, c], -1)], axis=2).reshape(-1, 3)
    return vertices, np.concatenate([bottom, sides, top]).astype(np.int64), ""


def cylinder(radius: float, length: float) -> Shape:
    """A cylinder about z, centred on the origin."""
    n, error = _segments(radius)
    half = length / 2
    vertices, faces, _ = _lathe(
        np.array([0.0, radius, radius, 0.0]), np.array([-half, -half, half, half]), n
    )
    return vertices, faces, f"{n} segments, chord error {millimetres(error)}"


def capsule(radius: float, length: float) -> Shape:
    """A capsule about z: a cylinder of ``length`` between two half spheres of ``radius``."""
    n, error = _segments(radius, per_quad=2.0)
    m = n // 4  # latitude steps per quarter circle: the same angle as around
    phi = np.linspace(-math.pi / 2, 0.0, m + 1)
    lower_r, lower_z = radius * np.cos(phi), -length / 2 + radius * np.sin(phi)
    radii = np.concatenate([lower_r, lower_r[::-1]])
    heights = np.concatenate([lower_z, -lower_z[::-1]])
    radii[0] = radii[-1] = 0.0
    vertices, faces, _ = _lathe(radii, heights, n)
    return vertices, faces, f"{n} segments, chord error {millimetres(error)}"


# --------------------------------------------------------------------------- spheres


@cache
def _icosphere(level: int) -> tuple[NDArray[np.float64], NDArray[np.int64], float]:
    """The unit icosphere of ``level`` subdivisions and its largest face-to-sphere distance."""
    t = (1 + math.sqrt(5)) / 2
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float64,
    )  # fmt: skip
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )  # fmt: skip
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(level):
        edges = np.sort(f[:, [[0, 1], [1, 2], [2, 0]]], axis=2).reshape(-1, 2)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = v[unique[:, 0]] + v[unique[:, 1]]
        v = np.concatenate([v, mid / np.linalg.norm(mid, axis=1, keepdims=True)])
        m = inverse.reshape(-1, 3) + (len(v) - len(unique))  # m01, m12, m20
        f = np.concatenate(
            [
                np.stack([f[:, 0], m[:, 0], m[:, 2]], 1),
                np.stack([f[:, 1], m[:, 1], m[:, 0]], 1),
                np.stack([f[:, 2], m[:, 2], m[:, 1]], 1),
                m,
            ]
        )
    tri = v[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    nearest = float(np.abs(np.einsum("ij,ij->i", normal, tri[:, 0])).min())
    return v, f, 1.0 - nearest


def ellipsoid(radii: NDArray[np.float64]) -> Shape:
    """An ellipsoid of semi-axes ``radii`` (x, y, z) centred on the origin (a sphere when the
    three are equal)."""
    biggest = float(np.max(radii))
    level = 0
    while level < MAX_ICOSPHERE_LEVEL and _icosphere(level)[2] * biggest > CHORD_TOLERANCE:
        level += 1
    v, f, error = _icosphere(level)
    return v * radii, f.copy(), f"icosphere level {level}, error {millimetres(error * biggest)}"


# --------------------------------------------------------------------------- planes


def plane(
    normal: NDArray[np.float64],
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
    simulator: str,
) -> tuple[NDArray[np.float64], NDArray[np.int64], str]:
    """A ``<plane>`` as the simulator's physics builds it, in the WORLD frame (the collision's
    world ``rotation`` and ``translation`` applied as that physics applies them)."""
    length = float(np.linalg.norm(normal))
    if not (length > 0 and math.isfinite(length)):
        raise ShapeError("a plane's <normal> must be a nonzero vector")
    n = normal / length
    if simulator == "gz":
        # dartsim: rotate z onto the normal, then a cube of PLANE_SIDE whose top is the plane,
        # in the collision frame.
        frame = _dartsim_rotation(n)
        cube, faces, _ = box(np.full(3, PLANE_SIDE))
        cube[:, 2] -= PLANE_SIDE / 2
        local = cube @ frame.T
        world = local @ rotation.T + translation
        return world, faces, f"dartsim's {PLANE_SIDE:g} m cube, its top the plane"
    # ODE: n . p = altitude / |normal| (dGeomPlaneSetParams normalises all four numbers), the
    # normal not rotated by the pose.
    altitude = float(translation[2]) / length
    centre = translation - (float(n @ translation) - altitude) * n
    frame = _rotation_onto(n)
    half = PLANE_SIDE / 2
    square = np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]])
    world = square @ frame.T + centre
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    return world, faces, f"ODE's infinite plane cut to {PLANE_SIDE:g} m"


def _dartsim_rotation(n: NDArray[np.float64]) -> NDArray[np.float64]:
    """dartsim's ConstructPlane rotation for the unit normal ``n``: about z x n by
    asin(|z x n|), none when that angle is under 1e-12. asin is never obtuse, so a normal
    pointing below the horizon gets the cube of its mirror image above it (a normal straight
    down, none at all): replicated, it is what the physics collides with."""
    axis = np.cross(np.array([0.0, 0.0, 1.0]), n)
    s = float(np.linalg.norm(axis))
    angle = math.asin(min(s, 1.0))
    if angle <= 1e-12:
        return np.eye(3)
    return _axis_angle(axis / s, angle)


def _rotation_onto(n: NDArray[np.float64]) -> NDArray[np.float64]:
    """A rotation taking +z onto the unit vector ``n``."""
    axis = np.cross(np.array([0.0, 0.0, 1.0]), n)
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        return np.eye(3) if n[2] > 0 else np.diag([1.0, -1.0, -1.0])
    return _axis_angle(axis / s, math.atan2(s, float(n[2])))


def _axis_angle(k: NDArray[np.float64], angle: float) -> NDArray[np.float64]:
    """Rodrigues' rotation about the unit axis ``k``."""
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    rotation: NDArray[np.float64] = (
        np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * (kx @ kx)
    )
    return rotation


# --------------------------------------------------------------------------- polylines


def polyline(rings: list[NDArray[np.float64]], height: float) -> Shape:
    """A ``<geometry>``'s ``<polyline>`` elements extruded from z = 0 to ``height`` together.

    As gz-common 4's ``MeshManager::CreateExtrudedPolyline`` (gz-sim's Physics system; Gazebo
    Classic's polyline shape calls the same): each ring is closed (its last point dropped when
    within 1e-4 m of the first, :data:`POLYLINE_TOLERANCE`), points closer than that to the
    previous one merged; the caps are what lies inside an odd number of rings (even-odd: holes
    stay open, islands in holes are solid again); every ring edge gets a wall. The caps are
    triangulated with mapbox-earcut instead of GTS's constrained Delaunay triangulation: other
    triangles, the same surface.

    Raises
    ------
    ShapeError
        A ring of fewer than 3 distinct points, or caps whose triangles do not cover exactly the
        even-odd area (rings that cross each other: gz-common's triangulation fails on them too,
        and gz-sim then builds no shape).
    """
    import mapbox_earcut

    cleaned = [_clean_ring(r) for r in rings]
    for k, ring in enumerate(cleaned):
        if len(ring) < 3:
            raise ShapeError(f"<polyline> {k + 1} has fewer than 3 distinct points")
    sizes = np.array([len(r) for r in cleaned], dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    xy = np.concatenate(cleaned)
    n = len(xy)
    if len(cleaned) == 1:
        depth, parent = np.zeros(1, dtype=np.int64), np.full(1, -1, dtype=np.int64)
    else:
        depth, parent = _nesting(cleaned, xy, start, sizes)
    caps: list[NDArray[np.int64]] = []
    area_caps = 0.0
    for outer in np.flatnonzero(depth % 2 == 0):
        members = [int(outer), *np.flatnonzero((depth % 2 == 1) & (parent == outer)).tolist()]
        points = np.concatenate([cleaned[k] for k in members])
        ends = np.cumsum([sizes[k] for k in members]).astype(np.uint32)
        local = np.asarray(mapbox_earcut.triangulate_float64(points, ends), dtype=np.int64)
        index = np.concatenate([np.arange(start[k], start[k] + sizes[k]) for k in members])
        tri = index[local.reshape(-1, 3)]
        caps.append(tri)
        area_caps += float(np.abs(_areas(xy[tri])).sum())
    signed = np.array([abs(_ring_area(r)) for r in cleaned]) * np.where(depth % 2 == 0, 1, -1)
    area_rings = float(signed.sum())
    if abs(area_caps - area_rings) > 1e-9 * max(1.0, area_rings) + 1e-12 * n:
        raise ShapeError(
            f"its rings do not bound a region by the even-odd rule (rings that cross?): the "
            f"caps cover {area_caps:.6g} m^2, the rings enclose {area_rings:.6g} m^2"
        )
    cap = np.concatenate(caps) if caps else np.zeros((0, 3), dtype=np.int64)
    vertices = np.empty((2 * n, 3))
    vertices[:n, :2] = xy
    vertices[n:, :2] = xy
    vertices[:n, 2] = 0.0
    vertices[n:, 2] = height
    a = np.arange(n, dtype=np.int64)
    nxt = a + 1
    last = start + sizes - 1
    nxt[last] = start
    walls = np.stack([a, nxt, nxt + n, a, nxt + n, a + n], axis=1).reshape(-1, 3)
    faces = np.concatenate([walls, cap[:, ::-1], cap + n]).astype(np.int64)
    return vertices, faces, f"{len(cleaned)} rings, caps by even-odd"


def _clean_ring(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """A ring's points without the closing duplicate and without points within
    :data:`POLYLINE_TOLERANCE` of the previous kept one (consecutive duplicates)."""
    p: NDArray[np.float64] = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(p) == 0:
        return p
    step = np.hypot(*np.diff(p, axis=0).T)
    keep = np.concatenate([[True], step > POLYLINE_TOLERANCE])
    p = p[keep]
    if len(p) > 1 and math.hypot(*(p[-1] - p[0])) <= POLYLINE_TOLERANCE:
        p = p[:-1]
    return p


def _ring_area(ring: NDArray[np.float64]) -> float:
    x, y = ring[:, 0], ring[:, 1]
    closing = x[-1] * y[0] - x[0] * y[-1]
    return 0.5 * float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1]) + closing)


def _areas(tri: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed areas of triangles (T, 3, 2)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    return 0.5 * cross


def _nesting(
    rings: list[NDArray[np.float64]],
    xy: NDArray[np.float64],
    start: NDArray[np.int64],
    sizes: NDArray[np.int64],
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Per ring: how many other rings contain it (its depth) and the innermost of them (its
    parent, -1 for none). A ring is tested at the midpoint of its first edge (a point of its own,
    not a vertex it may share with a touching ring), with the even-odd crossing rule against
    every edge of the other rings whose y range holds it (pairs found by sorting, not R x E)."""
    count = len(rings)
    probe = 0.5 * (xy[start] + xy[start + 1])
    ring_of = np.repeat(np.arange(count), sizes)
    a = xy
    idx = np.arange(len(xy))
    nxt = idx + 1
    nxt[start + sizes - 1] = start
    b = xy[nxt]
    lo = np.minimum(a[:, 1], b[:, 1])
    hi = np.maximum(a[:, 1], b[:, 1])
    order = np.argsort(probe[:, 1], kind="stable")
    ys = probe[order, 1]
    # Edges cross the probe's horizontal line when lo <= y < hi (half-open: a vertex at that
    # height counts once).
    first = np.searchsorted(ys, lo, side="left")
    stop = np.searchsorted(ys, hi, side="left")
    counts = np.maximum(stop - first, 0)
    edge = np.repeat(np.arange(len(xy)), counts)
    offset = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    ring = order[first[edge] + offset]
    keep = ring_of[edge] != ring
    edge, ring = edge[keep], ring[keep]
    py = probe[ring, 1]
    px = probe[ring, 0]
    ea, eb = a[edge], b[edge]
    t = (py - ea[:, 1]) / (eb[:, 1] - ea[:, 1])
    x_cross = ea[:, 0] + t * (eb[:, 0] - ea[:, 0])
    crossed = x_cross > px
    pair, crossings = np.unique(ring[crossed] * count + ring_of[edge[crossed]], return_counts=True)
    odd = pair[crossings % 2 == 1]
    inside, container = odd // count, odd % count
    depth = np.bincount(inside, minlength=count).astype(np.int64)
    parent = np.full(count, -1, dtype=np.int64)
    if len(inside):
        # The innermost container is the deepest one.
        best = np.lexsort((depth[container], inside))
        last_of = np.r_[inside[best][1:] != inside[best][:-1], True]
        parent[inside[best][last_of]] = container[best][last_of]
    return depth, parent
