"""The tf tree of a recording: :class:`TfBuffer`, tf2's ``BufferCore`` lookups without ROS.

It holds the ``/tf`` and ``/tf_static`` samples of a bag and looks up the pose of one frame in
another at any time, through their common ancestor; :class:`TfEdge` and :class:`ParentConflict`
describe its edges and refused samples for reports. Each dynamic edge is a
:class:`~scan2terrain.readers.tracks.PoseTrack`, interpolated as described there. Conventions are
those of :mod:`scan2terrain.readers.poses`.

Choices:

* **Maximum gap** (no pose inside a longer gap between two samples, see
  :mod:`scan2terrain.readers.tracks`): 1 s by default. tf publishers run at 10-200 Hz (odometry
  20-50 Hz, AMCL, slam_toolbox and Cartographer republish map -> odom at >= 10 Hz even when
  standing still), so 1 s is ten missed messages of the slowest of them and never a normal rate.
* **One parent per frame**: tf2 lets a frame change parent over time; bags that do so are almost
  always misconfigured (two nodes publishing the same child), so the first parent seen is kept
  and every later sample naming another parent (or the other of static / dynamic) is counted in
  :meth:`TfBuffer.conflicts`. An edge that would close a loop is refused the same way.
* **Static edges** hold only their latest transform and are valid at every time, as in tf2.
* Lookups are vectorised over query times (:meth:`TfBuffer.lookup_many`); messages are only
  appended to per-edge lists while a bag is read, and the arrays of an edge's track are built
  once, on the first lookup after new samples arrived.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from scan2terrain.readers._limits import MAX_COORDINATE_M
from scan2terrain.readers.poses import (
    DEFAULT_MAX_GAP_NS,
    NS_PER_S,
    Bools,
    Floats,
    Ints,
    Lookup,
    _compose,
    check_max_gap,
    quaternions_to_matrices,
)
from scan2terrain.readers.tracks import PoseTrack
from scan2terrain.types import Transform, normalise_frame

#: Why a sample whose translation no place on a planet has is refused (a damaged number).
_FAR = f"translation beyond {MAX_COORDINATE_M:g} m"

__all__ = [
    "ParentConflict",
    "TfBuffer",
    "TfEdge",
]


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
        self.max_gap_ns = check_max_gap(max_gap_ns)
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
        Refused samples (non-finite numbers, a zero quaternion, a translation beyond
        ``MAX_COORDINATE_M``) are counted, not raised (a bag is read to the end). A static edge
        keeps its latest sample.
        """
        parent, child = normalise_frame(parent), normalise_frame(child)
        x, y, z = (float(v) for v in translation)
        qx, qy, qz, qw = (float(v) for v in quaternion_xyzw)
        norm2 = qx * qx + qy * qy + qz * qz + qw * qw
        finite = all(math.isfinite(v) for v in (x, y, z, norm2))
        if not (finite and norm2 > 0):
            self._reject("non-finite number or zero quaternion")
            return
        if max(abs(x), abs(y), abs(z)) > MAX_COORDINATE_M:
            self._reject(_FAR)
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
        far = good & (np.abs(p) > MAX_COORDINATE_M).any(axis=1)
        if far.any():
            self._reject(_FAR, int(far.sum()))
            good &= ~far
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
                r_e = quaternions_to_matrices(q_e)
            r, p = _compose(r_e, p_e, r, p)
        return valid, r, p

    def sample_times(self, target: str, source: str) -> Ints:
        """Every sample time (nanoseconds, sorted, distinct) of the dynamic edges between two
        frames: the times at which the pose of ``source`` in ``target`` was recorded. Empty
        when the frames are unknown, not connected, or linked by static edges only."""
        target, source = normalise_frame(target), normalise_frame(source)
        path = self._path(target, source) if {target, source} <= self.frames() else None
        if path is None:
            return np.zeros(0, dtype=np.int64)
        times = [
            self._track(child).times_ns
            for child in path[0] + path[1]
            if not self._edges[child].static
        ]
        return np.unique(np.concatenate(times)) if times else np.zeros(0, dtype=np.int64)

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
