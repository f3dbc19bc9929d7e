"""ROS1 in MCAP (issue 16): fixture ROS1 bags rewritten as profile-``ros1`` MCAP files read
exactly as the bags are, in every layout (chunk compression zstd, lz4, none; indexed or
summary-less; chunked or not), and damaged ones refused with one line naming the file.

The rewriting is :func:`tests.bagmaker.ros1_bag_to_mcap` (the ``mcap`` package's writer), what
``mcap convert`` makes of a ROS1 bag. The command-level twins are in
tests/test_bag2world_mcap.py.
"""

from __future__ import annotations

import struct
import warnings
from pathlib import Path
from typing import Any

import pytest
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from scan2terrain.errors import InputError
from scan2terrain.readers._mcap import McapFile, mcap_profile
from scan2terrain.readers.bag import BagWarning, open_bag
from tests.bagmaker import (
    LAYOUTS,
    first_chunk_data,
    one_message_mcap,
    read_messages,
    ros1_bag_to_mcap,
)
from tests.fixtures import EMBARK_MCAP, EMBARK_ROS1, FUSE


def rewrite(bag: Path, tmp: Path, layout: str) -> Path:
    compression, summary, chunked = LAYOUTS[layout]
    return ros1_bag_to_mcap(
        bag, tmp / f"{layout}.mcap", compression=compression, summary=summary, chunked=chunked
    )


def stream(path: Path, start: int | None = None, end: int | None = None) -> list[Any]:
    with open_bag(path) as bag:
        return [(t, n, repr(m)) for t, n, m in bag.messages(list(bag.topics), start, end)]


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_ros1_mcap_reads_as_the_bag(tmp_path: Path, layout: str) -> None:
    mcap = rewrite(FUSE, tmp_path, layout)
    assert mcap_profile(mcap) == "ros1"
    with open_bag(FUSE) as a, open_bag(mcap) as b:
        assert b.topics == a.topics and b.skipped == a.skipped == {}
        assert (b.start_ns, b.end_ns) == (a.start_ns, a.end_ns)
        assert b.frame_ids("/scan") == a.frame_ids("/scan")
        # a time slice, as --stream's tasks read them: counts and messages
        lo, hi = a.start_ns + 10**9, a.start_ns + 5 * 10**9
        assert b.count(["/scan", "/odom"], lo, hi) == a.count(["/scan", "/odom"], lo, hi)
        assert b.container.describe() == "MCAP, profile 'ros1', read with mcap"
        assert b.container.encodings["/scan"] == (
            "ros1 / ros1msg sensor_msgs/LaserScan, decoded as ROS1 (rosbags)"
        )
        assert isinstance(b._reader, McapFile)
        assert b._reader.indexed == (layout in {"zstd", "lz4", "none"})
    assert stream(mcap) == stream(FUSE)  # every message, in the same order, equal fields
    assert stream(mcap, lo, hi) == stream(FUSE, lo, hi)


@pytest.mark.parametrize("layout", ["lz4", "zstd-no-summary"])
def test_ros1_mcap_pointclouds_read_as_the_bag(tmp_path: Path, layout: str) -> None:
    mcap = rewrite(EMBARK_ROS1, tmp_path, layout)
    with open_bag(EMBARK_ROS1) as a, open_bag(mcap) as b:
        assert b.topics == a.topics
        got = [m for _, _, m in read_messages(b, "/luminar_pointcloud")]
        want = [m for _, _, m in read_messages(a, "/luminar_pointcloud")]
    assert len(got) == len(want) > 0
    for x, y in zip(got, want, strict=True):
        assert bytes(x.data) == bytes(y.data) and repr(x.fields) == repr(y.fields)


# --- what is refused ----------------------------------------------------------------------------


def refused(path: Path) -> str:
    with pytest.raises(InputError) as info, open_bag(path) as bag:
        for _ in bag.messages(list(bag.topics)):
            pass
    assert info.value.path == path
    text = str(info.value)
    assert "\n" not in text
    return info.value.problem


def test_truncated_mcap_is_refused(tmp_path: Path) -> None:
    data = rewrite(FUSE, tmp_path, "zstd").read_bytes()
    for cut in (len(data) // 2, len(data) - 3, 30):
        half = tmp_path / f"cut{cut}.mcap"
        half.write_bytes(data[:cut])
        assert "the MCAP file is truncated or damaged" in refused(half)


@pytest.mark.parametrize("layout", ["none", "zstd-no-summary", "lz4"])
def test_corrupt_chunk_is_refused(tmp_path: Path, layout: str) -> None:
    data = bytearray(rewrite(FUSE, tmp_path, layout).read_bytes())
    at = first_chunk_data(bytes(data)) + 200
    data[at : at + 8] = bytes(b ^ 0x5A for b in data[at : at + 8])
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    problem = refused(bad)
    assert "the MCAP file is truncated or damaged" in problem
    if layout == "none":
        assert "CRC" in problem


def test_chunk_claiming_huge_size_is_refused_before_allocating(tmp_path: Path) -> None:
    data = bytearray(rewrite(FUSE, tmp_path, "zstd").read_bytes())
    chunk = first_chunk_data(bytes(data))
    (n,) = struct.unpack_from("<I", data, chunk - 8 - 4 - 4)  # the compression string's length
    size_at = chunk - 8 - n - 4 - 4 - 8  # uncompressed size
    struct.pack_into("<Q", data, size_at, 1 << 50)
    bad = tmp_path / "bomb.mcap"
    bad.write_bytes(bytes(data))
    assert "claims 1,125,899,906,842,624 bytes" in refused(bad)


def test_unknown_schema_encoding_only_is_refused_with_what_is_supported(tmp_path: Path) -> None:
    bad = one_message_mcap(tmp_path / "fb.mcap", [("/points", "flatbuffer", "flatbuffer", None)])
    problem = refused(bad)
    assert problem.startswith("no channel of this MCAP file can be read: /points: ")
    assert "supported: ros1/ros1msg" in problem


def test_unknown_schema_encoding_beside_ros1_is_skipped_with_a_warning(tmp_path: Path) -> None:
    path = one_message_mcap(
        tmp_path / "mixed.mcap",
        [("/thing", "ros1", "ros1msg", None), ("/points", "flatbuffer", "flatbuffer", None)],
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", BagWarning)
        bag = open_bag(path)
    with bag:
        assert "/points" in bag.skipped and "/thing" not in bag.skipped
        ((_, _, msg),) = list(read_messages(bag, "/thing"))
        assert msg.x == 1
        assert bag.topics["/thing"].msgtype == "pkg/msg/Thing"
    assert len(caught) == 1 and "skipping topics: /points" in str(caught[0].message)


def test_missing_schema_is_refused(tmp_path: Path) -> None:
    bad = one_message_mcap(tmp_path / "noschema.mcap", [("/thing", "ros1", "ros1msg", 7)])
    assert "names schema 7, which is missing" in refused(bad)


def test_ros2_profile_keeps_the_rosbags_path() -> None:
    mcap = EMBARK_MCAP
    with open_bag(mcap) as bag:
        assert not isinstance(bag._reader, McapFile)
        assert bag.container.describe() == "rosbag2, read with rosbags"
    single = mcap / "bag2_derived_embark_luminar_mcap.mcap"
    assert mcap_profile(single) == "ros2"
    with open_bag(single) as bag:
        assert bag.container.describe() == "MCAP, profile 'ros2', read with rosbags"


@pytest.mark.parametrize("chunk_size", [40, 1 << 20])
def test_messages_merge_in_time_then_connection_then_file_order(
    tmp_path: Path, chunk_size: int
) -> None:
    """Messages written out of time order, in overlapping chunks or in order, with equal times
    on two channels: read in log-time order, ties in the order the connections are asked for,
    then in file order, whichever way (merged or in a block's own order) they are read."""
    times = [50, 10, 10, 30, 30, 20, 60, 60, 40, 70, 80, 80, 90]
    path = tmp_path / "order.mcap"
    with path.open("wb") as f:
        w = McapWriter(f, compression=CompressionType.NONE, chunk_size=chunk_size)
        w.start(profile="ros1", library="test")
        sid = w.register_schema("std_msgs/Int32", "ros1msg", b"int32 data\n")
        a = w.register_channel("/a", "ros1", sid)
        b = w.register_channel("/b", "ros1", sid)
        for n, t in enumerate(times):
            w.add_message(b if n % 3 else a, t, struct.pack("<i", n), t)
        for n, t in enumerate(sorted(times), start=len(times)):  # a second pass, in order
            w.add_message(a if n % 2 else b, t + 100, struct.pack("<i", n), t + 100)
        w.finish()  # type: ignore[no-untyped-call]
    reader = McapFile(path)
    try:
        by_topic = {c.topic: c for c in reader.connections}
        for asked in (["/a", "/b"], ["/b", "/a"]):
            conns = [by_topic[t] for t in asked]
            got = [
                (t, c.topic, struct.unpack("<i", bytes(raw))[0])
                for c, t, raw in reader.messages(conns)
            ]
            written = [(t, "/b" if n % 3 else "/a", n) for n, t in enumerate(times)]
            written += [
                (t + 100, "/a" if n % 2 else "/b", n)
                for n, t in enumerate(sorted(times), start=len(times))
            ]
            want = sorted(written, key=lambda m: (m[0], asked.index(m[1]), m[2]))
            assert got == want
    finally:
        reader.close()
