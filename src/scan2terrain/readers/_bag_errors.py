"""How reading a bag fails, in words, and the defects of old ROS1 bags that are read anyway.

:func:`_explain` puts an exception of rosbags (or of its sqlite/mcap/zstd backends) in one line,
:func:`_culprit` finds the file of a split ROS1 recording to name, :func:`_undecodable` says why
a message type cannot be deserialised; all for :mod:`scan2terrain.readers.bag`. Choices:

* **Broken ROS1 indexes are rebuilt.** Some old rosbag writers (e.g. the 2010 CCNY demo bag)
  wrote ``IDXDATA`` records whose declared length does not match their entries; rosbags then
  fails with a bare ``AssertionError``. The per-chunk index only says where each message sits in
  its chunk, so when rosbags rejects it, :class:`_Ros1Reader` walks that chunk's records
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

from scan2terrain.readers._bag_source import _Source

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

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


# --- rosbags' failures, in words ------------------------------------------------------------------


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
