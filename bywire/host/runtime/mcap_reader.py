"""The MCAP reader: recordings read back, tolerant of a missing end (a crash), strict about damage.

Seed 000 section 3 (logged objects are replayed, DESIGN.md section 1): `read_objects` decodes a
recording (`mcap_recorder`'s, or any MCAP file with JSON messages) back into the same Python objects
through `log_schema`, for `bywire log info|plot|replay`; `read_frames` gives its CAN frames back as
python-can messages.

This reader (not `mcap.reader.make_reader`, which needs the footer of a closed file) reads a file
whose writer was killed up to its last complete record. Reading is for untrusted input: a log never
names Python code to import; schema names are looked up in the registry filled by `register_type`,
and unknown types come back as dicts. The recorder writes CRCs over every chunk, over the whole data
section and over the summary, so damage is found wherever it is: damaged files (bytes flipped,
garbage, a closed file cut inside) raise `LogError` naming the file, the byte offset and what
failed; a damaged summary behind an intact data section only marks the file as not complete. A file
that merely ends early (a crash: no footer) yields what it holds and reports itself as not complete.
"""

from __future__ import annotations

import io
import json
import os
import struct
import zlib
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from typing import Any, BinaryIO

import can

from bywire.host.runtime.can_frame import CAN_TOPIC_PREFIX, CanFrame
from bywire.host.runtime.log_schema import MESSAGE_ENCODING, SCHEMA_ENCODING, LogError, decode_message

MCAP_MAGIC = b"\x89MCAP0\r\n"

_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
_OP_DATA_END = 0x0F


class _Short(Exception):
    """A record's content is shorter than its fields say."""


class _Cursor:
    __slots__ = ("buf", "end", "pos")

    def __init__(self, buf: bytes, pos: int = 0, end: int | None = None) -> None:
        self.buf = buf
        self.pos = pos
        self.end = len(buf) if end is None else end

    def take(self, n: int) -> bytes:
        if n > self.end - self.pos:
            raise _Short(f"needs {n} bytes, {self.end - self.pos} left")
        out = self.buf[self.pos : self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return int(struct.unpack("<H", self.take(2))[0])

    def u32(self) -> int:
        return int(struct.unpack("<I", self.take(4))[0])

    def u64(self) -> int:
        return int(struct.unpack("<Q", self.take(8))[0])

    def string(self) -> str:
        return self.take(self.u32()).decode("utf-8")


@dataclass(frozen=True)
class SchemaInfo:
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class ChannelInfo:
    topic: str
    message_encoding: str
    schema: SchemaInfo | None


@dataclass(frozen=True)
class RawMessage:
    """One message as stored: its channel's topic and schema, times and undecoded payload."""

    channel: ChannelInfo
    sequence: int
    log_time_ns: int
    publish_time_ns: int
    data: bytes

    @property
    def topic(self) -> str:
        return self.channel.topic


class McapLogReader:
    """One pass over an MCAP file, tolerant of a missing end (a crash) and strict about damage.

    `messages()` yields the messages in file order; afterwards `complete` says whether the file was
    closed cleanly (footer and closing magic present, data section and summary CRCs right) and
    `end_note` how it ended; `channels` holds every channel seen. Damage to what messages are made
    of (a chunk, a schema, a channel) raises LogError naming the file, the byte offset and the
    problem (so does a data section whose CRC fails); damage only to the summary after a verified
    data section is noted in `damage` and leaves `complete` False, since every message is intact.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        self.complete = False
        self.end_note = "not read yet"
        self.channels: dict[int, ChannelInfo] = {}
        self.message_count = 0
        self.damage: str | None = None  # damage found outside the messages (they have their own CRC)
        self._schemas: dict[int, SchemaInfo] = {}

    def _fail(self, offset: int, problem: str) -> LogError:
        return LogError(self.path, f"byte {offset}: {problem}")

    def messages(self, topics: Collection[str] | None = None) -> Iterator[RawMessage]:
        try:
            f = open(self.path, "rb")  # noqa: SIM115 (closed in the finally below; this is a generator)
        except OSError as exc:
            raise LogError(self.path, f"cannot open: {exc.strerror or exc}") from None
        try:
            yield from self._read(f, None if topics is None else frozenset(topics))
        except OSError as exc:
            raise LogError(self.path, f"reading failed: {exc}") from None
        finally:
            f.close()

    def _read(self, f: BinaryIO, topics: frozenset[str] | None) -> Iterator[RawMessage]:
        size = os.fstat(f.fileno()).st_size
        magic = f.read(len(MCAP_MAGIC))
        if len(magic) < len(MCAP_MAGIC):
            what = "empty file" if not magic else f"only {len(magic)} bytes"
            raise LogError(self.path, f"{what}: not an MCAP recording (no header)")
        if magic != MCAP_MAGIC:
            raise LogError(self.path, f"not an MCAP file (starts with {magic!r})")
        # A file that ends with a footer and the magic was closed: anything that looks cut short
        # inside it is damage, not a crash.
        closed = False
        if size >= 2 * len(MCAP_MAGIC) + 9 + 20:
            f.seek(size - len(MCAP_MAGIC) - 9 - 20)
            end = f.read(9 + 20 + len(MCAP_MAGIC))
            closed = end[:9] == struct.pack("<BQ", _OP_FOOTER, 20) and end[-len(MCAP_MAGIC) :] == MCAP_MAGIC
            f.seek(len(MCAP_MAGIC))
        offset = len(MCAP_MAGIC)
        # CRCs of the data section (up to the DataEnd record) and of the summary (after it), as
        # written into DataEnd and the footer: damage outside the chunks (which have their own CRC)
        # is found too. None for the summary until DataEnd has been read.
        data_crc = zlib.crc32(magic)
        summary_crc: int | None = None
        while True:
            head = f.read(9)
            if len(head) < 9:
                self.end_note = (
                    f"ends at byte {offset} without a footer (not closed: the recorder crashed or was killed)"
                    if not head
                    else f"ends inside a record header at byte {offset} (not closed: crash?)"
                )
                return
            opcode, length = struct.unpack("<BQ", head)
            if closed and (opcode == 0 or length > size - offset - 9):
                raise self._fail(
                    offset, f"record {opcode:#04x} of {length} bytes runs past the end of this closed file"
                )
            if opcode == 0:
                # Not a valid opcode: zeros where a record should start are a file system's unwritten tail.
                self.end_note = f"zero bytes from byte {offset} on (an unfinished write)"
                return
            if length > size - offset - 9:
                self.end_note = (
                    f"the record at byte {offset} ends past the end of the file ({size} bytes): "
                    "cut short (not closed: crash?)"
                )
                return
            body = f.read(length)
            if len(body) < length:  # the file shrank while being read
                self.end_note = f"the record at byte {offset} was cut short while reading"
                return
            try:
                if opcode == _OP_FOOTER:
                    self._footer(f, offset, head, _Cursor(body), summary_crc)
                    return
                if summary_crc is not None:
                    # The summary only repeats schemas and channels and indexes what came before.
                    summary_crc = zlib.crc32(body, zlib.crc32(head, summary_crc))
                elif opcode == _OP_DATA_END:
                    expected = _Cursor(body).u32()
                    if expected not in (0, data_crc):
                        raise self._fail(
                            offset,
                            "the data section's CRC does not match: the file is damaged (the messages "
                            "read passed their chunk's CRC, but others may be missing)",
                        )
                    summary_crc = 0
                else:
                    data_crc = zlib.crc32(body, zlib.crc32(head, data_crc))
                    if opcode == _OP_CHUNK:
                        yield from self._chunk(body, offset, topics)
                    else:
                        msg = self._record(opcode, _Cursor(body), offset)
                        if msg is not None and (topics is None or msg.topic in topics):
                            yield msg
            except _Short as exc:
                raise self._fail(offset, f"record {opcode:#04x} is damaged: {exc}") from None
            except UnicodeDecodeError:
                raise self._fail(offset, f"record {opcode:#04x} is damaged: a name is not UTF-8") from None
            offset += 9 + length

    def _damaged(self, note: str) -> None:
        """Damage after the data section (summary, footer): every message was read intact, so noted."""
        self.damage = note if self.damage is None else f"{self.damage}; {note}"

    def _footer(self, f: BinaryIO, offset: int, head: bytes, cur: _Cursor, summary_crc: int | None) -> None:
        cur.u64(), cur.u64()  # summary start, summary offset start
        expected = cur.u32()
        if (
            summary_crc is not None
            and expected != 0
            and zlib.crc32(cur.buf[:16], zlib.crc32(head, summary_crc)) != expected
        ):
            self._damaged(f"the summary's CRC does not match (footer at byte {offset})")
        tail = f.read(len(MCAP_MAGIC))
        if len(tail) < len(MCAP_MAGIC):
            self.end_note = "the closing magic after the footer is cut short (crash while closing?)"
            return
        if tail != MCAP_MAGIC:
            self._damaged(f"the footer is not followed by the MCAP magic ({tail!r})")
        if self.damage is None:
            self.complete = True
            self.end_note = "closed cleanly (summary and footer present)"
        else:
            self.end_note = f"closed, but damaged after the messages (all of them intact): {self.damage}"

    def _record(self, opcode: int, cur: _Cursor, offset: int) -> RawMessage | None:
        if opcode == _OP_SCHEMA:
            schema_id = cur.u16()
            schema = SchemaInfo(cur.string(), cur.string(), cur.take(cur.u32()))
            if schema_id == 0:
                raise self._fail(offset, "a schema with id 0 (reserved for 'no schema')")
            known = self._schemas.setdefault(schema_id, schema)
            if known != schema:
                raise self._fail(offset, f"schema {schema_id} is defined twice, differently")
        elif opcode == _OP_CHANNEL:
            channel_id, schema_id = cur.u16(), cur.u16()
            topic, encoding = cur.string(), cur.string()
            meta = _Cursor(cur.buf, cur.pos, cur.end)
            meta_length = meta.u32()
            if meta_length > meta.end - meta.pos:
                raise _Short("channel metadata runs past the record")
            meta.end = meta.pos + meta_length
            while meta.pos < meta.end:
                meta.string(), meta.string()
            if schema_id != 0 and schema_id not in self._schemas:
                raise self._fail(offset, f"channel {topic!r} refers to schema {schema_id}, never defined")
            channel = ChannelInfo(topic, encoding, self._schemas.get(schema_id))
            known_channel = self.channels.setdefault(channel_id, channel)
            if known_channel != channel:
                raise self._fail(offset, f"channel {channel_id} is defined twice, differently")
        elif opcode == _OP_MESSAGE:
            channel_id, sequence, log_time, publish_time = struct.unpack("<HIQQ", cur.take(22))
            info = self.channels.get(channel_id)
            if info is None:
                raise self._fail(offset, f"a message on channel {channel_id}, which was never defined")
            self.message_count += 1
            return RawMessage(info, sequence, log_time, publish_time, cur.buf[cur.pos : cur.end])
        # Header, indexes, statistics, metadata, attachments, data end: nothing we need.
        return None

    def _chunk(self, body: bytes, offset: int, topics: frozenset[str] | None) -> Iterator[RawMessage]:
        cur = _Cursor(body)
        cur.u64(), cur.u64()  # message start/end time
        uncompressed_size, crc = cur.u64(), cur.u32()
        compression = cur.string()
        records = cur.take(cur.u64())
        data = self._decompress(compression, records, uncompressed_size, offset)
        if crc != 0 and zlib.crc32(data) != crc:
            raise self._fail(offset, "chunk CRC mismatch: the file is damaged")
        inner = _Cursor(data)
        while inner.pos < inner.end:
            start = inner.pos
            opcode, length = struct.unpack("<BQ", inner.take(9))
            if length > inner.end - inner.pos:
                raise self._fail(offset, f"chunk record at +{start} runs past the chunk")
            rec = _Cursor(inner.buf, inner.pos, inner.pos + length)
            inner.pos += length
            if opcode in (_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE):
                msg = self._record(opcode, rec, offset)
                if msg is not None and (topics is None or msg.topic in topics):
                    yield msg

    def _decompress(self, compression: str, data: bytes, size: int, offset: int) -> bytes:
        try:
            if compression == "":
                out = data
            elif compression == "zstd":
                import zstandard

                pieces, total = [], 0
                for piece in zstandard.ZstdDecompressor().read_to_iter(io.BytesIO(data), write_size=1 << 16):
                    total += len(piece)
                    if total > size:
                        break  # more than announced: a damaged chunk (or a bomb), stop inflating
                    pieces.append(piece)
                out = b"".join(pieces)
            elif compression == "lz4":
                import lz4.frame

                out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
            else:
                raise self._fail(offset, f"chunk compression {compression!r} is not one this reader knows")
        except LogError:
            raise
        except Exception as exc:  # zstd/lz4 errors have their own types: all mean a damaged chunk here
            raise self._fail(offset, f"chunk does not decompress ({compression}): {exc}") from None
        if len(out) != size:
            raise self._fail(
                offset, f"chunk decompresses to {len(out)}{'+' if len(out) > size else ''} bytes, not {size}"
            )
        return out


# -- decoding messages -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LogEntry:
    """One decoded message: `obj` is an instance of the registered type named by the schema, else a
    dict (non-finite floats restored where the file's schema says number); `raw` is the JSON as stored."""

    topic: str
    log_time_ns: int
    obj: Any
    raw: dict[str, Any]
    schema_name: str = ""

    @property
    def t_s(self) -> float:
        return self.log_time_ns * 1e-9


class _Decoder:
    def __init__(self, path: str) -> None:
        self.path = path
        self._file_schemas: dict[SchemaInfo, Any] = {}

    def decode(self, raw_msg: RawMessage) -> LogEntry:
        info = raw_msg.channel
        where = f"topic {info.topic!r}, message at {raw_msg.log_time_ns * 1e-9:.9f} s"
        if info.message_encoding != MESSAGE_ENCODING:
            raise LogError(self.path, f"{where}: message encoding {info.message_encoding!r} is not JSON")
        name = info.schema.name if info.schema is not None else ""
        try:
            obj, raw = decode_message(name, raw_msg.data, lambda: self._file_schema(info.schema))
        except LogError as exc:
            raise LogError(self.path, f"{where}: {exc.problem}") from None
        return LogEntry(info.topic, raw_msg.log_time_ns, obj, raw, name)

    def _file_schema(self, schema: SchemaInfo | None) -> Any:
        if schema is None or schema.encoding != SCHEMA_ENCODING:
            return None
        if schema not in self._file_schemas:
            try:
                self._file_schemas[schema] = json.loads(schema.data)
            except (ValueError, RecursionError):
                self._file_schemas[schema] = None  # an unreadable schema: leave the values as stored
        return self._file_schemas[schema]


def read_objects(path: str | os.PathLike[str], topics: Collection[str] | None = None) -> Iterator[LogEntry]:
    """The messages of a recording (optionally only `topics`), decoded, in file order.

    A crash-truncated file yields what it holds; a damaged one raises LogError.
    """
    reader = McapLogReader(path)
    decoder = _Decoder(reader.path)
    for raw_msg in reader.messages(topics):
        yield decoder.decode(raw_msg)


def read_frames(path: str | os.PathLike[str], bus: str | None = None) -> Iterator[can.Message]:
    """The CAN frames of a recording (all buses, or `bus`), as python-can messages with `channel` = bus."""
    reader = McapLogReader(path)
    decoder = _Decoder(reader.path)
    for raw_msg in reader.messages():
        topic = raw_msg.topic
        if not topic.startswith(CAN_TOPIC_PREFIX) or (bus is not None and topic != CAN_TOPIC_PREFIX + bus):
            continue
        entry = decoder.decode(raw_msg)
        if not isinstance(entry.obj, CanFrame):
            raise LogError(reader.path, f"topic {topic!r} has schema {entry.schema_name!r}, not CAN frames")
        try:
            yield entry.obj.to_message(channel=topic[len(CAN_TOPIC_PREFIX) :])
        except ValueError as exc:
            raise LogError(reader.path, f"topic {topic!r} at {entry.t_s:.9f} s: {exc}") from None
