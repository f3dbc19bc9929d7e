"""sensor_msgs/LaserScan messages -> points in the laser frame, ready for the octree.

Reading i lies along the angle ``angle_min + i * angle_increment`` (radians, CCW about the laser's
z axis), in the laser's xy plane (z = 0). The readings mean (REP 117):

* finite, ``range_min <= r < range_max``: an obstacle at ``r`` (a hit);
* ``+inf`` or finite ``>= range_max``: nothing within range (the beam only clears);
* ``NaN``, ``-inf`` (too close) or ``r < range_min``: no information (dropped).

The octree (``VoxelOctree.insert_scan(points, origin, max_range=...)``, OctoMap's model) cuts
beams longer than ``max_range`` at ``max_range`` and lets them only clear, so a clear-only beam is
returned as a point far beyond the returned max range, and hits all lie inside it. Computed with
numpy over all readings at once.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from numpy.typing import NDArray

from scan2terrain.errors import InputError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

#: The returned max range exceeds the cut-off by this fraction, so a hit just below ``range_max``
#: stays a hit after the octree computes its distance from float32 coordinates (relative error
#: ~1e-7 per coordinate; 1e-5 leaves room for sensor poses tens of range lengths from the origin).
RANGE_SLACK = 1e-5
#: Clear-only beams end this many max ranges from the sensor (anything > 1 works).
CLEAR_FACTOR = 2.0


def laserscan_points(msg: Any, max_range: float | None = None) -> tuple[NDArray[np.float64], float]:
    """Points of a LaserScan in the laser frame, and the max range to insert them with.

    Parameters
    ----------
    msg : sensor_msgs/msg/LaserScan
        As rosbags deserialises it, or any object with ``angle_min``, ``angle_increment``
        (radians), ``range_min``, ``range_max`` (metres) and ``ranges`` (metres, float32 array).
        ``intensities`` are ignored.
    max_range : float, optional
        A shorter cut-off than the scanner's ``range_max`` (metres, > 0): readings at or beyond it
        become clear-only too. Ignored when not below ``range_max``.

    Returns
    -------
    points : float64 array, shape (N, 3)
        Metres, laser frame, z = 0, in reading order (dropped readings left out): hits at their
        range, clear-only beams at ``2 * max_range`` along their direction.
    max_range : float
        The cut-off for ``insert_scan``: ``min(range_max, max_range)`` plus a relative
        ``RANGE_SLACK``; every hit lies within it and every clear-only point beyond it.

    Raises
    ------
    InputError
        For a non-finite angle, ``angle_increment`` 0 with more than one reading, a
        ``range_max`` that is not a positive number, or a ``range_min`` that is not in
        ``[0, range_max)``.
    ValueError
        For a ``max_range`` argument that is not a positive number.
    """
    ranges = np.asarray(msg.ranges, dtype=np.float64).reshape(-1)
    angle_min, increment = float(msg.angle_min), float(msg.angle_increment)
    range_min, range_max = float(msg.range_min), float(msg.range_max)
    if not (math.isfinite(angle_min) and math.isfinite(increment)):
        raise InputError(
            None, f"LaserScan angles must be finite (angle_min {angle_min}, increment {increment})"
        )
    if increment == 0.0 and ranges.size > 1:
        raise InputError(None, f"LaserScan angle_increment is 0 with {ranges.size} readings")
    if not (range_max > 0.0 and math.isfinite(range_max)):
        raise InputError(None, f"LaserScan range_max must be a positive number, got {range_max}")
    if not 0.0 <= range_min < range_max:
        raise InputError(
            None, f"LaserScan range_min {range_min} must be in [0, range_max {range_max})"
        )
    limit = range_max
    if max_range is not None:
        if not (max_range > 0.0 and math.isfinite(max_range)):
            raise ValueError(f"max_range must be a positive number of metres, got {max_range}")
        limit = min(limit, float(max_range))
    cutoff = limit * (1.0 + RANGE_SLACK)

    with np.errstate(invalid="ignore"):  # NaN comparisons are False, as wanted
        usable = ranges >= range_min  # False for NaN; True for +inf
        hit = usable & (ranges < limit)
        clear = usable & (ranges >= limit)  # also +inf
    keep = np.flatnonzero(hit | clear)
    distance = np.where(hit[keep], ranges[keep], CLEAR_FACTOR * cutoff)
    angles = angle_min + increment * keep.astype(np.float64)
    points = np.zeros((keep.size, 3))
    points[:, 0] = distance * np.cos(angles)
    points[:, 1] = distance * np.sin(angles)
    return points, cutoff


# --- many scans at once (issue 31) ----------------------------------------------------------------


@dataclass(frozen=True)
class ScanBlock:
    """LaserScans of one beam count as columns: the fields :func:`laserscan_points` reads, one
    row per scan (float32 values as float64, exactly)."""

    angle_min: NDArray[np.float64]  #: (S,)
    angle_increment: NDArray[np.float64]  #: (S,)
    range_min: NDArray[np.float64]  #: (S,)
    range_max: NDArray[np.float64]  #: (S,)
    ranges: NDArray[np.floating]  #: (S, B), float32 as recorded

    @staticmethod
    def of(msgs: Sequence[Any]) -> ScanBlock:
        """Decoded LaserScans (rosbags' objects, a CARMEN log's), all of one beam count."""

        def column(name: str) -> NDArray[np.float64]:
            return np.array([float(getattr(m, name)) for m in msgs], dtype=np.float64)

        return ScanBlock(
            column("angle_min"),
            column("angle_increment"),
            column("range_min"),
            column("range_max"),
            np.stack([np.asarray(m.ranges).reshape(-1) for m in msgs]),
        )


@dataclass(frozen=True)
class BlockPoints:
    """:func:`block_points`' answer: per scan, which rows :func:`laserscan_points` would refuse
    (``refused``: ask it for the words), the max range, and the points of every reading."""

    refused: NDArray[np.bool_]  #: (S,)
    cutoff: NDArray[np.float64]  #: (S,) the max range laserscan_points returns
    keep: NDArray[np.bool_]  #: (S, B) the readings laserscan_points keeps
    points: NDArray[np.float64]  #: (S, B, 3) laser frame; rows of kept readings as it gives them


def block_points(block: ScanBlock, max_range: float | None = None) -> BlockPoints:
    """:func:`laserscan_points` of every scan of ``block`` in one numpy pass: the same arithmetic,
    element by element, so a scan's kept rows of ``points`` are bit for bit the points it returns.
    Scans it would refuse (and all of them for a ``max_range`` it would refuse) are flagged in
    ``refused``, never raised: the caller asks :func:`laserscan_points` for the error, in order."""
    s, b = block.ranges.shape
    a0, inc = block.angle_min, block.angle_increment
    lo, hi = block.range_min, block.range_max
    with np.errstate(invalid="ignore"):
        refused = ~(np.isfinite(a0) & np.isfinite(inc))
        refused |= (inc == 0.0) & (b > 1)
        refused |= ~((hi > 0.0) & np.isfinite(hi))
        refused |= ~((lo >= 0.0) & (lo < hi))
    if max_range is not None and not (max_range > 0.0 and math.isfinite(max_range)):
        refused[:] = True
    ok = ~refused
    # Refused rows computed with harmless values (no warnings), then dropped.
    a0, inc = np.where(ok, a0, 0.0), np.where(ok, inc, 0.0)
    lo, hi = np.where(ok, lo, 0.0), np.where(ok, hi, 1.0)
    limit = hi if max_range is None or refused.all() else np.minimum(hi, float(max_range))
    cutoff = limit * (1.0 + RANGE_SLACK)
    ranges = block.ranges.astype(np.float64)
    with np.errstate(invalid="ignore"):
        usable = ranges >= lo[:, None]
        hit = usable & (ranges < limit[:, None])
        clear = usable & (ranges >= limit[:, None])
    keep = (hit | clear) & ok[:, None]
    distance = np.where(hit, ranges, (CLEAR_FACTOR * cutoff)[:, None])
    angles = a0[:, None] + inc[:, None] * np.arange(b, dtype=np.float64)
    points = np.zeros((s, b, 3))
    points[:, :, 0] = distance * np.cos(angles)
    points[:, :, 1] = distance * np.sin(angles)
    return BlockPoints(refused, cutoff, keep, points)


# Raw LaserScan bytes as numpy views. ROS1 (little-endian, packed): header (uint32 seq, int32 sec,
# uint32 nanosec, uint32 length + frame_id bytes), seven float32 (angle_min, angle_max,
# angle_increment, time_increment, scan_time, range_min, range_max), uint32 count + float32
# ranges, uint32 count + float32 intensities; nothing after. CDR: a 4-byte encapsulation header
# (00 01: little-endian; big-endian ones are left to rosbags), header (int32 sec, uint32 nanosec,
# uint32 length + frame_id bytes with its NUL), padding to 4 (offsets count from after the
# encapsulation header), then as ROS1; up to 3 bytes of padding after.
_FLOATS = ("angle_min", "angle_increment", "range_min", "range_max")
_FLOAT_AT = {"angle_min": 0, "angle_increment": 8, "range_min": 20, "range_max": 24}
#: The LaserScan definitions read from bytes: (field, type) in order, nested types inlined.
_ROS1_FIELDS = ("seq uint32", "sec int32", "nanosec uint32", "frame_id string")
_CDR_FIELDS = ("sec int32", "nanosec uint32", "frame_id string")
_SCAN_FIELDS = (
    *(f"{n} float32" for n in ("angle_min", "angle_max", "angle_increment", "time_increment")),
    *(f"{n} float32" for n in ("scan_time", "range_min", "range_max")),
    "ranges float32[]",
    "intensities float32[]",
)


@dataclass(frozen=True)
class RawScans:
    """LaserScans of one layout read from their bytes: ``index`` (S,) their places in the list
    given to :func:`raw_laserscans`, ``stamps_ns`` (S,) their header stamps (0 or less: none),
    and their fields."""

    index: NDArray[np.intp]
    stamps_ns: NDArray[np.int64]
    block: ScanBlock


def _flat_fields(typestore: Typestore, msgtype: str) -> tuple[str, ...]:
    from rosbags.interfaces import Nodetype  # noqa: PLC0415  (rosbags only once a bag is read)

    out: list[str] = []
    for name, (node, sub) in typestore.get_msgdef(msgtype).fields:
        if node == Nodetype.NAME and isinstance(sub, str):
            out += _flat_fields(typestore, sub)
        elif node == Nodetype.BASE and not isinstance(sub, str):
            out.append(f"{name} {sub[0]}")
        elif node == Nodetype.SEQUENCE and not isinstance(sub, str):
            elem = cast(Any, sub)[0]
            out.append(f"{name} {elem[1][0]}[]" if elem[0] == Nodetype.BASE else f"{name} ?")
        else:
            out.append(f"{name} ?")
    return tuple(out)


def wire_layout_known(wire: str, typestore: Typestore, msgtype: str) -> bool:
    """Whether ``msgtype`` in ``typestore`` is the LaserScan :func:`raw_laserscans` reads."""
    head = _ROS1_FIELDS if wire == "ros1" else _CDR_FIELDS
    try:
        return _flat_fields(typestore, msgtype) == (*head, *_SCAN_FIELDS)
    except Exception:  # an unknown nested type: not ours to read
        return False


def _u32(rows: NDArray[np.uint8], at: NDArray[np.int64] | int) -> NDArray[np.int64]:
    """The little-endian uint32 at byte ``at`` of each row (``at`` per row or one for all)."""
    cols = np.asarray(at, dtype=np.int64).reshape(-1, 1) + np.arange(4)
    four = np.take_along_axis(rows, np.broadcast_to(cols, (len(rows), 4)), axis=1)
    return np.ascontiguousarray(four).view("<u4")[:, 0].astype(np.int64)


def raw_laserscans(
    raws: Sequence[bytes | memoryview], wire: str, template: Callable[[int], Any | None]
) -> list[RawScans]:
    """The LaserScans among ``raws`` (serialised as ``wire``, ``ros1`` or ``cdr``) that share a
    layout with others (same length, frame_id, beam and intensity counts), read together as
    numpy views of their bytes; the rest (alone in their layout, big-endian, damaged) are left
    for rosbags, message by message.

    ``template(i)`` is message ``i`` decoded by rosbags (None if it cannot be): the first message
    of each layout is, and the layout is read only if its fields read here match the decoded
    ones. The messages of a layout differ from that first one only in fixed-size numbers (the
    counts, lengths and frame_id bytes are the same), so rosbags would decode each of them too.
    """
    n = len(raws)
    if n < 2:
        return []
    cdr = wire == "cdr"
    lengths = np.fromiter((len(r) for r in raws), dtype=np.int64, count=n)
    out: list[RawScans] = []
    for size in np.unique(lengths):
        at = np.flatnonzero(lengths == size)
        if len(at) < 2 or size < 52:
            continue
        rows = np.frombuffer(b"".join(raws[int(i)] for i in at), np.uint8).reshape(
            len(at), int(size)
        )
        fit = (rows[:, 0] == 0) & (rows[:, 1] == 1) if cdr else np.ones(len(at), bool)
        frame_len = _u32(rows, 12)
        floats_at = 4 + ((12 + frame_len + 3) & ~3) if cdr else 16 + frame_len
        fit &= floats_at + 36 <= size
        beams = np.zeros(len(at), np.int64)
        beams[fit] = _u32(rows[fit], floats_at[fit] + 28)
        fit &= floats_at + 36 + 4 * beams <= size
        extra = np.zeros(len(at), np.int64)
        extra[fit] = _u32(rows[fit], floats_at[fit] + 32 + 4 * beams[fit])
        end = floats_at + 36 + 4 * beams + 4 * extra
        fit &= (end <= size) & (size - end <= (3 if cdr else 0))
        keys = np.stack([frame_len, beams, extra], axis=1)[fit]
        for key in np.unique(keys, axis=0) if len(keys) else ():
            sel = np.flatnonzero(fit)[(keys == key).all(axis=1)]
            if len(sel) < 2:
                continue
            group = _raw_group(rows[sel], at[sel], int(key[0]), int(key[1]), cdr, template)
            if group is not None:
                out.append(group)
    return out


def _raw_group(
    rows: NDArray[np.uint8],
    index: NDArray[np.intp],
    frame_len: int,
    beams: int,
    cdr: bool,
    template: Callable[[int], Any | None],
) -> RawScans | None:
    """One layout's messages (see :func:`raw_laserscans`): those with the first one's frame_id
    bytes, if rosbags decodes the first one to the same fields."""
    same = (rows[:, 16 : 16 + frame_len] == rows[0, 16 : 16 + frame_len]).all(axis=1)
    rows, index = rows[same], index[same]
    if len(rows) < 2 or (first := template(int(index[0]))) is None:
        return None
    floats_at = 4 + ((12 + frame_len + 3) & ~3) if cdr else 16 + frame_len
    sec_at = 4
    sec = np.ascontiguousarray(rows[:, sec_at : sec_at + 4]).view("<i4")[:, 0]
    nsec = np.ascontiguousarray(rows[:, sec_at + 4 : sec_at + 8]).view("<u4")[:, 0]
    stamps = sec.astype(np.int64) * 1_000_000_000 + nsec.astype(np.int64)

    def column(name: str) -> NDArray[np.float64]:
        at = floats_at + _FLOAT_AT[name]
        return np.ascontiguousarray(rows[:, at : at + 4]).view("<f4")[:, 0].astype(np.float64)

    start = floats_at + 32
    ranges = rows[:, start : start + 4 * beams].view("<f4")
    a0, inc, lo, hi = (column(n) for n in _FLOATS)
    block = ScanBlock(a0, inc, lo, hi, ranges)
    # The first message as rosbags read it: the same stamp, fields and readings, bit for bit?
    want = [float(getattr(first, n)) for n in _FLOATS]
    got = [float(getattr(block, n)[0]) for n in _FLOATS]
    st = first.header.stamp
    ok = (int(st.sec), int(st.nanosec)) == (int(sec[0]), int(nsec[0]))
    ok &= np.array_equal(np.array(want), np.array(got), equal_nan=True)
    first_ranges = np.asarray(first.ranges, dtype=np.float32)
    ok &= first_ranges.tobytes() == np.ascontiguousarray(ranges[0]).tobytes()
    return RawScans(index, stamps, block) if ok else None
