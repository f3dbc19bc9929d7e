"""Synthetic 2D laser recordings with known truth, for pose correction (issue 27).

A :class:`Scene` is a set of 2D wall segments (metres, all walls :data:`WALL_HEIGHT` high) with a
closed route through it. :func:`simulate` drives the route, scans the scene by ray casting and
integrates an odometry that drifts on purpose, and returns a :class:`Recording`: the truth, the
odometry, the ranges, and writers for a bag (ROS1 or ROS 2), TUM files and the truth occupancy.

Scenes (:data:`SCENES`, :func:`make_scene`; ``scale`` sizes the layout, never the corridors):

* ``corridor_loop``: a rectangular corridor ring (outer ``30 x 20 m`` times ``scale``, corridor
  2 m wide) with door niches, pilasters and two side rooms (one with a pillar, one with a
  cabinet), and plain stretches between them.
* ``rooms``: a corridor with ``round(3 * scale)`` rooms (4 x 4 m) on each side, doors to the
  corridor and between neighbouring rooms, furniture and clutter (placed by a fixed seed, so each
  room differs) and an open door at the corridor's west end. The route (``route="north"``)
  drives the corridor east and comes back west through the northern rooms; ``route="both"``
  adds the southern rooms (a figure eight that drives the corridor twice per lap).
* ``parallel_corridors``: two corridors 2 m wide whose centre lines are 4 m apart (a 2 m block
  between them), joined at both ends. Both have the same niches and pilasters at the same x,
  so in their middle one corridor is the other moved by 4 m: a careless loop closer matches
  them. The two ends differ (a side room at the west end), so the true loop can be closed.

Scene coordinates are multiples of 0.05 m plus 0.025 m (as :mod:`tests.bagmaker`'s room): no
wall lies on a cell boundary at 0.05 or 0.1 m, so :meth:`Scene.occupancy` is exact there.

The route is followed at ``speed`` (0.5 m/s), slower in turns so that the turn rate stays under
``max_turn_rate`` (0.5 rad/s); corners are arcs (so the heading, which follows the path, is
continuous). Everything is seeded: the same arguments give the same arrays and the same bag bytes.

Typical use::

    rec = simulate("corridor_loop", drift=Drift(scale=0.02), seed=1)
    rec.write_bag(tmp_path / "raw.bag", "ros1")               # /scan, /odom, /tf_static
    rec.write_bag(tmp_path / "slam.bag", "ros1", map_frame=True)  # + /tf odom->base_link, map->odom
    rec.truth, rec.odom, rec.laser_poses                      # (K, 3) x, y, yaw at the scans
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from scan2terrain.exporters.trajectory import tum_bytes
from scan2terrain.slam.pose2 import between, compose, inverse, wrap
from tests.bagmaker import (
    LASER_SCAN,
    ODOMETRY,
    TF_MESSAGE,
    Fmt,
    MsgSpec,
    laserscan_msg,
    odometry_msg,
    tf_msg,
    write_bag,
    yaw_quaternion,
)

WALL_HEIGHT = 2.5
#: Scene coordinates are designed on a 0.05 m lattice and moved by this much (see the module doc).
OFFSET = 0.025
START_NS = 1_700_000_000_000_000_000
SCAN_TOPIC, ODOM_TOPIC = "/scan", "/odom"
LASER_FRAME, BASE_FRAME, ODOM_FRAME, MAP_FRAME = "laser", "base_link", "odom", "map"
#: Bag (record) time after the header stamp: tf and odometry first, then the scan.
SCAN_LAG_NS, POSE_LAG_NS = 5_000_000, 1_000_000

Floats = NDArray[np.float64]
Segs = list[tuple[float, float, float, float]]
#: The frame of a TUM file of the truth: the robot base or the laser.
TumFrame = Literal["base_link", "laser"]


# --- 2D poses (x, y, yaw) ------------------------------------------------------------------------


# The planar rigid motions of the pose correction itself (yaw wrapped to [-pi, pi)).
relative = between

# --- scenes ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Occupancy:
    """Truth occupancy: ``grid`` bool (H, W), True where a wall passes through the cell; row 0 =
    lowest y (ROS grid order); ``origin`` the x, y of cell (0, 0)'s lower-left corner."""

    grid: NDArray[np.bool_]
    resolution: float
    origin: tuple[float, float]

    def cells(self, points: Floats) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """(row, col) of points (N, 2); may lie outside the grid."""
        col = np.floor((points[:, 0] - self.origin[0]) / self.resolution).astype(np.intp)
        row = np.floor((points[:, 1] - self.origin[1]) / self.resolution).astype(np.intp)
        return row, col


@dataclass(frozen=True)
class Scene:
    """Walls and a route.

    Attributes
    ----------
    name : str
    segments : float64 (S, 4)
        x0, y0, x1, y1 of every wall face, metres (all :data:`WALL_HEIGHT` high).
    route : float64 (N, 3)
        A closed route: waypoints x, y and the radius (m) of the arc that rounds the corner at
        each. The first waypoint lies on a straight (no turn); the robot starts there heading
        to the second.
    laps : float
        Default number of times :func:`simulate` drives the route (> 1: places are revisited).
    """

    name: str
    segments: Floats = field(repr=False)
    route: Floats = field(repr=False)
    laps: float = 1.2
    height: float = WALL_HEIGHT

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """x0, y0, x1, y1 of the walls."""
        xs, ys = self.segments[:, 0::2], self.segments[:, 1::2]
        return float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max())

    @cached_property
    def path(self) -> Path2D:
        return Path2D.from_route(self.route)

    @property
    def lap_length(self) -> float:
        """Metres driven in one lap."""
        return float(self.path.length.sum())

    def distance(self, points: Floats, *, chunk: int = 4096) -> Floats:
        """Distance (N,) from each point (N, 2) to the nearest wall."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        a = self.segments[None, :, :2]
        e = self.segments[None, :, 2:] - a
        ee = np.maximum((e**2).sum(-1), 1e-300)
        out = np.empty(len(pts))
        for i in range(0, len(pts), chunk):  # bounded (chunk, S) temporaries
            w = pts[i : i + chunk, None, :] - a
            u = np.clip((w * e).sum(-1) / ee, 0.0, 1.0)
            out[i : i + chunk] = np.sqrt(((w - u[..., None] * e) ** 2).sum(-1)).min(axis=1)
        return out

    def occupancy(
        self,
        resolution: float,
        *,
        origin: tuple[float, float] | None = None,
        shape: tuple[int, int] | None = None,
        margin: float = 0.5,
    ) -> Occupancy:
        """The walls rasterised: a cell is occupied when a wall passes through it.

        ``origin`` defaults to the walls' lower-left corner less ``margin``, down to a multiple
        of ``resolution``; ``shape`` (H, W) to what reaches ``margin`` past the upper-right one.
        Walls outside the grid are left out.
        """
        x0, y0, x1, y1 = self.bounds
        if origin is None:
            origin = (
                round(math.floor((x0 - margin) / resolution) * resolution, 9),
                round(math.floor((y0 - margin) / resolution) * resolution, 9),
            )
        if shape is None:
            shape = (
                math.ceil((y1 + margin - origin[1]) / resolution),
                math.ceil((x1 + margin - origin[0]) / resolution),
            )
        seg = self.segments
        lengths = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
        n = np.maximum(np.ceil(lengths / (resolution / 8)).astype(np.intp), 1) + 1
        which = np.repeat(np.arange(len(seg)), n)
        first = np.repeat(np.cumsum(n) - n, n)
        frac = (np.arange(n.sum()) - first) / np.repeat(n - 1, n)
        pts = seg[which, :2] + frac[:, None] * (seg[which, 2:] - seg[which, :2])
        occ = Occupancy(np.zeros(shape, dtype=bool), resolution, origin)
        row, col = occ.cells(pts)
        inside = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
        occ.grid[row[inside], col[inside]] = True
        return occ


def _snap(v: float) -> float:
    """Onto the 0.05 m design lattice."""
    return round(round(v / 0.05) * 0.05, 4)


def _box(x0: float, y0: float, x1: float, y1: float) -> Segs:
    return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]


def _polygon(points: Sequence[tuple[float, float]]) -> Segs:
    """Segments of a closed polygon (zero-length edges dropped)."""
    p = np.asarray(points, dtype=np.float64)
    q = np.roll(p, -1, axis=0)
    keep = np.hypot(*(q - p).T) > 1e-9
    return [tuple(map(float, r)) for r in np.hstack([p, q])[keep]]  # type: ignore[misc]


#: A wall feature's outline in the wall's own frame: (along, away from the corridor), from its
#: start on the wall to its end on the wall.
Profile = list[tuple[float, float]]


def niche(width: float, depth: float = 0.3) -> Profile:
    """A door niche: the wall steps back ``depth`` for ``width``."""
    return [(0.0, 0.0), (0.0, depth), (width, depth), (width, 0.0)]


def pilaster(width: float = 0.4, depth: float = 0.2) -> Profile:
    """A pillar against the wall: the wall steps into the corridor."""
    return [(0.0, 0.0), (0.0, -depth), (width, -depth), (width, 0.0)]


def side_room(door: float, left: float, right: float, depth: float, wall: float = 0.1) -> Profile:
    """A room behind a ``wall`` thick wall, reached through a ``door`` wide opening; the room
    reaches ``left`` before the door and ``right`` past it, ``depth`` from the corridor wall."""
    return [
        (0.0, 0.0),
        (0.0, wall),
        (-left, wall),
        (-left, depth),
        (door + right, depth),
        (door + right, wall),
        (door, wall),
        (door, 0.0),
    ]


@dataclass
class _Walls:
    """A closed wall outline built side by side, each side with its features."""

    points: list[tuple[float, float]] = field(default_factory=list)
    boxes: Segs = field(default_factory=list)

    def side(
        self,
        a: tuple[float, float],
        b: tuple[float, float],
        away: Literal["left", "right"],
        features: Sequence[tuple[float, Profile]] = (),
        *,
        name: str = "",
    ) -> Callable[[float, float], tuple[float, float]]:
        """Add the side from ``a`` to ``b`` (b is the next side's start), features at their
        distances along it (metres, increasing, not overlapping, inside the side); return the map
        from (along, away) to scene coordinates."""
        pa, pb = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        length = float(np.hypot(*(pb - pa)))
        u = (pb - pa) / length
        n = np.array([-u[1], u[0]]) if away == "left" else np.array([u[1], -u[0]])

        def at(s: float, o: float) -> tuple[float, float]:
            p = pa + s * u + o * n
            return (round(float(p[0]), 6), round(float(p[1]), 6))

        self.points.append(at(0.0, 0.0))
        end = 0.05
        for s0, profile in features:
            lo = s0 + min(p[0] for p in profile)
            hi = s0 + max(p[0] for p in profile)
            if lo < end or hi > length - 0.05:
                raise ValueError(
                    f"wall {name or (a, b)}: features overlap or leave the wall at this scale "
                    f"(feature at {s0:.2f} m of {length:.2f} m)"
                )
            end = hi + 0.1
            self.points.extend(at(s0 + da, do) for da, do in profile)
        return at


def _scene(
    name: str, segments: Segs, route: Sequence[tuple[float, float, float]], laps: float
) -> Scene:
    seg = np.asarray(segments, dtype=np.float64) + OFFSET
    rt = np.asarray(route, dtype=np.float64)
    rt[:, :2] += OFFSET
    return Scene(name, seg, rt, laps)


def corridor_loop(scale: float = 0.4) -> Scene:
    """A corridor ring, outer ``30 x 20 m`` times ``scale`` (>= 0.3), 2 m wide, driven
    counter-clockwise along its centre line (corners: 1 m arcs)."""
    if scale < 0.3:
        raise ValueError(f"corridor_loop needs scale >= 0.3, got {scale}")
    w, h, c = _snap(30 * scale), _snap(20 * scale), 2.0
    outer, inner = _Walls(), _Walls()
    # Outer wall, counter-clockwise; away from the corridor = outside = right.
    bottom = outer.side(
        (0, 0),
        (w, 0),
        "right",
        [
            (_snap(0.22 * w), niche(1.0)),
            (_snap(0.5 * w), side_room(1.0, 1.0, 1.5, 2.5)),
            (_snap(0.8 * w), niche(1.0)),
        ],
        name="outer bottom",
    )
    outer.side(
        (w, 0), (w, h), "right", [(_snap(0.35 * h), pilaster()), (_snap(0.6 * h), niche(1.2))]
    )
    top = outer.side(
        (w, h),
        (0, h),
        "right",
        [
            (_snap(0.15 * w), niche(1.0)),
            (_snap(0.27 * w), niche(1.0)),
            (_snap(0.65 * w), side_room(1.2, 1.5, 1.0, 3.0)),
        ],
        name="outer top",
    )
    outer.side((0, h), (0, 0), "right")
    # Inner block, counter-clockwise; away from the corridor = into the block = left.
    inner.side((c, c), (w - c, c), "left", [(_snap(0.3 * (w - 2 * c)), pilaster())])
    inner.side((w - c, c), (w - c, h - c), "left", [(_snap(0.45 * (h - 2 * c)), niche(0.8))])
    inner.side(
        (w - c, h - c),
        (c, h - c),
        "left",
        [(_snap(0.2 * (w - 2 * c)), pilaster(0.3)), (_snap(0.6 * (w - 2 * c)), pilaster())],
    )
    inner.side((c, h - c), (c, c), "left")
    s0 = _snap(0.5 * w)
    pillar = [bottom(s0 + 0.5 + dx, dy) for dx, dy in ((-0.15, 1.2), (0.15, 1.5))]
    s1 = _snap(0.65 * w)
    cabinet = [top(s1 + dx, dy) for dx, dy in ((-1.0, 2.4), (0.2, 2.9))]
    boxes = [
        _box(min(p[0] for p in b), min(p[1] for p in b), max(p[0] for p in b), max(p[1] for p in b))
        for b in (pillar, cabinet)
    ]
    segments = _polygon(outer.points) + _polygon(inner.points) + [s for b in boxes for s in b]
    m = c / 2
    route = [(_snap(0.5 * w), m, 0.0), (w - m, m, 1.0), (w - m, h - m, 1.0), (m, h - m, 1.0),
             (m, m, 1.0)]  # fmt: skip
    return _scene("corridor_loop", segments, route, 1.2)


def parallel_corridors(scale: float = 0.4) -> Scene:
    """Two corridors (2 m wide, centre lines 4 m apart, ``30 m`` times ``scale`` long, >= 0.35)
    joined at both ends; the robot drives east along the southern one (A) and back west along
    the northern one (B). Both have the same niches and pilasters at the same x."""
    if scale < 0.35:
        raise ValueError(f"parallel_corridors needs scale >= 0.35, got {scale}")
    length = _snap(30 * scale)
    c = 2.0
    # The same features, by x, on the south and north wall of each corridor.
    south = [(_snap(0.25 * length), 1.0, "niche"), (_snap(0.58 * length), 1.4, "niche")]
    north = [(_snap(0.4 * length), 0.8, "niche"), (_snap(0.72 * length), 0.4, "pilaster")]

    def along(x0: float, features: list[tuple[float, float, str]], reverse: bool) -> Any:
        out = []
        for x, width, kind in features:
            prof = niche(width) if kind == "niche" else pilaster(width)
            out.append(((x0 - x - width) if reverse else (x - x0), prof))
        return sorted(out)

    outer, inner = _Walls(), _Walls()
    outer.side((0, 0), (length, 0), "right", along(0, south, False), name="A south")
    outer.side((length, 0), (length, 6), "right", [(2.6, pilaster(0.6, 0.15))])
    outer.side((length, 6), (0, 6), "right", along(length, north, True), name="B north")
    west = outer.side((0, 6), (0, 0), "right", [(2.4, side_room(1.0, 0.8, 1.2, 2.0))])
    inner.side((c, c), (length - c, c), "left", along(c, north, False), name="A north")
    inner.side((length - c, c), (length - c, 6 - c), "left")
    inner.side((length - c, 6 - c), (c, 6 - c), "left", along(length - c, south, True))
    inner.side((c, 6 - c), (c, c), "left")
    crate = [west(2.4 + dx, dy) for dx, dy in ((-0.5, 1.3), (0.3, 1.7))]
    xs, ys = [p[0] for p in crate], [p[1] for p in crate]
    segments = (
        _polygon(outer.points) + _polygon(inner.points) + _box(min(xs), min(ys), max(xs), max(ys))
    )
    route = [(_snap(0.3 * length), 1.0, 0.0), (length - 1, 1, 1.0), (length - 1, 5, 1.0),
             (1, 5, 1.0), (1, 1, 1.0)]  # fmt: skip
    return _scene("parallel_corridors", segments, route, 1.25)


def _route_points(route: Sequence[tuple[float, float, float]], step: float = 0.05) -> Floats:
    """Points every ``step`` along a closed polyline (x, y, radius rows)."""
    p = np.asarray(route, dtype=np.float64)[:, :2]
    q = np.roll(p, -1, axis=0)
    n = np.maximum(np.ceil(np.hypot(*(q - p).T) / step).astype(np.intp), 1)
    which = np.repeat(np.arange(len(p)), n)
    frac = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
    out: Floats = p[which] + frac[:, None] * (q[which] - p[which])
    return out


def _box_distance(points: Floats, box: tuple[float, float, float, float]) -> float:
    dx = np.maximum(np.maximum(box[0] - points[:, 0], points[:, 0] - box[2]), 0.0)
    dy = np.maximum(np.maximum(box[1] - points[:, 1], points[:, 1] - box[3]), 0.0)
    return float(np.hypot(dx, dy).min())


def rooms(scale: float = 1.0, route: Literal["north", "both"] = "north") -> Scene:
    """A corridor (2 m wide) with ``n = max(2, round(3 * scale))`` rooms of 4 x 4 m on each side.

    Each room has a 1 m door to the corridor; neighbouring rooms on a side are joined by 1 m
    doors, so a side is a suite the robot drives through. The corridor's west end is an open
    door (beams through it have no return). Furniture (a shelf against a wall, a table, two or
    three small boxes) is placed by a fixed seed, clear of every route and door, so each room
    differs. ``route="north"``: east along the corridor, back west through the northern suite;
    ``"both"``: then east along the corridor again and back west through the southern suite.
    """
    n = max(2, round(3 * scale))
    if route not in ("north", "both"):
        raise ValueError(f"rooms route must be 'north' or 'both', got {route!r}")
    length = 4.0 * n
    east, west = length - 1.5, 1.5
    segs: Segs = []
    # Corridor walls with each room's door (the end rooms' doors where the route passes).
    doors = [west] + [4 * i + (1.6 if i % 2 else 2.6) for i in range(1, n - 1)] + [east]
    for y in (1.0, -1.0):
        xs = [0.0, *[v for d in doors for v in (d - 0.5, d + 0.5)], length]
        segs += [(xs[j], y, xs[j + 1], y) for j in range(0, len(xs), 2)]
    # Partitions between rooms, with a door on the suite's centre line; outer walls.
    for i in range(1, n):
        for y0, y1 in ((1.0, 2.5), (3.5, 5.0), (-5.0, -3.5), (-2.5, -1.0)):
            segs.append((4.0 * i, y0, 4.0 * i, y1))
    segs += [(0, 5, length, 5), (0, -5, length, -5), (length, -5, length, 5)]
    segs += [(0, -5, 0, -0.6), (0, 0.6, 0, 5)]  # the corridor's west end: an open door

    start = (_snap(0.5 * (west + east)) - 1.0, 0.0, 0.0)
    north = [(east, 0, 0.5), (east, 3, 0.5), (west, 3, 0.5), (west, 0, 0.5)]
    south = [(east, 0, 0.5), (east, -3, 0.5), (west, -3, 0.5), (west, 0, 0.5)]
    waypoints = [start, *north] + (south if route == "both" else [])
    # Furniture keeps clear of both routes and of every door.
    keep = np.vstack(
        [
            _route_points([start, *north, *south]),
            np.array([(d, y) for d in doors for y in (0.6, 1.4, -0.6, -1.4)]),
            np.array([(4.0 * i + dx, y) for i in range(1, n) for dx in (-0.4, 0.4)
                      for y in (3.0, -3.0)]),
        ]
    )  # fmt: skip
    rng = np.random.default_rng(27)
    placed: list[tuple[float, float, float, float]] = [
        (3.0, 0.7, 3.3, 0.95),  # against the corridor walls: a bin, an extinguisher box
        (_snap(0.6 * length), -0.95, _snap(0.6 * length) + 0.4, -0.75),
    ]
    for side in (1.0, -1.0):
        for i in range(n):
            x0, y_near, y_far = 4.0 * i, side * 1.0, side * 5.0
            lo_y, hi_y = min(y_near, y_far), max(y_near, y_far)
            wanted = ["shelf", "table", "clutter", "clutter"] + (["clutter"] if i % 2 else [])
            for kind in wanted:
                for _ in range(200):  # rejection sampling of a handful of boxes
                    if kind == "shelf":
                        length_s = _snap(rng.uniform(1.0, 2.0))
                        depth = _snap(rng.uniform(0.3, 0.45))
                        bx = _snap(rng.uniform(x0 + 0.05, x0 + 3.95 - length_s))
                        by = (hi_y - 0.05 - depth) if side > 0 else (lo_y + 0.05)
                        box = (bx, by, bx + length_s, by + depth)
                    else:
                        wx, wy = (
                            (rng.uniform(0.8, 1.6), rng.uniform(0.6, 0.9))
                            if kind == "table"
                            else (rng.uniform(0.2, 0.45), rng.uniform(0.2, 0.45))
                        )
                        wx, wy = (
                            (_snap(wx), _snap(wy)) if rng.random() < 0.5 else (_snap(wy), _snap(wx))
                        )
                        bx = _snap(rng.uniform(x0 + 0.15, x0 + 3.85 - wx))
                        by = _snap(rng.uniform(lo_y + 0.15, hi_y - 0.15 - wy))
                        box = (bx, by, bx + wx, by + wy)
                    clear = _box_distance(keep, box) >= 0.75
                    apart = all(
                        box[2] + 0.3 <= o[0] or o[2] + 0.3 <= box[0] or box[3] + 0.3 <= o[1]
                        or o[3] + 0.3 <= box[1] for o in placed
                    )  # fmt: skip
                    if clear and apart:
                        placed.append(box)
                        break
    for box in placed:
        segs += _box(*box)
    return _scene("rooms", segs, waypoints, 1.3 if route == "north" else 1.15)


SCENES: dict[str, Callable[..., Scene]] = {
    "corridor_loop": corridor_loop,
    "rooms": rooms,
    "parallel_corridors": parallel_corridors,
}


def make_scene(name: str, scale: float | None = None, **options: Any) -> Scene:
    """The named scene at ``scale`` (None: its default; see each builder for its options)."""
    if name not in SCENES:
        raise KeyError(f"no scene {name!r}; scenes: {', '.join(sorted(SCENES))}")
    return SCENES[name](**options) if scale is None else SCENES[name](scale, **options)


# --- the route as a path of lines and arcs --------------------------------------------------------


@dataclass(frozen=True)
class Path2D:
    """A closed path of pieces (straights and arcs), one lap: each starts at ``start`` (P, 2)
    heading ``heading`` (P,), runs ``length`` (P,) metres with curvature ``kappa`` (P,)
    (1/m, + = left, 0 = straight)."""

    start: Floats
    heading: Floats
    length: Floats
    kappa: Floats

    @staticmethod
    def from_route(route: Floats) -> Path2D:
        p = np.asarray(route[:, :2], dtype=np.float64)
        radius = np.asarray(route[:, 2], dtype=np.float64)
        d = np.roll(p, -1, axis=0) - p  # side i: from waypoint i to i + 1
        side = np.hypot(d[:, 0], d[:, 1])
        h_out = np.arctan2(d[:, 1], d[:, 0])
        turn = wrap(h_out - np.roll(h_out, 1))  # at waypoint i
        if abs(turn[0]) > 1e-9:
            raise ValueError("a route starts on a straight: its first waypoint must not turn")
        if np.any(np.abs(turn) > np.radians(150)):
            raise ValueError("a route turns more than 150 degrees at a waypoint")
        tangent = radius * np.tan(np.abs(turn) / 2)
        straight = side - tangent - np.roll(tangent, -1)
        if np.any(straight < -1e-9):
            bad = int(np.argmin(straight))
            raise ValueError(f"route side {bad} is too short for the arcs at its ends")
        # Piece 2i: the straight of side i; piece 2i+1: the arc at waypoint i + 1.
        nxt = np.roll(np.arange(len(p)), -1)
        s_start = p + tangent[:, None] * np.column_stack([np.cos(h_out), np.sin(h_out)])
        a_start = p[nxt] - tangent[nxt, None] * np.column_stack([np.cos(h_out), np.sin(h_out)])
        with np.errstate(divide="ignore", invalid="ignore"):
            a_kappa = np.where(np.abs(turn[nxt]) > 1e-12, np.sign(turn[nxt]) / radius[nxt], 0.0)
        start = np.stack([s_start, a_start], axis=1).reshape(-1, 2)
        heading = np.repeat(h_out, 2)
        length = np.stack([np.maximum(straight, 0.0), radius[nxt] * np.abs(turn[nxt])], 1)
        kappa = np.stack([np.zeros(len(p)), a_kappa], axis=1).reshape(-1)
        keep = length.reshape(-1) > 1e-12
        return Path2D(start[keep], heading[keep], length.reshape(-1)[keep], kappa[keep])

    def sample(
        self, times_s: Floats, speed: float, max_turn_rate: float, laps: float
    ) -> tuple[Floats, float]:
        """Poses (M, 3) at ``times_s`` (seconds from the start, increasing, within the drive) and
        the drive's duration (seconds) for ``laps`` laps at ``speed`` (m/s), slower where the turn
        rate would pass ``max_turn_rate`` (rad/s)."""
        reps = math.ceil(laps) + 1
        length = np.tile(self.length, reps)
        kappa = np.tile(self.kappa, reps)
        start = np.tile(self.start, (reps, 1))
        heading = np.tile(self.heading, reps)
        total = laps * float(self.length.sum())
        s_end = np.cumsum(length)
        keep = (s_end - length) < total
        length, kappa, start, heading, s_end = (
            length[keep], kappa[keep], start[keep], heading[keep], s_end[keep]
        )  # fmt: skip
        length[-1] -= s_end[-1] - total
        with np.errstate(divide="ignore"):
            v = np.minimum(speed, max_turn_rate / np.abs(kappa))
        t_end = np.cumsum(length / v)
        t_start = t_end - length / v
        j = np.minimum(np.searchsorted(t_end, times_s, side="right"), len(length) - 1)
        s = np.minimum((times_s - t_start[j]) * v[j], length[j])
        k, h0 = kappa[j], heading[j]
        h = h0 + k * s
        straight = np.abs(k) < 1e-12
        safe = np.where(straight, 1.0, k)
        dx = np.where(straight, s * np.cos(h0), (np.sin(h) - np.sin(h0)) / safe)
        dy = np.where(straight, s * np.sin(h0), (np.cos(h0) - np.cos(h)) / safe)
        poses = np.column_stack([start[j, 0] + dx, start[j, 1] + dy, wrap(h)])
        return poses, float(t_end[-1])


# --- the laser ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Laser:
    """A 2D laser scanner.

    ``beams`` readings over ``fov_deg`` degrees centred on the laser's x axis (360: the last
    reading stops one step short of the first; less: both ends are read). Readings get Gaussian
    ``noise`` (metres, sigma); beams that meet nothing within ``range_max`` (or whose noisy
    reading reaches it) read ``+inf`` (``no_return="inf"``, REP 117) or ``range_max + 1``
    (``"over"``, in the bag only), both "no return" to
    :func:`scan2terrain.readers.laserscan.laserscan_points`.
    """

    beams: int = 360
    fov_deg: float = 360.0
    range_min: float = 0.05
    range_max: float = 25.0
    noise: float = 0.01
    no_return: Literal["inf", "over"] = "inf"

    @property
    def angle_increment(self) -> float:
        fov = math.radians(self.fov_deg)
        return fov / self.beams if self.fov_deg >= 360.0 else fov / (self.beams - 1)

    @property
    def angle_min(self) -> float:
        return -math.radians(self.fov_deg) / 2

    @property
    def angles(self) -> Floats:
        """(B,) beam angles in the laser frame, radians."""
        return self.angle_min + self.angle_increment * np.arange(self.beams, dtype=np.float64)


def cast_scans(
    origins: Floats, yaws: Floats, angles: Floats, segments: Floats, *, chunk: int = 32
) -> Floats:
    """Distance (K, B) along each beam to the first segment it meets (inf if none).

    Beam b of scan k leaves ``origins[k]`` (K, 2) at ``yaws[k] + angles[b]``. The same
    arithmetic as :func:`tests.bagmaker.segment_distances`, but each beam is only tested against
    the segments whose angular extent (seen from the origin, one beam to spare on each side)
    covers it: a building's beams cross a few walls each, not all of them.
    """
    k_all, b_all = len(origins), len(angles)
    inc = float(angles[1] - angles[0]) if b_all > 1 else 2 * np.pi
    a0 = float(angles[0])
    p, q = segments[:, :2], segments[:, 2:]
    out = np.full((k_all, b_all), np.inf)
    for c0 in range(0, k_all, chunk):  # one chunk of scans at a time, vectorised within
        o = origins[c0 : c0 + chunk]
        yaw = yaws[c0 : c0 + chunk]
        cn = len(o)
        rp = p[None] - o[:, None]
        rq = q[None] - o[:, None]
        phi_p = np.arctan2(rp[..., 1], rp[..., 0])
        delta = wrap(np.arctan2(rq[..., 1], rq[..., 0]) - phi_p)
        lo = np.where(delta >= 0, phi_p, phi_p + delta)
        span = np.abs(delta)
        rel = (lo - yaw[:, None] - a0) % (2 * np.pi)  # (C, S), from the first beam
        firsts, counts = [], []
        for shift in (0.0, 2 * np.pi):  # the extent, and its wrap past the first beam
            i0 = np.clip(np.ceil((rel - shift) / inc) - 1, 0, b_all - 1).astype(np.intp)
            i1 = np.clip(np.floor((rel + span - shift) / inc) + 1, -1, b_all - 1).astype(np.intp)
            hit_any = (rel + span - shift) / inc > -1
            firsts.append(i0)
            counts.append(np.where(hit_any, np.maximum(i1 - i0 + 1, 0), 0))
        first = np.concatenate([f.reshape(-1) for f in firsts])
        count = np.concatenate([n.reshape(-1) for n in counts])
        scan = np.tile(np.repeat(np.arange(cn), len(segments)), 2)
        seg = np.tile(np.tile(np.arange(len(segments)), cn), 2)
        total = int(count.sum())
        if total == 0:
            continue
        offset = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
        beam = np.repeat(first, count) + offset
        ks, ss = np.repeat(scan, count), np.repeat(seg, count)
        ang = yaw[ks] + angles[beam]
        d0, d1 = np.cos(ang), np.sin(ang)
        e = q[ss] - p[ss]
        w = p[ss] - o[ks]
        denom = d0 * e[:, 1] - d1 * e[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / denom
            u = (w[:, 0] * d1 - w[:, 1] * d0) / denom
        ok = (np.abs(denom) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
        flat = np.full(cn * b_all, np.inf)
        np.minimum.at(flat, (ks * b_all + beam)[ok], t[ok])
        out[c0 : c0 + cn] = flat.reshape(cn, b_all)
    return out


# --- odometry -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Drift:
    """How the odometry drifts, applied to each step of the truth (in the robot's frame).

    Attributes
    ----------
    scale : float
        Translation scale error (0.02: the odometry says 1.02 m per metre driven).
    yaw_bias_deg_per_m, yaw_bias_deg_per_s : float
        Heading bias added per metre driven and per second (degrees, + = counter-clockwise).
    turn_scale : float
        Rotation scale error (0.01: 1.01 rad per radian turned).
    trans_noise : float
        Random walk of the position, metres per square root of the metres driven (each step's
        x and y get Gaussian noise of sigma ``trans_noise * sqrt(step)``).
    yaw_noise : float
        Random walk of the heading, degrees per square root of the metres driven.
    """

    scale: float = 0.02
    yaw_bias_deg_per_m: float = 0.5
    yaw_bias_deg_per_s: float = 0.0
    turn_scale: float = 0.0
    trans_noise: float = 0.005
    yaw_noise: float = 0.1

    @property
    def none(self) -> bool:
        return not any(
            (self.scale, self.yaw_bias_deg_per_m, self.yaw_bias_deg_per_s, self.turn_scale,
             self.trans_noise, self.yaw_noise)
        )  # fmt: skip


#: No drift: the odometry is the truth.
TRUTH = Drift(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def drift_odometry(truth: Floats, dt: float, drift: Drift, rng: np.random.Generator) -> Floats:
    """Odometry (M, 3) integrated from the steps of ``truth`` (M, 3), ``dt`` seconds apart,
    drifting as ``drift`` says; it starts at the truth's first pose."""
    if drift.none:
        same: Floats = truth.copy()
        return same
    step = relative(truth[:-1], truth[1:])  # (M-1, 3) in the robot's frame
    dist = np.hypot(step[:, 0], step[:, 1])
    noise = rng.standard_normal((len(step), 3))
    xy = step[:, :2] * (1 + drift.scale) + noise[:, :2] * (
        drift.trans_noise * np.sqrt(dist)[:, None]
    )
    dyaw = (
        step[:, 2] * (1 + drift.turn_scale)
        + np.radians(drift.yaw_bias_deg_per_m) * dist
        + np.radians(drift.yaw_bias_deg_per_s) * dt
        + noise[:, 2] * np.radians(drift.yaw_noise) * np.sqrt(dist)
    )
    yaw = truth[0, 2] + np.concatenate([[0.0], np.cumsum(dyaw)])
    c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    moved = np.column_stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]])
    xy_all = truth[0, :2] + np.vstack([np.zeros((1, 2)), np.cumsum(moved, axis=0)])
    return np.column_stack([xy_all, wrap(yaw)])


# --- the recording --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Recording:
    """A simulated recording and its truth.

    Poses are x, y, yaw (metres, radians) of base_link: ``truth`` in the scene frame (the map),
    ``odom`` in the odometry frame, which coincides with the scene frame at the first sample
    (the odometry starts at the truth) unless :func:`simulate` was given ``odom_start``. Arrays
    named ``samples_*`` hold every motion sample (``odom_per_scan`` per scan; odometry and tf are
    written at these); the others hold the scans' samples (every ``odom_per_scan``-th, starting
    with the first).

    Attributes
    ----------
    scene : Scene
    laser : Laser
    drift : Drift
    mount : (x, y, z, yaw)
        base_link -> laser.
    samples_ns : int64 (M,)
        Header stamps of the motion samples.
    samples_truth, samples_odom : float64 (M, 3)
    scan_index : intp (K,)
        The scans' rows in the ``samples_*`` arrays.
    ranges : float32 (K, B)
        The readings as written to the bag.
    seed : int
    """

    scene: Scene
    laser: Laser
    drift: Drift
    mount: tuple[float, float, float, float]
    samples_ns: NDArray[np.int64] = field(repr=False)
    samples_truth: Floats = field(repr=False)
    samples_odom: Floats = field(repr=False)
    scan_index: NDArray[np.intp] = field(repr=False)
    ranges: NDArray[np.float32] = field(repr=False)
    seed: int = 0

    # -- views ----------------------------------------------------------------------------------

    @property
    def stamps_ns(self) -> NDArray[np.int64]:
        """(K,) the scans' header stamps."""
        return self.samples_ns[self.scan_index]

    @property
    def truth(self) -> Floats:
        """(K, 3) base_link in the scene frame at the scans."""
        return self.samples_truth[self.scan_index]

    @property
    def odom(self) -> Floats:
        """(K, 3) base_link in the odometry frame at the scans."""
        return self.samples_odom[self.scan_index]

    @property
    def mount_pose(self) -> Floats:
        return np.array([self.mount[0], self.mount[1], self.mount[3]])

    @property
    def laser_poses(self) -> Floats:
        """(K, 3) the laser in the scene frame (truth)."""
        p = compose(self.truth, self.mount_pose)
        return p

    @property
    def odom_laser_poses(self) -> Floats:
        """(K, 3) the laser in the odometry frame."""
        p = compose(self.odom, self.mount_pose)
        return p

    @property
    def map_to_odom(self) -> Floats:
        """(M, 3) the odometry frame in the scene frame at each sample: map -> odom, such that
        map -> odom -> base_link is the truth."""
        p = compose(self.samples_truth, inverse(self.samples_odom))
        return p

    @property
    def duration(self) -> float:
        """Seconds from the first sample to the last."""
        return float(self.samples_ns[-1] - self.samples_ns[0]) / 1e9

    @property
    def distance(self) -> float:
        """Metres driven (sum of the truth's steps)."""
        d = np.diff(self.samples_truth[:, :2], axis=0)
        return float(np.hypot(d[:, 0], d[:, 1]).sum())

    def odom_error(self) -> tuple[float, float]:
        """End-point error of the odometry: the last scan's pose relative to the first, odometry
        against truth: (translation in metres, yaw in degrees, signed, within [-180, 180))."""
        t = relative(self.truth[0], self.truth[-1])
        o = relative(self.odom[0], self.odom[-1])
        return float(np.hypot(*(o[:2] - t[:2]))), float(np.degrees(wrap(o[2] - t[2])))

    def pose_errors(self, poses: Floats, *, align: bool = True) -> tuple[Floats, Floats]:
        """Errors (K,) of estimated base_link poses (K, 3) at the scans against the truth:
        translation (metres) and yaw (degrees, absolute). ``align``: each trajectory is first
        taken relative to its own first pose (an estimate in a frame of its own)."""
        est, ref = np.asarray(poses, dtype=np.float64), self.truth
        if align:
            est, ref = relative(est[:1], est), relative(ref[:1], ref)
        d = est - ref
        return np.hypot(d[:, 0], d[:, 1]), np.abs(np.degrees(wrap(d[:, 2])))

    def hits(self, laser_poses: Floats | None = None) -> tuple[Floats, NDArray[np.intp]]:
        """The returns as scene points (N, 2), posed by ``laser_poses`` (K, 3; default: the
        truth), and the scan each comes from (N,). From the float32 ranges the bag holds."""
        poses = self.laser_poses if laser_poses is None else laser_poses
        r = self.ranges.astype(np.float64)
        valid = np.isfinite(r) & (r >= self.laser.range_min) & (r < self.laser.range_max)
        k, b = np.nonzero(valid)
        a = poses[k, 2] + self.laser.angles[b]
        pts = np.column_stack(
            [poses[k, 0] + r[k, b] * np.cos(a), poses[k, 1] + r[k, b] * np.sin(a)]
        )
        return pts, k

    # -- writers ----------------------------------------------------------------------------------

    def messages(
        self, *, tf: bool = False, map_frame: bool | str = False, odom: bool = True
    ) -> list[MsgSpec]:
        """The recording's messages (see :meth:`write_bag`)."""
        start = int(self.samples_ns[0])
        mx, my, mz, myaw = self.mount
        out: list[MsgSpec] = [
            (
                "/tf_static",
                TF_MESSAGE,
                start,
                tf_msg([(BASE_FRAME, LASER_FRAME, start, (mx, my, mz), yaw_quaternion(myaw))]),
            )
        ]
        laser = self.laser
        inc, a_min = laser.angle_increment, laser.angle_min
        ranges = self.ranges
        if laser.no_return == "over":
            ranges = np.where(np.isinf(ranges), np.float32(laser.range_max + 1.0), ranges)
        period = (
            float(self.samples_ns[1] - self.samples_ns[0]) / 1e9
            if len(self.samples_ns) > 1
            else 0.1
        )
        scan_time = period * (
            self.scan_index[1] - self.scan_index[0] if len(self.scan_index) > 1 else 1
        )
        for k, row in enumerate(self.scan_index):
            t = int(self.samples_ns[row])
            msg = laserscan_msg(t, LASER_FRAME, a_min, inc, ranges[k], laser.range_min,
                                laser.range_max, scan_time=scan_time)  # fmt: skip
            out.append((SCAN_TOPIC, LASER_SCAN, t + SCAN_LAG_NS, msg))
        poses = self.samples_odom
        if odom:
            # Velocities in base_link: the step to the next sample (the last repeats its own).
            step = relative(poses[:-1], poses[1:]) / max(period, 1e-9)
            step = np.vstack([step, step[-1:]]) if len(step) else np.zeros((1, 3))
            for m, (x, y, yaw) in enumerate(poses):
                t = int(self.samples_ns[m])
                msg = odometry_msg(t, ODOM_FRAME, BASE_FRAME, (x, y, 0.0), yaw_quaternion(yaw),
                                   linear=(step[m, 0], step[m, 1], 0.0),
                                   angular=(0.0, 0.0, step[m, 2]))  # fmt: skip
                out.append((ODOM_TOPIC, ODOMETRY, t + POSE_LAG_NS, msg))
        if tf or map_frame:
            fixed = MAP_FRAME if map_frame is True else str(map_frame)
            m2o = self.map_to_odom
            for m, (x, y, yaw) in enumerate(poses):
                t = int(self.samples_ns[m])
                edges = [(ODOM_FRAME, BASE_FRAME, t, (x, y, 0.0), yaw_quaternion(yaw))]
                if map_frame:
                    a, b, g = m2o[m]
                    edges.append((fixed, ODOM_FRAME, t, (a, b, 0.0), yaw_quaternion(g)))
                out.append(("/tf", TF_MESSAGE, t + POSE_LAG_NS, tf_msg(edges)))
        return out

    def write_bag(
        self,
        path: Path,
        fmt: Fmt = "ros1",
        *,
        tf: bool = False,
        map_frame: bool | str = False,
        odom: bool = True,
    ) -> Path:
        """Write the recording as a bag and return its path.

        Always ``/scan`` (LaserScan, frame ``laser``) and ``/tf_static`` (base_link -> laser,
        the mount); ``/odom`` (Odometry, odom -> base_link, at every motion sample) unless
        ``odom=False``. ``tf=True`` adds ``/tf`` with odom -> base_link (the odometry) at every
        sample; ``map_frame`` (True for ``map``, or a frame name) adds map -> odom to it, such
        that map -> base_link is the truth: a recording a SLAM system ran on. Header stamps are
        the samples'; bag times are 1 ms (poses) or 5 ms (scans) later.
        """
        return write_bag(path, fmt, self.messages(tf=tf, map_frame=map_frame, odom=odom))

    def write_tum(
        self,
        path: Path,
        *,
        poses: Literal["truth", "odom"] = "truth",
        frame: TumFrame = "base_link",
    ) -> Path:
        """The truth (scene frame) or the odometry (odometry frame) at the scans as a TUM file,
        of base_link (z = 0) or of the laser (z = the mount's height)."""
        base = self.truth if poses == "truth" else self.odom
        if frame == "laser":
            p = compose(base, self.mount_pose)
            z = self.mount[2]
        else:
            p, z = base, 0.0
        q = np.array([yaw_quaternion(float(a)) for a in p[:, 2]])
        xyz = np.column_stack([p[:, :2], np.full(len(p), z)])
        path.write_bytes(tum_bytes(self.stamps_ns, xyz, q, comment=f"{poses} {frame}"))
        return path


def simulate(
    scene: str | Scene = "corridor_loop",
    *,
    scale: float | None = None,
    laps: float | None = None,
    speed: float = 0.5,
    max_turn_rate: float = 0.5,
    rate_hz: float = 10.0,
    odom_per_scan: int = 1,
    laser: Laser = Laser(),
    drift: Drift = Drift(),
    mount: tuple[float, float, float, float] = (0.2, 0.0, 0.3, 0.0),
    seed: int = 0,
    start_ns: int = START_NS,
    odom_start: tuple[float, float, float] | None = None,
) -> Recording:
    """Drive ``scene``'s route, scan, and integrate drifting odometry.

    Parameters
    ----------
    scene : str or Scene
        A name in :data:`SCENES` (built at ``scale``) or a scene.
    laps : float, optional
        Times round the route (default: the scene's, > 1 so that the start is revisited).
    speed, max_turn_rate : float
        m/s on straights; turns are driven slower so the turn rate stays under rad/s.
    rate_hz : float
        Scans per second.
    odom_per_scan : int
        Motion samples (odometry and tf) per scan: 2 writes odometry at twice the scan rate.
    laser, drift : Laser, Drift
        The scanner, and the odometry's drift (:data:`TRUTH`: none).
    mount : (x, y, z, yaw)
        base_link -> laser, metres and radians.
    seed : int
        Seeds the range noise and the odometry noise (independent streams).
    start_ns : int
        Header stamp of the first sample.
    odom_start : (x, y, yaw), optional
        The odometry's first pose (default: the truth's, so the odometry frame starts as the
        scene frame; ``(0, 0, 0)``: where a robot's odometry starts when it boots).
    """
    if isinstance(scene, str):
        scene = make_scene(scene, scale)
    laps = scene.laps if laps is None else laps
    if odom_per_scan < 1:
        raise ValueError(f"odom_per_scan must be >= 1, got {odom_per_scan}")
    period_ns = round(1e9 / (rate_hz * odom_per_scan))
    dt = period_ns / 1e9
    _, duration = scene.path.sample(np.zeros(1), speed, max_turn_rate, laps)
    m = math.floor(duration / dt + 1e-9) + 1
    m -= (m - 1) % odom_per_scan  # end on a scan
    times = np.arange(m, dtype=np.float64) * dt
    truth, _ = scene.path.sample(times, speed, max_turn_rate, laps)
    range_rng, odom_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    odom = drift_odometry(truth, dt, drift, odom_rng)
    if odom_start is not None:  # the same odometry seen from another odometry frame
        moved = compose(np.asarray(odom_start, dtype=np.float64), inverse(truth[0]))
        odom = compose(moved[None], odom)
    index = np.arange(0, m, odom_per_scan)
    mnt = np.array([mount[0], mount[1], mount[3]])
    sensor = compose(truth[index], mnt)
    dist = cast_scans(sensor[:, :2], sensor[:, 2], laser.angles, scene.segments)
    noisy = (dist + laser.noise * range_rng.standard_normal(dist.shape)).astype(np.float32)
    # A reading the noise pushes to range_max or past it is no return, as the reader takes it.
    ranges = np.where(noisy < np.float32(laser.range_max), noisy, np.float32(np.inf))
    return Recording(
        scene=scene,
        laser=laser,
        drift=drift,
        mount=tuple(map(float, mount)),  # type: ignore[arg-type]
        samples_ns=start_ns + np.arange(m, dtype=np.int64) * period_ns,
        samples_truth=truth,
        samples_odom=odom,
        scan_index=index,
        ranges=ranges,
        seed=seed,
    )


# --- what the tests and benchmarks/bench_slam.py measure -------------------------------------


def flat_scans(rec: Recording) -> list[NDArray[np.float64]]:
    """Each scan's returns (N, 2) in the laser's frame."""
    a = rec.laser.angles
    out = []
    for r in rec.ranges.astype(np.float64):
        ok = np.isfinite(r) & (r >= rec.laser.range_min) & (r < rec.laser.range_max)
        out.append(np.c_[r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])])
    return out


def aligned_errors(
    poses: NDArray[np.float64], truth: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Translation (m) and yaw (deg) errors after the best rigid alignment of the whole
    trajectory onto the truth (a SLAM estimate has no absolute frame: the usual ATE)."""
    a, b = poses[:, :2], truth[:, :2]
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ma).T @ (b - mb))
    r = (u @ vt).T
    if np.linalg.det(r) < 0:
        vt[-1] *= -1
        r = (u @ vt).T
    moved = (a - ma) @ r.T + mb
    turn = math.atan2(r[1, 0], r[0, 0])
    yaw = np.degrees(np.abs(wrap(poses[:, 2] + turn - truth[:, 2])))
    return np.hypot(*(moved - b).T), yaw
