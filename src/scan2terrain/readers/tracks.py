"""Pose tracks: the poses of one frame in another over time, from odometry or a TUM file.

:class:`PoseTrack` holds the samples and interpolates between them (the tf tree's dynamic edges
are tracks too); :func:`odometry_track` builds one from ``nav_msgs/Odometry`` messages
(:class:`OdometryArrays`), :func:`read_tum` from a TUM trajectory file. Conventions are those of
:mod:`scan2terrain.readers.poses`.

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
  line through wherever the robot really went. The tf buffer defaults to 1 s
  (:mod:`scan2terrain.readers.tf` says why). A :class:`PoseTrack` and :func:`read_tum` default
  to no limit: a trajectory file is a deliberate input, and SLAM key-frame trajectories are
  sparse by design. :func:`odometry_track` uses the tf default, since odometry is streamed like
  tf.
* Interpolation is vectorised over query times (:meth:`PoseTrack.at_many`); the arrays of a
  track are built once.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from scan2terrain.errors import InputError
from scan2terrain.readers._files import regular_file
from scan2terrain.readers._limits import MAX_COORDINATE_M
from scan2terrain.readers.poses import (
    DEFAULT_MAX_GAP_NS,
    NS_PER_S,
    Bools,
    Floats,
    Ints,
    Lookup,
    _slerp,
    check_max_gap,
    quaternions_to_matrices,
    sign_continuous,
)
from scan2terrain.types import Transform, normalise_frame

__all__ = [
    "OdometryArrays",
    "PoseTrack",
    "odometry_track",
    "read_tum",
]

# Seconds a TUM time may hold and still fit int64 nanoseconds (+-292 years around 1970).
_MAX_ABS_SECONDS = 9.2e9
_TUM_COLUMNS = "t x y z qx qy qz qw"
#: The largest TUM file read (it is read whole): 4 million poses of 64 bytes, 11 hours at 100 Hz.
MAX_TUM_BYTES = 1 << 28


def _fmt_time(t_ns: int) -> str:
    return f"{t_ns / NS_PER_S:.3f} s"


def _fmt_span(dt_ns: int) -> str:
    return f"{dt_ns / NS_PER_S:.3f} s"


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
        if (far := np.abs(p) > MAX_COORDINATE_M).any():
            row, axis = divmod(int(np.flatnonzero(far)[0]), 3)
            raise ValueError(
                f"translations must be within {MAX_COORDINATE_M:g} m, not {p[row, axis]:g} "
                f"(row {row + 1}, {'xyz'[axis]})"
            )
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
        self.quaternions_xyzw = sign_continuous(q)
        for a in (self.times_ns, self.translations, self.quaternions_xyzw):
            a.setflags(write=False)
        self.max_gap_ns = check_max_gap(max_gap_ns)
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
        r = quaternions_to_matrices(q)
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
        raise InputError(source, f"odometry: {exc}") from exc


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
            "MAX_TUM_BYTES of scan2terrain.readers.tracks): thin it out",
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
        raise InputError(path, f"cannot read: {exc.strerror}") from exc
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
    far = np.abs(data[:, 1:4]) > MAX_COORDINATE_M
    if far.any():
        row, axis = divmod(int(np.flatnonzero(far)[0]), 3)
        raise InputError(
            path,
            f"line {rows[row][0]}: {'xyz'[axis]} {data[row, 1 + axis]:g} is beyond "
            f"{MAX_COORDINATE_M:g} m",
        )
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
