"""How reading a bag fails, in words, and the defects of old ROS1 bags that are read anyway.

:func:`explain` puts an exception of rosbags (or of its sqlite/mcap/zstd backends) in one
sentence of ours naming what holds the bag (the ROS1 bag, the MCAP file, the sqlite3 file), never
Python's own words ("ord() expected a character...", "unpack requires a buffer..."),
:func:`culprit` finds the file of a split ROS1 recording to name, :func:`_undecodable` says why
a message type cannot be deserialised; all for :mod:`scan2terrain.readers.bag`. Choices:

* **Broken ROS1 indexes are rebuilt.** Some old rosbag writers (e.g. the 2010 CCNY demo bag)
  wrote ``IDXDATA`` records whose declared length does not match their entries; rosbags then
  fails with a bare ``AssertionError``. The per-chunk index only says where each message sits in
  its chunk, so when rosbags rejects it, :class:`Ros1Reader` walks that chunk's records
  instead (a few dozen lines, the layout rosbags' own reader parses) and a
  :class:`~scan2terrain.readers.bag.BagWarning` says so. Bags whose *file-level* index is
  missing (a killed recording, a truncated copy) are refused with the ROS1 fix
  (``rosbag reindex``): rebuilding the chunk list as well would be a reimplementation of
  ``rosbag reindex``.
* **Old ROS1 definitions.** Bags from ROS C-Turtle (2010) define ``Header`` as
  ``roslib/Header``; rosbags resolves ``Header`` to ``std_msgs/Header`` and fails. The
  definition text is renamed when it is read (same fields, same MD5).
"""

from __future__ import annotations

import os
import re
import struct
from io import BytesIO
from pathlib import Path
from typing import TYPE_CHECKING

from rosbags.interfaces import Connection, MessageDefinition
from rosbags.rosbag1 import Reader as _RosbagsReader1
from rosbags.rosbag1.reader import Header as _Ros1Header
from rosbags.rosbag1.reader import IndexData as _IndexData
from rosbags.rosbag1.reader import RecordType as _Ros1Record
from rosbags.rosbag1.reader import read_bytes as _read_bytes
from rosbags.rosbag1.reader import read_uint32 as _read_uint32

from scan2terrain.readers._bag_source import Source

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

# --- ROS1: the rosbags reader, with an index rebuilt from the chunks where it is broken -----------


class Ros1Reader(_RosbagsReader1):
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


# --- rosbags' failures, in words ------------------------------------------------------------------

#: What holds a bag's records, by the suffix rosbags dispatches on.
_STORAGE_BY_SUFFIX = {".bag": "ros1", ".mcap": "mcap", ".db3": "sqlite3"}
#: How a message names the file of each storage.
_NOUN = {"ros1": "the ROS1 bag", "mcap": "the MCAP file", "sqlite3": "the sqlite3 file"}
#: rosbags' (and its backends') complaints about a file, as our sentences: (pattern matched in
#: the exception's text, storage it applies to or None for any, sentence; ``{noun}`` and the
#: pattern's groups are filled in). The first match wins.
_SENTENCES: tuple[tuple[str, str | None, str], ...] = (
    (
        r"index looks damaged|not indexed|header could not be read",
        None,
        "the bag's index is missing or damaged (a truncated file or a recording that was "
        "killed?); in ROS1 'rosbag reindex' rebuilds it",
    ),
    (r"end magic", None, "the MCAP file is truncated or damaged (its end marker is missing)"),
    (r"seems to be empty", None, "{noun} is empty"),
    (
        r"ord\(\) expected a character",
        "mcap",
        "{noun} is truncated or damaged: it ends after its magic",
    ),
    (
        r"ord\(\) expected a character",
        None,
        "{noun} is truncated: it ends where a record should begin",
    ),
    (
        r"file magic is invalid",
        "mcap",
        "{noun} is truncated or damaged: it does not start with the MCAP magic",
    ),
    (
        r"file magic is invalid",
        "ros1",
        "{noun} is truncated or damaged: its first line is not '#ROSBAG V2.0'",
    ),
    (
        r"truncated record at offset (\d+): expected (\d+) bytes, got (\d+)",
        None,
        "{noun} is truncated or damaged: the record at byte {0} needs {1} bytes, {2} are left",
    ),
    (r"unexpected record", "mcap", "{noun} is damaged: its first record is not a header"),
    (
        r"could not read \w+ field|header field could not be parsed",
        None,
        "{noun} is damaged: a record header cannot be parsed",
    ),
    (
        r"missing tables",
        None,
        "the sqlite3 file is empty or not a rosbag2 database (its tables are missing)",
    ),
    (
        r"malformed|not a database|cannot open database",
        None,
        "the sqlite3 file is truncated or damaged (database disk image is malformed)",
    ),
)


def _storage(read: Path) -> str | None:
    """``ros1``, ``mcap`` or ``sqlite3``: what holds the records of a path rosbags opens (a
    file, or a rosbag2 folder's storage files); None when that cannot be told."""
    try:
        files = sorted(read.iterdir()) if read.is_dir() else [read]
    except OSError:
        return None
    kinds = {_STORAGE_BY_SUFFIX.get(p.suffix) for p in files} - {None}
    return kinds.pop() if len(kinds) == 1 else None


def explain(exc: BaseException, *, reading: bool = False, storage: str | None = None) -> str:
    """One sentence for an exception raised by rosbags (or its sqlite/mcap/zstd backends).

    ``reading``: raised while streaming messages, after the bag opened fine. ``storage``: what
    holds the bag's records (:func:`_storage`), for naming it. Known complaints become our own
    sentences (:data:`_SENTENCES`); rosbags' other sentences are quoted as its words; what
    Python itself raised inside rosbags (a ``TypeError``, ``struct.error``...) is not shown:
    it would tell a user nothing (``-v`` prints the traceback).
    """
    noun = _NOUN.get(storage or "", "the bag")
    if isinstance(exc, MemoryError):  # a length field read as gigabytes
        return (
            f"{noun} is damaged: a record claims more bytes than can be allocated (a corrupt "
            "length field)"
        )
    if isinstance(exc, UnicodeError):  # its args hold the whole undecodable bytes
        return f"{noun} is damaged: it holds text (a name or a definition) that is not UTF-8"
    text = " ".join(str(a) for a in exc.args) if exc.args else ""
    text = one_line(text).rstrip(".")
    for pattern, only, sentence in _SENTENCES:
        if only not in (None, storage):
            continue
        if found := re.search(pattern, text, re.IGNORECASE):
            return sentence.format(*found.groups(), noun=noun)
    # Python's own exceptions (builtins, struct.error) say nothing about the file.
    raw = type(exc).__module__ == "builtins" or isinstance(exc, struct.error)
    if _decompression_failed(exc):
        detail = " (a compressed chunk does not decompress)"
    elif raw or not text:
        detail = ""
    else:
        detail = f" (rosbags: {text!r})"
    if reading:
        return f"cannot read message data: the file is damaged or truncated{detail}"
    if detail:
        return f"cannot read {noun}{detail}"
    return f"{noun} is truncated or damaged: rosbags cannot parse it (-v shows where it fails)"


def _decompression_failed(exc: BaseException) -> bool:
    """A chunk's bz2, lz4 or zstd data that does not decompress."""
    name = type(exc).__name__
    return name == "ZstdError" or "lz4" in type(exc).__module__ or "data stream" in str(exc)


def one_line(text: str, limit: int = 200) -> str:
    """A library's message as one short line (rosbags quotes whole message definitions)."""
    text = " ".join(text.split())
    return text if len(text) <= limit else text[:limit] + "..."


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
        return f"the definition of {msgtype} cannot be used ({one_line(str(exc))})"
    return None


def culprit(source: Source, default: Path) -> Path:
    """Which file of a split ROS1 set fails to open on its own (the first one if none does)."""
    if len(source.paths) == 1:
        return default
    for given, read in zip(source.paths, source.read, strict=True):
        reader = Ros1Reader(read)
        try:
            reader.open()
        except Exception:  # the same failure as in open_bag, now attributed to one file
            return given
        reader.close()
    return default
