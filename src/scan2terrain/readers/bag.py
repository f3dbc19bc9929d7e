"""ROS bags in, deserialised messages out: ROS1 ``.bag`` files and rosbag2 recordings, no ROS.

Everything is read through :class:`rosbags.highlevel.AnyReader`, with ROS 2 Humble's message
definitions as the fallback for bags that carry none (old sqlite3 rosbag2). This module is the
API: :func:`open_bag`, :class:`Bag` (topics, time span, messages) and :func:`resolve_time`. What
a path may name and how it is handed to rosbags (format sniffing, only regular files, capped zstd
decompression, temporary folders) is in :mod:`scan2terrain.readers._bag_source`; the wording of
rosbags' failures and the defects of old ROS1 bags that are read anyway (broken chunk indexes,
``roslib/Header``) in :mod:`scan2terrain.readers._bag_errors`. Choices:

* **Errors.** Every failure is one :class:`~scan2terrain.errors.InputError` naming the file:
  missing, not a bag, the pre-2010 ``#ROSRECORD V1.2`` format, a truncated or damaged file
  (rosbags raises many exception types, some only while iterating, so iteration is wrapped
  too), a topic that does not exist (the message lists the ones there are), a time range without
  messages (:meth:`Bag.require_messages`).
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

import os
import warnings
from collections import defaultdict
from collections.abc import Iterable, Iterator, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol, cast

from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection
from rosbags.interfaces import TopicInfo as _RosbagsTopic
from rosbags.rosbag2.reader import DirectoryReader
from rosbags.rosbag2.storage_mcap import McapReader
from rosbags.typesys import Stores, get_typestore

from scan2terrain.errors import InputError, shown
from scan2terrain.readers._bag_errors import (
    Ros1Reader,
    _storage,
    _undecodable,
    culprit,
    explain,
    one_line,
)
from scan2terrain.readers._bag_source import Source, _source
from scan2terrain.readers._files import regular_file
from scan2terrain.readers._mcap import McapFile, mcap_profile
from scan2terrain.readers._mcap_layout import DAMAGED, Damaged
from scan2terrain.readers._mcap_rosbags import CheckedMcapReader
from scan2terrain.readers.carmen import CarmenFile, is_carmen_log, named_like_log
from scan2terrain.readers.messages import (
    LASER_SCAN,
    MAP_TYPES,
    OCCUPANCY_GRID,
    ODOMETRY,
    ODOMETRY_TYPES,
    POINT_CLOUD2,
    SCAN_TYPES,
    TF_MESSAGE,
    TF_MESSAGE_ROS1_OLD,
    TF_TYPES,
    resolve_time,
)
from scan2terrain.types import normalise_frame

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping

    from rosbags.typesys.store import Typestore

__all__ = [
    "LASER_SCAN",
    "MAP_TYPES",
    "OCCUPANCY_GRID",
    "ODOMETRY",
    "ODOMETRY_TYPES",
    "POINT_CLOUD2",
    "SCAN_TYPES",
    "TF_MESSAGE",
    "TF_MESSAGE_ROS1_OLD",
    "TF_TYPES",
    "Bag",
    "BagWarning",
    "Container",
    "TopicInfo",
    "open_bag",
    "resolve_time",
]


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


# --- the readers behind a bag ---------------------------------------------------------------------


class _Reader(Protocol):
    """What :class:`Bag` reads through: rosbags' ``AnyReader`` (:class:`_Rosbags`) or, for MCAP
    files that are not rosbag2's, :class:`~scan2terrain.readers._mcap.McapFile`, or for CARMEN
    logs :class:`~scan2terrain.readers.carmen.CarmenFile`."""

    @property
    def start_time(self) -> int: ...
    @property
    def end_time(self) -> int: ...  # one past the last message
    @property
    def topics(self) -> Mapping[str, _RosbagsTopic]: ...
    @property
    def connections(self) -> list[Connection]: ...
    # The raw item is the message's bytes (rosbags, MCAP), or its index (a CARMEN log): only
    # ``decode`` looks at it.
    def messages(
        self,
        connections: Collection[Connection] = (),
        start: int | None = None,
        stop: int | None = None,
    ) -> Iterator[tuple[Connection, int, Any]]: ...
    def decode(self, conn: Connection, raw: Any) -> object: ...
    def undecodable(self, conn: Connection) -> str | None: ...


class _Rosbags(AnyReader):
    """rosbags' AnyReader with the two calls :class:`_Reader` adds: decoding by connection
    (ROS1 or CDR as the bag is), and why a connection's type cannot be decoded."""

    def decode(self, conn: Connection, raw: bytes | memoryview) -> object:
        if self.is2:
            return self.typestore.deserialize_cdr(raw, conn.msgtype)
        return self.typestore.deserialize_ros1(raw, conn.msgtype)

    def undecodable(self, conn: Connection) -> str | None:
        return _undecodable(self.typestore, conn.msgtype)


@dataclass(frozen=True)
class Container:
    """What kind of file a bag is, and per topic how it is encoded and read (for ``inspect``).

    Attributes
    ----------
    kind : str
        ``ROS1 bag``, ``rosbag2``, ``MCAP``, or ``CARMEN log``.
    profile : str or None
        An MCAP file's header profile (``ros1``, ``ros2``, ``""``); None for the others.
    reader : str
        Which code reads it: ``rosbags`` or ``mcap`` (the ``mcap`` package's records).
    encodings : dict of str to str
        Per topic (MCAP files read with ``mcap``, CARMEN logs): ``"ros1 / ros1msg
        sensor_msgs/LaserScan, decoded as ROS1 (rosbags)"`` or the reason it is not read; what a
        CARMEN log's topic is made of.
    detail : str
        More on the file (a CARMEN log's lines and the records not used), or "".
    notes : tuple of str
        What the plan is to say of the recording (a CARMEN log's mounts, raw or corrected
        poses, timestamps that step back).
    """

    kind: str
    profile: str | None
    reader: str
    encodings: dict[str, str]
    detail: str = ""
    notes: tuple[str, ...] = ()

    def describe(self) -> str:
        """One line: ``MCAP, profile 'ros1', read with mcap``."""
        profile = "" if self.profile is None else f", profile {self.profile!r}"
        detail = f" ({self.detail})" if self.detail else ""
        return f"{self.kind}{profile}{detail}, read with {self.reader}"


def _container(reader: _Reader, source: Source) -> Container:
    if isinstance(reader, CarmenFile):
        return Container(
            "CARMEN log", None, "scan2terrain (text, line by line)", reader.encodings(),
            reader.described, tuple(reader.notes),
        )  # fmt: skip
    if isinstance(reader, McapFile):
        encodings: dict[str, str] = {}
        for conn in reader.connections:
            message, schema_name, schema = reader.encodings(conn)
            why = reader.undecodable(conn)
            how = f"not read: {why}" if why else f"decoded as {reader.decoder_label(conn)}"
            text = f"{message} / {schema or 'no schema'} {schema_name}".rstrip()
            encodings.setdefault(conn.topic, f"{text}, {how}")
        return Container("MCAP", reader.profile, "mcap", encodings)
    read = source.read[0]
    if read.is_dir():
        return Container("rosbag2", None, "rosbags", {})
    if read.suffix == ".mcap":
        return Container("MCAP", mcap_profile(read), "rosbags", {})
    return Container("ROS1 bag" if read.suffix == ".bag" else "rosbag2", None, "rosbags", {})


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

    def __init__(self, reader: _Reader, source: Source, stack: ExitStack) -> None:
        self._reader = reader
        self.container = _container(reader, source)
        self._stack = stack
        self.paths = source.paths
        self._given = {str(r): p for r, p in zip(source.read, source.paths, strict=True)}
        self._storage = _storage(source.read[0])  # for naming it in errors
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
            for conn in sorted(conns, key=lambda c: c.msgtype):
                if reason := reader.undecodable(conn):
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
            kind = shown(t.msgtype) if t.msgtype else "mixed types"
            parts.append(f"{shown(t.name)} ({kind}, {t.count}{note})")
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
        """The topic's info, or an InputError if it is missing, skipped or of another type.

        ``topic`` may be given with or without its leading slash (``/scan`` and ``scan`` name
        the same topic, as frame names do: ROS1 bags record ``/scan``, Foxglove MCAP channels
        often ``scan``); a topic recorded under exactly the given name comes first.
        """
        info = self.topics.get(topic)
        if info is None:
            key = topic.strip().lstrip("/")
            same = [t for name, t in self.topics.items() if name.lstrip("/") == key]
            if len(same) > 1:
                raise InputError(
                    self.path,
                    f"topic {topic!r} could be {' or '.join(repr(t.name) for t in same)}: "
                    "give it as recorded",
                )
            info = same[0] if same else None
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
    ) -> Iterator[tuple[Connection, int, bytes | memoryview]]:
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
        except Damaged as exc:
            raise InputError(self._owner(conns), f"{DAMAGED}: {exc}") from None
        except Exception as exc:  # rosbags' backends raise many types mid-stream; name the file
            problem = explain(exc, reading=True, storage=self._storage)
            raise InputError(self._owner(conns), problem) from exc

    def _owner(self, conns: list[Connection]) -> Path:
        """The file to name for an error: in a split set, the one holding these connections."""
        owner = conns[0].owner if conns else None
        if isinstance(owner, Ros1Reader):
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
        for conn, t_ns, raw in self._raw(conns, start_ns, end_ns):
            yield conn.topic, int(t_ns), self.decode(conn, t_ns, raw)

    def raw_messages(
        self,
        topics: str | Iterable[str],
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[tuple[Connection, int, Any]]:
        """:meth:`messages` undecoded: ``(connection, bag time ns, raw)`` in the same order, raw
        as the reader holds it (the message's bytes, or a CARMEN log's record index); give it
        to :meth:`decode`, or read it as :meth:`wire` says. Errors as :meth:`messages`."""
        _, conns = self._conns(topics)
        return self._raw(conns, start_ns, end_ns)

    def decode(self, conn: Connection, t_ns: int, raw: Any) -> object:
        """One message of :meth:`raw_messages` as :meth:`messages` gives it.

        Raises
        ------
        InputError
            Bytes that do not fit the message definition, naming the topic and time.
        """
        try:
            return self._reader.decode(conn, raw)
        except Exception as exc:  # a damaged message: its bytes do not fit the definition
            raise InputError(
                self._owner([conn]),
                f"message on {shown(conn.topic)} at {(t_ns - self.start_ns) / 1e9:.3f} s "
                f"cannot be decoded as {conn.msgtype} "
                f"({one_line(str(exc)) or type(exc).__name__})",
            ) from exc

    def wire(self, conn: Connection) -> tuple[str, Typestore] | None:
        """How a connection's raw messages are serialised when rosbags decodes them from bytes:
        ``("ros1" or "cdr", the typestore decoding them)``; None for other readers (MCAP files
        read with ``mcap``, CARMEN logs), whose raw items only :meth:`decode` reads."""
        if isinstance(self._reader, _Rosbags):
            return ("cdr" if self._reader.is2 else "ros1"), self._reader.typestore
        return None

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


def open_bag(path: Path | str | Sequence[Path | str]) -> Bag:
    """Open a ROS1 or ROS 2 bag for reading.

    Parameters
    ----------
    path : Path, str, or sequence of them
        A ROS1 ``.bag``; several ``.bag`` files of a split recording (or a folder of them); a
        rosbag2 folder (or its ``metadata.yaml``); a standalone ``.db3``, ``.mcap``,
        ``.mcap.zstd`` or ``.db3.zstd`` file; a CARMEN log (``.clf``, ``.log``, plain, ``.gz``
        or ``.bz2``, :mod:`scan2terrain.readers.carmen`).

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
        carmen = _carmen_log(path)
        source = Source((carmen,), (carmen,)) if carmen else _source(path, stack)
        where = source.paths[0]
        reader: _Rosbags | McapFile | CarmenFile
        if carmen is not None:
            reader = CarmenFile(carmen)
        elif len(source.read) == 1 and mcap_profile(source.read[0]) not in (None, "ros2"):
            reader = McapFile(source.read[0], where)  # rosbags reads only profile ros2
        else:
            try:
                reader = _Rosbags(list(source.read), default_typestore=_default_typestore())
                if not reader.is2:
                    reader.readers = [Ros1Reader(p) for p in source.read]
                _check_mcap(reader)
                reader.open()
            except Damaged as exc:
                raise InputError(where, f"{DAMAGED}: {exc}") from None
            except Exception as exc:  # AssertionError, struct.error, apsw, mcap... name the file
                problem = explain(exc, storage=_storage(source.read[0]))
                raise InputError(culprit(source, where), problem) from exc
        stack.callback(reader.close)
        if reader.message_count == 0:
            raise InputError(where, "the bag holds no messages")
        bag = Bag(reader, source, stack)
    except BaseException:
        stack.close()
        raise
    readers = reader.readers if isinstance(reader, _Rosbags) else [reader]
    for r, p in zip(readers, source.paths, strict=True):
        if isinstance(r, Ros1Reader) and r.rebuilt_chunks:
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


def _check_mcap(reader: _Rosbags) -> None:
    """rosbags' MCAP storage replaced by :class:`~._mcap_rosbags.CheckedMcapReader` (every
    length checked against its chunk and the file) in ``reader``, before it is opened."""
    if not reader.is2:
        return
    for r in reader.readers:
        storage = getattr(r, "storage", None)
        if type(storage) is McapReader:
            r.storage = CheckedMcapReader(storage.path)  # type: ignore[union-attr]
        elif isinstance(storage, DirectoryReader):  # opens its storage files from this table
            plugins = {**storage.STORAGE_PLUGINS, "mcap": CheckedMcapReader}
            storage.STORAGE_PLUGINS = plugins


def _carmen_log(path: Path | str | Sequence[Path | str]) -> Path | None:
    """The CARMEN log ``path`` names (:func:`~scan2terrain.readers.carmen.is_carmen_log`), or
    None; several paths of which one is a log are refused (a log is read alone)."""
    items = [Path(path)] if isinstance(path, (str, os.PathLike)) else [Path(p) for p in path]
    for p in items:
        if named_like_log(p):  # missing, a folder, a FIFO: said now, as a log's problem
            regular_file(p, "CARMEN log")
    logs = [p for p in items if is_carmen_log(p)]
    if logs and len(items) > 1:
        raise InputError(logs[0], "a CARMEN log is read alone: give one log, not several paths")
    return logs[0] if logs else None
