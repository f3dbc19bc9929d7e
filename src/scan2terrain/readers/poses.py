"""Poses for every scan without ROS installed: tf trees, odometry and TUM trajectories.

A scan is placed in the fixed frame by the pose of its sensor frame at the scan's stamp. That pose
comes from one of:

* the tf tree recorded in the bag (``/tf`` and ``/tf_static``): :class:`TfBuffer`, a small
  re-implementation of tf2's ``BufferCore`` lookups;
* an odometry topic (``nav_msgs/Odometry``): :func:`odometry_track`;
* a TUM trajectory file (``t x y z qx qy qz qw``): :func:`read_tum`;
* a fixed pose for a sensor that did not move: :func:`fixed_pose`, plus :func:`mount` for the
  sensor's mount on the robot.

Conventions, as tf2's:

* Times are int64 nanoseconds (``sec * 1e9 + nanosec`` of the message stamps); lengths are
  metres; quaternions are ``(x, y, z, w)``.
* An edge ``parent -> child`` holds the pose of ``child`` in ``parent``:
  ``p_parent = T.apply(p_child)``. ``lookup(target, source, t)`` returns the pose of ``source``
  in ``target``, so ``p_target = T.apply(p_source)``.
* Frame names are normalised by :func:`normalise_frame` (ROS 1 tf names often carry a leading
  ``/`` that ``header.frame_id`` does not).

Choices:

* **Interpolation**: translation linearly, rotation by slerp between the two samples around ``t``,
  exactly as tf2 does; a sample's own time gives the sample itself, bit for bit. Quaternions are
  normalised and made sign-continuous when a track is built, and slerp takes the short way, so a
  publisher that flips the sign of ``q`` (the same rotation) does not make the interpolated pose
  swing through a full turn.
* **No extrapolation**: like tf2, a time before the first or after the last sample of any edge on
  the path has no pose. Extrapolating a moving robot's pose for even 0.1 s misplaces a 20 m range
  point by decimetres when it turns; the scan is better dropped and counted.
* **Maximum gap**: inside a gap between two samples longer than ``max_gap_ns`` there is no pose
  either (except at the samples themselves). tf2 has no such limit, but a bag in which tf stopped
  for seconds (a dropped recording, a restarted localiser) would otherwise interpolate a straight
  line through wherever the robot really went. :class:`TfBuffer` defaults to 1 s: tf publishers
  run at 10-200 Hz (odometry 20-50 Hz, AMCL, slam_toolbox and Cartographer republish map -> odom
  at >= 10 Hz even when standing still), so 1 s is ten missed messages of the slowest of them and
  never a normal rate. A :class:`PoseTrack` and :func:`read_tum` default to no limit: a trajectory
  file is a deliberate input, and SLAM key-frame trajectories are sparse by design.
  :func:`odometry_track` uses the tf default, since odometry is streamed like tf.
* **One parent per frame**: tf2 lets a frame change parent over time; bags that do so are almost
  always misconfigured (two nodes publishing the same child), so the first parent seen is kept
  and every later sample naming another parent (or the other of static / dynamic) is counted in
  :meth:`TfBuffer.conflicts`. An edge that would close a loop is refused the same way.
* **Static edges** hold only their latest transform and are valid at every time, as in tf2.
* Interpolation is vectorised over query times (:meth:`PoseTrack.at_many`,
  :meth:`TfBuffer.lookup_many`); messages are only appended to per-edge lists while a bag is read,
  and the arrays of a track are built once, on the first lookup after new samples arrived.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scan2terrain.errors import InputError
from scan2terrain.readers._files import regular_file
from scan2terrain.types import Transform, normalise_frame

__all__ = [
    "DEFAULT_MAX_GAP_NS",
    "OdometryArrays",
    "ParentConflict",
    "PoseTrack",
    "TfBuffer",
    "TfEdge",
    "fixed_pose",
    "mount",
    "odometry_track",
    "read_tum",
    "rpy_matrix",
]

#: Default longest gap between two tf (or odometry) samples that is interpolated: 1 s.
DEFAULT_MAX_GAP_NS = 1_000_000_000
NS_PER_S = 1_000_000_000

Floats = NDArray[np.float64]
Ints = NDArray[np.int64]
Bools = NDArray[np.bool_]
Lookup = tuple[Bools, Floats, Floats]

# Seconds a TUM time may hold and still fit int64 nanoseconds (+-292 years around 1970).
_MAX_ABS_SECONDS = 9.2e9
_TUM_COLUMNS = "t x y z qx qy qz qw"
#: The largest TUM file read (it is read whole): 4 million poses of 64 bytes, 11 hours at 100 Hz.
MAX_TUM_BYTES = 1 << 28


def _fmt_time(t_ns: int) -> str:
    return f"{t_ns / NS_PER_S:.3f} s"


def _fmt_span(dt_ns: int) -> str:
    return f"{dt_ns / NS_PER_S:.3f} s"


# --------------------------------------------------------------------------- quaternion helpers


def _quaternions_to_matrices(q: Floats) -> Floats:
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


def _sign_continuous(q: Floats) -> Floats:
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


def _check_max_gap(max_gap_ns: int | None) -> int | None:
    if max_gap_ns is None:
        return None
    if isinstance(max_gap_ns, bool) or not isinstance(max_gap_ns, (int, np.integer)):
        raise ValueError(
            f"max_gap_ns must be an integer number of nanoseconds or None, got {max_gap_ns!r}"
        )
    if max_gap_ns < 0:
        raise ValueError(f"max_gap_ns must be >= 0, got {max_gap_ns}")
    return int(max_gap_ns)


# --------------------------------------------------------------------------------- PoseTrack


class PoseTrack:
    """A time-ordered series of poses of one frame (``child_frame_id``) in another (``frame_id``).

    Parameters
    ----------
    times_ns : integer array-like, shape (M,), M >= 1
        Sample times in nanoseconds, in any order. Of samples with equal times the last one given
        is kept.
    translations : array-like, shape (M, 3)
        Position of the child frame's origin in the parent frame, metres.
    quaternions_xyzw : array-like, shape (M, 4)
        Orientation of the child frame in the parent frame, ``(x, y, z, w)``, any non-zero norm.
    max_gap_ns : int or None
        Longest gap between two samples that is interpolated, nanoseconds; ``None``: no limit.
    frame_id, child_frame_id : str
        Names of the parent and child frames, normalised; may be empty when unknown.

    Attributes
    ----------
    times_ns : int64 array, shape (M,)
        Strictly increasing.
    translations : float64 array, shape (M, 3)
    quaternions_xyzw : float64 array, shape (M, 4)
        Unit norm, sign-continuous (consecutive dot products >= 0).

    Raises
    ------
    ValueError
        Naming the parameter, for wrong shapes, non-integer times, non-finite values or a zero
        quaternion.
    """

    __slots__ = (
        "child_frame_id",
        "frame_id",
        "max_gap_ns",
        "quaternions_xyzw",
        "times_ns",
        "translations",
    )

    times_ns: Ints
    translations: Floats
    quaternions_xyzw: Floats
    max_gap_ns: int | None
    frame_id: str
    child_frame_id: str

    def __init__(
        self,
        times_ns: ArrayLike,
        translations: ArrayLike,
        quaternions_xyzw: ArrayLike,
        *,
        max_gap_ns: int | None = None,
        frame_id: str = "",
        child_frame_id: str = "",
    ) -> None:
        t = np.asarray(times_ns)
        if t.ndim != 1 or t.size == 0:
            raise ValueError(f"times_ns must be a non-empty 1D array, got shape {t.shape}")
        if not np.issubdtype(t.dtype, np.integer):
            raise ValueError(f"times_ns must hold integer nanoseconds, got {t.dtype}")
        m = t.size
        p = np.asarray(translations, dtype=np.float64)
        q = np.asarray(quaternions_xyzw, dtype=np.float64)
        if p.shape != (m, 3):
            raise ValueError(f"translations must have shape ({m}, 3), got {p.shape}")
        if q.shape != (m, 4):
            raise ValueError(f"quaternions_xyzw must have shape ({m}, 4), got {q.shape}")
        if not np.isfinite(p).all():
            raise ValueError("translations must be finite")
        norms = np.linalg.norm(q, axis=1)
        if not (np.isfinite(norms).all() and (norms > 0).all()):
            raise ValueError("quaternions_xyzw must be finite and non-zero")
        order = np.argsort(t, kind="stable")
        t = t[order].astype(np.int64)
        # A stable sort keeps equal times in input order: the last of each run is the newest.
        keep = np.append(t[1:] != t[:-1], True)
        order = order[keep]
        q = q[order] / norms[order, None]
        self.times_ns = t[keep]
        self.translations = p[order]
        self.quaternions_xyzw = _sign_continuous(q)
        for a in (self.times_ns, self.translations, self.quaternions_xyzw):
            a.setflags(write=False)
        self.max_gap_ns = _check_max_gap(max_gap_ns)
        self.frame_id = normalise_frame(frame_id)
        self.child_frame_id = normalise_frame(child_frame_id)

    def __len__(self) -> int:
        return int(self.times_ns.size)

    def __repr__(self) -> str:
        names = f"{self.frame_id or '?'} -> {self.child_frame_id or '?'}"
        return (
            f"PoseTrack({names}, {len(self)} samples, {_fmt_time(self.start_ns)} .. "
            f"{_fmt_time(self.end_ns)}, max_gap_ns={self.max_gap_ns})"
        )

    @property
    def start_ns(self) -> int:
        """Time of the first sample, nanoseconds."""
        return int(self.times_ns[0])

    @property
    def end_ns(self) -> int:
        """Time of the last sample, nanoseconds."""
        return int(self.times_ns[-1])

    def _interpolate(self, times_ns: ArrayLike) -> tuple[Bools, Floats, Floats]:
        """Valid mask (K,), unit quaternions (K, 4) and translations (K, 3) at the given times.

        Entries that are not valid hold unspecified (finite) values.
        """
        t = np.asarray(times_ns, dtype=np.int64).reshape(-1)
        ts = self.times_ns
        m = ts.size
        i0 = np.searchsorted(ts, t, side="right") - 1  # last sample at or before t
        inside = (i0 >= 0) & (t <= ts[-1])
        i0 = np.clip(i0, 0, m - 1)
        i1 = np.minimum(i0 + 1, m - 1)
        t0 = ts[i0]
        dt = ts[i1] - t0
        exact = t == t0
        u = np.zeros(t.shape, dtype=np.float64)
        np.divide(
            (t - t0).astype(np.float64), dt.astype(np.float64), out=u, where=inside & (dt > 0)
        )
        valid = inside if self.max_gap_ns is None else inside & (exact | (dt <= self.max_gap_ns))
        p0 = self.translations[i0]
        p = p0 + u[:, None] * (self.translations[i1] - p0)
        q0 = self.quaternions_xyzw[i0]
        q = np.where(exact[:, None], q0, _slerp(q0, self.quaternions_xyzw[i1], u))
        return valid, q, p

    def at_many(self, times_ns: ArrayLike) -> Lookup:
        """Poses at many times at once.

        Parameters
        ----------
        times_ns : integer array-like, shape (K,)
            Query times, nanoseconds, in any order.

        Returns
        -------
        valid : bool array, shape (K,)
            False outside ``[start_ns, end_ns]`` and inside gaps longer than ``max_gap_ns``.
        rotations : float64 array, shape (K, 3, 3)
            Orientation of the child frame in the parent frame; NaN where not valid.
        translations : float64 array, shape (K, 3)
            Position of the child frame in the parent frame, metres; NaN where not valid.
        """
        valid, q, p = self._interpolate(times_ns)
        r = _quaternions_to_matrices(q)
        r[~valid] = np.nan
        p[~valid] = np.nan
        return valid, r, p

    def at(self, t_ns: int) -> Transform | None:
        """Pose of the child frame in the parent frame at ``t_ns`` (nanoseconds), or None.

        Exact at the samples; linear (translation) and slerp (rotation) interpolation between
        them; None outside ``[start_ns, end_ns]`` or inside a gap longer than ``max_gap_ns``.
        """
        valid, r, p = self.at_many([t_ns])
        return Transform(r[0], p[0]) if valid[0] else None

    def why_not(self, t_ns: int) -> str:
        """Why :meth:`at` gives no pose at ``t_ns``, as one human sentence; ``""`` if it does."""
        ts = self.times_ns
        if t_ns < ts[0]:
            return (
                f"no data before {_fmt_time(self.start_ns)} (asked for {_fmt_time(t_ns)}, "
                f"{_fmt_span(self.start_ns - t_ns)} earlier; no extrapolation)"
            )
        if t_ns > ts[-1]:
            return (
                f"no data after {_fmt_time(self.end_ns)} (asked for {_fmt_time(t_ns)}, "
                f"{_fmt_span(t_ns - self.end_ns)} later; no extrapolation)"
            )
        i0 = int(np.searchsorted(ts, t_ns, side="right")) - 1
        if ts[i0] == t_ns or self.max_gap_ns is None:
            return ""
        a, b = int(ts[i0]), int(ts[i0 + 1])
        if b - a <= self.max_gap_ns:
            return ""
        return (
            f"a gap of {_fmt_span(b - a)} between samples at {_fmt_time(a)} and {_fmt_time(b)} "
            f"around {_fmt_time(t_ns)} (longest interpolated: {_fmt_span(self.max_gap_ns)})"
        )


# ---------------------------------------------------------------------------------- TfBuffer


@dataclass(frozen=True)
class TfEdge:
    """One edge of the tf tree, for ``inspect``: ``parent -> child``, times in nanoseconds."""

    parent: str
    child: str
    static: bool
    samples: int  #: distinct sample times (static: messages received)
    first_ns: int
    last_ns: int


@dataclass(frozen=True)
class ParentConflict:
    """Samples refused because they disagree with the tree already built.

    ``kept_parent`` is the parent the child frame keeps (None if it is a root); ``static`` says
    whether the refused samples came from ``/tf_static``.
    """

    child: str
    parent: str
    static: bool
    kept_parent: str | None
    samples: int
    reason: str


class _Edge:
    """Samples of one ``parent -> child`` edge, appended as they arrive, built on demand."""

    __slots__ = (
        "chunks",
        "parent",
        "static",
        "static_first",
        "static_last",
        "static_n",
        "static_tf",
        "times",
        "track",
        "values",
    )

    def __init__(self, parent: str, static: bool) -> None:
        self.parent = parent
        self.static = static
        self.times: list[int] = []
        self.values: list[tuple[float, ...]] = []  # (x, y, z, qx, qy, qz, qw)
        self.chunks: list[tuple[Ints, Floats]] = []  # (times (n,), values (n, 7)) from add_many
        self.track: PoseTrack | None = None
        self.static_tf: Transform | None = None
        self.static_n = 0
        self.static_first = 0
        self.static_last = 0

    def pending(self) -> bool:
        return bool(self.times) or bool(self.chunks)

    def flush(self) -> None:
        """Move the listed samples into a chunk, so chunks stay in arrival order."""
        if self.times:
            values = np.asarray(self.values, dtype=np.float64).reshape(-1, 7)
            self.chunks.append((np.asarray(self.times, dtype=np.int64), values))
            self.times, self.values = [], []

    def get_track(self, max_gap_ns: int | None, frame_id: str, child: str) -> PoseTrack:
        if self.track is not None and not self.pending():
            return self.track
        self.flush()
        parts_t = [c[0] for c in self.chunks]
        parts_v = [c[1] for c in self.chunks]
        if self.track is not None:  # rebuild from what was built plus what came since
            tr = self.track
            parts_t.insert(0, tr.times_ns)
            parts_v.insert(0, np.hstack([tr.translations, tr.quaternions_xyzw]))
        values = np.concatenate(parts_v)
        self.track = PoseTrack(
            np.concatenate(parts_t),
            values[:, :3],
            values[:, 3:],
            max_gap_ns=max_gap_ns,
            frame_id=frame_id,
            child_frame_id=child,
        )
        self.chunks = []
        return self.track


class TfBuffer:
    """The tf tree of a recording: ``/tf`` and ``/tf_static`` samples, looked up as tf2 does.

    Parameters
    ----------
    max_gap_ns : int or None
        Longest gap between two samples of a dynamic edge that is interpolated, nanoseconds
        (default 1 s, see the module notes); ``None``: no limit.

    Notes
    -----
    Every frame has at most one parent, the first one seen; later samples naming another parent,
    or arriving on ``/tf`` for a static edge (or the reverse), or that would close a loop, are
    refused and counted (:meth:`conflicts`). Samples with an empty frame name, a child equal to
    its parent, non-finite numbers or a zero quaternion are refused and counted in
    :attr:`rejected`.
    """

    def __init__(self, max_gap_ns: int | None = DEFAULT_MAX_GAP_NS) -> None:
        self.max_gap_ns = _check_max_gap(max_gap_ns)
        self._edges: dict[str, _Edge] = {}  # child -> edge from its parent
        # (child, refused parent, static) -> samples refused, and why
        self._conflicts: dict[tuple[str, str, bool], int] = {}
        self._conflict_reasons: dict[tuple[str, str, bool], str] = {}
        #: Refused samples by reason (empty frame name, child equals parent, bad numbers).
        self.rejected: dict[str, int] = {}

    # ---------------------------------------------------------------------------- ingestion

    def _reject(self, reason: str, n: int = 1) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + n

    def _edge_for(self, parent: str, child: str, static: bool, n: int) -> _Edge | None:
        """The edge that accepts these ``n`` samples, created if new, or None (counted)."""
        if not parent or not child:
            self._reject("empty frame name", n)
            return None
        if parent == child:
            self._reject("child frame equals its parent", n)
            return None
        edge = self._edges.get(child)
        if edge is not None and edge.parent == parent and edge.static == static:
            return edge
        if edge is not None:
            if edge.parent != parent:
                reason = f"'{child}' already has parent '{edge.parent}'"
            else:
                kinds = ("/tf_static", "/tf") if edge.static else ("/tf", "/tf_static")
                reason = f"'{edge.parent} -> {child}' came on {kinds[0]} first, then on {kinds[1]}"
            self._conflict(child, parent, static, reason, n)
            return None
        # A new child: refuse it if ``child`` is an ancestor of ``parent`` (a loop).
        frame: str | None = parent
        while frame is not None:
            if frame == child:
                self._conflict(
                    child, parent, static, f"'{parent} -> {child}' would close a loop", n
                )
                return None
            up = self._edges.get(frame)
            frame = None if up is None else up.parent
        edge = _Edge(parent, static)
        self._edges[child] = edge
        return edge

    def _conflict(self, child: str, parent: str, static: bool, reason: str, n: int) -> None:
        key = (child, parent, static)
        self._conflicts[key] = self._conflicts.get(key, 0) + n
        self._conflict_reasons.setdefault(key, reason)

    def add(
        self,
        parent: str,
        child: str,
        t_ns: int,
        translation: Sequence[float] | Floats,
        quaternion_xyzw: Sequence[float] | Floats,
        *,
        static: bool = False,
    ) -> None:
        """Add one sample of the pose of ``child`` in ``parent`` at ``t_ns`` (nanoseconds).

        ``translation`` is (x, y, z) in metres, ``quaternion_xyzw`` any non-zero quaternion.
        Refused samples are counted, not raised (a bag is read to the end). A static edge keeps
        its latest sample.
        """
        parent, child = normalise_frame(parent), normalise_frame(child)
        x, y, z = (float(v) for v in translation)
        qx, qy, qz, qw = (float(v) for v in quaternion_xyzw)
        norm2 = qx * qx + qy * qy + qz * qz + qw * qw
        finite = all(math.isfinite(v) for v in (x, y, z, norm2))
        if not (finite and norm2 > 0):
            self._reject("non-finite number or zero quaternion")
            return
        edge = self._edge_for(parent, child, static, 1)
        if edge is None:
            return
        t = int(t_ns)
        if static:
            edge.static_tf = Transform.from_quaternion((x, y, z), (qx, qy, qz, qw))
            edge.static_first = t if edge.static_n == 0 else min(edge.static_first, t)
            edge.static_last = t if edge.static_n == 0 else max(edge.static_last, t)
            edge.static_n += 1
        else:
            edge.times.append(t)
            edge.values.append((x, y, z, qx, qy, qz, qw))

    def add_many(
        self,
        parent: str,
        child: str,
        times_ns: ArrayLike,
        translations: ArrayLike,
        quaternions_xyzw: ArrayLike,
    ) -> None:
        """Add many samples (shapes (M,), (M, 3), (M, 4)) of one dynamic edge at once.

        E.g. an odometry track when the bag has no ``odom -> base_link`` on ``/tf``. Rows with
        non-finite numbers or a zero quaternion are refused and counted.
        """
        parent, child = normalise_frame(parent), normalise_frame(child)
        t = np.asarray(times_ns)
        if t.ndim != 1 or not np.issubdtype(t.dtype, np.integer):
            raise ValueError(f"times_ns must be a 1D integer array, got {t.dtype} {t.shape}")
        m = t.size
        p = np.asarray(translations, dtype=np.float64)
        q = np.asarray(quaternions_xyzw, dtype=np.float64)
        if p.shape != (m, 3) or q.shape != (m, 4):
            raise ValueError(
                f"translations and quaternions_xyzw must have shapes ({m}, 3) and ({m}, 4), "
                f"got {p.shape} and {q.shape}"
            )
        norms = np.linalg.norm(q, axis=1)
        good = np.isfinite(p).all(axis=1) & np.isfinite(norms) & (norms > 0)
        if not good.all():
            self._reject("non-finite number or zero quaternion", int((~good).sum()))
        n = int(good.sum())
        if n == 0:
            return
        edge = self._edge_for(parent, child, False, n)
        if edge is not None:
            edge.flush()
            edge.chunks.append((t[good].astype(np.int64), np.hstack([p[good], q[good]])))

    def add_track(self, track: PoseTrack, parent: str = "", child: str = "") -> None:
        """Add a :class:`PoseTrack` as the dynamic edge ``parent -> child`` (default: its own
        ``frame_id`` and ``child_frame_id``)."""
        self.add_many(
            parent or track.frame_id,
            child or track.child_frame_id,
            track.times_ns,
            track.translations,
            track.quaternions_xyzw,
        )

    def add_message(self, msg: Any, static: bool, bag_time_ns: int | None = None) -> None:
        """Add every transform of a deserialised ``tf2_msgs/msg/TFMessage``.

        Parameters
        ----------
        msg
            As rosbags deserialises it (ROS 1 or 2): ``msg.transforms`` is a list of
            ``geometry_msgs/TransformStamped`` with ``header.stamp.sec/.nanosec``,
            ``header.frame_id`` (parent), ``child_frame_id`` and ``transform.translation`` /
            ``transform.rotation``.
        static
            True for messages from ``/tf_static``.
        bag_time_ns
            Used for a transform whose stamp is zero, if given (nanoseconds).
        """
        for ts in msg.transforms:
            stamp = ts.header.stamp
            t = int(stamp.sec) * NS_PER_S + int(stamp.nanosec)
            if t == 0 and bag_time_ns is not None:
                t = int(bag_time_ns)
            tr, rot = ts.transform.translation, ts.transform.rotation
            self.add(
                ts.header.frame_id,
                ts.child_frame_id,
                t,
                (tr.x, tr.y, tr.z),
                (rot.x, rot.y, rot.z, rot.w),
                static=static,
            )

    # ------------------------------------------------------------------------------ queries

    def _track(self, child: str) -> PoseTrack:
        edge = self._edges[child]
        return edge.get_track(self.max_gap_ns, edge.parent, child)

    def frames(self) -> set[str]:
        """Every frame named by an accepted edge."""
        return set(self._edges) | {e.parent for e in self._edges.values()}

    def parent(self, frame: str) -> str | None:
        """The parent of ``frame``, or None for a root or unknown frame."""
        edge = self._edges.get(normalise_frame(frame))
        return None if edge is None else edge.parent

    def edges(self) -> list[TfEdge]:
        """Every accepted edge, sorted by (parent, child)."""
        out = []
        for child, edge in self._edges.items():
            if edge.static:
                out.append(
                    TfEdge(
                        edge.parent, child, True, edge.static_n, edge.static_first, edge.static_last
                    )
                )
            else:
                tr = self._track(child)
                out.append(TfEdge(edge.parent, child, False, len(tr), tr.start_ns, tr.end_ns))
        return sorted(out, key=lambda e: (e.parent, e.child))

    def conflicts(self) -> list[ParentConflict]:
        """Refused edges and how many samples each lost, sorted by child frame."""
        out = []
        for key, count in sorted(self._conflicts.items()):
            child, parent, static = key
            reason = self._conflict_reasons[key]
            out.append(ParentConflict(child, parent, static, self.parent(child), count, reason))
        return out

    @property
    def conflict_count(self) -> int:
        """Samples refused because they disagreed with the tree."""
        return sum(self._conflicts.values())

    def problems(self) -> list[str]:
        """One line per kind of refused sample, for reports; empty when all were used."""
        lines = [
            f"tf: {c.samples} sample(s) of '{c.parent} -> {c.child}'"
            f"{' (static)' if c.static else ''} ignored: {c.reason}"
            for c in self.conflicts()
        ]
        lines += [f"tf: {n} sample(s) ignored: {why}" for why, n in sorted(self.rejected.items())]
        return lines

    def fixed_frame(self) -> str | None:
        """``'map'`` if the tree has it, else ``'odom'``, else None (the user must name one)."""
        frames = self.frames()
        for name in ("map", "odom"):
            if name in frames:
                return name
        return None

    def _chain(self, frame: str) -> list[str]:
        """``frame`` and its ancestors up to the root (the tree has no loops)."""
        chain = [frame]
        while (edge := self._edges.get(chain[-1])) is not None:
            chain.append(edge.parent)
        return chain

    def _path(self, target: str, source: str) -> tuple[list[str], list[str]] | None:
        """Children whose edges lead from the common ancestor down to source and to target."""
        up_source = self._chain(source)
        up_target = self._chain(target)
        in_source = set(up_source)
        common = next((f for f in up_target if f in in_source), None)
        if common is None:
            return None
        return up_source[: up_source.index(common)], up_target[: up_target.index(common)]

    def _edges_lookup(self, children: list[str], t: Ints) -> tuple[Bools, Floats, Floats]:
        """Pose of ``children[0]`` in the parent of ``children[-1]`` at times ``t``."""
        valid = np.ones(t.shape, dtype=bool)
        r: Floats = np.eye(3)
        p: Floats = np.zeros(3)
        for child in children:  # from the bottom up: acc = edge * acc
            edge = self._edges[child]
            if edge.static:
                assert edge.static_tf is not None  # set with the edge
                r_e, p_e = edge.static_tf.rotation, edge.static_tf.translation
            else:
                ok, q_e, p_e = self._track(child)._interpolate(t)
                valid &= ok
                r_e = _quaternions_to_matrices(q_e)
            r, p = _compose(r_e, p_e, r, p)
        return valid, r, p

    def lookup_many(self, target: str, source: str, times_ns: ArrayLike) -> Lookup:
        """Poses of ``source`` in ``target`` at many times: ``p_target = R @ p_source + t``.

        Parameters
        ----------
        target, source : str
            Frame names (normalised here).
        times_ns : integer array-like, shape (K,)
            Query times, nanoseconds.

        Returns
        -------
        valid : bool array, shape (K,)
            False where any dynamic edge on the path has no data at that time (outside its
            samples, or in a gap longer than ``max_gap_ns``), and everywhere if the frames are
            unknown or not connected (see :meth:`why_not`).
        rotations : float64 array, shape (K, 3, 3)
            NaN where not valid.
        translations : float64 array, shape (K, 3)
            Metres; NaN where not valid.
        """
        t = np.asarray(times_ns, dtype=np.int64).reshape(-1)
        k = t.size
        target, source = normalise_frame(target), normalise_frame(source)
        frames = self.frames()
        path = self._path(target, source) if {target, source} <= frames else None
        if path is None:
            return np.zeros(k, dtype=bool), np.full((k, 3, 3), np.nan), np.full((k, 3), np.nan)
        down_source, down_target = path
        ok_s, r_s, p_s = self._edges_lookup(down_source, t)
        ok_t, r_t, p_t = self._edges_lookup(down_target, t)
        # pose of source in target = inverse(target in ancestor) * (source in ancestor)
        r_ti = np.swapaxes(r_t, -1, -2)
        r, p = _compose(r_ti, -np.einsum("...ij,...j->...i", r_ti, p_t), r_s, p_s)
        valid = ok_s & ok_t
        r = np.array(np.broadcast_to(r, (k, 3, 3)))
        p = np.array(np.broadcast_to(p, (k, 3)))
        r[~valid] = np.nan
        p[~valid] = np.nan
        return valid, r, p

    def lookup(self, target: str, source: str, t_ns: int) -> Transform | None:
        """Pose of frame ``source`` in frame ``target`` at ``t_ns`` (nanoseconds), or None.

        ``p_target = T.apply(p_source)``. The path runs through the common ancestor; every dynamic
        edge on it is interpolated at ``t_ns``; static edges hold at every time. A frame looked
        up in itself is the identity if the frame is known. :meth:`why_not` says why a lookup
        gives None.
        """
        valid, r, p = self.lookup_many(target, source, [t_ns])
        return Transform(r[0], p[0]) if valid[0] else None

    def why_not(self, target: str, source: str, t_ns: int) -> str:
        """Why :meth:`lookup` gives None, as one human sentence; ``""`` when it gives a pose."""
        target, source = normalise_frame(target), normalise_frame(source)
        frames = self.frames()
        unknown = [f for f in (target, source) if f not in frames]
        if unknown:
            known = sorted(frames)
            listed = ", ".join(known[:12]) + (", ..." if len(known) > 12 else "")
            return f"frame '{unknown[0]}' is not in the tf data (frames: {listed or 'none'})"
        path = self._path(target, source)
        if path is None:
            return (
                f"frames '{source}' and '{target}' are not connected: '{source}' hangs from "
                f"'{self._chain(source)[-1]}', '{target}' from '{self._chain(target)[-1]}'"
            )
        for child in path[0] + path[1]:
            edge = self._edges[child]
            if edge.static:
                continue
            reason = self._track(child).why_not(int(t_ns))
            if reason:
                return f"tf '{edge.parent} -> {child}' has {reason}"
        return ""


# ---------------------------------------------------------------------------------- odometry


@dataclass(frozen=True)
class OdometryArrays:
    """The fields of a run of ``nav_msgs/Odometry`` messages that give poses.

    Attributes
    ----------
    stamps_ns : int64 array, shape (M,)
        ``header.stamp`` in nanoseconds; 0 where the publisher left it unset.
    positions : float64 array, shape (M, 3)
        ``pose.pose.position``, metres, in ``frame_id``.
    quaternions_xyzw : float64 array, shape (M, 4)
        ``pose.pose.orientation``.
    frame_id, child_frame_id : str
        Normalised; empty when the messages leave them empty.
    """

    stamps_ns: Ints
    positions: Floats
    quaternions_xyzw: Floats
    frame_id: str = ""
    child_frame_id: str = ""

    @staticmethod
    def from_messages(messages: Iterable[Any], source: str | None = None) -> OdometryArrays:
        """Collect deserialised ``nav_msgs/msg/Odometry`` messages (as rosbags gives them).

        Raises
        ------
        InputError
            (naming ``source``, e.g. ``"run.bag:/odom"``) if the messages name different
            parent or child frames.
        """
        stamps: list[int] = []
        values: list[tuple[float, ...]] = []
        frames: set[str] = set()
        children: set[str] = set()
        for msg in messages:
            stamp = msg.header.stamp
            stamps.append(int(stamp.sec) * NS_PER_S + int(stamp.nanosec))
            pos, rot = msg.pose.pose.position, msg.pose.pose.orientation
            values.append((pos.x, pos.y, pos.z, rot.x, rot.y, rot.z, rot.w))
            frames.add(normalise_frame(msg.header.frame_id))
            children.add(normalise_frame(msg.child_frame_id))
        for what, names in (("header.frame_id", frames), ("child_frame_id", children)):
            if len(names) > 1:
                raise InputError(
                    source,
                    f"odometry messages name different frames in {what}: "
                    f"{', '.join(repr(n) for n in sorted(names))}",
                )
        v = np.asarray(values, dtype=np.float64).reshape(-1, 7)
        return OdometryArrays(
            np.asarray(stamps, dtype=np.int64),
            v[:, :3],
            v[:, 3:],
            next(iter(frames), ""),
            next(iter(children), ""),
        )


def odometry_track(
    bag_times_ns: ArrayLike,
    odometry: Sequence[Any] | OdometryArrays,
    *,
    max_gap_ns: int | None = DEFAULT_MAX_GAP_NS,
    default_frame: str = "odom",
    default_child_frame: str = "base_link",
    source: str | None = None,
) -> PoseTrack:
    """The pose of the robot's base frame in the odometry frame, from ``nav_msgs/Odometry``.

    Parameters
    ----------
    bag_times_ns : integer array-like, shape (M,)
        The bag's receive time of each message, nanoseconds; used where ``header.stamp`` is zero.
    odometry : sequence of messages or OdometryArrays
        Deserialised ``nav_msgs/msg/Odometry`` messages, or their fields as arrays.
    max_gap_ns : int or None
        Longest gap that is interpolated (default 1 s, as tf).
    default_frame, default_child_frame : str
        Frame names used when the messages leave ``header.frame_id`` / ``child_frame_id`` empty
        (some bags, e.g. the Embark one, leave ``child_frame_id`` empty).
    source : str or None
        Named in errors, e.g. ``"run.bag:/odom"``.

    Returns
    -------
    PoseTrack
        ``frame_id`` = the odometry frame, ``child_frame_id`` = the base frame.

    Raises
    ------
    InputError
        If there are no messages, the counts differ, frames disagree, or a pose holds
        non-finite numbers or a zero quaternion.
    """
    arrays = (
        odometry
        if isinstance(odometry, OdometryArrays)
        else OdometryArrays.from_messages(odometry, source)
    )
    bag_t = np.asarray(bag_times_ns, dtype=np.int64).reshape(-1)
    m = arrays.stamps_ns.size
    if m == 0:
        raise InputError(source, "no odometry messages")
    if bag_t.size != m:
        raise InputError(source, f"{bag_t.size} bag times for {m} odometry messages")
    times = np.where(arrays.stamps_ns == 0, bag_t, arrays.stamps_ns)
    try:
        return PoseTrack(
            times,
            arrays.positions,
            arrays.quaternions_xyzw,
            max_gap_ns=max_gap_ns,
            frame_id=arrays.frame_id or default_frame,
            child_frame_id=arrays.child_frame_id or default_child_frame,
        )
    except ValueError as exc:
        raise InputError(source, f"odometry: {exc}") from None


# ------------------------------------------------------------------------------------ TUM


def _tum_problem(lines: list[tuple[int, str]]) -> str:
    """Why ``np.loadtxt`` refused these (line number, text) rows; one sentence."""
    for number, text in lines:
        fields = text.split()
        if len(fields) != 8:
            return f"line {number} has {len(fields)} columns, expected 8 ({_TUM_COLUMNS})"
        for field in fields:
            try:
                float(field)
            except ValueError:
                return f"line {number}: {field!r} is not a number"
    return "cannot parse the file as TUM poses"  # pragma: no cover - loadtxt and float() agree


def _seconds_to_ns(texts: list[str], seconds: Floats) -> Ints:
    """Times written in decimal seconds -> int64 nanoseconds, exactly where the text allows.

    A float64 holds a Unix time only to ~0.2 us, which would move a pose off the scan stamp it
    was written for (and the last pose before it, refusing that scan). Plain decimals
    (``[+-]digits[.digits]``) are converted digit by digit, truncated after 9 decimals; other
    spellings (``1.7e9``) go through the float, rounded to the nearest nanosecond.
    """
    s = np.asarray(texts, dtype=str)
    negative = np.char.startswith(s, "-")
    parts = np.char.partition(np.char.lstrip(s, "+-"), ".")
    whole, frac = parts[:, 0], parts[:, 2]
    plain = (
        (np.char.isdigit(whole) | (whole == ""))
        & (np.char.isdigit(frac) | (frac == ""))
        & ((whole != "") | (frac != ""))
    )
    ns = np.where(plain & (whole != ""), whole, "0").astype(np.int64) * NS_PER_S
    ns += np.char.ljust(np.where(plain, frac, ""), 9, "0").astype("U9").astype(np.int64)
    ns = np.where(negative, -ns, ns)
    return np.where(plain, ns, np.rint(seconds * NS_PER_S).astype(np.int64))


def read_tum(
    path: Path | str,
    *,
    max_gap_ns: int | None = None,
    frame_id: str = "",
    child_frame_id: str = "",
) -> PoseTrack:
    """Read a TUM trajectory file: one pose per line, ``t x y z qx qy qz qw``.

    ``t`` is in seconds (decimals are read exactly to the nanosecond, not through a float), the
    position in metres, the quaternion ``(x, y, z, w)`` of the sensor (or body) in
    the trajectory's frame. ``#`` starts a comment; blank lines are ignored; the poses may come
    in any order (of equal times the last is kept).

    Raises
    ------
    InputError
        Naming the file and, where it applies, the line: missing, not a regular file (a FIFO
        would wait for a writer), larger than :data:`MAX_TUM_BYTES` or unreadable, a line
        without 8 columns, a value that is not a finite number, a zero quaternion, a time out of
        range, or fewer than two distinct times.
    """
    path = Path(path)
    size = regular_file(path, "TUM trajectory file", missing="no such file")
    if size > MAX_TUM_BYTES:
        raise InputError(
            path,
            f"a TUM trajectory of {size:,} bytes, more than the {MAX_TUM_BYTES:,} read (the limit "
            "MAX_TUM_BYTES of scan2terrain.readers.poses): thin it out",
        )
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except IsADirectoryError:
        raise InputError(path, "is a folder, expected a TUM trajectory file") from None
    except UnicodeDecodeError:
        raise InputError(path, "not a text file (TUM: t x y z qx qy qz qw per line)") from None
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror}") from None
    # Line numbers of the data rows, for error messages (a cheap string pass; parsing is loadtxt).
    rows = [
        (number, body)
        for number, line in enumerate(text.splitlines(), start=1)
        if (body := line.split("#", 1)[0].strip())
    ]
    if not rows:
        raise InputError(path, f"no poses (expected lines of: {_TUM_COLUMNS})")
    try:
        data = np.loadtxt([body for _, body in rows], dtype=np.float64, ndmin=2)
    except ValueError:
        raise InputError(path, _tum_problem(rows)) from None
    if data.shape[1] != 8:
        raise InputError(path, _tum_problem(rows))
    bad = ~np.isfinite(data).all(axis=1)
    if bad.any():
        raise InputError(path, f"line {rows[int(np.argmax(bad))][0]} holds a NaN or infinity")
    bad = np.abs(data[:, 0]) > _MAX_ABS_SECONDS
    if bad.any():
        raise InputError(path, f"line {rows[int(np.argmax(bad))][0]}: time out of range")
    bad = ~(np.linalg.norm(data[:, 4:], axis=1) > 0)
    if bad.any():
        raise InputError(path, f"line {rows[int(np.argmax(bad))][0]} has a zero quaternion")
    times = _seconds_to_ns([body.split(None, 1)[0] for _, body in rows], data[:, 0])
    if np.unique(times).size < 2:
        raise InputError(
            path,
            f"{len(rows)} pose(s) at one time only; a trajectory needs at least two times "
            "(for a sensor that did not move, give a fixed pose instead)",
        )
    return PoseTrack(
        times,
        data[:, 1:4],
        data[:, 4:],
        max_gap_ns=max_gap_ns,
        frame_id=frame_id,
        child_frame_id=child_frame_id,
    )


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
