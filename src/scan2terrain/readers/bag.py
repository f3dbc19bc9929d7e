"""ROS bags in, deserialised messages out: ROS1 ``.bag`` files and rosbag2 recordings, no ROS.

Everything is read through :class:`rosbags.highlevel.AnyReader`, with ROS 2 Humble's message
definitions as the fallback for bags that carry none (old sqlite3 rosbag2). Choices:

* **What can be opened.** A ROS1 ``.bag`` file; several ``.bag`` files of one split recording
  (a list of paths, or a folder of ``.bag`` files); a rosbag2 folder (``metadata.yaml``
  plus ``.db3``/``.mcap``, also with ``compression_mode: FILE`` zstd, which rosbags decompresses
  itself); a standalone ``.db3`` or ``.mcap`` file without ``metadata.yaml``; a standalone
  zstd-compressed ``.mcap.zstd``/``.db3.zstd`` file, decompressed here into a temporary folder
  (with the ``zstd`` module rosbags itself depends on, so no extra dependency). The format is
  sniffed from the first bytes, not the suffix, so errors can say what a file really is; a bag
  with the wrong suffix is opened through a temporary symlink because rosbags dispatches on
  the suffix.
* **Only regular files are opened** (:func:`~scan2terrain.readers._files.regular_file`): a named
  pipe given as a bag, or as the storage file of a rosbag2 folder, waited for a writer forever.
* **Decompression is capped.** A whole-file zstd bag (standalone, or each file of a rosbag2
  folder with ``compression_mode: FILE``, which rosbags would decompress without a limit) is
  decompressed here, streamed, to at most :data:`MAX_ZSTD_RATIO` times its size (at least
  :data:`MIN_ZSTD_BUDGET`): a 49 KB file inflated to 1.6 GB. A frame that states its size is
  refused before anything is written.
* **Temporary folders** (``.s2t-bag-*.part`` in the system's temporary folder) are held under
  an exclusive ``flock`` while they live, and removed when the bag is closed; those of killed
  runs, which nobody holds, are removed by the next bag read (the rule and the code of
  :mod:`scan2terrain.exporters.output`'s output folders).
* **Errors.** Every failure is one :class:`~scan2terrain.errors.InputError` naming the file:
  missing, not a bag, the pre-2010 ``#ROSRECORD V1.2`` format, a truncated or damaged file
  (rosbags raises many exception types, some only while iterating, so iteration is wrapped
  too), a topic that does not exist (the message lists the ones there are), a time range without
  messages (:meth:`Bag.require_messages`).
* **Broken ROS1 indexes are rebuilt.** Some old rosbag writers (e.g. the 2010 CCNY demo bag)
  wrote ``IDXDATA`` records whose declared length does not match their entries; rosbags then
  fails with a bare ``AssertionError``. The per-chunk index only says where each message sits in
  its chunk, so when rosbags rejects it, :class:`_Ros1Reader` walks that chunk's records
  instead (a few dozen lines, the layout rosbags' own reader parses) and a :class:`BagWarning`
  says so. Bags whose *file-level* index is missing (a killed recording, a truncated copy) are
  refused with the ROS1 fix (``rosbag reindex``): rebuilding the chunk list as well would be a
  reimplementation of ``rosbag reindex``.
* **Old ROS1 definitions.** Bags from ROS C-Turtle (2010) define ``Header`` as
  ``roslib/Header``; rosbags resolves ``Header`` to ``std_msgs/Header`` and fails. The
  definition text is renamed when it is read (same fields, same MD5).
* **Unknown message types** (no definition in the bag nor in ROS 2 Humble, e.g. a custom type
  in a schema-less sqlite3 bag) never stop the run: such topics are listed in
  :attr:`Bag.skipped` with the reason, and *one* :class:`BagWarning` (a ``UserWarning``) is
  issued by :func:`open_bag`. Library code never prints; the CLI is to show warnings on stderr.
  Asking :meth:`Bag.messages` for a skipped topic is an ``InputError``.
* **Times** are bag (record) times in integer nanoseconds. Ranges are *inclusive* at both ends
  (``end_ns`` is the last message's time). :func:`resolve_time` turns a user value into
  nanoseconds: values ``>= 1e9`` are absolute UNIX seconds, smaller ones are seconds from the
  bag's first message (simulated-time bags therefore take offsets, not their small absolute
  stamps); values outside the bag are clamped to just before its first / just after its last
  message, so an out-of-bag range comes out empty and :meth:`Bag.require_messages` reports it.
* **Type names** are ROS 2 style for ROS1 bags as well (``sensor_msgs/msg/LaserScan``), as
  rosbags reports them. ROS1 messages keep ``header.seq``; ROS 2 ones have none.
"""

from __future__ import annotations

import codecs
import os
import shutil
import sys
import tempfile
import warnings
from collections import defaultdict
from collections.abc import Iterable, Iterator, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from functools import lru_cache
from io import BytesIO
from pathlib import Path, PurePath
from types import TracebackType
from typing import TYPE_CHECKING, Any, cast

from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection, MessageDefinition
from rosbags.rosbag1 import Reader as _RosbagsReader1
from rosbags.rosbag1.reader import Header as _Ros1Header
from rosbags.rosbag1.reader import IndexData as _IndexData
from rosbags.rosbag1.reader import RecordType as _Ros1Record
from rosbags.rosbag1.reader import read_bytes as _read_bytes
from rosbags.rosbag1.reader import read_uint32 as _read_uint32
from rosbags.typesys import Stores, get_typestore

from scan2terrain.errors import InputError
from scan2terrain.readers._files import regular_file
from scan2terrain.types import normalise_frame

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

__all__ = [
    "LASER_SCAN",
    "OCCUPANCY_GRID",
    "ODOMETRY",
    "POINT_CLOUD2",
    "SCAN_TYPES",
    "TF_MESSAGE",
    "TF_MESSAGE_ROS1_OLD",
    "TF_TYPES",
    "Bag",
    "BagWarning",
    "TopicInfo",
    "open_bag",
    "resolve_time",
]

#: Message types the pipeline consumes (ROS 2 names; ROS1 bags report the same names).
LASER_SCAN = "sensor_msgs/msg/LaserScan"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
#: ROS1's pre-tf2 ``tf/tfMessage``: the same layout (``geometry_msgs/TransformStamped[]``).
TF_MESSAGE_ROS1_OLD = "tf/msg/tfMessage"
TF_TYPES = frozenset({TF_MESSAGE, TF_MESSAGE_ROS1_OLD})
SCAN_TYPES = frozenset({LASER_SCAN, POINT_CLOUD2})

#: Values at or above this many seconds are absolute UNIX times in :func:`resolve_time`.
ABSOLUTE_TIME_S = 1e9

_MAGIC_ROS1 = b"#ROSBAG V2.0"
_MAGIC_ROSRECORD = b"#ROSRECORD"
_MAGIC_SQLITE = b"SQLite format 3\x00"
_MAGIC_MCAP = b"\x89MCAP0\r\n"
_MAGIC_ZSTD = b"\x28\xb5\x2f\xfd"
_STORAGE_SUFFIX = {"sqlite3": ".db3", "mcap": ".mcap"}
_STORAGE_NAMES = (".db3", ".mcap", ".db3.zstd", ".mcap.zstd")
#: A zstd bag is decompressed to at most this many times its size (and at least
#: :data:`MIN_ZSTD_BUDGET` bytes). Recordings compress 2 to 10 times; the nav2 fixture, mostly
#: an empty costmap, 120 times. A trusted file beyond it can be decompressed with ``zstd -d``.
MAX_ZSTD_RATIO = 200
MIN_ZSTD_BUDGET = 64 << 20
#: A rosbag2 ``metadata.yaml`` lists topics and files: kilobytes.
MAX_METADATA_BYTES = 16 << 20
_LEGACY_HINT = (
    "this is the pre-2010 '#ROSRECORD V1.2' bag format, which only ROS1's own rosbag reads; "
    "convert it in ROS1 with 'rosbag reindex old.bag' (rewrites it as V2.0, keeping "
    "old.orig.bag) or 'rosbag fix old.bag new.bag'"
)


class BagWarning(UserWarning):
    """A bag was read, but not all of it: skipped topics, a rebuilt index."""


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag.

    Attributes
    ----------
    name : str
        Topic name as recorded (ROS1 names are normalised to one leading ``/``).
    msgtype : str or None
        ROS 2 style type name, e.g. ``sensor_msgs/msg/LaserScan``; None when the topic's
        connections disagree on the type.
    count : int
        Number of messages in the whole bag.
    """

    name: str
    msgtype: str | None
    count: int


@lru_cache(maxsize=1)
def _default_typestore() -> Typestore:
    return get_typestore(Stores.ROS2_HUMBLE)


# --- ROS1: the rosbags reader, with an index rebuilt from the chunks where it is broken -----------


class _Ros1Reader(_RosbagsReader1):
    """rosbags' ROS1 reader that survives two defects of old bags.

    * ``IDXDATA`` records that rosbags rejects (an ``AssertionError`` from its fast parser): the
      entries for that chunk are rebuilt by walking the chunk's records (each is ``uint32``
      header length, header fields ``name=value``, ``uint32`` data length, data; messages are
      ``op=2`` with ``conn`` and ``time``), exactly what the index would have said.
    * ``roslib/Header`` in message definitions (ROS C-Turtle) is renamed ``std_msgs/Header``.
    """

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.rebuilt_chunks: set[int] = set()

    def read_connection(self) -> Connection:
        conn = super().read_connection()
        text = conn.msgdef.data
        if "\nMSG: roslib/Header\n" in text:
            text = text.replace("\nMSG: roslib/Header\n", "\nMSG: std_msgs/Header\n")
            conn = conn._replace(msgdef=MessageDefinition(conn.msgdef.format, text))
        return conn

    def read_index_data(self, pos: int, indexes: dict[int, list[_IndexData]]) -> None:
        if pos in self.rebuilt_chunks:
            return  # the walk already indexed every message of this chunk
        try:
            super().read_index_data(pos, indexes)
        except AssertionError:
            self._walk_chunk(pos, indexes)

    def _walk_chunk(self, pos: int, indexes: dict[int, list[_IndexData]]) -> None:
        assert self.bio is not None  # only called from open()
        self.rebuilt_chunks.add(pos)
        for conn_entries in indexes.values():  # drop entries of this chunk read before the error
            conn_entries[:] = [e for e in conn_entries if e.chunk_pos != pos]
        chunk = self.chunks[pos]
        self.bio.seek(chunk.datapos)
        data = chunk.decompressor(_read_bytes(self.bio, chunk.datasize))
        src = BytesIO(data)
        while src.tell() < len(data):
            offset = src.tell()
            header = _Ros1Header.read(src)
            size = _read_uint32(src)
            if header.get_uint8("op") == _Ros1Record.MSGDATA:
                entry = _IndexData(header.get_time("time"), pos, offset)
                indexes[header.get_uint32("conn")].append(entry)
            src.seek(size, os.SEEK_CUR)


# --- finding out what a path is -------------------------------------------------------------------


def _sniff(path: Path) -> str:
    """The format of a file from its first bytes: ros1, rosrecord, sqlite3, mcap, zstd, ..."""
    with path.open("rb") as f:
        head = f.read(256)
    if not head:
        return "empty"
    for kind, magic in (
        ("ros1", _MAGIC_ROS1),
        ("rosrecord", _MAGIC_ROSRECORD),
        ("sqlite3", _MAGIC_SQLITE),
        ("mcap", _MAGIC_MCAP),
        ("zstd", _MAGIC_ZSTD),
    ):
        if head.startswith(magic):
            return kind
    if head.startswith(b"#ROSBAG"):
        return "ros1-other"
    printable = all(b >= 0x20 or b in b"\t\n\r\f" for b in head)
    try:
        codecs.getincrementaldecoder("utf-8")().decode(head, final=False)
    except UnicodeDecodeError:
        return "unknown"
    return "text" if printable else "unknown"


def _not_a_bag(path: Path, kind: str) -> InputError:
    if kind == "empty":
        return InputError(path, "the file is empty, not a bag")
    if kind == "rosrecord":
        return InputError(path, _LEGACY_HINT)
    if kind == "ros1-other":
        return InputError(path, "unsupported ROS1 bag version (only '#ROSBAG V2.0' is read)")
    if kind == "text":
        hint = (
            "; for a rosbag2 recording pass the folder that holds metadata.yaml"
            if path.suffix in {".yaml", ".yml"}
            else ""
        )
        return InputError(path, f"this is a text file, not a ROS bag{hint}")
    return InputError(
        path,
        "not a ROS bag (expected a ROS1 .bag, a rosbag2 folder, or a .db3 / .mcap file)",
    )


@dataclass(frozen=True)
class _Source:
    """What to hand to AnyReader, and which path to name in messages."""

    paths: tuple[Path, ...]  # as given by the user (named in errors)
    read: tuple[Path, ...]  # what rosbags opens (staged copies or symlinks where needed)


def _temp_folder(stack: ExitStack) -> Path:
    """A new folder in the system's temporary folder, removed when ``stack`` closes.

    It holds an exclusive flock while it lives, so the next bag read can tell the folder of a
    killed run from a live one's and remove it (:func:`scan2terrain.fileio.sweep`,
    under a short lock on the temporary folder, as for output folders).
    """
    # Lazy: the output module is a later stage's, shared here as fileio shares it.
    from scan2terrain.fileio import TMP_PREFIX, locked, sweep, try_lock

    parent = Path(tempfile.gettempdir())
    try:
        with locked(parent):
            sweep(parent)
            folder = Path(tempfile.mkdtemp(prefix=f"{TMP_PREFIX}bag-", suffix=".part", dir=parent))
            lock = try_lock(folder)
    except OSError as exc:
        raise InputError(
            None, f"cannot make a temporary folder in {parent} ({exc.strerror or exc})"
        ) from None
    if lock is not None:
        stack.callback(os.close, lock)
    stack.callback(shutil.rmtree, folder, ignore_errors=True)  # first, then the lock goes
    return folder


def _stage(path: Path, kind: str, stack: ExitStack) -> Path:
    """A path rosbags will accept for a file of this kind (it dispatches on the suffix)."""
    want = ".bag" if kind == "ros1" else _STORAGE_SUFFIX[kind]
    if path.suffix == want:
        return path
    link = _temp_folder(stack) / (path.stem + want)
    link.symlink_to(path.resolve())
    return link


def _too_big(limit: int, size: int) -> str:
    return (
        f"more than {limit:,} bytes, {MAX_ZSTD_RATIO} times its {size:,} (at least "
        f"{MIN_ZSTD_BUDGET:,}: MAX_ZSTD_RATIO in scan2terrain.readers.bag): a zstd bomb? If the "
        "file is trusted, decompress it with 'zstd -d' and give the result"
    )


def _inflate(path: Path, out: Path) -> None:
    """Decompress the zstd file ``path`` into ``out``, streamed, refusing (before writing
    anything, when its first frame states its size) more than the budget."""
    size = path.stat().st_size
    limit = max(MIN_ZSTD_BUDGET, MAX_ZSTD_RATIO * size)
    try:
        with path.open("rb") as raw:
            try:
                declared = zstd.get_frame_info(raw.read(18)).decompressed_size
            except zstd.ZstdError:  # no frame header: decompression says what is wrong
                declared = None
            if declared is not None and declared > limit:
                raise InputError(
                    path, f"its zstd frame holds {declared:,} bytes, {_too_big(limit, size)}"
                )
            raw.seek(0)
            total = 0
            with zstd.open(raw, "rb") as src, out.open("wb") as dst:
                while chunk := src.read(1 << 20):
                    total += len(chunk)
                    if total > limit:
                        raise InputError(path, f"decompresses to {_too_big(limit, size)}")
                    dst.write(chunk)
    except (OSError, zstd.ZstdError, EOFError) as exc:
        raise InputError(path, f"cannot decompress this zstd file ({exc})") from None
    except InputError:
        out.unlink(missing_ok=True)  # now: the folder goes only when the bag is closed
        raise


def _decompress(path: Path, stack: ExitStack) -> Path:
    """Decompress a whole-file zstd bag (``.mcap.zstd``) into a temporary file."""
    out = _temp_folder(stack) / "bag"
    _inflate(path, out)
    kind = _sniff(out)
    if kind not in _STORAGE_SUFFIX:
        raise InputError(path, "a zstd file that does not hold a .mcap or .db3 bag")
    return out.rename(out.with_suffix(_STORAGE_SUFFIX[kind]))


def _metadata(folder: Path) -> dict[str, Any] | None:
    """The ``rosbag2_bagfile_information`` of a rosbag2 folder, with ``relative_file_paths``
    as plain names; None when it is not in order (rosbags then reads it and says what is
    wrong)."""
    import yaml

    errors = (OSError, UnicodeError, yaml.YAMLError, RecursionError, ValueError, KeyError)
    try:
        doc = yaml.safe_load((folder / "metadata.yaml").read_text(encoding="utf-8"))
        info = dict(doc["rosbag2_bagfile_information"])
        info["relative_file_paths"] = [PurePath(str(x)).name for x in info["relative_file_paths"]]
    except (*errors, TypeError, AttributeError):
        return None
    return info


def _unpack_file_mode(folder: Path, info: dict[str, Any], stack: ExitStack) -> Path | None:
    """For a rosbag2 folder compressed file by file (``compression_mode: FILE``, zstd): a copy
    with its files decompressed here (capped) and a metadata.yaml that says so, for rosbags to
    read instead of decompressing them itself without a limit; None for any other folder."""
    import yaml

    names: list[str] = info["relative_file_paths"]
    mode = str(info.get("compression_mode") or "").lower()
    if mode != "file" or info.get("compression_format") != "zstd" or not names:
        return None
    if not all((folder / name).is_file() for name in names):
        return None  # rosbags names the missing ones
    staged = _temp_folder(stack) / folder.name
    staged.mkdir()
    unpacked = [PurePath(name).stem for name in names]  # rosbags' own names for them
    for name, out in zip(names, unpacked, strict=True):
        _inflate(folder / name, staged / out)
    plain = {**info, "compression_mode": "", "compression_format": ""}
    plain["relative_file_paths"] = unpacked
    (staged / "metadata.yaml").write_text(
        yaml.safe_dump({"rosbag2_bagfile_information": plain}), encoding="utf-8"
    )
    return staged


def _rosbag2(path: Path, stack: ExitStack) -> _Source:
    """A rosbag2 folder: its metadata.yaml and storage files must be regular files."""
    meta = path / "metadata.yaml"
    if regular_file(meta, "bag") > MAX_METADATA_BYTES:
        raise InputError(
            meta, f"larger than {MAX_METADATA_BYTES:,} bytes: not a rosbag2 metadata file"
        )
    info = _metadata(path)
    listed = set() if info is None else set(info["relative_file_paths"])
    for entry in sorted(path.iterdir()):
        if entry.name.endswith(_STORAGE_NAMES) or entry.name in listed:
            regular_file(entry, "bag")
    staged = None if info is None else _unpack_file_mode(path, info, stack)
    if staged is not None:
        return _Source((path,), (staged,))
    if path.suffix == ".bag":  # rosbags reads every *.bag path as a ROS1 file
        link = _temp_folder(stack) / path.stem
        link.symlink_to(path.resolve(), target_is_directory=True)
        return _Source((path,), (link,))
    return _Source((path,), (path,))


def _source(given: Path | str | Sequence[Path | str], stack: ExitStack) -> _Source:
    items = [Path(given)] if isinstance(given, (str, os.PathLike)) else [Path(p) for p in given]
    if not items:
        raise InputError(None, "no bag given")
    for p in items:
        if not p.is_dir():  # a file, or nothing: refused before it is opened unless regular
            regular_file(p, "bag", missing="bag not found")
    if len(items) > 1:  # a split ROS1 recording
        staged = []
        for p in items:
            if p.is_dir() or (kind := _sniff(p)) != "ros1":
                raise InputError(
                    p,
                    "several paths are read as one split ROS1 recording: "
                    "each must be a ROS1 .bag file",
                )
            staged.append(_stage(p, kind, stack))
        return _Source(tuple(items), tuple(staged))

    path = items[0]
    if path.is_file() and path.name == "metadata.yaml":
        path = path.parent
    if path.is_dir():
        meta = path / "metadata.yaml"
        if meta.exists() or meta.is_symlink():
            return _rosbag2(path, stack)
        bags = sorted(p for p in path.iterdir() if p.suffix == ".bag" and p.is_file())
        if bags:
            return _source(bags, stack) if len(bags) > 1 else _source(bags[0], stack)
        storage = sorted(
            p for p in path.iterdir() if p.is_file() and p.name.endswith(_STORAGE_NAMES)
        )
        if len(storage) == 1:
            return _Source((path,), _source(storage[0], stack).read)
        raise InputError(
            path,
            "no bag in this folder (expected metadata.yaml, .bag files, or one .db3/.mcap file)",
        )
    kind = _sniff(path)
    if kind == "zstd":
        return _Source((path,), (_decompress(path, stack),))
    if kind in {"ros1", *_STORAGE_SUFFIX}:
        return _Source((path,), (_stage(path, kind, stack),))
    raise _not_a_bag(path, kind)


def _explain(exc: BaseException, *, reading: bool = False) -> str:
    """One line for an exception raised by rosbags (or its sqlite/mcap/zstd backends).

    ``reading``: raised while streaming messages, after the bag opened fine.
    """
    if isinstance(exc, MemoryError):  # a length field read as gigabytes
        return (
            "the bag is damaged: a record claims more bytes than can be allocated (a corrupt "
            "length field)"
        )
    if isinstance(exc, UnicodeError):  # its args hold the whole undecodable bytes
        text = str(exc)
    else:
        text = " ".join(str(a) for a in exc.args) if exc.args else ""
    text = _one_line(text).rstrip(".") or type(exc).__name__
    low = text.lower()
    if "index looks damaged" in low or "not indexed" in low or "header could not be read" in low:
        return (
            "the bag's index is missing or damaged (a truncated file or a recording that was "
            "killed?); in ROS1 'rosbag reindex' rebuilds it"
        )
    if "end magic" in low:
        return "the MCAP file is truncated or damaged (its end marker is missing)"
    if "malformed" in low or "not a database" in low:
        return "the sqlite3 file is truncated or damaged (database disk image is malformed)"
    if reading:
        return (
            f"cannot read message data ({text}, {type(exc).__name__}): "
            "the file is damaged or truncated"
        )
    return f"cannot read the bag: {text} ({type(exc).__name__})"


def _one_line(text: str, limit: int = 200) -> str:
    """A library's message as one short line (rosbags quotes whole message definitions)."""
    text = " ".join(text.split())
    return text if len(text) <= limit else text[:limit] + "..."


# --- the bag --------------------------------------------------------------------------------------


class Bag:
    """An open bag: its topics, time span, and a stream of deserialised messages.

    Use :func:`open_bag` to create one; close it (or use it as a context manager) to release the
    files and any temporary decompressed copy.

    Attributes
    ----------
    paths : tuple of Path
        What was opened, as given (one path, or the files of a split ROS1 recording).
    start_ns, end_ns : int
        Bag time of the first and of the last message, nanoseconds (UNIX or simulated time).
    topics : dict of str to TopicInfo
        Every topic in the bag, sorted by name, including skipped ones.
    skipped : dict of str to str
        Topics whose messages cannot be deserialised, with the reason.
    """

    def __init__(self, reader: AnyReader, source: _Source, stack: ExitStack) -> None:
        self._reader = reader
        self._stack = stack
        self.paths = source.paths
        self._given = {str(r): p for r, p in zip(source.read, source.paths, strict=True)}
        self.start_ns = int(reader.start_time)
        self.end_ns = int(reader.end_time) - 1  # rosbags' end is one past the last message
        self.topics = {
            name: TopicInfo(name, info.msgtype, int(info.msgcount))
            for name, info in reader.topics.items()
        }
        self._connections: dict[str, list[Connection]] = defaultdict(list)
        for conn in reader.connections:
            self._connections[conn.topic].append(conn)
        self.skipped: dict[str, str] = {}
        for name, conns in self._connections.items():
            for msgtype in sorted({c.msgtype for c in conns}):
                if reason := _undecodable(reader.typestore, msgtype):
                    self.skipped[name] = reason

    # context manager -------------------------------------------------------------------------

    def close(self) -> None:
        """Close the files and remove temporary copies (idempotent)."""
        self._stack.close()

    def __enter__(self) -> Bag:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # facts -----------------------------------------------------------------------------------

    @property
    def path(self) -> Path:
        """The path named in messages (the first one of a split set)."""
        return self.paths[0]

    @property
    def duration_s(self) -> float:
        """Seconds from the first to the last message."""
        return (self.end_ns - self.start_ns) / 1e9

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    def describe_topics(self) -> str:
        """All topics on one line: ``/scan (sensor_msgs/msg/LaserScan, 360), ...``."""
        parts = []
        for t in self.topics.values():
            note = ", cannot be decoded" if t.name in self.skipped else ""
            parts.append(f"{t.name} ({t.msgtype or 'mixed types'}, {t.count}{note})")
        return ", ".join(parts) if parts else "no topics"

    def topics_of_type(self, msgtypes: str | Iterable[str]) -> list[str]:
        """Decodable topics whose type is one of ``msgtypes``, sorted by name."""
        wanted = {msgtypes} if isinstance(msgtypes, str) else set(msgtypes)
        return [
            t.name
            for t in self.topics.values()
            if t.msgtype in wanted and t.name not in self.skipped
        ]

    def require(self, topic: str, msgtypes: str | Iterable[str] | None = None) -> TopicInfo:
        """The topic's info, or an InputError if it is missing, skipped or of another type."""
        info = self.topics.get(topic)
        if info is None and not topic.startswith("/"):
            info = self.topics.get("/" + topic)
        if info is None:
            raise InputError(
                self.path, f"no topic {topic!r} in the bag; it has: {self.describe_topics()}"
            )
        if info.name in self.skipped:
            raise InputError(
                self.path, f"topic {info.name!r} cannot be read: {self.skipped[info.name]}"
            )
        if msgtypes is not None:
            wanted = {msgtypes} if isinstance(msgtypes, str) else set(msgtypes)
            if info.msgtype not in wanted:
                raise InputError(
                    self.path,
                    f"topic {info.name!r} is {info.msgtype}, "
                    f"expected {' or '.join(sorted(wanted))}",
                )
        return info

    def pick_topic(self, msgtypes: str | Iterable[str], topic: str | None = None) -> TopicInfo:
        """The topic to read: ``topic`` if given (checked), else the only one of ``msgtypes``.

        Raises
        ------
        InputError
            No topic of these types (the message lists what the bag has), or several and none
            chosen (the message lists them).
        """
        wanted = [msgtypes] if isinstance(msgtypes, str) else sorted(msgtypes)
        if topic is not None:
            return self.require(topic, wanted)
        found = self.topics_of_type(wanted)
        if not found:
            raise InputError(
                self.path,
                f"no usable {' or '.join(wanted)} topic; the bag has: {self.describe_topics()}",
            )
        if len(found) > 1:
            raise InputError(
                self.path, f"several {' or '.join(wanted)} topics ({', '.join(found)}): pick one"
            )
        return self.topics[found[0]]

    def _conns(self, topics: str | Iterable[str]) -> tuple[list[str], list[Connection]]:
        names = [self.require(t).name for t in ([topics] if isinstance(topics, str) else topics)]
        if not names:
            raise InputError(self.path, "no topics asked for")
        return names, [c for n in dict.fromkeys(names) for c in self._connections[n]]

    # messages --------------------------------------------------------------------------------

    def _raw(
        self, conns: list[Connection], start_ns: int | None, end_ns: int | None
    ) -> Iterator[tuple[Connection, int, bytes]]:
        stop = None if end_ns is None else end_ns + 1  # rosbags' stop is exclusive
        try:
            it = self._reader.messages(conns, start=start_ns, stop=stop)
            while True:
                try:
                    item = next(it)
                except StopIteration:
                    return
                yield item
        except InputError:
            raise
        except Exception as exc:  # rosbags' backends raise many types mid-stream; name the file
            raise InputError(self._owner(conns), _explain(exc, reading=True)) from None

    def _owner(self, conns: list[Connection]) -> Path:
        """The file to name for an error: in a split set, the one holding these connections."""
        owner = conns[0].owner if conns else None
        if isinstance(owner, _Ros1Reader):
            return self._given.get(str(owner.path), self.path)
        return self.path

    def messages(
        self,
        topics: str | Iterable[str],
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[tuple[str, int, object]]:
        """Stream ``(topic, bag time ns, message)`` in bag-time order.

        Parameters
        ----------
        topics : str or iterable of str
            Topic names; each must exist and be decodable.
        start_ns, end_ns : int, optional
            Inclusive bag-time bounds in nanoseconds (see :func:`resolve_time`).

        Returns
        -------
        iterator of (str, int, object)
            Topic, record time (ns), and the message object rosbags deserialised (fields as
            attributes, numeric arrays as numpy arrays). Messages of two bags never compare
            equal, even with equal fields: each bag has its own generated classes.

        Raises
        ------
        InputError
            Unknown or skipped topic (at the call), or data that cannot be read (truncated,
            damaged; while iterating).
        """
        _, conns = self._conns(topics)  # checked now, not at the first next()
        return self._decoded(conns, start_ns, end_ns)

    def _decoded(
        self, conns: list[Connection], start_ns: int | None, end_ns: int | None
    ) -> Iterator[tuple[str, int, object]]:
        deserialize = self._reader.deserialize
        for conn, t_ns, raw in self._raw(conns, start_ns, end_ns):
            try:
                msg = deserialize(raw, conn.msgtype)
            except Exception as exc:  # a damaged message: its bytes do not fit the definition
                raise InputError(
                    self._owner([conn]),
                    f"message on {conn.topic} at {(t_ns - self.start_ns) / 1e9:.3f} s cannot be "
                    f"decoded as {conn.msgtype} ({_one_line(str(exc)) or type(exc).__name__})",
                ) from None
            yield conn.topic, int(t_ns), msg

    def count(
        self,
        topics: str | Iterable[str],
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> dict[str, int]:
        """Messages per topic in ``[start_ns, end_ns]`` (from the index for the whole bag)."""
        names, conns = self._conns(topics)
        if start_ns is None and end_ns is None:
            return {n: self.topics[n].count for n in names}
        counts = dict.fromkeys(names, 0)
        for conn, _, _ in self._raw(conns, start_ns, end_ns):
            counts[conn.topic] += 1
        return counts

    def require_messages(
        self,
        topics: str | Iterable[str],
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> None:
        """Raise InputError unless at least one message of ``topics`` lies in the range.

        Reads at most one message, so it is cheap on any bag.
        """
        names, conns = self._conns(topics)
        for _ in self._raw(conns, start_ns, end_ns):
            return
        lo = self.start_ns if start_ns is None else start_ns
        hi = self.end_ns if end_ns is None else end_ns
        span = f"the bag spans 0 to {self.duration_s:.3f} s"
        if lo > self.end_ns:
            why = "the time range starts after the bag's last message"
        elif hi < self.start_ns:
            why = "the time range ends before the bag's first message"
        elif lo > hi:
            why = "the time range ends before it starts"
        else:
            why = (
                f"between {(lo - self.start_ns) / 1e9:.3f} s and "
                f"{(hi - self.start_ns) / 1e9:.3f} s from the bag start"
            )
        raise InputError(self.path, f"no messages on {', '.join(names)}: {why} ({span})")

    def frame_ids(self, topic: str, max_messages: int = 20) -> frozenset[str]:
        """Frame names used by the first messages of a topic, leading slashes removed.

        ``header.frame_id`` for stamped messages (and ``child_frame_id`` for odometry); parent
        and child frames for tf messages.
        """
        frames: set[str] = set()
        for n, (_, _, msg) in enumerate(self.messages(topic)):
            if n >= max_messages:
                break
            m = cast(Any, msg)
            for tf in getattr(m, "transforms", ()):
                frames.update((tf.header.frame_id, tf.child_frame_id))
            if header := getattr(m, "header", None):
                frames.add(header.frame_id)
            if child := getattr(m, "child_frame_id", None):
                frames.add(child)
        return frozenset(normalise_frame(f) for f in frames if normalise_frame(f))


def _undecodable(typestore: Typestore, msgtype: str) -> str | None:
    """Why messages of this type cannot be deserialised, or None if they can."""
    try:
        typestore.get_msgdef(msgtype)
    except KeyError as exc:
        missing = exc.args[0] if exc.args else msgtype
        if missing == msgtype:
            return f"message type {msgtype} has no definition in the bag nor in ROS 2 Humble"
        return f"the definition of {msgtype} needs {missing}, which is not defined"
    except Exception as exc:  # rosbags' code generator rejecting a definition
        return f"the definition of {msgtype} cannot be used ({_one_line(str(exc))})"
    return None


def _culprit(source: _Source, default: Path) -> Path:
    """Which file of a split ROS1 set fails to open on its own (the first one if none does)."""
    if len(source.paths) == 1:
        return default
    for given, read in zip(source.paths, source.read, strict=True):
        reader = _Ros1Reader(read)
        try:
            reader.open()
        except Exception:  # the same failure as in open_bag, now attributed to one file
            return given
        reader.close()
    return default


def open_bag(path: Path | str | Sequence[Path | str]) -> Bag:
    """Open a ROS1 or ROS 2 bag for reading.

    Parameters
    ----------
    path : Path, str, or sequence of them
        A ROS1 ``.bag``; several ``.bag`` files of a split recording (or a folder of them); a
        rosbag2 folder (or its ``metadata.yaml``); a standalone ``.db3``, ``.mcap``,
        ``.mcap.zstd`` or ``.db3.zstd`` file.

    Returns
    -------
    Bag
        Open; close it or use ``with open_bag(p) as bag:``.

    Raises
    ------
    InputError
        Missing, not a bag, legacy format, truncated or damaged, or without messages.

    Warns
    -----
    BagWarning
        Topics that cannot be decoded (listed in ``Bag.skipped``), or a ROS1 index that had to be
        rebuilt from the chunks.
    """
    stack = ExitStack()
    try:
        source = _source(path, stack)
        where = source.paths[0]
        try:
            reader = AnyReader(list(source.read), default_typestore=_default_typestore())
            if not reader.is2:
                reader.readers = [_Ros1Reader(p) for p in source.read]
            reader.open()
        except Exception as exc:  # AssertionError, struct.error, apsw, mcap... name the file
            raise InputError(_culprit(source, where), _explain(exc)) from None
        stack.callback(reader.close)
        if reader.message_count == 0:
            raise InputError(where, "the bag holds no messages")
        bag = Bag(reader, source, stack)
    except BaseException:
        stack.close()
        raise
    for r, p in zip(reader.readers, source.paths, strict=True):
        if isinstance(r, _Ros1Reader) and r.rebuilt_chunks:
            warnings.warn(
                BagWarning(
                    f"{p}: the bag's index does not match its data (an old rosbag writer bug); "
                    f"rebuilt it from {len(r.rebuilt_chunks)} chunk(s). 'rosbag reindex' in "
                    "ROS1 fixes the file"
                ),
                stacklevel=2,
            )
    if bag.skipped:
        listed = "; ".join(f"{t}: {why}" for t, why in bag.skipped.items())
        warnings.warn(BagWarning(f"{bag.path}: skipping topics: {listed}"), stacklevel=2)
    return bag


def resolve_time(value: str | float | None, bag: Bag) -> int | None:
    """A user-given time as bag time in nanoseconds (None stays None: no bound).

    Parameters
    ----------
    value : str, float or None
        Seconds. ``>= 1e9`` is an absolute UNIX time; smaller values count from the bag's first
        message (``"12.5"`` is 12.5 s into the bag).
    bag : Bag
        The bag the time refers to.

    Returns
    -------
    int or None
        Nanoseconds, clamped to ``[start_ns - 1, end_ns + 1]``: a bound before the bag admits
        every message from its start, one after it every message to its end, and a range that
        lies outside the bag is empty (see :meth:`Bag.require_messages`).

    Raises
    ------
    InputError
        Not a number.
    """
    if value is None:
        return None
    try:  # Decimal keeps "1663929585.503548227" exact, float would round it to ~200 ns
        seconds = Decimal(value if isinstance(value, str) else repr(float(value)))
    except (InvalidOperation, TypeError, ValueError):
        raise InputError(None, f"time {value!r} is not a number of seconds") from None
    if not seconds.is_finite():
        raise InputError(None, f"time {value!r} is not a finite number of seconds")
    ns = int((seconds * 1_000_000_000).to_integral_value())
    if seconds < ABSOLUTE_TIME_S:
        ns += bag.start_ns
    return min(max(ns, bag.start_ns - 1), bag.end_ns + 1)
