"""CAN frames over unicast UDP in the cannelloni wire format: the host <-> ECU Ethernet link.

Kammel et al. 2008 (seed 000) Sec. 2.1: "Both computer systems communicate over an Ethernet link."
We keep the CAN framing over that link so that the same CANopen stack (and the same bus URLs) runs
over CAN and over Ethernet, and a real box running cannelloni (https://github.com/mguentner/cannelloni,
doc/udp_format.md, format version 2) can bridge the link onto a physical CAN bus.

Datagram: version u8 (2), op_code u8 (0 = DATA), seq_no u8, count u16; then `count` frames, each
can_id u32 (Linux `canid_t`: EFF 0x80000000, RTR 0x40000000, ERR 0x20000000 flag bits), len u8
(bit 7 set = CAN FD, then a flags u8: BRS 0x01, ESI 0x02), then `len & 0x7F` data bytes; RTR frames
carry no data bytes (their len is the DLC). Everything big-endian.

Deviations from cannelloni: a datagram that is malformed anywhere (bad version/op code, truncated
frame, bad length, trailing bytes) is dropped whole and counted, where cannelloni delivers the
frames before the defect; datagrams from an address other than the configured peer are dropped
and counted (`rx_foreign`). We send one frame per datagram (no batching timer), which cannelloni
accepts; received datagrams may carry any number of frames. Never python-can's udp_multicast
(DESIGN section 5).
"""

from __future__ import annotations

import collections
import copy
import logging
import select
import socket
import struct
import sys
import time
from collections.abc import Sequence
from typing import Any

import can
from can.bus import CanProtocol

log = logging.getLogger(__name__)

CANNELLONI_VERSION = 2
OP_DATA = 0
HEADER = struct.Struct(">BBBH")  # version, op_code, seq_no, count
FRAME_HEAD = struct.Struct(">IB")  # can_id, len

CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CAN_SFF_MASK = 0x000007FF
CAN_EFF_MASK = 0x1FFFFFFF
CANFD_FRAME = 0x80  # in `len`: an FD frame, a flags byte follows
CANFD_BRS = 0x01
CANFD_ESI = 0x02
CANFD_LENGTHS = frozenset({0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64})

MAX_DATAGRAM_BYTES = 65535
DEFAULT_BIND = "127.0.0.1:0"
DEFAULT_RECEIVE_BUFFER_BYTES = 1 << 20


class MalformedDatagram(ValueError):
    """A datagram that is not a valid cannelloni v2 DATA packet."""


def parse_host_port(text: str, what: str, *, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """'HOST:PORT', '[IPv6]:PORT' or ':PORT' (host defaults to loopback) -> (host, port)."""
    host, sep, port_text = text.rpartition(":")
    if not sep:
        raise ValueError(f"{what} {text!r} is not HOST:PORT")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    host = host or default_host
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"{what} {text!r}: port {port_text!r} is not an integer") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"{what} {text!r}: port {port} is outside 0..65535")
    return host, port


def encode_frame(msg: can.Message) -> bytes:
    """One python-can message -> its cannelloni frame bytes."""
    can_id = msg.arbitration_id
    if msg.is_extended_id:
        if not 0 <= can_id <= CAN_EFF_MASK:
            raise ValueError(f"extended CAN id 0x{can_id:X} does not fit in 29 bits")
        can_id |= CAN_EFF_FLAG
    elif not 0 <= can_id <= CAN_SFF_MASK:
        raise ValueError(f"standard CAN id 0x{can_id:X} does not fit in 11 bits (set is_extended_id)")
    if msg.is_remote_frame:
        can_id |= CAN_RTR_FLAG
    if msg.is_error_frame:
        can_id |= CAN_ERR_FLAG
    data = bytes(msg.data or b"")
    if msg.is_fd:
        if msg.is_remote_frame:
            raise ValueError(f"CAN id 0x{msg.arbitration_id:X}: CAN FD has no remote frames")
        if len(data) not in CANFD_LENGTHS:
            raise ValueError(f"CAN id 0x{msg.arbitration_id:X}: {len(data)} is not a CAN FD length")
        flags = (CANFD_BRS if msg.bitrate_switch else 0) | (CANFD_ESI if msg.error_state_indicator else 0)
        return FRAME_HEAD.pack(can_id, len(data) | CANFD_FRAME) + bytes([flags]) + data
    if msg.is_remote_frame:
        if not 0 <= msg.dlc <= 8:
            raise ValueError(f"CAN id 0x{msg.arbitration_id:X}: remote frame DLC {msg.dlc} > 8")
        return FRAME_HEAD.pack(can_id, msg.dlc)
    if len(data) > 8:
        raise ValueError(f"CAN id 0x{msg.arbitration_id:X}: {len(data)} data bytes in a classic frame")
    return FRAME_HEAD.pack(can_id, len(data)) + data


def encode_datagram(msgs: Sequence[can.Message], seq_no: int) -> bytes:
    """Messages -> one cannelloni v2 DATA datagram."""
    if not 0 <= seq_no <= 0xFF:
        raise ValueError(f"seq_no {seq_no} is outside 0..255")
    if len(msgs) > 0xFFFF:
        raise ValueError(f"{len(msgs)} frames do not fit one datagram (count is u16)")
    return HEADER.pack(CANNELLONI_VERSION, OP_DATA, seq_no, len(msgs)) + b"".join(
        encode_frame(m) for m in msgs
    )


def decode_datagram(
    data: bytes, *, timestamp: float = 0.0, channel: str | None = None
) -> tuple[int, list[can.Message]]:
    """One datagram -> (seq_no, messages). MalformedDatagram says what is wrong and at which byte."""
    if len(data) < HEADER.size:
        raise MalformedDatagram(f"{len(data)} bytes is shorter than the {HEADER.size}-byte header")
    version, op_code, seq_no, count = HEADER.unpack_from(data, 0)
    if version != CANNELLONI_VERSION:
        raise MalformedDatagram(f"version {version}, expected {CANNELLONI_VERSION}")
    if op_code != OP_DATA:
        raise MalformedDatagram(f"op_code {op_code}, expected {OP_DATA} (DATA)")
    msgs: list[can.Message] = []
    pos = HEADER.size
    for i in range(count):
        if pos + FRAME_HEAD.size > len(data):
            raise MalformedDatagram(f"frame {i} of {count}: header truncated at byte {pos}")
        raw_id, length = FRAME_HEAD.unpack_from(data, pos)
        pos += FRAME_HEAD.size
        is_extended = bool(raw_id & CAN_EFF_FLAG)
        is_remote = bool(raw_id & CAN_RTR_FLAG)
        is_error = bool(raw_id & CAN_ERR_FLAG)
        arbitration_id = raw_id & CAN_EFF_MASK
        if not is_extended and arbitration_id > CAN_SFF_MASK:
            raise MalformedDatagram(f"frame {i}: standard id 0x{arbitration_id:X} exceeds 11 bits")
        is_fd = bool(length & CANFD_FRAME)
        size = length & ~CANFD_FRAME
        brs = esi = False
        if is_fd:
            if pos >= len(data):
                raise MalformedDatagram(f"frame {i}: CAN FD flags byte missing at byte {pos}")
            flags = data[pos]
            pos += 1
            brs, esi = bool(flags & CANFD_BRS), bool(flags & CANFD_ESI)
            if size not in CANFD_LENGTHS:
                raise MalformedDatagram(f"frame {i}: {size} is not a CAN FD length")
            if is_remote:
                raise MalformedDatagram(f"frame {i}: CAN FD frame with the RTR flag")
        elif size > 8:
            raise MalformedDatagram(f"frame {i}: classic CAN length {size} > 8")
        if is_remote:
            payload = b""
        else:
            if pos + size > len(data):
                raise MalformedDatagram(f"frame {i}: {size} data bytes truncated at byte {pos}")
            payload = data[pos : pos + size]
            pos += size
        msgs.append(
            can.Message(
                timestamp=timestamp,
                arbitration_id=arbitration_id,
                is_extended_id=is_extended,
                is_remote_frame=is_remote,
                is_error_frame=is_error,
                is_fd=is_fd,
                bitrate_switch=brs,
                error_state_indicator=esi,
                dlc=size,
                data=payload,
                channel=channel,
                check=False,
            )
        )
    if pos != len(data):
        raise MalformedDatagram(f"{len(data) - pos} trailing bytes after {count} frames")
    return seq_no, msgs


# SO_TIMESTAMPNS (Linux, asm-generic and x86 alike; Python's socket module does not name it): each
# datagram carries an SCM_TIMESTAMPNS control message with its receive time as a struct timespec
# on CLOCK_REALTIME, the clock python-can stamps frames on.
_SO_TIMESTAMPNS = 35
_TIMESPEC = struct.Struct("@ll")
_STAMP_SPACE = socket.CMSG_SPACE(_TIMESPEC.size)


def _enable_kernel_timestamps(sock: socket.socket) -> bool:
    if not sys.platform.startswith("linux"):
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def _kernel_stamp(ancillary: list[tuple[int, int, bytes]]) -> float:
    """The datagram's kernel receive time (UNIX seconds), or now if the kernel gave none."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(data) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(data)
            return float(sec + nsec * 1e-9)
    return time.time()


class UdpCanBus(can.BusABC):
    """python-can bus over unicast UDP (cannelloni v2 format), python-can interface "bywire_udp".

    `channel` is the local bind address "HOST:PORT" (port 0 picks a free one, see `local_address`),
    `peer` the remote "HOST:PORT" that frames are sent to and accepted from. Loss and reordering are
    those of UDP: on loopback and a point-to-point cable neither happens in practice, and the CANopen
    layer above counts what does (alive counters, heartbeat timeouts).
    """

    def __init__(
        self,
        channel: Any = DEFAULT_BIND,
        peer: str | tuple[str, int] | None = None,
        receive_own_messages: bool = False,
        can_filters: can.typechecking.CanFilters | None = None,
        receive_buffer_bytes: int = DEFAULT_RECEIVE_BUFFER_BYTES,
        **kwargs: object,
    ) -> None:
        bind_text = str(channel) if channel else DEFAULT_BIND
        try:
            bind_host, bind_port = parse_host_port(bind_text, "UdpCanBus channel (bind address)")
        except ValueError as exc:
            raise can.CanInitializationError(str(exc)) from None
        self._receive_own = receive_own_messages
        self._pending: collections.deque[can.Message] = collections.deque()
        self._seq_tx = 0
        self._seq_rx_last: int | None = None
        self.rx_frames = 0
        self.tx_frames = 0
        self.rx_errors = 0  # malformed datagrams dropped
        self.rx_foreign = 0  # datagrams from an address other than the peer, dropped
        self.rx_seq_gaps = 0  # sequence numbers skipped: datagrams lost or reordered on the way
        try:
            family, _, _, _, bind_addr = socket.getaddrinfo(bind_host, bind_port, type=socket.SOCK_DGRAM)[0]
            self._sock = socket.socket(family, socket.SOCK_DGRAM)
            # Best effort (the kernel caps it at net.core.rmem_max): UDP drops what overflows the
            # buffer, and a burst of small CAN datagrams costs far more buffer than its bytes.
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer_bytes)
            # Frames are stamped with the kernel's receive time where it gives one, so a receiver
            # that stalled judges a queued frame by when it arrived, not by when it was read.
            self._kernel_stamps = _enable_kernel_timestamps(self._sock)
            self._sock.bind(bind_addr)
            self._sock.setblocking(False)
        except OSError as exc:
            raise can.CanInitializationError(f"UdpCanBus cannot bind {bind_text!r}: {exc}") from exc
        self._peer: tuple[str, int] | None = None
        if peer is not None:
            self.set_peer(peer)
        local_host, local_port = self.local_address
        self.channel = f"[{local_host}]:{local_port}" if ":" in local_host else f"{local_host}:{local_port}"
        self.channel_info = f"UDP (cannelloni v2) {self.local_address} -> {self._peer}"
        self._can_protocol = CanProtocol.CAN_FD
        super().__init__(channel=self.channel, can_filters=can_filters, **kwargs)

    @property
    def local_address(self) -> tuple[str, int]:
        """The bound (host, port): the port is the real one when bound to port 0."""
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    @property
    def peer(self) -> tuple[str, int] | None:
        return self._peer

    def set_peer(self, peer: str | tuple[str, int]) -> None:
        """Set where frames go and whom frames are accepted from ("HOST:PORT" or (host, port))."""
        host, port = parse_host_port(peer, "UdpCanBus peer") if isinstance(peer, str) else peer
        if not 1 <= port <= 65535:
            raise ValueError(f"UdpCanBus peer port {port} is outside 1..65535")
        try:
            info = socket.getaddrinfo(host, port, self._sock.family, socket.SOCK_DGRAM)
        except OSError as exc:
            raise ValueError(f"UdpCanBus peer {host}:{port} cannot be resolved: {exc}") from exc
        addr = info[0][4]
        self._peer = (str(addr[0]), int(addr[1]))

    def fileno(self) -> int:
        return self._sock.fileno()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._peer is None:
            raise can.CanOperationError("UdpCanBus has no peer to send to (give peer=HOST:PORT)")
        try:
            datagram = encode_datagram([msg], self._seq_tx)
        except ValueError as exc:
            raise can.CanOperationError(f"UdpCanBus cannot encode {msg}: {exc}") from exc
        try:
            self._sock.sendto(datagram, self._peer)
        except OSError as exc:
            raise can.CanOperationError(f"UdpCanBus send to {self._peer} failed: {exc}") from exc
        self._seq_tx = (self._seq_tx + 1) & 0xFF
        self.tx_frames += 1
        if self._receive_own:
            own = copy.copy(msg)
            own.timestamp = time.time()
            own.is_rx = False
            own.channel = self.channel
            self._pending.append(own)

    def _accept(self, data: bytes, addr: tuple[Any, ...], stamp: float) -> list[can.Message]:
        if self._peer is not None and (str(addr[0]), int(addr[1])) != self._peer:
            self.rx_foreign += 1
            return []
        try:
            seq_no, msgs = decode_datagram(data, timestamp=stamp, channel=self.channel)
        except MalformedDatagram as exc:
            self.rx_errors += 1
            log.debug("UdpCanBus %s: dropped datagram from %s: %s", self.channel, addr, exc)
            return []
        if self._seq_rx_last is not None and seq_no != (self._seq_rx_last + 1) & 0xFF:
            self.rx_seq_gaps += 1
        self._seq_rx_last = seq_no
        self.rx_frames += len(msgs)
        return msgs

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._pending:
            return self._pending.popleft(), False
        deadline = None if timeout is None else time.monotonic() + max(timeout, 0.0)
        while True:
            # Drain what the socket already holds before waiting, so that one malformed datagram
            # does not end a recv(timeout=0) poll while valid frames sit behind it.
            while True:
                try:
                    if self._kernel_stamps:
                        data, ancillary, _, addr = self._sock.recvmsg(MAX_DATAGRAM_BYTES, _STAMP_SPACE)
                        stamp = _kernel_stamp(ancillary)
                    else:
                        data, addr = self._sock.recvfrom(MAX_DATAGRAM_BYTES)
                        stamp = time.time()
                except (BlockingIOError, InterruptedError):
                    break
                except OSError as exc:
                    # e.g. an ICMP port-unreachable reported on the socket: not a frame, keep going.
                    self.rx_errors += 1
                    log.debug("UdpCanBus %s: recvfrom failed: %s", self.channel, exc)
                    break
                msgs = self._accept(data, addr, stamp)
                if msgs:
                    self._pending.extend(msgs[1:])
                    return msgs[0], False
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return None, False
            readable, _, _ = select.select([self._sock], [], [], remaining)
            if not readable:
                return None, False

    def shutdown(self) -> None:
        super().shutdown()
        self._sock.close()
