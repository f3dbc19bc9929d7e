"""MCAP files that are not rosbag2's: ROS1 in MCAP, Foxglove's schemas in protobuf or JSON (and
CDR without the ``ros2`` profile).

For :func:`scan2terrain.readers.bag.open_bag`, which sends here every MCAP file whose header
profile is not ``ros2`` (rosbags' own reader refuses those: "Profile is not ros2"). A
:class:`McapFile` offers what :class:`~scan2terrain.readers.bag.Bag` asks of rosbags'
``AnyReader`` (connections, topics, time span, raw messages in log-time order, decoding), so
every decoder downstream sees exactly the objects the ROS1 ``.bag`` path gives. Choices:

* **Records with the** ``mcap`` **package.** Header, footer, schema, channel, chunk, chunk index
  and statistics records are parsed by ``mcap.records``. The file is walked here, not through
  ``mcap.reader``: its ``SeekingReader`` loads whole summary-less files into memory to sort them,
  allocates what a corrupt length field claims (up to 4 GiB a record), and decompresses chunks
  without a limit. Messages inside a chunk are split with one ``struct`` call each (the hot
  loop; ``mcap.records.Message.read`` costs five reads and a dataclass per message).
* **Indexed or not.** With a summary that has statistics and a chunk index, the index says
  which chunks hold which channels and when; without (a summary-less, streaming-written file,
  or unchunked messages), the data section is read once when the file is opened, chunks
  decompressed, to count messages and find the schemas and channels. Either way messages are
  merged in log-time order (ties in file order) chunk by chunk, as ``mcap``'s own reader does,
  so memory holds the chunks that overlap in time, not the file. Runs of unchunked messages are
  cut into blocks of at most :data:`RUN_BYTES` that are read like chunks.
* **Decoding** is per channel, from the pair (message encoding, schema encoding) in
  :data:`DECODERS`: ``ros1``/``ros1msg`` with rosbags' ROS1 deserialiser and ``cdr`` with
  ``ros2msg`` or ``ros2idl`` with its CDR one, the schema text registered in a typestore of the
  file's own, as rosbags does for a ROS1 bag (``roslib/Header`` renamed as in
  :mod:`scan2terrain.readers._bag_errors`). Type names are ROS 2 style, as rosbags reports them
  (``sensor_msgs/LaserScan`` -> ``sensor_msgs/msg/LaserScan``). ``protobuf``/``protobuf`` and
  ``json``/``jsonschema`` channels get a decoding function each from
  :mod:`scan2terrain.readers.foxglove` (protobuf classes built from the schema's
  ``FileDescriptorSet``; Foxglove's scan, tf, pose and grid schemas turned into objects shaped
  like the ROS messages); their type is the schema's name (``foxglove.PointCloud``). A channel
  without a schema, or
  with encodings not in the table, is *skipped* (listed with the reason, as a bag's unknown
  types are), not fatal: the file may hold usable scans beside it.
* **Hostile input.** Every length is checked against the file, or its chunk, before anything is
  read or allocated by it; a chunk's declared size is capped as a whole-file zstd bag is
  (:data:`~scan2terrain.readers._bag_source.MAX_ZSTD_RATIO` times its compressed size, at least
  :data:`~scan2terrain.readers._bag_source.MIN_ZSTD_BUDGET`), decompression stops at that size,
  and chunk CRCs are checked. A truncated file, a damaged record or chunk, a channel that names a
  schema the file lacks: one :class:`~scan2terrain.errors.InputError` naming the file.
"""

from __future__ import annotations

import heapq
import io
import itertools
import os
import struct
import sys
from collections import defaultdict
from collections.abc import Callable, Collection, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

from mcap.opcode import Opcode
from mcap.records import Channel, ChunkIndex, Footer, Header, Schema, Statistics
from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag1,
    MessageDefinition,
    MessageDefinitionFormat,
    TopicInfo,
)
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.msg import normalize_msgtype

from scan2terrain.errors import InputError, shown
from scan2terrain.readers import _foxglove_decode, foxglove
from scan2terrain.readers._bag_errors import _undecodable, one_line
from scan2terrain.readers._mcap_layout import (
    DAMAGED,
    MAGIC,
    MESSAGE_HEAD,
    MESSAGE_HEAD_SIZE,
    OPLEN,
    RUN_BYTES,
    Block,
    Damaged,
    Layout,
    _messages,
    _parse,
    _records,
    _split,
    chunk_bytes,
    in_order,
    read_chunk,
)

if sys.version_info >= (3, 14):  # pragma: no cover
    pass
else:
    pass


if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore


@dataclass(frozen=True)
class _Decoder:
    """How one (message encoding, schema encoding) pair is read.

    Either rosbags types: ``types``, the schema as rosbags types (name -> parse tree), raising on
    a bad definition, and ``ros1``, whether messages are ROS1 bytes (else CDR); or ``make``, a
    per-channel decoding function from the schema's name and bytes, raising ValueError on a
    schema it cannot use (protobuf and JSON, :mod:`scan2terrain.readers.foxglove`).
    """

    label: str
    types: Callable[[str, str], dict[str, object]] | None = None
    ros1: bool = False
    make: Callable[[str, bytes], Callable[[bytes | memoryview], object]] | None = None


def _ros1_types(text: str, name: str) -> dict[str, object]:
    if "\nMSG: roslib/Header\n" in text:  # ROS C-Turtle's Header, as _Ros1Reader renames it
        text = text.replace("\nMSG: roslib/Header\n", "\nMSG: std_msgs/Header\n")
    return dict(get_types_from_msg(text, name))


def _idl_types(text: str, name: str) -> dict[str, object]:
    sep = "=" * 80 + "\n"
    if text.startswith(f"{sep}IDL: "):  # several IDL files, as rosbag2 writes them
        typs: dict[str, object] = {}
        for part in text.split(sep)[1:]:
            typs.update(get_types_from_idl(part.split("\n", 1)[1]))
        return typs
    return dict(get_types_from_idl(text))


#: What can be decoded: (channel message encoding, schema encoding) -> decoder.
DECODERS: dict[tuple[str, str], _Decoder] = {
    ("ros1", "ros1msg"): _Decoder("ROS1 (rosbags)", _ros1_types, ros1=True),
    ("cdr", "ros2msg"): _Decoder(
        "CDR (rosbags)", lambda t, n: dict(get_types_from_msg(t, n)), ros1=False
    ),
    ("cdr", "ros2idl"): _Decoder("CDR (rosbags)", _idl_types, ros1=False),
    ("protobuf", "protobuf"): _Decoder(
        "protobuf (the file's descriptors)", make=_foxglove_decode.protobuf_decoder
    ),
    ("json", "jsonschema"): _Decoder("JSON", make=_foxglove_decode.json_decoder),
}


def supported() -> str:
    """The encodings :data:`DECODERS` reads, for messages: ``ros1/ros1msg, cdr/ros2msg``."""
    return ", ".join(f"{m}/{s}" for m, s in DECODERS)


class McapFile:
    """One MCAP file, opened for :class:`~scan2terrain.readers.bag.Bag` (the part of rosbags'
    ``AnyReader`` it uses: ``connections``, ``topics``, ``start_time``, ``end_time`` (one past
    the last message), ``message_count``, ``messages``, and ``decode``/``undecodable``).

    Raises
    ------
    InputError
        Truncated or damaged (one line naming ``path``).
    """

    def __init__(self, path: Path, named: Path | None = None) -> None:
        self.path = path
        self._named = named or path
        self._f: IO[bytes] = path.open("rb")
        try:
            self._layout = self._read_layout()
            self._connections()
        except Damaged as exc:
            self._f.close()
            raise InputError(self._named, f"{DAMAGED}: {exc}") from None
        except BaseException:
            self._f.close()
            raise

    # what the file holds ---------------------------------------------------------------------

    @property
    def profile(self) -> str:
        return self._layout.profile

    @property
    def library(self) -> str:
        return self._layout.library

    @property
    def indexed(self) -> bool:
        """Whether the summary's index was used (else the data section was scanned)."""
        return self._layout.indexed

    @property
    def start_time(self) -> int:
        return self._layout.start_ns or 0

    @property
    def end_time(self) -> int:
        return (self._layout.end_ns or 0) + 1

    @property
    def message_count(self) -> int:
        return sum(self._layout.counts.values())

    def _read_layout(self) -> Layout:
        f = self._f
        size = f.seek(0, io.SEEK_END)
        f.seek(0)
        if f.read(8) != MAGIC:
            raise Damaged("it does not start with the MCAP magic")
        footer_at = size - 8 - 9 - 20
        if footer_at < 8:
            raise Damaged("too short to hold a header and a footer")
        f.seek(size - 8)
        if f.read(8) != MAGIC:
            raise Damaged("its end marker is missing")
        layout = Layout()
        records = _records(f, 8, footer_at)
        _, opcode, length = next(records)
        if opcode != Opcode.HEADER:
            raise Damaged("its first record is not a header")
        header = _parse(Header.read, f.read(length), "header")
        assert isinstance(header, Header)
        layout.profile, layout.library = header.profile, header.library
        f.seek(footer_at)
        opcode, length = OPLEN.unpack(f.read(9))
        if opcode != Opcode.FOOTER or length != 20:
            raise Damaged("its footer is missing")
        footer = _parse(Footer.read, f.read(20), "footer")
        assert isinstance(footer, Footer)
        if footer.summary_start and self._read_summary(layout, footer, footer_at):
            return layout
        layout.counts.clear()
        layout.blocks.clear()
        self._scan(layout, footer_at)
        return layout

    def _read_summary(self, layout: Layout, footer: Footer, footer_at: int) -> bool:
        """The schemas, channels, counts and chunks from the summary: False when it lacks
        statistics or a chunk index (the data section is scanned then)."""
        if not 8 <= footer.summary_start <= footer_at:
            raise Damaged("its footer points outside the file")
        stats: Statistics | None = None
        chunks: list[ChunkIndex] = []
        for _, opcode, length in _records(self._f, footer.summary_start, footer_at):
            if opcode == Opcode.SCHEMA:
                schema = _parse(Schema.read, self._f.read(length), "schema")
                assert isinstance(schema, Schema)
                layout.schemas[schema.id] = schema
            elif opcode == Opcode.CHANNEL:
                channel = _parse(Channel.read, self._f.read(length), "channel")
                assert isinstance(channel, Channel)
                layout.channels[channel.id] = channel
            elif opcode == Opcode.STATISTICS:
                read = _parse(Statistics.read, self._f.read(length), "statistics")
                assert isinstance(read, Statistics)
                stats = read
            elif opcode == Opcode.CHUNK_INDEX:
                index = _parse(ChunkIndex.read, self._f.read(length), "chunk index")
                assert isinstance(index, ChunkIndex)
                chunks.append(index)
        if stats is None or not chunks or stats.chunk_count != len(chunks):
            return False
        if any(c not in layout.channels for i in chunks for c in i.message_index_offsets):
            return False  # channels only defined in the chunks
        for i in chunks:
            end = i.chunk_start_offset + i.chunk_length
            if not 8 <= i.chunk_start_offset < end <= footer_at:
                raise Damaged("its chunk index points outside the file")
            channels = set(i.message_index_offsets) or None
            times = (i.message_start_time, i.message_end_time)
            layout.blocks.append(Block(i.chunk_start_offset, end, *times, channels, chunk=True))
        layout.counts.update(stats.channel_message_counts)
        if stats.message_count:
            layout.saw(stats.message_start_time)
            layout.saw(stats.message_end_time)
        layout.indexed = True
        return True

    def _scan(self, layout: Layout, stop: int) -> None:
        """Every record of the data section, once: schemas, channels, counts, blocks."""
        f = self._f
        run: Block | None = None
        for offset, opcode, length in _records(f, 8, stop):
            if opcode == Opcode.MESSAGE:
                if length < MESSAGE_HEAD_SIZE:
                    raise Damaged("a message record shorter than its header")
                channel, _, t_ns = MESSAGE_HEAD.unpack(f.read(14))
                if run is None or offset - run.offset > RUN_BYTES:
                    run = Block(offset, offset, t_ns, t_ns, set(), chunk=False)
                    layout.blocks.append(run)
                run.end = offset + 9 + length
                run.start_ns, run.end_ns = min(run.start_ns, t_ns), max(run.end_ns, t_ns)
                assert run.channels is not None
                run.channels.add(channel)
                layout.counts[channel] += 1
                layout.saw(t_ns)
                continue
            run = None
            if opcode == Opcode.CHUNK:
                chunk = read_chunk(f.read(length), offset)
                block = Block(offset, offset + 9 + length, 0, 0, set(), chunk=True)
                times = self._scan_chunk(layout, chunk_bytes(chunk, offset), block)
                if times:
                    block.start_ns, block.end_ns = min(times), max(times)
                    layout.blocks.append(block)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                self._define(layout, opcode, f.read(length))
            elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
                break

    def _scan_chunk(self, layout: Layout, data: memoryview, block: Block) -> list[int]:
        times = []
        assert block.channels is not None
        for op, body, end, t_ns in _split(data, block.offset):
            if t_ns >= 0:
                channel = op >> 8
                block.channels.add(channel)
                layout.counts[channel] += 1
                layout.saw(t_ns)
                times.append(t_ns)
            elif op in (Opcode.SCHEMA, Opcode.CHANNEL):
                self._define(layout, op, bytes(data[body:end]))
        return times

    @staticmethod
    def _define(layout: Layout, opcode: int, body: bytes) -> None:
        if opcode == Opcode.SCHEMA:
            schema = _parse(Schema.read, body, "schema")
            assert isinstance(schema, Schema)
            layout.schemas[schema.id] = schema
        else:
            channel = _parse(Channel.read, body, "channel")
            assert isinstance(channel, Channel)
            layout.channels[channel.id] = channel

    # connections, as rosbags has them ----------------------------------------------------------

    def _connections(self) -> None:
        layout = self._layout
        unknown = sorted(set(layout.counts) - set(layout.channels))
        if unknown:
            raise Damaged(f"messages on channel {unknown[0]}, which is not defined")
        self.typestore: Typestore = get_typestore(Stores.EMPTY)
        self._skip: dict[int, str] = {}
        self._ros1: dict[int, bool] = {}
        self._decode: dict[int, Callable[[bytes | memoryview], object]] = {}
        self.connections: list[Connection] = []
        self._by_id: dict[int, Connection] = {}
        typs: dict[str, object] = {}
        for cid, ch in sorted(layout.channels.items()):
            msgtype, reason, text = self._channel_type(ch, typs)
            if reason:
                self._skip[cid] = reason
            meta = ch.metadata
            conn = Connection(
                cid,
                ch.topic,
                msgtype,
                MessageDefinition(MessageDefinitionFormat.MSG, text),
                meta.get("md5sum", ""),
                layout.counts.get(cid, 0),
                ConnectionExtRosbag1(meta.get("callerid"), int(meta.get("latching") or 0)),
                self,
            )
            self.connections.append(conn)
            self._by_id[cid] = conn
        try:
            self.typestore.register(typs)  # type: ignore[arg-type]
        except Exception as exc:  # two channels defining one type differently
            raise InputError(
                self._named, f"its schemas cannot be used together ({one_line(str(exc))})"
            ) from exc
        for conn in self.connections:
            if conn.id in self._decode:
                continue
            if conn.id not in self._skip and (why := _undecodable(self.typestore, conn.msgtype)):
                self._skip[conn.id] = why.replace("in the bag nor in ROS 2 Humble", "in the file")
        if self.connections and len(self._skip) == len(self.connections):
            found = "; ".join(
                f"{shown(c.topic)}: {self._skip[c.id]}" for c in self.connections[:4]
            ) + ("; ..." if len(self.connections) > 4 else "")
            raise InputError(self._named, f"no channel of this MCAP file can be read: {found}")

    def _channel_type(self, ch: Channel, typs: dict[str, object]) -> tuple[str, str, str]:
        """``(msgtype, why it cannot be decoded or "", schema text)``, types into ``typs``."""
        if ch.schema_id == 0:
            return "", f"no schema for {ch.message_encoding!r} messages", ""
        schema = self._layout.schemas.get(ch.schema_id)
        if schema is None:
            raise Damaged(
                f"channel {shown(ch.topic)} names schema {ch.schema_id}, which is missing"
            )
        pair = (ch.message_encoding, schema.encoding)
        decoder = DECODERS.get(pair)
        if decoder is None:
            return (
                schema.name,
                (
                    f"{schema.name} in {ch.message_encoding!r} messages with a "
                    f"{schema.encoding!r} schema: not read (supported: {supported()})"
                ),
                "",
            )
        if decoder.make is not None:
            try:
                self._decode[ch.id] = decoder.make(schema.name, bytes(schema.data))
            except ValueError as exc:
                return (
                    schema.name,
                    f"the {schema.encoding} schema of {schema.name} cannot be used "
                    f"({one_line(str(exc))})",
                    "",
                )
            return schema.name, "", ""
        assert decoder.types is not None
        msgtype = normalize_msgtype(schema.name) if "/" in schema.name else schema.name
        try:
            text = schema.data.decode()
            typs.update(decoder.types(text, msgtype))
        except Exception as exc:  # rosbags' parsers: the definition text is not valid
            return (
                msgtype,
                (
                    f"the {schema.encoding} definition of {msgtype} cannot be used "
                    f"({one_line(str(exc))})"
                ),
                "",
            )
        self._ros1[ch.id] = decoder.ros1
        return msgtype, "", text

    @property
    def topics(self) -> dict[str, TopicInfo]:
        grouped: dict[str, list[Connection]] = defaultdict(list)
        for conn in self.connections:
            grouped[conn.topic].append(conn)
        out = {}
        for name in sorted(grouped):
            conns = grouped[name]
            types = {c.msgtype for c in conns}
            defs = {c.msgdef for c in conns}
            out[name] = TopicInfo(
                types.pop() if len(types) == 1 else None,
                defs.pop()
                if len(defs) == 1
                else MessageDefinition(MessageDefinitionFormat.NONE, ""),
                sum(c.msgcount for c in conns),
                conns,
            )
        return out

    def undecodable(self, conn: Connection) -> str | None:
        """Why this channel's messages cannot be decoded, or None."""
        return self._skip.get(conn.id)

    def encodings(self, conn: Connection) -> tuple[str, str, str]:
        """``(message encoding, schema name, schema encoding)`` of a connection."""
        ch = self._layout.channels[conn.id]
        schema = self._layout.schemas.get(ch.schema_id)
        return ch.message_encoding, schema.name if schema else "", schema.encoding if schema else ""

    def decoder_label(self, conn: Connection) -> str:
        encoding, _, schema = self.encodings(conn)
        decoder = DECODERS.get((encoding, schema))
        if decoder is None:
            return ""
        use = foxglove.USES.get(conn.msgtype)
        return f"{decoder.label}, {use}" if use and conn.id in self._decode else decoder.label

    def decode(self, conn: Connection, raw: bytes | memoryview) -> object:
        if (decode := self._decode.get(conn.id)) is not None:
            return decode(raw)
        if self._ros1[conn.id]:
            return self.typestore.deserialize_ros1(raw, conn.msgtype)
        return self.typestore.deserialize_cdr(raw, conn.msgtype)

    # messages --------------------------------------------------------------------------------

    def messages(
        self,
        connections: Collection[Connection] = (),
        start: int | None = None,
        stop: int | None = None,
    ) -> Iterator[tuple[Connection, int, memoryview]]:
        """``(connection, log time ns, raw bytes)`` in log-time order (ties in file order), for
        ``start <= t < stop``; every connection when none are given."""
        try:
            yield from self._merged(connections, start, stop)
        except Damaged as exc:
            raise InputError(self._named, f"{DAMAGED}: {exc}") from None

    def _merged(
        self, connections: Collection[Connection], start: int | None, stop: int | None
    ) -> Iterator[tuple[Connection, int, memoryview]]:
        # Ties in time go in the order the connections were asked for, then in file order: as
        # rosbags' ROS1 reader merges its per-connection indexes, so both give the same stream.
        order = [c.id for c in connections] if connections else sorted(self._by_id)
        rank = {cid: r for r, cid in reversed(list(enumerate(order)))}
        lo = -1 if start is None else start
        hi = 1 << 64 if stop is None else stop
        # (time, rank or -1 for a block, offset, index in block or block number)
        heap: list[tuple[int, int, int, int]] = []
        blocks = self._layout.blocks
        for n, b in enumerate(blocks):
            if (
                b.end_ns >= lo
                and b.start_ns < hi
                and (b.channels is None or b.channels & rank.keys())
            ):
                heap.append((b.start_ns, -1, b.offset, n))
        # The blocks leave the heap in (start time, offset) order, whatever the messages do: a
        # thread loads the next one (file read, decompression and CRC, which release the GIL)
        # while the messages of this one are used. A block's messages come only after its
        # checks, as without the thread.
        after = dict(itertools.pairwise(n for *_, n in sorted(heap)))
        heapq.heapify(heap)
        pending: dict[tuple[int, int], tuple[int, memoryview]] = {}
        by_id = self._by_id
        with ThreadPoolExecutor(max_workers=1) as loader:
            loading: dict[int, Future[memoryview]] = {}
            while heap:
                t_ns, r, offset, n = heapq.heappop(heap)
                if r < 0:
                    load = loading.pop(n, None) or loader.submit(self._load, blocks[n])
                    if (ahead := after.get(n)) is not None:
                        loading[ahead] = loader.submit(self._load, blocks[ahead])
                    data = load.result()
                    chunk = blocks[n].chunk
                    wanted = [
                        m
                        for m in _messages(data, offset, chunk=chunk)
                        if m[0] in rank and lo <= m[1] < hi
                    ]
                    if (
                        wanted
                        and (not heap or wanted[-1][1] < heap[0][0])
                        and in_order(wanted, rank)
                    ):
                        # Before anything else in the heap and in order already: as they are.
                        for cid, t, raw in wanted:
                            yield by_id[cid], t, raw
                        continue
                    for k, (cid, t, raw) in enumerate(wanted):
                        pending[offset, k] = (cid, raw)
                        heapq.heappush(heap, (t, rank[cid], offset, k))
                    continue
                cid, raw = pending.pop((offset, n))
                yield by_id[cid], t_ns, raw
            for load in loading.values():
                load.cancel()

    def _load(self, block: Block) -> memoryview:
        """A block's records: its chunk read, decompressed and checked, or its bytes. One
        ``pread`` per block (no seek, one release of the GIL: the loader thread then does not
        wait for the interpreter between small reads)."""
        size = block.end - block.offset
        data = memoryview(os.pread(self._f.fileno(), size, block.offset))
        if len(data) != size:
            raise Damaged("the file changed while it was read")
        if not block.chunk:
            return data
        opcode, length = OPLEN.unpack_from(data)
        if opcode != Opcode.CHUNK or 9 + length != size:
            raise Damaged(
                f"the chunk index points at byte {block.offset} for {size:,} bytes, where there "
                f"is a record of opcode {opcode} and {9 + length:,} bytes"
            )
        return chunk_bytes(read_chunk(data[9:], block.offset), block.offset)

    def close(self) -> None:
        self._f.close()


def mcap_profile(path: Path) -> str | None:
    """The profile in an MCAP file's header (``ros1``, ``ros2``, ``""``), or None when the file
    is not MCAP or its header cannot be read (the reader chosen then says what is wrong)."""
    try:
        with path.open("rb") as f:
            head = f.read(8 + 9 + 4)
            if len(head) < 21 or not head.startswith(MAGIC) or head[8] != Opcode.HEADER:
                return None
            (n,) = struct.unpack_from("<I", head, 17)
            if n > 1 << 16:
                return None
            profile = f.read(n)
            return profile.decode() if len(profile) == n else None
    except (OSError, UnicodeDecodeError):
        return None
