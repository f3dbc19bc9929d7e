"""Poses for every scan without ROS installed: the conventions and maths the pose sources share.

A scan is placed in the fixed frame by the pose of its sensor frame at the scan's stamp. That pose
comes from one of:

* the tf tree recorded in the bag (``/tf`` and ``/tf_static``):
  :class:`~scan2terrain.readers.tf.TfBuffer`, a small re-implementation of tf2's ``BufferCore``
  lookups;
* an odometry topic (``nav_msgs/Odometry``): :func:`~scan2terrain.readers.tracks.odometry_track`;
* a TUM trajectory file (``t x y z qx qy qz qw``): :func:`~scan2terrain.readers.tracks.read_tum`;
* a fixed pose for a sensor that did not move: :func:`fixed_pose`, plus :func:`mount` for the
  sensor's mount on the robot.

This module holds what they share: the conventions below, :data:`DEFAULT_MAX_GAP_NS`, the
quaternion maths (rotation matrices, sign continuity, slerp, composition) and the fixed poses
(:func:`rpy_matrix`, :func:`fixed_pose`, :func:`mount`). How poses are interpolated (and not
extrapolated) is described in :mod:`scan2terrain.readers.tracks`; the rules of the tf tree in
:mod:`scan2terrain.readers.tf`.

Conventions, as tf2's:

* Times are int64 nanoseconds (``sec * 1e9 + nanosec`` of the message stamps); lengths are
  metres; quaternions are ``(x, y, z, w)``.
* An edge ``parent -> child`` holds the pose of ``child`` in ``parent``:
  ``p_parent = T.apply(p_child)``. ``lookup(target, source, t)`` returns the pose of ``source``
  in ``target``, so ``p_target = T.apply(p_source)``.
* Frame names are normalised by :func:`~scan2terrain.types.normalise_frame` (ROS 1 tf names often
  carry a leading ``/`` that ``header.frame_id`` does not).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from scan2terrain.types import Transform

__all__ = [
    "DEFAULT_MAX_GAP_NS",
    "fixed_pose",
    "mount",
    "rpy_matrix",
]

#: Default longest gap between two tf (or odometry) samples that is interpolated: 1 s.
DEFAULT_MAX_GAP_NS = 1_000_000_000
NS_PER_S = 1_000_000_000

Floats = NDArray[np.float64]
Ints = NDArray[np.int64]
Bools = NDArray[np.bool_]
Lookup = tuple[Bools, Floats, Floats]


# --------------------------------------------------------------------------- quaternion helpers


def quaternions_to_matrices(q: Floats) -> Floats:
    """Unit quaternions (..., 4) xyzw -> rotation matrices (..., 3, 3), as Transform's formula."""
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty((*q.shape[:-1], 3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - z * w)
    r[..., 0, 2] = 2 * (x * z + y * w)
    r[..., 1, 0] = 2 * (x * y + z * w)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - x * w)
    r[..., 2, 0] = 2 * (x * z - y * w)
    r[..., 2, 1] = 2 * (y * z + x * w)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def matrices_to_quaternions(r: Floats) -> Floats:
    """Rotation matrices (K, 3, 3) -> unit quaternions (K, 4) xyzw with w >= 0 (Shepperd: each
    from its largest component, so none is taken from a difference of nearly equal terms)."""
    m = np.asarray(r, dtype=np.float64)
    m00, m11, m22 = m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]
    # 4 w^2, 4 x^2, 4 y^2, 4 z^2
    four = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22,
                     1 - m00 - m11 + m22], axis=1)  # fmt: skip
    k = np.argmax(four, axis=1)
    s = 2.0 * np.sqrt(np.maximum(four[np.arange(len(k)), k], 0.0))  # 4 |largest component|
    wx, wy, wz = m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]
    xy, xz, yz = m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1]
    # Rows: the largest component k; columns: w, x, y, z times s.
    table = np.stack(
        [
            np.stack([s * s / 4, wx, wy, wz], axis=1),
            np.stack([wx, s * s / 4, xy, xz], axis=1),
            np.stack([wy, xy, s * s / 4, yz], axis=1),
            np.stack([wz, xz, yz, s * s / 4], axis=1),
        ],
        axis=1,
    )
    wxyz = table[np.arange(len(k)), k] / s[:, None]
    q = wxyz[:, [1, 2, 3, 0]]
    q = np.where(q[:, 3:4] < 0, -q, q)
    return q / np.linalg.norm(q, axis=1, keepdims=True)  # type: ignore[no-any-return]


def sign_continuous(q: Floats) -> Floats:
    """Flip signs so that consecutive quaternions (M, 4) have a non-negative dot product."""
    if len(q) < 2:
        return q
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    # The sign of sample i relative to the original is the product of the flips before it.
    signs = np.cumprod(np.where(dots < 0, -1.0, 1.0))
    out: Floats = q.copy()
    out[1:] *= signs[:, None]
    return out


def _slerp(q0: Floats, q1: Floats, u: Floats) -> Floats:
    """Spherical interpolation of unit quaternions (K, 4) at fractions ``u`` (K,), the short way."""
    dots = np.einsum("ij,ij->i", q0, q1)
    q1 = np.where(dots[:, None] < 0, -q1, q1)
    # Half the rotation angle between them, accurate for tiny and large angles alike (arccos of
    # the dot product loses half the digits near 0).
    theta = 2.0 * np.arctan2(np.linalg.norm(q1 - q0, axis=1), np.linalg.norm(q1 + q0, axis=1))
    s = np.sin(theta)
    small = s < 1e-12
    safe = np.where(small, 1.0, s)
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / safe)
    w1 = np.where(small, u, np.sin(u * theta) / safe)
    q = w0[:, None] * q0 + w1[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)  # type: ignore[no-any-return]


def _compose(r_a: Floats, p_a: Floats, r_b: Floats, p_b: Floats) -> tuple[Floats, Floats]:
    """``a * b`` for stacks (or single) rotations (..., 3, 3) and translations (..., 3)."""
    return r_a @ r_b, np.einsum("...ij,...j->...i", r_a, p_b) + p_a


def check_max_gap(max_gap_ns: int | None) -> int | None:
    if max_gap_ns is None:
        return None
    if isinstance(max_gap_ns, bool) or not isinstance(max_gap_ns, (int, np.integer)):
        raise ValueError(
            f"max_gap_ns must be an integer number of nanoseconds or None, got {max_gap_ns!r}"
        )
    if max_gap_ns < 0:
        raise ValueError(f"max_gap_ns must be >= 0, got {max_gap_ns}")
    return int(max_gap_ns)


# ----------------------------------------------------------------------------- fixed poses


def rpy_matrix(roll: float, pitch: float, yaw: float) -> Floats:
    """Rotation (3, 3) from roll, pitch, yaw (radians) as ROS/tf: ``Rz(yaw) Ry(pitch) Rx(roll)``.

    That is, fixed axes x, y, z in that order (tf2's ``Quaternion::setRPY``, URDF ``rpy``).
    """
    for name, value in (("roll", roll), ("pitch", pitch), ("yaw", yaw)):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value}")
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _pose(x: float, y: float, z: float, *, roll: float, pitch: float, yaw: float) -> Transform:
    for name, value in (("x", x), ("y", y), ("z", z)):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value}")
    return Transform(rpy_matrix(roll, pitch, yaw), np.array([x, y, z], dtype=np.float64))


def fixed_pose(
    x: float, y: float, z: float, *, roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0
) -> Transform:
    """The pose of a sensor that did not move, in the fixed frame.

    Metres and radians; the rotation is ``Rz(yaw) Ry(pitch) Rx(roll)`` (:func:`rpy_matrix`).
    Use it for every scan in place of a lookup: ``p_fixed = T.apply(p_sensor)``.
    """
    return _pose(x, y, z, roll=roll, pitch=pitch, yaw=yaw)


def mount(
    x: float, y: float, z: float, *, roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0
) -> Transform:
    """The pose of a sensor on its robot: sensor frame in the base frame (metres, radians).

    As ``static_transform_publisher x y z yaw pitch roll`` (note tf's argument order there) or a
    URDF joint's ``xyz``/``rpy``; compose it after the base pose:
    ``base_in_fixed.compose(mount(...))`` is the sensor in the fixed frame.
    """
    return _pose(x, y, z, roll=roll, pitch=pitch, yaw=yaw)


def pose6(values: Sequence[float]) -> Transform:
    """A config pose [x, y, z, roll, pitch, yaw] (metres, radians; ``scans.pose``/``mount``)."""
    x, y, z, roll, pitch, yaw = values
    return mount(x, y, z, roll=roll, pitch=pitch, yaw=yaw)
