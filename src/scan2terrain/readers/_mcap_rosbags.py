"""rosbags' MCAP storage (rosbag2's ``ros2`` profile) with the length checks of
:mod:`scan2terrain.readers._mcap_layout`, for :func:`scan2terrain.readers.bag.open_bag`.

rosbags reads a chunk with the sizes its chunk index states, skips the records it does not use
by seeking (past the end of a chunk's bytes without noticing) and never reads a chunk record's
own length: a chunk whose record claimed a terabyte, whose stated size disagreed with its data,
or whose records ran past its end, was read as valid from whatever was left (a world written
from the scans before a damaged record). :class:`CheckedMcapReader` checks, before rosbags
parses the file, that every top-level record lies inside the file and every chunk's records
inside its chunk record; that its chunk index names exactly the chunks there are, with their
lengths, compressions and sizes; and reads each chunk itself when messages are asked for
(:func:`~._mcap_layout.read_chunk`, the capped decompression and CRC of
:func:`~._mcap_layout.chunk_bytes`, :func:`~._mcap_layout._split`): each record inside its
chunk. Messages come in rosbags' own order (the same merge of the same tuples), so outputs do
not change. A file without a chunk index, which rosbags scans, has every chunk checked when it
is opened. Damage is a :class:`~._mcap_layout.Damaged`, said in one line by ``open_bag``.
"""

from __future__ import annotations

import heapq
import struct
from collections.abc import Collection, Generator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from mcap.opcode import Opcode
from rosbags.rosbag2.storage_mcap import ChunkInfo, McapReader, Msg

from scan2terrain.readers._mcap_layout import (
    CHUNK_HEAD,
    MAGIC,
    OPLEN,
    Damaged,
    _records,
    _split,
    chunk_bytes,
    read_chunk,
)

if TYPE_CHECKING:
    from rosbags.interfaces import Connection


@dataclass(frozen=True)
class _ChunkHead:
    """What a chunk record says of itself: its record's length, compression, compressed and
    uncompressed sizes."""

    length: int
    compression: str
    compressed: int
    size: int


class CheckedMcapReader(McapReader):
    """rosbags' :class:`~rosbags.rosbag2.storage_mcap.McapReader`, every length checked."""

    def open(self) -> None:
        heads = self._walk()
        super().open()
        indexed = {c.chunk_start_offset: c for c in self.chunks}
        if not self.chunks:  # rosbags scans the chunks: their records are checked now
            for at in heads:
                for _ in _split(self._chunk_records(at, None), at):
                    pass
            return
        if set(indexed) != set(heads):
            lost = sorted(set(heads) - set(indexed))
            stray = sorted(set(indexed) - set(heads))
            raise Damaged(
                f"its chunk index does not match its chunks (chunks at byte {lost[:3]} not "
                f"indexed, indexed chunks at byte {stray[:3]} not there)"
                if lost and stray
                else f"the chunk at byte {lost[0]} is not in its chunk index"
                if lost
                else f"its chunk index names a chunk at byte {stray[0]}, where there is none"
            )
        for at, chunk in indexed.items():
            _agrees(at, heads[at], chunk)

    def _walk(self) -> dict[int, _ChunkHead]:
        """Every top-level record inside the file, every chunk's data inside its record: the
        chunks by offset. A file without its magic or footer is left to rosbags, which says
        what is wrong."""
        with self.path.open("rb") as f:
            size = f.seek(0, 2)
            footer_at = size - 8 - 9 - 20
            f.seek(0)
            if f.read(8) != MAGIC or footer_at < 8:
                return {}
            f.seek(footer_at)
            tail = f.read(9 + 20 + 8)
            if tail[:9] != OPLEN.pack(Opcode.FOOTER, 20) or tail[-8:] != MAGIC:
                return {}
            heads = {}
            for at, opcode, length in _records(f, 8, footer_at):
                if opcode != Opcode.CHUNK:
                    continue
                head = f.read(min(length, CHUNK_HEAD.size + 256))
                heads[at] = _head(at, length, head)
            return heads

    def _chunk_records(self, at: int, index: ChunkInfo | None) -> memoryview:
        """The records of the chunk at byte ``at``: its record read whole, agreeing with its
        ``index`` entry, decompressed and checked (:func:`~._mcap_layout._split` then checks
        each record inside it)."""
        assert self.bio is not None
        self.bio.seek(at)
        head = self.bio.read(9)
        if len(head) < 9:
            raise Damaged(f"the chunk at byte {at} is past the end of the file")
        opcode, length = OPLEN.unpack(head)
        if opcode != Opcode.CHUNK or (index is not None and 9 + length != index.chunk_length):
            raise Damaged(
                f"the chunk index points at byte {at}, where there is a record of opcode "
                f"{opcode} and {9 + length:,} bytes, not its chunk"
            )
        body = self.bio.read(length)
        if len(body) != length:
            raise Damaged(
                f"the chunk at byte {at} claims {length:,} bytes, the file holds {len(body):,}"
            )
        chunk = read_chunk(body, at)
        if index is not None:
            _agrees(at, _ChunkHead(length, chunk.compression, len(chunk.data),
                                   chunk.uncompressed_size), index)  # fmt: skip
        return chunk_bytes(chunk, at)

    def _source(
        self, chunk: ChunkInfo, channel_map: dict[int, Connection], start: int, stop: int
    ) -> Generator[Msg, None, None]:
        """rosbags' ``msgsrc``: a chunk's messages in time order, after a first item at its
        start time, read only when the merge reaches it; the records checked."""
        yield Msg(chunk.message_start_time, 0, None, None)
        at = chunk.chunk_start_offset
        data = self._chunk_records(at, chunk)
        messages = []
        for op, body, end, t_ns in _split(data, at):
            if t_ns >= 0 and start <= t_ns < stop and (op >> 8) in channel_map:
                messages.append(Msg(t_ns, at, channel_map[op >> 8], bytes(data[body:end])))
        yield from sorted(messages, key=lambda x: x.timestamp)

    def messages(
        self,
        connections: Collection[Connection],
        start: int | None = None,
        stop: int | None = None,
    ) -> Generator[tuple[Connection, int, bytes], None, None]:
        """rosbags' ``McapReader.messages``, each chunk read by :meth:`_source`."""
        assert self.bio
        if not self.chunks:  # scanned by rosbags; every chunk was checked at open
            yield from super().messages(connections, start, stop)
            return
        channel_map = {conn.id: conn for conn in connections}
        chunks = [
            self._source(
                x,
                channel_map,
                x.message_start_time if start is None else start,
                x.message_end_time + 1 if stop is None else stop,
            )
            for x in self.chunks
            if (start is None or start < x.message_end_time + 1)
            and (stop is None or x.message_start_time < stop)
            and (any(x.channel_count.get(cid, 0) for cid in channel_map))
        ]
        for timestamp, offset, connection, data in heapq.merge(*chunks):
            if not offset:
                continue
            assert connection
            assert data is not None
            yield connection, timestamp, data


def _head(at: int, length: int, head: bytes) -> _ChunkHead:
    """A chunk record's head (``head``: its first bytes) checked against its ``length``."""
    where = f"the chunk at byte {at}"
    if len(head) < CHUNK_HEAD.size:
        raise Damaged(f"{where} is cut short ({length:,} bytes)")
    _, _, size, _, n = CHUNK_HEAD.unpack_from(head)
    fixed = CHUNK_HEAD.size + n + 8
    if fixed > length or fixed > len(head):
        raise Damaged(f"{where}: its compression name claims {n:,} bytes (a corrupt length)")
    (compressed,) = struct.unpack_from("<Q", head, CHUNK_HEAD.size + n)
    if compressed > length - fixed:
        raise Damaged(
            f"{where}: its records claim {compressed:,} bytes, past the chunk's end "
            f"({length - fixed:,} bytes there)"
        )
    try:
        compression = head[CHUNK_HEAD.size : CHUNK_HEAD.size + n].decode()
    except UnicodeDecodeError:
        raise Damaged(f"{where}: its compression name is not text") from None
    if compression == "" and compressed != size:
        raise Damaged(
            f"{where} states {size:,} bytes of records, its uncompressed records are {compressed:,}"
        )
    return _ChunkHead(length, compression, compressed, size)


def _agrees(at: int, head: _ChunkHead, index: Any) -> None:
    """The chunk index's entry ``index`` for the chunk at byte ``at`` says what it says."""
    pairs = (
        ("length", 9 + head.length, index.chunk_length),
        ("compression", head.compression, index.compression),
        ("compressed size", head.compressed, index.compressed_size),
        ("size", head.size, index.uncompressed_size),
    )
    for name, own, listed in pairs:
        if own != listed:
            said = f"{own:,}" if isinstance(own, int) else repr(own)
            other = f"{listed:,}" if isinstance(listed, int) else repr(listed)
            raise Damaged(
                f"the chunk at byte {at} states a {name} of {said}, its chunk index {other}"
            )
