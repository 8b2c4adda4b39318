"""Link meters: loss/corruption of a test stream and round-trip latency (seed 003, Sec. III-B.3).

Seed 003 III-B.3 (1): "CALM Sender and Receiver: a pair of scripts that check the number of lost or
corrupted packages", vital "in estimating the probability of receiving wrong information" (CALM had no
checksum). (2): "CALM Roundtrip Sender and Receiver: the roundtrip receiver is an echo server ... it
immediately rebroadcasts everything that it receives. The roundtrip sender is sending packages with a
fixed content and a defined delay between packages ... and measures the roundtrip time for each
package." They measured ping times of 1-50 ms over 802.11p (III-A).

Probe datagram (ours, big-endian, not ASN.1: it must survive any corruption to be counted as such):

    magic "BWLM" | kind u8 (1 stream, 2 ping, 3 pong) | reserved u8 (0) | stream_id u32 | seq u32 |
    t_ns u64 | payload_len u16 | payload (bytes (seq + i) & 0xFF) | CRC-32 (zlib) of everything before

Deviation: the echo responder answers only pings, as pongs, instead of rebroadcasting everything: on a
broadcast link the responder hears its own echoes (and other responders'), and echoing those is a loop.

Definitions used by `LossMeter` (sequence numbers start at 0 per stream):

- corrupt: a datagram of the stream's size class that fails the magic / length / CRC check (its sequence
  number cannot be trusted, so it also stays among the lost);
- lost: expected - unique, expected = the sender's count if known, else highest seq + 1 (trailing losses
  are then invisible);
- duplicated: a sequence number seen before; reordered: one lower than the highest seen so far;
- rate_hz: (unique - 1) / time between the first and the last unique datagram (receive stamps).
"""

from __future__ import annotations

import math
import struct
import time
import zlib
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from .transport import V2xTransport

MAGIC = b"BWLM"
PROBE_HEAD = struct.Struct(">4sBBIIQH")  # magic, kind, reserved, stream_id, seq, t_ns, payload_len
CRC = struct.Struct(">I")
PROBE_MIN_BYTES = PROBE_HEAD.size + CRC.size  # 28
PROBE_MAX_BYTES = 1472  # one Ethernet frame's UDP payload
SEEN_WINDOW = 1 << 16  # sequence numbers remembered for duplicate detection


class ProbeKind(IntEnum):
    STREAM = 1
    PING = 2
    PONG = 3


class ProbeError(ValueError):
    """A probe datagram that fails a check; `reason` is short, magic, length or crc."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True, slots=True)
class Probe:
    kind: ProbeKind
    stream_id: int
    seq: int
    t_ns: int
    payload_len: int


def make_probe(kind: ProbeKind, stream_id: int, seq: int, t_ns: int, size_bytes: int = 64) -> bytes:
    """A probe datagram of exactly size_bytes (PROBE_MIN_BYTES..PROBE_MAX_BYTES)."""
    if not PROBE_MIN_BYTES <= size_bytes <= PROBE_MAX_BYTES:
        raise ValueError(f"probe size {size_bytes} bytes: must be {PROBE_MIN_BYTES}..{PROBE_MAX_BYTES}")
    n = size_bytes - PROBE_MIN_BYTES
    payload = bytes((seq + i) & 0xFF for i in range(n))
    body = PROBE_HEAD.pack(MAGIC, int(kind), 0, stream_id & 0xFFFF_FFFF, seq & 0xFFFF_FFFF, t_ns, n) + payload
    return body + CRC.pack(zlib.crc32(body))


def parse_probe(data: bytes) -> Probe:
    """Checks magic, length and CRC; ProbeError(reason) otherwise."""
    if len(data) < PROBE_MIN_BYTES:
        raise ProbeError("short", f"{len(data)} bytes < {PROBE_MIN_BYTES}")
    magic, kind, _reserved, stream_id, seq, t_ns, n = PROBE_HEAD.unpack_from(data, 0)
    if magic != MAGIC:
        raise ProbeError("magic", f"bytes 0..3 are {magic!r}, not {MAGIC!r}")
    if len(data) != PROBE_MIN_BYTES + n:
        raise ProbeError("length", f"{len(data)} bytes, header says {PROBE_MIN_BYTES + n}")
    (crc,) = CRC.unpack_from(data, len(data) - CRC.size)
    if crc != zlib.crc32(memoryview(data)[: len(data) - CRC.size]):
        raise ProbeError("crc", f"CRC-32 mismatch (seq field says {seq})")
    if kind not in (1, 2, 3):
        raise ProbeError("magic", f"kind {kind} at byte 4")  # CRC-valid but not ours: another version
    return Probe(ProbeKind(kind), stream_id, seq, t_ns, n)


def percentile(sorted_values: list[float], q: float) -> float:
    """Linear-interpolated percentile (q in 0..100) of an ascending list (numpy's default method)."""
    if not sorted_values:
        return math.nan
    pos = (len(sorted_values) - 1) * q / 100.0
    lo = math.floor(pos)
    hi = min(lo + 1, len(sorted_values) - 1)
    return sorted_values[lo] + (sorted_values[hi] - sorted_values[lo]) * (pos - lo)


# ---------------------------------------------------------------------------------------------- loss


@dataclass(frozen=True)
class LinkReport:
    stream_id: int | None
    datagrams: int  # everything fed, foreign included
    valid: int
    unique: int
    expected: int
    lost: int
    corrupt: int
    duplicated: int
    reordered: int
    foreign: int  # valid probes of another stream or kind, and datagrams that are not probes at all
    duration_s: float
    rate_hz: float

    @property
    def loss_ratio(self) -> float:
        return self.lost / self.expected if self.expected else 0.0

    def as_json(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["loss_ratio"] = self.loss_ratio
        return d


@dataclass
class LossMeter:
    """Classifies the datagrams of one STREAM (the first valid one seen, unless stream_id is given)."""

    stream_id: int | None = None
    expected: int | None = None
    datagrams: int = 0
    valid: int = 0
    unique: int = 0
    corrupt: int = 0
    duplicated: int = 0
    reordered: int = 0
    foreign: int = 0
    highest: int = -1
    first_rx_s: float = math.nan
    last_rx_s: float = math.nan
    _seen: set[int] = field(default_factory=set, repr=False)
    _size: int | None = field(default=None, repr=False)

    def feed(self, data: bytes, rx_time_s: float) -> str:
        """Classify one datagram: ok, reordered, duplicated, corrupt or foreign."""
        self.datagrams += 1
        try:
            probe = parse_probe(data)
        except ProbeError:
            # Scrambled bytes of our stream keep its size (the link corrupts, it does not resize):
            # anything else on the port (V2X traffic, another tool) is foreign, not corruption.
            if self._size is None or len(data) == self._size or data[:4] == MAGIC:
                self.corrupt += 1
                return "corrupt"
            self.foreign += 1
            return "foreign"
        if probe.kind is not ProbeKind.STREAM or (
            self.stream_id is not None and probe.stream_id != self.stream_id
        ):
            self.foreign += 1
            return "foreign"
        if self.stream_id is None:
            self.stream_id = probe.stream_id
        self._size = len(data)
        self.valid += 1
        seq = probe.seq
        # Beyond the remembered window an old number cannot be told from a duplicate: counted as one.
        if seq in self._seen or seq <= self.highest - SEEN_WINDOW:
            self.duplicated += 1
            return "duplicated"
        self._seen.add(seq)
        self.unique += 1
        if math.isnan(self.first_rx_s):
            self.first_rx_s = rx_time_s
        self.last_rx_s = rx_time_s
        if seq < self.highest:
            self.reordered += 1
            return "reordered"
        self.highest = seq
        if len(self._seen) > 2 * SEEN_WINDOW:
            floor = self.highest - SEEN_WINDOW
            self._seen = {s for s in self._seen if s > floor}
        return "ok"

    @property
    def complete(self) -> bool:
        return self.expected is not None and self.unique >= self.expected

    def report(self) -> LinkReport:
        expected = self.expected if self.expected is not None else self.highest + 1
        span = self.last_rx_s - self.first_rx_s if self.unique > 1 else math.nan
        rate = (self.unique - 1) / span if self.unique > 1 and span > 0 else math.nan
        return LinkReport(
            stream_id=self.stream_id,
            datagrams=self.datagrams,
            valid=self.valid,
            unique=self.unique,
            expected=expected,
            lost=max(0, expected - self.unique),
            corrupt=self.corrupt,
            duplicated=self.duplicated,
            reordered=self.reordered,
            foreign=self.foreign,
            duration_s=span,
            rate_hz=rate,
        )


def send_stream(
    transport: V2xTransport, stream_id: int, count: int, rate_hz: float, size_bytes: int = 64
) -> int:
    """The meter's sender: `count` STREAM probes at rate_hz on absolute deadlines; returns datagrams sent."""
    if count < 0:
        raise ValueError(f"count {count}: must be >= 0")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate {rate_hz!r} Hz: must be > 0")
    make_probe(ProbeKind.STREAM, stream_id, 0, 0, size_bytes)  # size check before the first send
    period = 1.0 / rate_hz
    start = time.monotonic()
    sent = 0
    for seq in range(count):
        delay = start + seq * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        if transport.send(make_probe(ProbeKind.STREAM, stream_id, seq, time.time_ns(), size_bytes)):
            sent += 1
    return sent


def receive_stream(
    transport: V2xTransport,
    meter: LossMeter,
    *,
    max_seconds: float,
    idle_s: float = 2.0,
) -> LinkReport:
    """Feed the meter until it has every expected datagram, idle_s passes without one (after the first),
    or max_seconds in all."""
    start = time.monotonic()
    last_rx = math.nan
    while not meter.complete:
        now = time.monotonic()
        if now - start >= max_seconds or (not math.isnan(last_rx) and now - last_rx >= idle_s):
            break
        if transport.wait(min(0.1, max_seconds - (now - start))):
            for d in transport.poll():
                meter.feed(d.payload, d.rx_time_s)
                last_rx = d.rx_mono_s
    return meter.report()


# ---------------------------------------------------------------------------------------------- echo


class EchoResponder:
    """Answers every PING heard on the transport with a PONG of the same content, at once."""

    def __init__(self, transport: V2xTransport) -> None:
        self.transport = transport
        self.echoed = 0
        self.ignored = 0

    def serve_once(self, timeout_s: float) -> int:
        """Wait up to timeout_s for datagrams and answer the pings among them; returns pongs sent."""
        sent = 0
        if not self.transport.wait(timeout_s):
            return 0
        for d in self.transport.poll():
            try:
                probe = parse_probe(d.payload)
            except ProbeError:
                self.ignored += 1
                continue
            if probe.kind is not ProbeKind.PING:
                self.ignored += 1
                continue
            pong = bytearray(d.payload)
            pong[4] = ProbeKind.PONG
            body = bytes(pong[: -CRC.size])
            if self.transport.send(body + CRC.pack(zlib.crc32(body))):
                sent += 1
        self.echoed += sent
        return sent

    def serve(self, *, duration_s: float | None = None, count: int | None = None) -> int:
        """Serve until duration_s passed or count pongs were sent (None and None: forever)."""
        end = math.inf if duration_s is None else time.monotonic() + duration_s
        start_echoed = self.echoed
        while (count is None or self.echoed - start_echoed < count) and time.monotonic() < end:
            self.serve_once(min(0.2, max(0.0, end - time.monotonic())))
        return self.echoed - start_echoed


@dataclass(frozen=True)
class RttReport:
    sent: int
    received: int
    lost: int
    duplicates: int
    rtt_ms: tuple[float, ...]  # in sequence order of the replies

    def stats(self) -> dict[str, float]:
        s = sorted(self.rtt_ms)
        return {
            "min_ms": s[0] if s else math.nan,
            "median_ms": percentile(s, 50.0),
            "p99_ms": percentile(s, 99.0),
            "max_ms": s[-1] if s else math.nan,
        }

    def as_json(self) -> dict[str, Any]:
        return {
            "sent": self.sent,
            "received": self.received,
            "lost": self.lost,
            "duplicates": self.duplicates,
            **self.stats(),
        }


class Pinger:
    """Sends PINGs at a fixed interval and times each one's PONG (monotonic clock of this process)."""

    def __init__(self, transport: V2xTransport, pinger_id: int, size_bytes: int = 64) -> None:
        make_probe(ProbeKind.PING, pinger_id, 0, 0, size_bytes)  # validate the size now
        self.transport = transport
        self.pinger_id = pinger_id & 0xFFFF_FFFF
        self.size_bytes = size_bytes

    def run(self, count: int, interval_s: float, timeout_s: float = 1.0) -> RttReport:
        if count < 1 or not (math.isfinite(interval_s) and interval_s > 0) or not timeout_s >= 0:
            raise ValueError(
                f"ping: count {count} >= 1, interval {interval_s} s > 0, timeout {timeout_s} s >= 0"
            )
        replies: dict[int, float] = {}
        duplicates = 0
        sent = 0
        start = time.monotonic()
        end = start + (count - 1) * interval_s + timeout_s
        seq = 0
        while True:
            now = time.monotonic()
            if seq < count and now >= start + seq * interval_s:
                ping = make_probe(ProbeKind.PING, self.pinger_id, seq, time.monotonic_ns(), self.size_bytes)
                if self.transport.send(ping):
                    sent += 1
                seq += 1
                continue
            if now >= end or (seq >= count and len(replies) >= sent):
                break
            next_send = start + seq * interval_s if seq < count else end
            if self.transport.wait(max(0.0, min(next_send, end) - now)):
                for d in self.transport.poll():
                    try:
                        probe = parse_probe(d.payload)
                    except ProbeError:
                        continue
                    if (
                        probe.kind is not ProbeKind.PONG
                        or probe.stream_id != self.pinger_id
                        or probe.seq >= seq
                    ):
                        continue
                    if probe.seq in replies:
                        duplicates += 1
                        continue
                    replies[probe.seq] = (d.rx_mono_s - probe.t_ns * 1e-9) * 1e3
        rtts = tuple(replies[k] for k in sorted(replies))
        return RttReport(sent, len(replies), sent - len(replies), duplicates, rtts)
