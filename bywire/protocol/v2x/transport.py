"""V2X datagrams over UDP broadcast: the car's radio link, or loopback in tests (seed 003, Sec. III).

Seed 003 III-B: the GCDC broadcast CALM frames over 802.11p; AnnieWAY's gateway PC passed their content
"via UDP over a wired connection" to the host. Here the host side is plain UDP broadcast, so an 802.11p
card in OCB mode (or a gateway that bridges one) is just an interface with a broadcast address.

Addresses: `v2x://HOST:PORT[?bind=ADDR&iface=NAME]`, HOST the destination (a broadcast address).
By default a socket binds to HOST itself: Linux lets a UDP socket bind to a local broadcast address, and
it then receives exactly the datagrams sent to that address, from any sender on the link.

- Loopback (tests): `v2x://127.255.255.255:47100`. The local routing table has a broadcast route for
  127.255.255.255 on `lo`, so nothing leaves the machine. With SO_REUSEADDR every socket bound to that
  address and port gets its own copy of every datagram (broadcast delivery is one-to-all; for unicast only
  one socket would get it), so several receivers, and the sender's own receive socket, see every packet.
  Measured here: 3 sockets x 3 datagrams -> 9 deliveries; a unicast to 127.0.0.1 reaches none of them.
- A car: `v2x://192.168.47.255:47100?iface=wlan1` (the interface's broadcast address; SO_BINDTODEVICE
  pins sending and receiving to the radio's interface, needs root or CAP_NET_RAW). `bind=0.0.0.0` also
  takes unicast datagrams addressed to this host.
- Never python-can's udp_multicast here (DESIGN 5: it sends IGMP out of the real interface).

Receive: non-blocking `poll()` drains the socket and stamps every datagram with the kernel's receive time
(SO_TIMESTAMPNS, CLOCK_REALTIME, as UNIX seconds, for the receiver's age checks: a datagram that waited in
the socket buffer is as old as it is) and the monotonic time when it was read (for RTTs). SO_RXQ_OVFL
reports datagrams the kernel dropped because the buffer was full (`kernel_drops`). The receive buffer is
asked for `rcvbuf_bytes` (SO_RCVBUFFORCE as root, beyond net.core.rmem_max) so that a flood is queued, not
dropped, while the receiver catches up.

Send: blocking `sendto` of one datagram; `PeriodicSender` runs a producer at the GCDC's 10-25 Hz on
absolute monotonic deadlines (no drift), stamping each message with the wall-clock time of its slot.

In one process (SIL, tests): `mem://NAME` is an in-process broadcast domain (`MemV2xTransport`) with the
same send / poll / wait / close surface: every member that receives gets its own copy of every datagram
(the sender's own too, as on loopback), stamped with the *receiver's* clock (inject a simulated one for
lockstep runs). No socket, no thread: deterministic. A member's queue holds at most `max_queue`
datagrams; beyond that they are dropped and counted in `kernel_drops`, like a full socket buffer.
`open_v2x(url)` opens either kind by its scheme.
"""

from __future__ import annotations

import errno
import math
import select
import socket
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType
from typing import ClassVar
from urllib.parse import parse_qs, urlsplit

DEFAULT_PORT = 47100
DEFAULT_URL = f"v2x://127.255.255.255:{DEFAULT_PORT}"
DEFAULT_RCVBUF_BYTES = 32 << 20  # ~40k small datagrams queued (kernel charges ~0.8 kB each)
MAX_DATAGRAM_BYTES = 65_535
GCDC_RATE_HZ = (10.0, 25.0)  # seed 003: state messages at 10-25 Hz

# Linux socket options the socket module does not name (asm-generic/socket.h).
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
SO_BINDTODEVICE = getattr(socket, "SO_BINDTODEVICE", 25)
_TIMESPEC = struct.Struct("@qq")  # struct timespec on 64-bit Linux
_ANCILLARY_BYTES = socket.CMSG_SPACE(_TIMESPEC.size) + socket.CMSG_SPACE(4)


class V2xUrlError(ValueError):
    """A v2x:// address that cannot be used; the message quotes it and says what is wrong."""


@dataclass(frozen=True)
class V2xEndpoint:
    """Where datagrams go (host:port) and where this socket listens (bind_host, default host)."""

    host: str
    port: int
    bind_host: str | None = None
    interface: str | None = None

    @property
    def url(self) -> str:
        query = []
        if self.bind_host is not None:
            query.append(f"bind={self.bind_host}")
        if self.interface is not None:
            query.append(f"iface={self.interface}")
        return f"v2x://{self.host}:{self.port}" + ("?" + "&".join(query) if query else "")


def _is_ipv4(text: str) -> bool:
    """Dotted quad only (inet_aton also takes '1', '0x7f.1', ... which would surprise in a config)."""
    try:
        return socket.inet_ntoa(socket.inet_aton(text)) == text
    except (OSError, ValueError):  # ValueError: an embedded NUL
        return False


def parse_v2x_url(url: str) -> V2xEndpoint:
    """'v2x://HOST:PORT[?bind=ADDR&iface=NAME]' -> V2xEndpoint (IPv4: broadcast is an IPv4 notion)."""
    try:
        parts = urlsplit(url)
    except ValueError as e:  # "Invalid IPv6 URL" and the like
        raise V2xUrlError(f"{url!r}: {e}") from None
    if parts.scheme != "v2x":
        raise V2xUrlError(f"{url!r}: scheme must be v2x:// (e.g. {DEFAULT_URL})")
    try:
        port = parts.port
    except ValueError as e:
        raise V2xUrlError(f"{url!r}: {e}") from None
    if not parts.hostname or port is None:
        raise V2xUrlError(f"{url!r}: needs HOST:PORT (e.g. {DEFAULT_URL})")
    if port == 0:
        raise V2xUrlError(f"{url!r}: port 0 is not a place to broadcast to")
    if not _is_ipv4(parts.hostname):
        raise V2xUrlError(f"{url!r}: host {parts.hostname!r} is not an IPv4 address")
    query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=False)
    unknown = set(query) - {"bind", "iface"}
    if unknown:
        raise V2xUrlError(f"{url!r}: unknown parameter(s) {sorted(unknown)}; known: bind, iface")
    bind = query.get("bind", [None])[-1]
    if bind is not None and not _is_ipv4(bind):
        raise V2xUrlError(f"{url!r}: bind {bind!r} is not an IPv4 address")
    iface = query.get("iface", [None])[-1] or None
    return V2xEndpoint(parts.hostname, port, bind, iface)


def _endpoint(address: V2xEndpoint | str) -> V2xEndpoint:
    return parse_v2x_url(address) if isinstance(address, str) else address


@dataclass(frozen=True, slots=True)
class Datagram:
    payload: bytes
    source: tuple[str, int]
    rx_time_s: float  # UNIX s: kernel receive stamp (SO_TIMESTAMPNS), or the wall clock at read
    rx_mono_s: float  # time.monotonic() when poll() read it


class V2xTransport:
    """One UDP socket that broadcasts to an endpoint and (receive=True) listens on it, non-blocking."""

    def __init__(
        self,
        address: V2xEndpoint | str = DEFAULT_URL,
        *,
        receive: bool = True,
        rcvbuf_bytes: int = DEFAULT_RCVBUF_BYTES,
    ) -> None:
        self.endpoint = _endpoint(address)
        self.receiving = receive
        self.sent = 0
        self.received = 0
        self.send_errors = 0
        self.kernel_drops = 0  # datagrams the kernel dropped on a full receive buffer (SO_RXQ_OVFL)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            if self.endpoint.interface:
                sock.setsockopt(socket.SOL_SOCKET, SO_BINDTODEVICE, self.endpoint.interface.encode() + b"\0")
            if receive:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self._set_rcvbuf(sock, rcvbuf_bytes)
                sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
                sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
                bind = self.endpoint.bind_host if self.endpoint.bind_host is not None else self.endpoint.host
                sock.bind((bind, self.endpoint.port))
        except OSError as e:
            sock.close()
            raise OSError(e.errno, f"{self.endpoint.url}: {e.strerror or e}") from None
        self.rcvbuf_bytes = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) if receive else 0
        self._sock = sock
        self._dest = (self.endpoint.host, self.endpoint.port)

    @staticmethod
    def _set_rcvbuf(sock: socket.socket, size: int) -> None:
        try:  # root / CAP_NET_ADMIN: past net.core.rmem_max
            sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, size)
        except OSError:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)

    def fileno(self) -> int:
        return self._sock.fileno()

    @property
    def local_address(self) -> tuple[str, int]:
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    def send(self, payload: bytes) -> bool:
        """Broadcast one datagram; False (counted in send_errors) if the kernel refused it."""
        try:
            self._sock.sendto(payload, self._dest)
        except OSError as e:
            if e.errno in (
                errno.ENOBUFS,
                errno.EAGAIN,
                errno.ENETUNREACH,
                errno.EHOSTUNREACH,
                errno.EMSGSIZE,
            ):
                self.send_errors += 1
                return False
            raise
        self.sent += 1
        return True

    def wait(self, timeout_s: float) -> bool:
        """Block until a datagram is readable or timeout_s passed; True if readable."""
        if not self.receiving:
            raise RuntimeError(f"{self.endpoint.url}: transport opened with receive=False")
        readable, _, _ = select.select([self._sock], [], [], max(0.0, timeout_s))
        return bool(readable)

    def poll(self, max_datagrams: int = 4096) -> list[Datagram]:
        """Every datagram waiting (up to max_datagrams), without blocking."""
        if not self.receiving:
            raise RuntimeError(f"{self.endpoint.url}: transport opened with receive=False")
        out: list[Datagram] = []
        sock = self._sock
        while len(out) < max_datagrams:
            try:
                data, ancdata, _flags, source = sock.recvmsg(
                    MAX_DATAGRAM_BYTES, _ANCILLARY_BYTES, socket.MSG_DONTWAIT
                )
            except (BlockingIOError, InterruptedError):
                break
            mono = time.monotonic()
            rx_time = math.nan
            for level, kind, value in ancdata:
                if level != socket.SOL_SOCKET:
                    continue
                if kind == SO_TIMESTAMPNS and len(value) >= _TIMESPEC.size:
                    sec, nsec = _TIMESPEC.unpack_from(value)
                    rx_time = sec + nsec * 1e-9
                elif kind == SO_RXQ_OVFL and len(value) >= 4:
                    self._note_drops(int.from_bytes(value[:4], "little"))
            if math.isnan(rx_time):
                rx_time = time.time()
            out.append(Datagram(data, (str(source[0]), int(source[1])), rx_time, mono))
        self.received += len(out)
        return out

    def _note_drops(self, total: int) -> None:
        # The kernel's counter is per socket and cumulative since it was created; it is only reported
        # (on the next datagram) once it is non-zero.
        self.kernel_drops = max(self.kernel_drops, total)

    def close(self) -> None:
        self._sock.close()

    def __enter__(self) -> V2xTransport:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


MEM_DEFAULT_QUEUE = 65_536


class MemV2xTransport:
    """A member of the in-process broadcast domain `mem://NAME` (see the module docstring)."""

    _domains: ClassVar[dict[str, list[MemV2xTransport]]] = {}

    def __init__(
        self,
        address: str,
        *,
        receive: bool = True,
        clock: Callable[[], float] = time.time,
        max_queue: int = MEM_DEFAULT_QUEUE,
    ) -> None:
        parts = urlsplit(address)
        name = (parts.netloc + parts.path).strip("/")
        if parts.scheme != "mem" or not name or parts.query:
            raise V2xUrlError(f"{address!r}: an in-process link is mem://NAME (e.g. mem://sil-v2x)")
        self.name = name
        self.url = f"mem://{name}"
        self.receiving = receive
        self.clock = clock
        self.max_queue = max_queue
        self.sent = 0
        self.received = 0
        self.send_errors = 0
        self.kernel_drops = 0
        self._queue: deque[Datagram] = deque()
        self._source = ("mem", id(self) & 0xFFFF)
        self._closed = False
        MemV2xTransport._domains.setdefault(name, []).append(self)

    def send(self, payload: bytes) -> bool:
        if self._closed:
            raise OSError(errno.EBADF, f"{self.url}: transport is closed")
        if len(payload) > MAX_DATAGRAM_BYTES:
            self.send_errors += 1
            return False
        data = bytes(payload)
        for member in MemV2xTransport._domains.get(self.name, ()):
            if not member.receiving:
                continue
            if len(member._queue) >= member.max_queue:
                member.kernel_drops += 1
                continue
            t = member.clock()
            member._queue.append(Datagram(data, self._source, t, t))
        self.sent += 1
        return True

    def wait(self, timeout_s: float) -> bool:
        """Never blocks (one thread holds every end in SIL): True if a datagram is waiting."""
        if not self.receiving:
            raise RuntimeError(f"{self.url}: transport opened with receive=False")
        return bool(self._queue)

    def poll(self, max_datagrams: int = 4096) -> list[Datagram]:
        if not self.receiving:
            raise RuntimeError(f"{self.url}: transport opened with receive=False")
        n = min(max_datagrams, len(self._queue))
        out = [self._queue.popleft() for _ in range(n)]
        self.received += n
        return out

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        members = MemV2xTransport._domains.get(self.name, [])
        if self in members:
            members.remove(self)
        if not members:
            MemV2xTransport._domains.pop(self.name, None)

    def __enter__(self) -> MemV2xTransport:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def open_v2x(
    url: str, *, receive: bool = True, clock: Callable[[], float] | None = None
) -> V2xTransport | MemV2xTransport:
    """`v2x://HOST:PORT...` (UDP broadcast) or `mem://NAME` (in process; `clock` stamps receptions)."""
    if url.startswith("mem:"):
        return MemV2xTransport(url, receive=receive, clock=clock or time.time)
    return V2xTransport(url, receive=receive)


class PeriodicSender:
    """Sends what `produce(t_unix_s)` returns every 1/rate_hz s on absolute monotonic deadlines.

    produce gets the wall-clock (UNIX) time of its slot, to stamp as the generation time, and may
    return None to skip a slot. A late slot is sent at once; slots missed by more than one period are
    skipped (counted in `skipped`), never sent in a burst. Two sends are at least half a period apart:
    a late slot sent at once must not be followed within the same millisecond by the next one, whose
    equal generation time receivers rightly reject as a replay (ETSI CAM: T_GenCamMin bounds the rate).
    """

    def __init__(self, transport: V2xTransport, rate_hz: float) -> None:
        if not (math.isfinite(rate_hz) and 0.0 < rate_hz <= 100.0):
            raise ValueError(
                f"rate_hz {rate_hz!r}: must be in (0, 100] Hz (GCDC: {GCDC_RATE_HZ[0]:g}-{GCDC_RATE_HZ[1]:g})"
            )
        self.transport = transport
        self.period_s = 1.0 / rate_hz
        self.sent = 0
        self.skipped = 0

    def run(
        self,
        produce: Callable[[float], bytes | None],
        *,
        count: int | None = None,
        duration_s: float | None = None,
        stop: Callable[[], bool] | None = None,
    ) -> int:
        """Send until `count` datagrams, `duration_s` elapsed, or stop() is true; returns datagrams sent."""
        if count is None and duration_s is None and stop is None:
            raise ValueError("PeriodicSender.run: give count, duration_s or stop, or it never ends")
        start = time.monotonic()
        end = math.inf if duration_s is None else start + duration_s
        slot = 0
        sent_here = 0
        last_send = -math.inf
        while (count is None or sent_here < count) and not (stop is not None and stop()):
            deadline = start + slot * self.period_s
            if deadline >= end:
                break
            now = time.monotonic()
            if now < last_send + 0.5 * self.period_s:
                time.sleep(last_send + 0.5 * self.period_s - now)
                now = time.monotonic()
            if now < deadline:
                time.sleep(deadline - now)
            elif now - deadline > self.period_s:
                missed = int((now - deadline) / self.period_s)
                self.skipped += missed
                slot += missed
                continue
            last_send = time.monotonic()
            payload = produce(time.time())
            if payload is not None and self.transport.send(payload):
                sent_here += 1
                self.sent += 1
            slot += 1
        return sent_here
