"""Rigid motions of the plane, as (x, y, yaw) rows: composition, inverse, relative poses.

Every function takes and returns float64 arrays of shape (..., 3), so one call handles one pose
or a whole trajectory. Yaw is radians counter-clockwise, wrapped to [-pi, pi).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Poses = NDArray[np.float64]


def wrap(angle: ArrayLike) -> NDArray[np.float64]:
    """Angles wrapped to [-pi, pi)."""
    a = np.asarray(angle, dtype=np.float64)
    return (a + np.pi) % (2 * np.pi) - np.pi


def compose(a: ArrayLike, b: ArrayLike) -> Poses:
    """a * b: pose ``b`` given in frame ``a``, expressed in ``a``'s parent frame."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, wrap(a[..., 2] + b[..., 2])], axis=-1)


def inverse(a: ArrayLike) -> Poses:
    a = np.asarray(a, np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -(c * a[..., 0] + s * a[..., 1])
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, wrap(-a[..., 2])], axis=-1)


def between(a: ArrayLike, b: ArrayLike) -> Poses:
    """a^-1 * b: pose ``b`` seen from pose ``a``."""
    return compose(inverse(a), b)


def apply(pose: ArrayLike, points: NDArray[np.floating]) -> NDArray[np.float64]:
    """Points (N, 2) of the frame ``pose`` (one pose) in its parent frame."""
    p = np.asarray(pose, np.float64)
    c, s = np.cos(p[2]), np.sin(p[2])
    r = np.array([[c, -s], [s, c]])
    out: NDArray[np.float64] = np.asarray(points, np.float64)[:, :2] @ r.T + p[:2]
    return out


def matrix(pose: ArrayLike) -> NDArray[np.float64]:
    """One pose as a 4 x 4 homogeneous matrix (a rotation about z)."""
    x, y, yaw = (float(v) for v in np.asarray(pose, np.float64))
    c, s = np.cos(yaw), np.sin(yaw)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:2, 3] = (x, y)
    return m


def from_matrix(m: NDArray[np.float64]) -> Poses:
    """The planar part of a 4 x 4 (or 3 x 3 rotation + translation) rigid motion: x, y and the
    yaw of its x axis."""
    return np.array([m[0, 3], m[1, 3], np.arctan2(m[1, 0], m[0, 0])])


def path_lengths(poses: ArrayLike) -> NDArray[np.float64]:
    """Distance travelled from the first pose to each pose, metres."""
    p = np.asarray(poses, np.float64)
    steps = np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1]))
    return np.concatenate([[0.0], np.cumsum(steps)])
