"""The MCAP recorder: the object store's topics and the CAN buses of a run, in one MCAP file.

Seed 000 section 3 (every object of the runtime can be logged, DESIGN.md section 1): every topic and
every bus frame of a run goes into one MCAP file that standard tools (Foxglove) open, and the file
stays readable when the host crashes. Messages are encoded by `log_schema` (JSON, a JSON Schema per
type); `mcap_reader` reads them back.

Time. log_time = publish_time = round(t_s * 1e9) ns, t_s being the object's own time on the run's
clock: simulated seconds in SIL, CLOCK_MONOTONIC in HIL, so not an epoch time (Foxglove shows it as
a date near 1970). Times that do not fit MCAP's unsigned nanoseconds (negative, non-finite) are
written as 0; the exact `t_s` is in the message either way. A CAN frame's log time is its
`timestamp` (python-can stamps frames with `time.time()`, an epoch time: pass `t_s=` to
`record_frame` to put frames on the run's clock, e.g. with `protocol.timebase.rx_time_s`).

Crash survival. The recorder writes through to the file descriptor (no user-space buffer), and
closes a chunk when it exceeds `chunk_size` bytes or when its first message is `flush_interval_s`
old (checked on every record, and every `flush_interval_s / 2` by a background thread that writes
chunks older than that). A process killed with SIGKILL therefore leaves a file holding every
message recorded more than `flush_interval_s` (plus thread scheduling latency) before the kill;
only the open chunk is lost. The data survives a process crash, not a
power loss (no fsync before `close()`). The recorder writes CRCs over every chunk, over the whole
data section and over the summary, so that the reader finds damage wherever it is.
"""

from __future__ import annotations

import os
import threading
import time
import typing
from pathlib import Path
from typing import BinaryIO

import can
from mcap.writer import CompressionType, Writer

import bywire
from bywire.host.runtime.can_frame import CAN_TOPIC_PREFIX, CanFrame
from bywire.host.runtime.log_schema import (
    MESSAGE_ENCODING,
    NONFINITE_CONVENTION,
    SCHEMA_ENCODING,
    LogError,
    encode_object,
    object_time_ns,
    schema_bytes,
    schema_name_of,
    time_ns,
)

DEFAULT_CHUNK_SIZE = 256 * 1024  # bytes before compression; a chunk this big is written at once
DEFAULT_FLUSH_INTERVAL_S = 0.25  # the most a crash can lose (see the module docstring)


class _WriteThrough:
    """A file the MCAP writer can use that hands every write to the kernel at once.

    mcap's Writer wraps raw files in a BufferedWriter; this object is not a RawIOBase, so it is used
    as is, and what the writer has written survives the death of the process.
    """

    def __init__(self, path: Path) -> None:
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._pos = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]
            self._pos += n
        return len(data)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass  # nothing buffered here

    def close(self, sync: bool = True) -> None:
        if self._fd >= 0:
            try:
                if sync:
                    os.fsync(self._fd)
            finally:
                os.close(self._fd)
                self._fd = -1


class McapRecorder:
    """Records store objects (`record`, usable as `store.add_tap(rec.record)`) and CAN frames
    (`record_frame`) into one MCAP file; thread-safe; `close()` writes the summary and footer.

    See the module docstring for the encoding, the time base and what a crash can lose.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        compression: str = "zstd",
    ) -> None:
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be at least 1 byte, not {chunk_size}")
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be > 0, not {flush_interval_s}")
        kinds = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in kinds:
            raise ValueError(f"compression must be one of {sorted(kinds)}, not {compression!r}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.flush_interval_s = flush_interval_s
        self._lock = threading.Lock()
        try:
            self._stream = _WriteThrough(self.path)
        except OSError as exc:
            raise LogError(self.path, f"cannot create the recording: {exc.strerror or exc}") from None
        self._writer = Writer(
            typing.cast(BinaryIO, self._stream),
            chunk_size=chunk_size,
            compression=kinds[compression],
            enable_data_crcs=True,  # a CRC over the whole data section, in DataEnd: damage anywhere shows
        )
        self._writer.start(profile="", library=f"bywire {bywire.__version__}")
        self._writer.add_metadata(
            "bywire",
            {
                "log_time": "t_s * 1e9 on the run's clock (simulated in SIL, CLOCK_MONOTONIC in HIL)",
                "nonfinite_floats": NONFINITE_CONVENTION,
            },
        )
        self._schemas: dict[str, int] = {}  # schema name -> id
        self._channels: dict[str, tuple[int, type]] = {}  # topic -> (channel id, type)
        self._sequence: dict[int, int] = {}
        self._pending_since: float | None = None  # monotonic time of the oldest unwritten message
        self._error: BaseException | None = None
        self._closed = False
        self.messages = 0
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="mcap-flush", daemon=True)
        self._flusher.start()

    def record(self, topic: str, obj: object) -> None:
        """Record a dataclass instance with a `t_s` on `topic` (log time from `t_s`)."""
        self._record(topic, obj, object_time_ns(obj, self.path, topic))

    def record_frame(self, bus: str, msg: can.Message, t_s: float | None = None) -> None:
        """Record a CAN frame on `/can/<bus>`; log time = `t_s` if given, else the frame's timestamp."""
        frame = CanFrame.from_message(msg, t_s)
        self._record(CAN_TOPIC_PREFIX + bus, frame, time_ns(frame.timestamp))

    def _record(self, topic: str, obj: object, log_time_ns: int) -> None:
        cls = type(obj)
        try:
            payload = encode_object(obj)
        except LogError as exc:
            raise LogError(self.path, f"topic {topic!r}: {exc.problem}") from None
        with self._lock:
            self._check_open()
            channel = self._channels.get(topic)
            if channel is None:
                channel = self._channels[topic] = (self._register(topic, cls), cls)
            elif channel[1] is not cls:
                raise LogError(
                    self.path, f"topic {topic!r} carries {channel[1].__name__}, not {cls.__name__}"
                )
            channel_id = channel[0]
            seq = self._sequence[channel_id] = self._sequence.get(channel_id, 0) + 1
            now_s = time.monotonic()
            try:
                self._writer.add_message(
                    channel_id=channel_id,
                    log_time=log_time_ns,
                    data=payload,
                    publish_time=log_time_ns,
                    sequence=seq & 0xFFFFFFFF,
                )
                self.messages += 1
                if self._pending_since is None:
                    self._pending_since = now_s
                elif now_s - self._pending_since >= self.flush_interval_s:
                    self._flush_locked()
            except OSError as exc:
                self._error = exc
                raise LogError(self.path, f"writing failed: {exc}") from exc

    def _register(self, topic: str, cls: type) -> int:
        name = schema_name_of(cls)
        schema_id = self._schemas.get(name)
        if schema_id is None:
            schema_id = self._schemas[name] = self._writer.register_schema(
                name=name, encoding=SCHEMA_ENCODING, data=schema_bytes(cls)
            )
        return self._writer.register_channel(
            topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=schema_id
        )

    def _check_open(self) -> None:
        if self._closed:
            raise LogError(self.path, "the recording is closed")
        if self._error is not None:
            raise LogError(self.path, f"writing failed earlier: {self._error}")

    def _flush_locked(self) -> None:
        self._writer.flush()  # closes the open chunk; _WriteThrough has no buffer of its own
        self._pending_since = None

    def _flush_loop(self) -> None:
        # Waking every half interval and writing chunks at least half an interval old bounds the age
        # of an unwritten message by one interval even when nothing else is recorded.
        half_s = self.flush_interval_s / 2
        while not self._stop.wait(half_s):
            with self._lock:
                if self._closed or self._error is not None:
                    return
                if self._pending_since is not None and time.monotonic() - self._pending_since >= half_s:
                    try:
                        self._flush_locked()
                    except OSError as exc:
                        self._error = exc  # reported by the next record() or close()
                        return

    def flush(self) -> None:
        """Write the open chunk now."""
        with self._lock:
            self._check_open()
            self._flush_locked()

    def close(self) -> None:
        """Write the summary and footer and close the file (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            try:
                if self._error is None:
                    self._writer.finish()
            except OSError as exc:
                self._error = exc
            finally:
                self._stream.close(sync=self._error is None)
        if threading.current_thread() is not self._flusher:
            self._flusher.join()
        if self._error is not None:
            raise LogError(self.path, f"writing failed: {self._error}")

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
