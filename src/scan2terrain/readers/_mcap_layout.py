"""An MCAP file's records, read with length checks: the record walk, chunks (capped, CRC-checked
decompression) and the messages inside them, for :class:`scan2terrain.readers._mcap.McapFile`."""

from __future__ import annotations

import io
import itertools
import struct
import sys
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import IO

from isal.isal_zlib import crc32  # the CRC-32 of zlib, 4-5x faster (chunk checks)
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Schema

from scan2terrain.readers._bag_errors import one_line
from scan2terrain.readers._bag_source import MAX_ZSTD_RATIO, MIN_ZSTD_BUDGET

if sys.version_info >= (3, 14):  # pragma: no cover
    from compression import zstd
else:
    from backports import zstd

MAGIC = b"\x89MCAP0\r\n"


#: Unchunked messages are read back in blocks of about this many bytes.
RUN_BYTES = 4 << 20


OPLEN = struct.Struct("<BQ")


MESSAGE_HEAD = struct.Struct("<HIQ")  # channel id, sequence, log time (publish time follows)


MESSAGE_HEAD_SIZE = 22


DAMAGED = "the MCAP file is truncated or damaged"


class Damaged(Exception):
    """A record that does not fit where it is: said as one line by :class:`McapFile`."""


class _Exact(ReadDataStream):
    """mcap's stream over one record's bytes, failing on a short read (it returns what is
    there): a length field inside a record that points past the record's end."""

    def read(self, length: int) -> bytes:
        data = super().read(length)
        if len(data) != length:
            raise EndOfFile()
        return data


def _parse(parse: Callable[[ReadDataStream], object], body: bytes, what: str) -> object:
    try:
        return parse(_Exact(io.BytesIO(body)))
    except (EndOfFile, struct.error, UnicodeDecodeError) as exc:
        raise Damaged(f"a damaged {what} record") from exc


@dataclass
class Block:
    """Messages read as one: a chunk record, or a run of top-level message records."""

    offset: int  #: of the chunk record, or of the run's first record
    end: int  #: just past the last record
    start_ns: int
    end_ns: int
    channels: set[int] | None  #: None: not known without reading it
    chunk: bool


@dataclass
class Layout:
    profile: str = ""
    library: str = ""
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=lambda: defaultdict(int))
    blocks: list[Block] = field(default_factory=list)
    start_ns: int | None = None
    end_ns: int | None = None
    indexed: bool = False

    def saw(self, t_ns: int) -> None:
        self.start_ns = t_ns if self.start_ns is None else min(self.start_ns, t_ns)
        self.end_ns = t_ns if self.end_ns is None else max(self.end_ns, t_ns)


def _records(f: IO[bytes], start: int, stop: int) -> Iterator[tuple[int, int, int]]:
    """``(offset, opcode, length)`` of each record in ``[start, stop)``, ``f`` left at its
    body; a record that does not fit before ``stop`` is damage."""
    pos = start
    while pos < stop:
        f.seek(pos)
        head = f.read(9)
        if len(head) < 9:
            raise Damaged("a record is cut short")
        opcode, length = OPLEN.unpack(head)
        if length > stop - pos - 9:
            what = "the chunk" if opcode == Opcode.CHUNK else "the record"
            raise Damaged(
                f"{what} at byte {pos} claims {length:,} bytes, more than the file holds there "
                f"({max(stop - pos - 9, 0):,})"
            )
        yield pos, opcode, length
        pos += 9 + length


CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length


#: What compressions a chunk may have, as MCAP names them.
COMPRESSIONS = ("", "zstd", "lz4")


def read_chunk(body: bytes | memoryview, at: int) -> Chunk:
    """mcap's :class:`~mcap.records.Chunk` of the body of the chunk record at byte ``at``, its
    ``data`` a view into ``body`` (``Chunk.read`` copies the data once more: a third of the read
    time here). Its records must fill what it holds of the record; uncompressed, they are as many
    bytes as it states."""
    where = f"the chunk at byte {at}"
    if len(body) < CHUNK_HEAD.size:
        raise Damaged(f"{where} is cut short ({len(body):,} bytes)")
    start, end, size, crc, n = CHUNK_HEAD.unpack_from(body)
    head = CHUNK_HEAD.size + n
    if head + 8 > len(body):
        raise Damaged(f"{where}: its compression name of {n:,} bytes runs past the chunk")
    (length,) = struct.unpack_from("<Q", body, head)
    if head + 8 + length > len(body):
        raise Damaged(
            f"{where}: its records claim {length:,} bytes, past the chunk's end "
            f"({len(body) - head - 8:,} bytes there)"
        )
    try:
        compression = bytes(body[CHUNK_HEAD.size : head]).decode()
    except UnicodeDecodeError as exc:
        raise Damaged(f"{where}: its compression name is not text") from exc
    if compression not in COMPRESSIONS:
        raise Damaged(
            f"{where} is compressed with {compression[:40]!r}; MCAP chunks are read with lz4, "
            "zstd or none"
        )
    if compression == "" and length != size:
        raise Damaged(
            f"{where} states {size:,} bytes of records, its uncompressed records are {length:,}"
        )
    data = memoryview(body)[head + 8 : head + 8 + length]
    return Chunk(compression, data, end, start, crc, size)  # type: ignore[arg-type]


def chunk_bytes(chunk: Chunk, at: int) -> memoryview:
    """The records of the chunk at byte ``at``, decompressed under the cap and checked against
    its size and CRC."""
    where = f"the chunk at byte {at}"
    size = chunk.uncompressed_size
    limit = max(MIN_ZSTD_BUDGET, MAX_ZSTD_RATIO * len(chunk.data))
    if size > limit:
        raise Damaged(
            f"{where} claims {size:,} bytes, more than {MAX_ZSTD_RATIO} times its "
            f"{len(chunk.data):,} compressed (a corrupt size, or a zstd bomb?)"
        )
    kind = chunk.compression
    short = f"{where} does not decompress to the {size:,} bytes it states"
    try:
        if kind == "" or size == 0:
            data = chunk.data if kind == "" else b""
        elif kind == "zstd":
            dz = zstd.ZstdDecompressor()
            data = dz.decompress(chunk.data, max_length=size)
            if not dz.eof:
                raise Damaged(f"{short} (more, or its data is cut short)")
        elif kind == "lz4":
            import lz4.frame  # type: ignore[import-untyped]

            dl = lz4.frame.LZ4FrameDecompressor()
            data = dl.decompress(chunk.data, max_length=size)
            if not dl.eof:
                raise Damaged(f"{short} (more, or its data is cut short)")
        else:
            raise Damaged(
                f"{where} is compressed with {kind!r}; MCAP chunks are read with lz4, zstd or none"
            )
    except (zstd.ZstdError, RuntimeError, ValueError, EOFError) as exc:  # lz4 raises RuntimeError
        raise Damaged(
            f"{where}: its {kind} data cannot be decompressed ({one_line(str(exc))})"
        ) from exc
    if len(data) != size:
        raise Damaged(f"{short} ({len(data):,})")
    if chunk.uncompressed_crc and crc32(data) != chunk.uncompressed_crc:
        raise Damaged(f"{where} fails its CRC check (corrupt data)")
    return memoryview(data)


def _split(
    data: bytes | memoryview, at: int, *, chunk: bool = True
) -> Iterator[tuple[int, int, int, int]]:
    """``(opcode, body start, body end, log time or -1)`` of each record in a chunk's bytes
    (the chunk record at byte ``at``; not ``chunk``: the top-level records from byte ``at``);
    for messages the body starts at the payload and the channel id is packed in the opcode's
    place as ``opcode | channel << 8``."""
    pos, n = 0, len(data)
    oplen, head = OPLEN.unpack_from, MESSAGE_HEAD.unpack_from
    message = Opcode.MESSAGE
    while pos < n:
        if pos + 9 > n:
            where = f"the chunk at byte {at}" if chunk else f"the records from byte {at}"
            raise Damaged(f"{where}: its last record is cut short")
        opcode, length = oplen(data, pos)
        body, end = pos + 9, pos + 9 + length
        if end > n:
            where = f"the chunk at byte {at}" if chunk else f"the records from byte {at}"
            raise Damaged(
                f"{where}: the record at byte {pos} of its {n:,} claims {length:,} bytes, past "
                "their end"
            )
        if opcode == message:
            if length < MESSAGE_HEAD_SIZE:
                where = f"the chunk at byte {at}" if chunk else f"the records from byte {at}"
                raise Damaged(
                    f"{where}: the message record at byte {pos} of its {n:,} claims {length:,} "
                    "bytes, less than its header"
                )
            channel, _, log_time = head(data, body)
            yield message | channel << 8, body + MESSAGE_HEAD_SIZE, end, log_time
        else:
            yield opcode, body, end, -1
        pos = end


def in_order(messages: list[tuple[int, int, memoryview]], rank: dict[int, int]) -> bool:
    """Whether the messages, in file order, are in the merge's order already: log time, then the
    rank of their connection (file order breaks the remaining ties)."""
    keys = [(t, rank[cid]) for cid, t, _ in messages]
    return all(a <= b for a, b in itertools.pairwise(keys))


def _messages(data: memoryview, at: int, *, chunk: bool) -> Iterator[tuple[int, int, memoryview]]:
    """``(channel id, log time, payload)`` of each message of a block's records (at byte
    ``at``: :func:`_split`), in file order. Views, not copies: rosbags' deserialisers take them
    (a message's arrays then view its chunk's bytes, as they view a .bag's message bytes)."""
    for op, body, end, t_ns in _split(data, at, chunk=chunk):
        if t_ns >= 0:
            yield op >> 8, t_ns, data[body:end]
