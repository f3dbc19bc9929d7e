"""A box room with a pillar, sampled by a simulated 3D lidar along a path: the octree tests'
scene (tests/octree/test_tree.py, test_sparse.py)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

#: (end points (N, 3), sensor origin (3,)), metres.
Scan = tuple[NDArray[np.float64], NDArray[np.float64]]

ROOM_LO, ROOM_HI = np.array([0.0, 0.0, 0.0]), np.array([8.0, 6.0, 3.0])
PILLAR_LO, PILLAR_HI = np.array([3.6, 2.6, 0.0]), np.array([4.2, 3.2, 3.0])


def lidar_scan(
    origin: NDArray[np.float64], yaw: float, rng: np.random.Generator, n_az: int = 200
) -> NDArray[np.float64]:
    """End points of a 16-beam lidar (elevations -30..30 degrees, ``n_az`` azimuths) inside the
    room: the first wall, floor, ceiling or pillar face each ray meets, with 1 cm range noise."""
    az = np.linspace(0.0, 2 * np.pi, n_az, endpoint=False) + yaw
    el = np.radians(np.linspace(-30.0, 30.0, 16))
    a, e = np.meshgrid(az, el)
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_wall = np.where(
            d > 0, (ROOM_HI - origin) / d, np.where(d < 0, (ROOM_LO - origin) / d, np.inf)
        ).min(axis=1)
        t1, t2 = (PILLAR_LO - origin) / d, (PILLAR_HI - origin) / d
        t_in = np.nanmax(np.minimum(t1, t2), axis=1)
        t_out = np.nanmin(np.maximum(t1, t2), axis=1)
    pillar = (t_in <= t_out) & (t_in > 0)
    t: NDArray[np.float64] = np.where(pillar, np.minimum(t_wall, t_in), t_wall)
    t = t + rng.normal(0.0, 0.01, len(d))
    return origin + d * t[:, None]


def room_scans() -> list[Scan]:
    """Ten scans along a path around the pillar; the robot waits for three scans at the start
    (so end points repeat and clamping is reached)."""
    rng = np.random.default_rng(7)
    path = [(1.0, 1.0), (1.0, 1.0), (1.0, 1.0), (2.0, 1.2), (3.0, 1.4)]
    path += [(4.5, 1.5), (6.0, 1.6), (6.5, 2.8), (6.4, 4.0), (5.0, 4.6)]
    scans = []
    for i, (x, y) in enumerate(path):
        origin = np.array([x, y, 1.2 + 0.05 * math.sin(i)])
        scans.append((lidar_scan(origin, 0.0 if i < 3 else 0.1 * i, rng), origin))
    return scans
