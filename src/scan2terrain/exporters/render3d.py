"""preview3d.png: an oblique, shaded picture of a world's collision triangles, drawn in numpy.

A software rasteriser of our own, because nothing made for the job fits a command that runs in
half a second on a machine with no display or GPU (issue 30): OSMesa/EGL through pyrender,
Open3D's or VTK's offscreen renderers take seconds to start a context and add a GL stack to
install, and a multithreaded GL rasteriser does not promise the same bytes on every run. This
one is a z-buffer in a few vectorised passes (no Python loop over triangles or pixels), gives
the same bytes for the same triangles, and draws the Willow Garage walls (31 k triangles,
1000 x 640 pixels) in a few tens of milliseconds.

The camera is orthographic, looking down at :data:`ELEVATION` from the south-west
(:data:`AZIMUTH`), so that a world's x axis runs to the lower right and its y axis to the upper
right; the picture is fitted to the triangles' extent. Each triangle is flat-shaded: a colour
from its height in the world's z range (low blue-grey through green to sand and white) times a
Lambert term of a light from the camera's upper left (both faces lit alike: triangle winding
is not relied on). The spawn pose is a red robot-sized box through the same z-buffer, with a
ring and heading arrow drawn over everything, so that it is found at a glance.
"""

from __future__ import annotations

import io
import itertools
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from PIL import ImageDraw

#: Picture size in pixels (width is what the issue asks for at least 800).
WIDTH, HEIGHT = 960, 640
#: View direction: degrees above the horizon, and compass angle the camera looks from (CCW
#: from +x: 225 = from the south-west, looking north-east).
ELEVATION, AZIMUTH = 38.0, 235.0
MARGIN = 24  #: pixels left around the fitted scene
SKY = (236, 240, 245)
SPAWN_RGB = (220, 40, 40)
#: The robot box at the spawn pose: length, width, height in metres.
ROBOT_BOX = (0.5, 0.4, 0.3)
#: Triangles gathered and drawn per pass (a 4097 x 4097 heightmap is 33.5 M): a pass holds some
#: 30 numbers a triangle, so 64 k of them take ~16 MB (1 M took 240 MB, a world folder's peak).
_FACES = 1 << 16
#: (triangle, pixel row) pairs handled per pass: bounds the memory of a pass to a few hundred MB
#: (a pair's span is at most a picture's width).
_PAIRS = 50_000
#: Pixels filled per pass (~50 bytes each while they are drawn: 13 MB).
_PIXELS = 1 << 18
#: Height colour ramp: (fraction of the z range, RGB): the ground's top grey-green, the highest
#: tops (walls, peaks) terracotta.
_RAMP = np.array(
    [
        (0.00, 150, 170, 150),
        (0.30, 110, 160, 110),
        (0.60, 205, 185, 115),
        (1.00, 190, 95, 65),
    ]
)


def camera_axes() -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Screen right, screen up and view direction (into the scene), unit vectors in the world."""
    el, az = math.radians(ELEVATION), math.radians(AZIMUTH)
    # The camera sits at azimuth az, elevation el; it looks at the scene along -position.
    back = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    view = -back
    right = np.cross(view, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, view)
    return right, up, view


def render_png(
    vertices: NDArray[np.float64],
    faces: NDArray[np.integer],
    *,
    spawn: tuple[float, float, float, float] | None = None,
    size: tuple[int, int] = (WIDTH, HEIGHT),
    fit: NDArray[np.float64] | None = None,
    cull: bool = True,
) -> bytes:
    """The PNG of the triangles ``faces`` (int (T, 3) into ``vertices``, float (V, 3), world
    frame, metres) seen obliquely, with the spawn pose ``(x, y, z, yaw)`` marked; ``size`` is
    (width, height) in pixels. The picture is fitted to the points ``fit`` (float (N, 3);
    default: the vertices used) and the robot box; what lies beyond is cut off.

    ``cull``: triangles facing away from the camera are not drawn. Our worlds' solids wind
    counter-clockwise seen from outside and their surfaces (heightmaps) from above, so those
    are hidden anyway; culling them halves the work, and the tests check that the picture is
    the same without it."""
    from PIL import Image, ImageDraw

    width, height = size
    faces = np.asarray(faces).reshape(-1, 3)
    if spawn is not None:  # the robot box: 8 more vertices, 12 more faces
        box, box_faces = _robot_box(spawn)
        faces = np.concatenate([faces, box_faces + len(vertices)])
        vertices = np.concatenate([vertices, box])
    right, up, view = camera_axes()
    if fit is None:
        used = np.zeros(len(vertices), bool)
        used[faces.ravel()] = True
        fit = vertices[used]
    elif spawn is not None:
        fit = np.concatenate([fit, vertices[-8:]])
    sx, sy = _dot(fit, right), _dot(fit, up)
    extent = (float(np.ptp(sx)), float(np.ptp(sy))) if len(sx) else (0.0, 0.0)
    span = max(extent[0] / (width - 2 * MARGIN), extent[1] / (height - 2 * MARGIN))
    scale = 1.0 / span if span > 0 else 1.0
    centre = ((sx.min() + sx.max()) / 2, (sy.min() + sy.max()) / 2) if len(sx) else (0.0, 0.0)

    def to_screen(points: NDArray[np.float64]) -> NDArray[np.float64]:
        """World points (..., 3) to pixel x (right), pixel y (down) and depth."""
        x = (_dot(points, right) - centre[0]) * scale + width / 2
        y = height / 2 - (_dot(points, up) - centre[1]) * scale
        return np.stack([x, y, _dot(points, view)], axis=-1)

    # Each vertex on screen, and its height as a band of the ramp (a pixel's colour is the band
    # at its own height): from the ground's top (the lowest triangle top) to the highest point.
    tops = vertices[:, 2][faces].max(axis=1) if len(faces) else np.zeros(1)
    lo, hi = float(tops.min()), float(vertices[:, 2][faces].max(initial=tops.min()))
    band = (vertices[:, 2] - lo) * ((_BANDS - 1) / (hi - lo if hi > lo else 1.0)) + 0.5
    screen = np.concatenate([to_screen(vertices), band[:, None]], axis=1)
    canvas = _Canvas(width, height)
    robot = len(faces) - (12 if spawn is not None else 0)
    for start in range(0, len(faces), _FACES):
        part = faces[start : start + _FACES]
        lit, away = _light(vertices[part], view)
        step = np.full(len(part), _LIGHTS, np.uint8)
        lit[max(robot - start, 0) :] = _RED  # the robot box: red whatever its height
        step[max(robot - start, 0) :] = 0
        if cull:
            away[max(robot - start, 0) :] = False
            part, lit, step = part[~away], lit[~away], step[~away]
        canvas.draw(screen[part], lit, step)
    img = Image.frombuffer("P", (width, height), canvas.image.tobytes(), "raw", "P", 0, 1)
    img.putpalette(_PALETTE.ravel().tolist())
    if spawn is not None:
        _mark_spawn(ImageDraw.Draw(img), spawn, to_screen, scale)
    buf = io.BytesIO()
    img.save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def _robot_box(
    spawn: tuple[float, float, float, float],
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The 8 corners and 12 triangles of a robot-sized box standing on the spawn point, turned
    by its yaw."""
    x, y, z, yaw = spawn
    length, width, tall = ROBOT_BOX
    cube = np.array(
        [[(i & 1) - 0.5, ((i >> 1) & 1) - 0.5, (i >> 2) & 1] for i in range(8)], np.float64
    ) * (length, width, tall)
    c, s = math.cos(yaw), math.sin(yaw)
    corners = cube @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) + (x, y, z)
    faces = np.array(
        [
            (0, 1, 3), (0, 3, 2), (4, 5, 7), (4, 7, 6), (0, 1, 5), (0, 5, 4),
            (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 3, 7), (1, 7, 5),
        ]
    )  # fmt: skip
    return corners, faces


def _light(
    tris: NDArray[np.float64], view: NDArray[np.float64]
) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
    """Each triangle's light level (0 .. :data:`_LIGHTS` - 1; both faces lit alike), and
    whether it faces away from the camera (counter-clockwise winding is its front)."""
    normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    away = _dot(normal, view) > 0
    length = np.sqrt((normal * normal).sum(axis=1))
    normal /= np.where(length > 0, length, 1.0)[:, None]
    light = _LIGHT - 0.4 * view
    light /= np.linalg.norm(light)
    lit = np.minimum((np.abs(_dot(normal, light)) * _LIGHTS).astype(np.uint8), _LIGHTS - 1)
    return lit, away


def _dot(points: NDArray[np.float64], axis: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rows of ``points`` (..., 3) dotted with ``axis`` (3,), without BLAS's thread start-up."""
    dotted: NDArray[np.float64] = (
        points[..., 0] * axis[0] + points[..., 1] * axis[1] + points[..., 2] * axis[2]
    )
    return dotted


def _palette() -> NDArray[np.uint8]:
    """256 RGB entries: :data:`_BANDS` height bands x :data:`_LIGHTS` light levels, then the
    sky and the spawn's red."""
    t = np.arange(_BANDS) / (_BANDS - 1)
    base = np.stack([np.interp(t, _RAMP[:, 0], _RAMP[:, k]) for k in (1, 2, 3)], axis=1)
    lambert = 0.35 + 0.65 * (np.arange(_LIGHTS) + 0.5) / _LIGHTS
    rgb = (base[:, None, :] * lambert[None, :, None]).reshape(-1, 3)
    palette = np.zeros((256, 3), np.uint8)
    palette[: len(rgb)] = np.clip(np.rint(rgb), 0, 255)
    palette[_SKY], palette[_RED] = SKY, SPAWN_RGB
    return palette


_BANDS, _LIGHTS = 15, 16  #: palette entries 0..239
_SKY, _RED = 254, 255
_LIGHT = np.array([-0.35, -0.25, 0.9])  #: towards the light, before tilting it to the camera
_PALETTE = _palette()


class _Canvas:
    """A z-buffer and the palette entry of the nearest triangle at each pixel (the sky where
    none is)."""

    def __init__(self, width: int, height: int) -> None:
        self.width, self.height = width, height
        self.depth = np.full(width * height, np.inf)
        self.entry = np.full(width * height, _SKY, dtype=np.uint8)

    @property
    def image(self) -> NDArray[np.uint8]:
        """Palette entries, (height, width), row 0 at the top."""
        return self.entry.reshape(self.height, self.width)

    def draw(
        self, screen: NDArray[np.float64], lit: NDArray[np.uint8], step: NDArray[np.uint8]
    ) -> None:
        """Flat-lit triangles ``screen`` (T, 3, 4: pixel x, pixel y, depth, height band). A
        pixel is a triangle's when its centre is inside it; the nearest wins (on a tie, the
        later). Its palette entry is ``lit + step * band`` at the pixel (``step`` 0: a fixed
        entry ``lit``).

        Scanline spans, vectorised: each (triangle, pixel row) pair gets the span of pixel
        centres between the triangle's long edge (top to bottom corner) and its short edge on
        that row, so no pixel outside a triangle is visited; depth and band are planes."""
        width, height = self.width, self.height
        order = np.argsort(screen[:, :, 1], axis=1, kind="stable")
        top, mid, bot = (
            np.take_along_axis(screen, order[:, k, None, None], axis=1)[:, 0] for k in range(3)
        )
        xt, yt, xm, ym, xb, yb = top[:, 0], top[:, 1], mid[:, 0], mid[:, 1], bot[:, 0], bot[:, 1]
        area = (xm - xt) * (yb - yt) - (xb - xt) * (ym - yt)
        row0 = np.ceil(yt - 0.5)
        row1 = np.floor(yb - 0.5)
        # A triangle thinner than a pixel that no row centre crosses gets its middle row.
        thin = row1 < row0
        row0[thin] = row1[thin] = np.floor((yt[thin] + yb[thin]) / 2)
        row0 = np.clip(row0, 0, height).astype(np.int64)
        row1 = np.clip(row1, -1, height - 1).astype(np.int64)
        keep = (np.abs(area) > 1e-9) & (row1 >= row0)
        x_min = np.minimum(np.minimum(xt, xm), xb)
        x_max = np.maximum(np.maximum(xt, xm), xb)
        with np.errstate(divide="ignore", invalid="ignore"):
            # Depth and band as planes: value at pixel (column c, row r) = v0 + vx c + vy r.
            u = (mid - top)[:, 2:] / np.where(keep, area, 1.0)[:, None]
            v = (bot - top)[:, 2:] / np.where(keep, area, 1.0)[:, None]
            vx = u * (yb - yt)[:, None] - v * (ym - yt)[:, None]
            vy = v * (xm - xt)[:, None] - u * (xb - xt)[:, None]
            # x along each edge per unit of y (0 for a level edge: its rows are its ends').
            long_slope = _slope(xb - xt, yb - yt)
            upper_slope = _slope(xm - xt, ym - yt)
            lower_slope = _slope(xb - xm, yb - ym)
        v0 = top[:, 2:] + vx * (0.5 - xt)[:, None] + vy * (0.5 - yt)[:, None]
        kept = np.flatnonzero(keep)
        rows = (row1 - row0 + 1)[kept]
        ends = np.cumsum(rows)
        start = 0
        while start < len(kept):
            before = ends[start - 1] if start else 0
            stop = max(int(np.searchsorted(ends, before + _PAIRS, side="right")), start + 1)
            n = rows[start:stop]
            tri = np.repeat(kept[start:stop], n)
            row = row0[tri] + np.arange(len(tri)) - np.repeat(np.cumsum(n) - n, n)
            yc = row + 0.5
            x_long = xt[tri] + (yc - yt[tri]) * long_slope[tri]
            x_short = np.where(
                yc < ym[tri],
                xt[tri] + (yc - yt[tri]) * upper_slope[tri],
                xm[tri] + (yc - ym[tri]) * lower_slope[tri],
            )
            left = np.maximum(np.minimum(x_long, x_short), x_min[tri])
            right = np.minimum(np.maximum(x_long, x_short), x_max[tri])
            lo, hi = np.ceil(left - 0.5), np.floor(right - 0.5)
            # A span narrower than a pixel that holds no pixel centre gets its middle pixel, so
            # that a wall a pixel thin is a line, not dashes.
            narrow = hi < lo
            lo[narrow] = hi[narrow] = np.floor((left[narrow] + right[narrow]) / 2)
            lo = np.clip(lo, 0, width).astype(np.int64)
            hi = np.clip(hi, -1, width - 1).astype(np.int64)
            base = v0[tri] + vy[tri] * row[:, None]
            self._fill(row * width, (lo, hi), base, vx[tri], (lit[tri], step[tri]))
            start = stop

    def _fill(
        self,
        row_start: NDArray[np.int64],
        span: tuple[NDArray[np.int64], NDArray[np.int64]],
        base: NDArray[np.float64],
        dx: NDArray[np.float64],
        entry: tuple[NDArray[np.uint8], NDArray[np.uint8]],
    ) -> None:
        """Every pixel of the (triangle, row) spans into the z-buffer, nearest kept:
        ``row_start`` is each row's first cell, ``span`` its first and last column, depth and
        band at column c are ``base + dx c`` (two columns), and the palette entry is
        ``lit + step * band`` (``entry`` = lit, step)."""
        lo, hi = span
        counts = np.maximum(hi - lo + 1, 0)
        ends = np.cumsum(counts)
        if len(ends) and ends[-1] > _PIXELS:  # pairs in runs of at most _PIXELS pixels, in order
            cuts = np.searchsorted(ends, np.arange(_PIXELS, int(ends[-1]), _PIXELS), "right")
            bounds = [0, *np.unique(np.maximum(cuts, 1)).tolist(), len(lo)]
            for a, b in itertools.pairwise(bounds):
                if b > a:
                    self._fill(row_start[a:b], (lo[a:b], hi[a:b]), base[a:b], dx[a:b],
                               (entry[0][a:b], entry[1][a:b]))  # fmt: skip
            return
        pair = np.repeat(np.arange(len(lo)), counts)
        col = np.arange(len(pair)) - np.repeat(np.cumsum(counts) - counts - lo, counts)
        depth_0, depth_dx = np.ascontiguousarray(base[:, 0]), np.ascontiguousarray(dx[:, 0])
        depth = depth_0[pair] + depth_dx[pair] * col
        cell = row_start[pair] + col
        np.minimum.at(self.depth, cell, depth)
        won = np.flatnonzero(depth <= self.depth[cell])
        pair, col = pair[won], col[won]
        band_0, band_dx = np.ascontiguousarray(base[:, 1]), np.ascontiguousarray(dx[:, 1])
        band = np.clip(band_0[pair] + band_dx[pair] * col, 0, _BANDS - 1).astype(np.uint8)
        lit, step = entry
        self.entry[cell[won]] = lit[pair] + step[pair] * band


def _slope(run: NDArray[np.float64], rise: NDArray[np.float64]) -> NDArray[np.float64]:
    slope: NDArray[np.float64] = np.where(rise > 0, run / np.where(rise > 0, rise, 1.0), 0.0)
    return slope


def _mark_spawn(
    draw: ImageDraw.ImageDraw,
    spawn: tuple[float, float, float, float],
    to_screen: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    scale: float,
) -> None:
    """A ring around the spawn point and an arrow along its heading, over everything."""
    x, y, z, yaw = spawn
    reach = max(1.0, 14.0 / scale)  # metres: at least 14 pixels long
    tip = (x + reach * math.cos(yaw), y + reach * math.sin(yaw), z)
    (sx, sy, _), (tx, ty, _) = to_screen(np.array([(x, y, z), tip]))
    r = 9
    draw.ellipse((sx - r, sy - r, sx + r, sy + r), outline=_RED, width=3)
    draw.line((sx, sy, tx, ty), fill=_RED, width=3)
    ang = math.atan2(ty - sy, tx - sx)
    head = [
        (tx + 8 * math.cos(ang + a), ty + 8 * math.sin(ang + a))
        for a in (math.pi * 0.8, -math.pi * 0.8)
    ]
    draw.polygon([(tx, ty), *head], fill=_RED)
