"""LaserScans decoded and posed in bulk (issue 31): ``posed_scans`` reads a batch's raw LaserScan
bytes (ROS1 and CDR) as numpy views and computes and poses all their points at once. It must
yield exactly what the per-message path yielded before (rosbags' object per message,
``laserscan_points`` per message, a matmul per message), kept below as :func:`reference`, on every
bundled recording, on bags of mixed layouts, and refuse damaged or absurd messages with the same
words."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterator
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2

from scan2terrain.config import ScansConfig, load_config
from scan2terrain.errors import InputError
from scan2terrain.readers.bag import Bag, open_bag
from scan2terrain.readers.foxglove import LaserScan as FoxgloveLaserScan
from scan2terrain.readers.foxglove import PointCloud as FoxglovePointCloud
from scan2terrain.readers.laserscan import laserscan_points
from scan2terrain.readers.pointcloud2 import pointcloud2_xyz
from scan2terrain.readers.scans import BATCH, BagPlan, _Poser, _stamp, plan_bag, posed_scans
from scan2terrain.types import Scan, ScanCounts
from tests.bagmaker import (
    LASER_SCAN,
    TF_MESSAGE,
    Fmt,
    build,
    laserscan_msg,
    tf_msg,
    yaw_quaternion,
)
from tests.bagmaker import typestore as _typestore
from tests.fixtures import FIXTURES

# --- today's per-message path, the reference ------------------------------------------------------


def reference(
    bag: Bag, cfg: ScansConfig, plan: BagPlan, counts: ScanCounts, max_range: float
) -> Iterator[Scan]:
    """``posed_scans`` as it was before issue 31: one rosbags object, one ``laserscan_points``
    and one matmul per message."""
    poser = _Poser(bag, cfg, plan)
    batch: list[tuple[str, int, Any]] = []
    for item in bag.messages(plan.scan_topics, plan.start_ns, plan.end_ns):
        batch.append(item)
        if len(batch) == BATCH:
            yield from _reference_batch(batch, poser, counts, max_range)
            batch = []
    if batch:
        yield from _reference_batch(batch, poser, counts, max_range)


def _reference_batch(
    batch: list[tuple[str, int, Any]], poser: _Poser, counts: ScanCounts, max_range: float
) -> Iterator[Scan]:
    by_topic: dict[str, list[tuple[int, Any]]] = {}
    for topic, t_ns, msg in batch:
        by_topic.setdefault(topic, []).append((t_ns, msg))
    out: list[Scan] = []
    for topic, items in by_topic.items():
        stamps = np.array([_stamp(m, t) for t, m in items], dtype=np.int64)
        valid, rot, trans = poser.poses(topic, stamps)
        for j, (t_ns, msg) in enumerate(items):
            counts.messages += 1
            if not valid[j]:
                counts.unposed += 1
                if not counts.first_unposed:
                    counts.first_unposed = f"{topic} at stamp {stamps[j] / 1e9:.3f} s: " + (
                        poser.why_not(topic, int(stamps[j]))
                    )
                continue
            r_j, t_j = rot[j], trans[j]
            try:
                if isinstance(msg, (FoxglovePointCloud, FoxgloveLaserScan)):
                    pts, mr = msg.points(max_range)
                    if (local := msg.local_pose) is not None:
                        r_j, t_j = r_j @ local.rotation, r_j @ local.translation + t_j
                elif hasattr(msg, "ranges"):
                    pts, mr = laserscan_points(msg, max_range if max_range > 0 else None)
                else:
                    pts, mr = pointcloud2_xyz(msg), max_range
            except InputError as exc:
                if exc.path is not None:
                    raise
                at = (t_ns - poser.start_ns) / 1e9
                raise InputError(
                    poser.source, f"message on {topic} at {at:.3f} s: {exc.problem}"
                ) from exc
            if len(pts) == 0:
                counts.empty += 1
                continue
            world = pts @ np.ascontiguousarray(r_j.T)
            world += t_j
            heading = math.atan2(float(r_j[1, 0]), float(r_j[0, 0]))
            origin = np.array(t_j, dtype=np.float64)
            out.append(Scan(world, origin, mr, int(stamps[j]), topic, heading, np.array(r_j)))
    out.sort(key=lambda s: s.stamp_ns)
    yield from out


def both(
    path: Path | list[Path], over: dict[str, Any], max_range: float = 30.0
) -> tuple[tuple[list[Scan], ScanCounts], tuple[list[Scan], ScanCounts]]:
    """(scans, counts) from ``posed_scans`` and from :func:`reference`, each on a fresh bag."""
    cfg = load_config(None, {"scans.correct": "off", **over})
    out = []
    for fn in (posed_scans, reference):
        with open_bag(path) as bag:
            plan = plan_bag(bag, cfg.scans, max_range=max_range)
            counts = ScanCounts()
            scans = list(fn(bag, cfg.scans, plan, counts, max_range=max_range))
        out.append((scans, counts))
    return out[0], out[1]


def same_bits(a: np.ndarray[Any, Any] | None, b: np.ndarray[Any, Any] | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def assert_same(
    new: tuple[list[Scan], ScanCounts], old: tuple[list[Scan], ScanCounts], least: int = 1
) -> None:
    (scans, counts), (want, want_counts) = new, old
    assert len(want) >= least
    assert counts == want_counts
    assert len(scans) == len(want)
    for i, (s, w) in enumerate(zip(scans, want, strict=True)):
        what = f"scan {i} ({w.topic} at {w.stamp_ns})"
        assert (s.stamp_ns, s.topic) == (w.stamp_ns, w.topic), what
        assert same_bits(s.points, w.points), what
        assert same_bits(s.origin, w.origin), what
        assert same_bits(s.rotation, w.rotation), what
        assert s.max_range == w.max_range or (math.isnan(s.max_range) and math.isnan(w.max_range))
        assert math.copysign(1, s.heading) == math.copysign(1, w.heading), what
        assert s.heading == w.heading, what


# --- every bundled recording --------------------------------------------------------------------

SICK: dict[str, Any] = {"scans.topics": ["/sick_lms_1xx/scan"], "scans.fixed_frame": "cloud"}
FIXED: dict[str, Any] = {"scans.pose": [0.3, -0.2, 0.3, 0.01, 0.02, 0.7]}
#: (recording, config overrides, max range): every bundled bag with laser scans, and the log.
RECORDINGS: dict[str, tuple[str, dict[str, Any], float]] = {
    "carmen_mit_csail": ("logs/raw_carmen_mit_csail/mit-csail.clf.bz2", {}, 30.0),
    "carmen_no_max_range": ("logs/raw_carmen_mit_csail/mit-csail.clf.bz2", {}, -1.0),
    "sick_lms1xx_tf": ("bags/bag1_sick_lms1xx_radar_tf", SICK, 30.0),
    "sick_lms1xx_db3": ("bags/bag2_derived_sick_lms1xx_db3", SICK, 30.0),
    "sick_scan_and_cloud": (
        "bags/bag1_sick_lms1xx_radar_tf",
        {**SICK, "scans.topics": ["/sick_lms_1xx/scan", "/cloud"]},
        2.0,
    ),
    "tb3_sim_odom": ("bags/bag1_fuse_tb3_sim_scan_odom", {}, 30.0),
    "tb3_sim_odom_short": ("bags/bag1_fuse_tb3_sim_scan_odom", {}, 1.5),
    "leg_tracker_fixed": ("bags/bag1_leg_tracker_room_scan", FIXED, 30.0),
    "ccny_hokuyo_fixed": ("bags/bag1_ccny_hokuyo_scan", FIXED, -1.0),
    "embark_ros1": ("bags/bag1_embark_luminar_pointcloud", {"scans.topics": ["/base_scan"]}, 30.0),
    "embark_mcap": ("bags/bag2_derived_embark_luminar_mcap", {"scans.topics": ["/base_scan"]}, 9.0),
}


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("name", sorted(RECORDINGS))
def test_bundled_recordings_give_the_same_scans(name: str) -> None:
    rel, over, max_range = RECORDINGS[name]
    new, old = both(FIXTURES / rel, over, max_range)
    assert_same(new, old, least=5)


# --- bags of mixed layouts, written here ---------------------------------------------------------

T0 = 1_700_000_000_000_000_000
typestore = lru_cache(maxsize=None)(_typestore)  # made once per format, not per message


def write_raw(path: Path, fmt: Fmt, items: list[tuple[str, str, int, bytes]]) -> Path:
    """A bag of ``(topic, msgtype, t_ns, message bytes)`` written as given (bytes may be bad)."""
    ts = typestore(fmt)
    writer: Writer1 | Writer2
    if fmt == "ros1":
        writer = Writer1(path)
    else:
        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        writer = Writer2(path, version=9, storage_plugin=plugin)
    with writer:
        conns: dict[str, Any] = {}
        for topic, msgtype, t_ns, raw in sorted(items, key=lambda m: m[2]):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], t_ns, raw)
    return path


def encode(fmt: Fmt, msgtype: str, msg: dict[str, Any], *, big_endian: bool = False) -> bytes:
    ts = typestore(fmt)
    obj = build(ts, msgtype, msg)
    if fmt == "ros1":
        return bytes(ts.serialize_ros1(obj, msgtype))
    return bytes(ts.serialize_cdr(obj, msgtype, little_endian=not big_endian))


def mixed_scans(n: int = 300, seed: int = 7) -> list[tuple[int, dict[str, Any]]]:
    """LaserScans that change layout: frame '/laser' or 'laser', 90 or 91 or 5 beams, with and
    without intensities; NaN, -inf, +inf, short and long readings; a zero stamp (bag time);
    a scan of one usable beam and one of none."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        beams = (90, 91, 5)[(i // 7) % 3]
        r = rng.uniform(0.05, 40.0, beams).astype(np.float32)
        r[rng.random(beams) < 0.1] = np.nan
        r[rng.random(beams) < 0.05] = np.inf
        r[rng.random(beams) < 0.03] = -np.inf
        if i == 40:
            r[:] = np.nan
            r[3] = 2.5  # one usable beam
        if i == 41:
            r[:] = np.nan  # none
        stamp = 0 if i % 13 == 5 else T0 + i * 50_000_000 + int(rng.integers(0, 1000))
        msg = laserscan_msg(
            stamp,
            "/laser" if (i // 5) % 2 else "laser",
            float(rng.uniform(-3.2, -1.0)),
            float(rng.uniform(0.001, 0.05)),
            r,
            float(rng.uniform(0.0, 0.3)),
            float(rng.uniform(5.0, 35.0)),
            intensities=rng.uniform(0, 100, beams) if i % 3 == 0 else None,
        )
        out.append((T0 + i * 50_000_000 + 1000, msg))
    return out


def tf_items(fmt: Fmt, n: int, *, start: int = 3) -> list[tuple[str, str, int, bytes]]:
    """map -> base_link moving (from scan ``start`` on: earlier scans are unposed), base_link ->
    laser fixed, both on /tf at 20 Hz."""
    out = []
    for k in range(start, n + 2):
        t = T0 + k * 50_000_000
        yaw = 0.01 * k
        msg = tf_msg(
            [
                ("map", "base_link", t, (0.1 * k, 5.0 - 0.03 * k, 0.0), yaw_quaternion(yaw)),
                ("base_link", "laser", t, (0.2, 0.0, 0.3), yaw_quaternion(0.05)),
            ]
        )
        out.append(("/tf", TF_MESSAGE, t, encode(fmt, TF_MESSAGE, msg)))
    return out


def scan_items(
    fmt: Fmt,
    scans: list[tuple[int, dict[str, Any]]],
    edit: Callable[[int, bytes], bytes] | None = None,
) -> list[tuple[str, str, int, bytes]]:
    out = []
    for i, (t, msg) in enumerate(scans):
        raw = encode(fmt, LASER_SCAN, msg)
        out.append(("/scan", LASER_SCAN, t, edit(i, raw) if edit else raw))
    return out


FORMATS: tuple[Fmt, ...] = ("ros1", "sqlite3", "mcap")


def bag_path(tmp_path: Path, fmt: Fmt, name: str = "b") -> Path:
    return tmp_path / (f"{name}.bag" if fmt == "ros1" else name)


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("max_range", [30.0, 8.0, -1.0])
def test_mixed_layouts_give_the_same_scans(tmp_path: Path, fmt: Fmt, max_range: float) -> None:
    scans = mixed_scans()
    path = write_raw(bag_path(tmp_path, fmt), fmt, scan_items(fmt, scans) + tf_items(fmt, 300))
    new, old = both(path, {"scans.poses": "tf"}, max_range)
    assert_same(new, old, least=250)
    assert new[1].unposed > 0 and new[1].empty > 0


@pytest.mark.parametrize("fmt", ["sqlite3", "mcap"])
def test_big_endian_cdr_gives_the_same_scans(tmp_path: Path, fmt: Fmt) -> None:
    scans = mixed_scans(150, seed=3)
    items = [
        ("/scan", LASER_SCAN, t, encode(fmt, LASER_SCAN, msg, big_endian=i % 2 == 0))
        for i, (t, msg) in enumerate(scans)
    ]
    path = write_raw(bag_path(tmp_path, fmt), fmt, items + tf_items(fmt, 150))
    new, old = both(path, {"scans.poses": "tf"})
    assert_same(new, old, least=100)


@pytest.mark.parametrize("fmt", FORMATS)
def test_fixed_pose_gives_the_same_scans(tmp_path: Path, fmt: Fmt) -> None:
    path = write_raw(bag_path(tmp_path, fmt), fmt, scan_items(fmt, mixed_scans(200, seed=5)))
    new, old = both(path, FIXED)
    assert_same(new, old, least=150)


# --- damaged and absurd messages: the same refusal ---------------------------------------------


def _ros1_count_at(raw: bytes) -> int:
    """Offset of a ROS1 LaserScan's ranges count."""
    length: int = struct.unpack_from("<I", raw, 12)[0]
    return 16 + length + 28


def _cdr_count_at(raw: bytes) -> int:
    length: int = struct.unpack_from("<I", raw, 12)[0]
    return 4 + ((12 + length + 3) & ~3) + 28


def count_at(fmt: Fmt, raw: bytes) -> int:
    return _ros1_count_at(raw) if fmt == "ros1" else _cdr_count_at(raw)


def _set_u32(raw: bytes, at: int, value: int) -> bytes:
    return raw[:at] + struct.pack("<I", value) + raw[at + 4 :]


def _set_f32(raw: bytes, field: int, fmt: Fmt, value: float) -> bytes:
    """Float field ``field`` (0 angle_min ... 6 range_max) of a LaserScan's bytes."""
    at = count_at(fmt, raw) - 28 + 4 * field
    return raw[:at] + struct.pack("<f", value) + raw[at + 4 :]


BAD = 100  # the damaged message: in the second batch


def _only(fn: Callable[[bytes, Fmt], bytes]) -> Callable[[Fmt], Callable[[int, bytes], bytes]]:
    def for_fmt(fmt: Fmt) -> Callable[[int, bytes], bytes]:
        return lambda i, raw: fn(raw, fmt) if i == BAD else raw

    return for_fmt


DAMAGE: dict[str, Callable[[Fmt], Callable[[int, bytes], bytes]]] = {
    "beams-beyond-message": _only(lambda r, f: _set_u32(r, count_at(f, r), 1_000_000)),
    "beams-one-more": _only(
        lambda r, f: _set_u32(r, count_at(f, r), struct.unpack_from("<I", r, count_at(f, r))[0] + 1)
    ),
    "beams-one-less": _only(
        lambda r, f: _set_u32(r, count_at(f, r), struct.unpack_from("<I", r, count_at(f, r))[0] - 1)
    ),
    "truncated": _only(lambda r, f: r[: len(r) - 9]),
    "trailing-bytes": _only(lambda r, f: r + b"\x00" * 8),
    "frame-not-utf8": _only(lambda r, f: r[:16] + b"\xff" + r[17:]),
    "frame-length-huge": _only(lambda r, f: _set_u32(r, 12, 0x7FFFFFF0)),
    "cdr-encapsulation": _only(lambda r, f: r if f == "ros1" else b"\x07\x07" + r[2:]),
    "increment-nan": _only(lambda r, f: _set_f32(r, 2, f, math.nan)),
    "increment-zero": _only(lambda r, f: _set_f32(r, 2, f, 0.0)),
    "angle_min-inf": _only(lambda r, f: _set_f32(r, 0, f, math.inf)),
    "range_max-zero": _only(lambda r, f: _set_f32(r, 6, f, 0.0)),
    "range_max-negative": _only(lambda r, f: _set_f32(r, 6, f, -4.0)),
    "range_max-nan": _only(lambda r, f: _set_f32(r, 6, f, math.nan)),
    "range_max-inf": _only(lambda r, f: _set_f32(r, 6, f, math.inf)),
    "range_min-huge": _only(lambda r, f: _set_f32(r, 5, f, 3e38)),
    "range_min-negative": _only(lambda r, f: _set_f32(r, 5, f, -1.0)),
    "every-increment-nan": lambda f: lambda i, r: _set_f32(r, 2, f, math.nan),
}


def outcome(path: Path, over: dict[str, Any], fn: Callable[..., Iterator[Scan]]) -> tuple[str, int]:
    """The error ``fn`` raises on ``path`` (type and words), and how many scans came first."""
    cfg = load_config(None, {"scans.correct": "off", **over})
    n = 0
    try:
        with open_bag(path) as bag:
            plan = plan_bag(bag, cfg.scans, max_range=30.0)
            for _ in fn(bag, cfg.scans, plan, ScanCounts(), max_range=30.0):
                n += 1
    except (InputError, ValueError) as exc:
        return f"{type(exc).__name__}: {exc}", n
    return "", n


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("damage", sorted(DAMAGE))
def test_damaged_and_absurd_messages_are_refused_alike(
    tmp_path: Path, fmt: Fmt, damage: str
) -> None:
    scans = [
        (t, {**m, "header": {**m["header"], "frame_id": "laser"}}) for t, m in mixed_scans(160)
    ]
    items = scan_items(fmt, scans, DAMAGE[damage](fmt)) + tf_items(fmt, 160, start=0)
    path = write_raw(bag_path(tmp_path, fmt), fmt, items)
    got, want = (outcome(path, {"scans.poses": "tf"}, fn) for fn in (posed_scans, reference))
    assert got == want
    if damage != "cdr-encapsulation" or fmt != "ros1":
        assert want[0], "the damage must be refused"
