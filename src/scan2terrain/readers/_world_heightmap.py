"""A ``<heightmap>`` collision as the physics of each simulator builds it, as triangles in the
WORLD frame.

Heights (both simulators): gz-common's ``ImageHeightmap::FillHeightMap``
(``ImageHeightmap.hh``, ``FillHeights``; Gazebo Classic's ``common/ImageHeightmap`` is its
origin and gives the same numbers for 8-bit images), vertex ``(row, col)`` of a
``V x V`` grid, ``V = W s - s + 1`` for a ``W x W`` image and sampling ``s``: the first channel
bilinear at ``(row / s, col / s)`` in the image (row 0 = the image's top row), each sample over
its full scale (255 or 65535), the two horizontal interpolations rounded to float32, then
``h = float32((h1 - (h1 - h2) dy) * scale.z)`` as the C++ computes it. ``scale.z =
|size.z| / MaxElevation`` (``dartsim/src/CustomHeightmapShape.cc``; 1 when MaxElevation is 0,
which only an all-black image gives, whose heights are 0 whatever the scale).

MaxElevation: gz-common's ``Image::MaxColor().R()``, the red of the first pixel (FreeImage's
order: bottom row first) whose R + G + B is largest, each channel through gz-math's
``Color::Set``, which divides a value by 255 only when it is over 1: a sample of 1 counts as
1.0, full brightness (checked with gz-math 6 here: ``Set(1, 1, 1).R()`` is 1). So an 8-bit
image holding a 1 anywhere gets MaxElevation 1 even when its brightest sample is 200, and its
terrain is only 200/255 of ``size.z`` high, in Gazebo and here. For 16-bit images the working
rule is used, the brightest first-channel sample over 65535: gz-common 4.5's ``MaxColor`` fails
on them (it returns 0, and gz-physics then uses ``scale.z = 1``, heights of at most 1 m); the
heightmap probe (``tests/gazebo/heightmap_probe.cpp``) makes the same substitution.

Placement:

* ``gz`` (gz-physics' dartsim plugin, the only gz-sim engine with heightmap collisions): the
  shape frame is the collision frame (``<pos>`` is not used; gz-sim #1295, #1803); vertex
  spacing ``size / V`` (not ``size / (V - 1)``: the field spans ``size (V - 1) / V``), centred;
  row 0 at +y; ``z = h``. Then the collision's full world pose.
* ``classic`` (Gazebo Classic 11, ODE): ``s = 2`` whatever ``<sampling>`` says
  (``physics/HeightmapShape.cc``), spacing ``size / (V - 1)``, centred on the WORLD ORIGIN
  whatever the model, link and collision positions (ODE's heightfield geom is not placeable,
  gazebo-classic #2167); only the collision's world rotation is applied (the geom's rotation is
  set once), and ``z = h + <pos>.z`` (ODE's height offset). Only 8-bit images (Classic reads the
  first byte of each pixel) and square images of side ``2^n + 1`` (Classic refuses others).
  See ``tests/gazebo_harness.py``, ``terrain_height`` and ``vertex_world_xy``.

Triangles, two per cell, split along one diagonal:

* ``gz``: the world our writer makes asks DART for Bullet's collision detector
  (``<dart><collision_detector>bullet``), and DART builds a ``btHeightfieldTerrainShape`` after
  flipping the rows (``dart/collision/bullet/BulletCollisionDetector.cpp``,
  ``createBulletCollisionShapeFromHeightmap``: ``heightMap->flipY()``, then
  ``heightFieldShape->setUseZigzagSubdivision(true)``). Bullet's ``processAllTriangles``
  (``btHeightfieldTerrainShape.cpp``), which contacts use, splits cell ``(x, j)`` (j = Bullet's
  row, counted from -y after the flip) along ``(x, j)-(x+1, j+1)`` when
  ``m_useZigzagSubdivision && !(j & 1)`` (even j: south-west to north-east) and along
  ``(x+1, j)-(x, j+1)`` otherwise (odd j: south-east to north-west). Bullet's default (no
  zigzag, no flipQuadEdges) would be south-east to north-west in every cell; DART turns the
  zigzag on, so rows alternate. Checked on this machine with DART 6.12.1 and Bullet 3.24: a
  1 cm sphere centred on the surface each split predicts touches the field only where the
  zigzag one is right. (Bullet's *ray* test, ``performRaycast``, ignores the zigzag flag and
  splits every cell south-east to north-west: a ray cast through DART, not a lidar, sees that.)
  A world without ``collision_detector`` bullet runs DART's default detector, whose heightfield
  is not modelled (the zigzag is used; vertices and cell edges are the same either way, only
  the inside of a cell can differ, by up to half the cell's height difference).
* ``classic``: ODE's ``dxHeightfield`` (``deps/opende/src/heightfield.cpp``): cell corners
  ``A = (x, z)``, ``B = (x+1, z)``, ``C = (x, z+1)``, ``D = (x+1, z+1)``, triangles ``ABC`` and
  ``DBC`` (``dCollideHeightfieldZone``; ``GetHeight`` uses ``dx + dz <= 1`` for the first), so
  the diagonal is ``B-C``; ODE's z grows to world -y (the geom is turned +90 degrees about x),
  so ``B`` is the north-east corner and ``C`` the south-west one: south-west to north-east in
  every cell.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

#: Gazebo Classic's physics samples every heightmap with 2, whatever <sampling> says.
CLASSIC_SUBSAMPLING = 2


class HeightmapError(ValueError):
    """A heightmap cannot be built as the simulator would; the message says why."""


def vertex_count(width: int, sampling: int) -> int:
    """Vertices per side of the height field of a ``width``-pixel image."""
    return width * sampling - sampling + 1


def max_elevation(first: NDArray[np.integer], colour: NDArray[np.integer], full: int) -> float:
    """gz-common's ``ImageHeightmap::MaxElevation`` (see the module docstring): ``first`` is the
    first channel (H, W), ``colour`` every colour channel (H, W, C), ``full`` 255 or 65535."""
    if full != 255:
        return float(first.max()) / full

    # gz-math Color::Set: values over 1 are divided by 255, 0 and 1 are kept as they are.
    def channel(k: int) -> NDArray[np.float32]:
        c = colour[:, :, min(k, colour.shape[2] - 1)].astype(np.float32)
        scaled: NDArray[np.float32] = np.where(c > 1, c / np.float32(255), c)
        return scaled

    red = channel(0)
    total = red + channel(1) + channel(2)  # float32 sums, as Color's floats
    # FreeImage scans the bottom row first; the first strictly larger sum wins.
    bottom_up = total[::-1].reshape(-1)
    best = int(np.argmax(bottom_up))
    if bottom_up[best] <= 0:
        return 0.0
    return float(red[::-1].reshape(-1)[best])


def fill_heights(
    first: NDArray[np.integer], full: int, sampling: int, scale_z: float
) -> NDArray[np.float32]:
    """``FillHeights``: the (V, V) float32 heights, row 0 = the image's top row."""
    width = first.shape[1]
    n = vertex_count(width, sampling)
    f = np.arange(n, dtype=np.float64) / sampling
    i1 = np.floor(f).astype(np.intp)
    i2 = np.minimum(np.ceil(f).astype(np.intp), width - 1)
    d = f - i1
    p = first.astype(np.float64) / float(full)
    if sampling == 1:
        return (p.astype(np.float32).astype(np.float64) * scale_z).astype(np.float32)
    dx = d[None, :]
    top = p[i1]
    bottom = p[i2]
    h1 = (top[:, i1] - (top[:, i1] - top[:, i2]) * dx).astype(np.float32)
    h2 = (bottom[:, i1] - (bottom[:, i1] - bottom[:, i2]) * dx).astype(np.float32)
    diff = (h1 - h2).astype(np.float64)  # float - float in C++: a float
    heights: NDArray[np.float64] = (h1.astype(np.float64) - diff * d[:, None]) * scale_z
    return heights.astype(np.float32)


def heightmap(  # noqa: PLR0913 (the SDF element's fields, as gz-common takes them)
    first: NDArray[np.integer],
    colour: NDArray[np.integer],
    full: int,
    *,
    size: NDArray[np.float64],
    pos: NDArray[np.float64],
    sampling: int,
    simulator: str,
    rotation: NDArray[np.float64],
    translation: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.int32], str]:
    """World vertices (V*V, 3), triangles (2 (V-1)^2, 3) and a note, for the image's first
    channel ``first`` (H, W) and all its colour channels ``colour`` (H, W, C) with full scale
    ``full``, the ``<heightmap>``'s ``size``, ``pos`` and ``sampling``, and the collision's
    world ``rotation`` (3, 3) and ``translation`` (3,)."""
    height, width = first.shape
    if height != width:
        raise HeightmapError(f"the image is {width}x{height} pixels: Gazebo needs a square one")
    if width < 2:
        raise HeightmapError(f"the image is {width}x{height} pixels: too small for a terrain")
    if simulator == "classic":
        if colour.shape[2] > 1 and not (colour == colour[:, :, :1]).all():
            raise HeightmapError(
                "a colour image whose channels differ: which one Gazebo Classic's ODE reads "
                "depends on FreeImage's byte order; use a greyscale image for Classic"
            )
        if full != 255:
            raise HeightmapError(
                "16-bit image: Gazebo Classic reads only the first byte of each pixel "
                "(gazebo/common/ImageHeightmap.cc); use an 8-bit image for Classic"
            )
        if (width - 1) & (width - 2):
            raise HeightmapError(
                f"the image is {width}x{width} pixels: Gazebo Classic needs a side of 2^n+1"
            )
        sampling = CLASSIC_SUBSAMPLING
    n = vertex_count(width, sampling)
    elevation = max_elevation(first, colour, full)
    scale_z = 1.0 if elevation == 0.0 else abs(float(size[2])) / elevation
    h = fill_heights(first, full, sampling, scale_z)
    half = (n - 1) / 2.0
    if simulator == "gz":
        dx, dy = float(size[0]) / n, float(size[1]) / n
        z_offset = 0.0
        origin = translation
    else:
        dx, dy = float(size[0]) / (n - 1), float(size[1]) / (n - 1)
        z_offset = float(pos[2])
        origin = np.zeros(3)
    xs = (np.arange(n) - half) * dx
    ys = (half - np.arange(n)) * dy
    # Local vertices -> world, one coordinate at a time (V^2 x 3 float64 is the output).
    vertices = np.empty((n * n, 3))
    for axis in range(3):
        column = vertices[:, axis].reshape(n, n)
        column[:] = rotation[axis, 0] * xs[None, :] + rotation[axis, 1] * ys[:, None]
        column += rotation[axis, 2] * (h + z_offset)
        column += origin[axis]
    faces = _cells(n, simulator)
    note = f"{width}x{width} px, {n}x{n} vertices, MaxElevation {elevation:.6g}"
    return vertices, faces, note


def _cells(n: int, simulator: str) -> NDArray[np.int32]:
    """Two triangles per cell, counter-clockwise seen from above, split as the module docstring
    says. The cell's corners are ``a b`` over ``d e`` (row r above row r + 1, i.e. north of
    it): ``b = a + 1``, ``d = a + n``, ``e = a + n + 1``."""
    # South-west to north-east (d-b): (d, b, a) and (d, e, b).
    sw_ne = np.array([[n, 1, 0], [n, n + 1, 1]], dtype=np.int32)
    # South-east to north-west (e-a): (d, e, a) and (e, b, a).
    se_nw = np.array([[n, n + 1, 0], [n + 1, 1, 0]], dtype=np.int32)
    pattern = np.broadcast_to(sw_ne, (n - 1, 2, 3)).copy()
    if simulator == "gz":
        # Bullet's row of the cell between image rows r and r + 1 is j = n - 2 - r; odd j are
        # split south-east to north-west.
        odd = ((n - 2 - np.arange(n - 1)) & 1) == 1
        pattern[odd] = se_nw
    corner = np.arange(n - 1, dtype=np.int32)
    a = corner[:, None] * np.int32(n) + corner[None, :]
    faces: NDArray[np.int32] = a[:, :, None, None] + pattern[:, None, :, :]
    return faces.reshape(-1, 3)


def size_problem(size: NDArray[np.float64]) -> str | None:
    """Why a heightmap's ``<size>`` cannot be built, or None."""
    if not (size[0] > 0 and size[1] > 0):
        return f"x and y must be positive, got {size[0]:g} {size[1]:g}"
    if size[2] < 0:
        return (
            f"z is {size[2]:g}: a negative height inverts the terrain in gz-common (h = 1 - h), "
            "which is not supported"
        )
    if not all(math.isfinite(float(v)) for v in size):
        return "holds a number that is not finite"
    return None
