"""Open a CAN bus from a URL-like string (DESIGN section 3), and serve a virtual bus to processes.

One string names the transport everywhere (command lines, scenario files, the HIL runner):

    virtual:NAME                          python-can "virtual" bus, one process
    remote:ws://127.0.0.1:PORT            a "virtual" bus served to several processes over a
                                          loopback websocket by python-can-remote
    socketcan:vcan0 | socketcan:can0      Linux SocketCAN (not in this machine's kernel)
    udp://BIND_HOST:BIND_PORT?peer=HOST:PORT
                                          CAN over unicast UDP, cannelloni format (the host <-> ECU
                                          Ethernet link, Kammel et al. 2008 Sec. 2.1)
    INTERFACE:CHANNEL[?key=value&...]     any other python-can interface (pcan, kvaser, ...)

Query parameters become keyword arguments of the bus, with int, float and bool (true/false,
yes/no, on/off) coercion. python-can's udp_multicast is refused on purpose: joining its group sends
IGMP out of the machine's real interface (DESIGN section 5).
"""

from __future__ import annotations

import faulthandler
import logging
import signal
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import parse_qsl, urlsplit

import can
from can_remote import RemoteServer

from bywire.protocol.udp_bus import UdpCanBus, parse_host_port

log = logging.getLogger(__name__)

ACCEPTED_FORMS = (
    "accepted forms: 'virtual:NAME', 'remote:ws://127.0.0.1:PORT', 'socketcan:vcan0', "
    "'udp://BIND_HOST:BIND_PORT?peer=HOST:PORT', 'INTERFACE:CHANNEL[?key=value&...]' "
    "for another python-can interface (e.g. 'pcan:PCAN_USBBUS1?bitrate=500000')"
)
UDP_INTERFACE = "bywire_udp"
REFUSED_INTERFACES = {
    "udp_multicast": "python-can's udp_multicast sends IGMP out of the machine's real network "
    "interface (DESIGN section 5); use 'udp://...' (unicast) or 'remote:ws://127.0.0.1:PORT'",
}
_TRUE = {"true", "yes", "on"}
_FALSE = {"false", "no", "off"}


class BusUrlError(ValueError):
    """A bus URL that cannot be understood; the message says what is wrong and what is accepted."""

    def __init__(self, url: str, problem: str) -> None:
        super().__init__(f"bus URL {url!r}: {problem}; {ACCEPTED_FORMS}")
        self.url = url
        self.problem = problem


@dataclass(frozen=True)
class BusSpec:
    """What a bus URL means: the python-can interface, its channel and keyword arguments."""

    interface: str
    channel: str
    kwargs: dict[str, Any] = field(default_factory=dict)


def coerce_value(text: str) -> int | float | bool | str:
    """Query value -> int ('500000', '0x10'), float ('0.5'), bool ('true', 'off', ...) or str."""
    lowered = text.strip().lower()
    if lowered in _TRUE:
        return True
    if lowered in _FALSE:
        return False
    try:
        return int(lowered, 0)
    except ValueError:
        pass
    try:
        return float(lowered)
    except ValueError:
        return text


def _parse_query(url: str, query: str) -> dict[str, Any]:
    params: dict[str, Any] = {}
    if not query:
        return params
    try:
        pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=True)
    except ValueError as exc:
        raise BusUrlError(url, f"query {query!r} is not key=value&...: {exc}") from None
    for key, value in pairs:
        if not key.isidentifier():
            raise BusUrlError(url, f"query key {key!r} is not a valid keyword argument name")
        if key in params:
            raise BusUrlError(url, f"query key {key!r} is given twice")
        params[key] = coerce_value(value)
    return params


def _parse_udp(url: str) -> BusSpec:
    parts = urlsplit(url)
    if parts.path not in ("", "/") or parts.fragment:
        raise BusUrlError(
            url, "a udp URL has no path or fragment: use udp://BIND_HOST:BIND_PORT?peer=HOST:PORT"
        )
    params = _parse_query(url, parts.query)
    peer = params.pop("peer", None)
    if peer is None:
        raise BusUrlError(url, "udp needs the peer to send to: add ?peer=HOST:PORT")
    try:
        bind_host, bind_port = parse_host_port(parts.netloc, "bind address")
        peer_host, peer_port = parse_host_port(str(peer), "peer")
    except ValueError as exc:
        raise BusUrlError(url, str(exc)) from None
    if peer_port == 0:
        raise BusUrlError(url, "peer port 0 is not a port one can send to")
    return BusSpec(UDP_INTERFACE, f"{bind_host}:{bind_port}", {"peer": f"{peer_host}:{peer_port}", **params})


def _parse_remote(url: str, target: str) -> BusSpec:
    parts = urlsplit(target)
    if parts.scheme not in ("ws", "wss"):
        raise BusUrlError(url, f"remote needs a ws:// or wss:// address, got {target!r}")
    try:
        port = parts.port
    except ValueError as exc:
        raise BusUrlError(url, f"remote port: {exc}") from None
    if not parts.hostname or port is None:
        raise BusUrlError(url, "remote needs host and port, e.g. remote:ws://127.0.0.1:54701")
    channel = f"{parts.scheme}://{parts.netloc}{parts.path}"
    return BusSpec("remote", channel, _parse_query(url, parts.query))


def parse_bus_url(url: str) -> BusSpec:
    """Bus URL -> BusSpec, without opening anything. BusUrlError says what is wrong."""
    if not isinstance(url, str) or not url.strip():
        raise BusUrlError(str(url), "empty bus URL")
    url = url.strip()
    interface, sep, rest = url.partition(":")
    interface = interface.lower()
    if not sep or not interface:
        raise BusUrlError(url, "no 'INTERFACE:' prefix")
    if interface == "udp":
        if not rest.startswith("//"):
            raise BusUrlError(url, "write udp buses as udp://BIND_HOST:BIND_PORT?peer=HOST:PORT")
        return _parse_udp(url)
    if interface in REFUSED_INTERFACES:
        raise BusUrlError(url, REFUSED_INTERFACES[interface])
    if interface == "remote":
        return _parse_remote(url, rest)
    channel, _, query = rest.partition("?")
    if not channel:
        raise BusUrlError(url, f"no channel after '{interface}:'")
    if interface not in can.interfaces.VALID_INTERFACES:
        known = ", ".join(sorted(can.interfaces.VALID_INTERFACES - set(REFUSED_INTERFACES)))
        raise BusUrlError(url, f"unknown python-can interface {interface!r} (installed: {known})")
    return BusSpec(interface, channel, _parse_query(url, query))


def open_bus(url: str, **kwargs: Any) -> can.BusABC:
    """Open the bus a URL names. Keyword arguments go to the bus; giving one twice (URL and here) is
    an error rather than a silent override."""
    spec = parse_bus_url(url)
    clash = sorted(set(spec.kwargs) & set(kwargs))
    if clash:
        raise BusUrlError(url, f"{', '.join(clash)} given both in the URL and as keyword arguments")
    merged = {**spec.kwargs, **kwargs}
    if spec.interface == UDP_INTERFACE:
        # Direct construction: works even where the package's entry points are not installed.
        return UdpCanBus(channel=spec.channel, **merged)
    return can.Bus(interface=spec.interface, channel=spec.channel, **merged)


# --- serving a virtual bus to several processes (python-can-remote) -------------------------------


def _quiet_remote_logging() -> None:
    # can_remote logs every connection and frame detail at DEBUG/INFO; a bus server is plumbing.
    logging.getLogger("can_remote").setLevel(logging.WARNING)


def serve_virtual_bus(
    port: int, channel: str, host: str = "127.0.0.1"
) -> tuple[RemoteServer, threading.Thread]:
    """Serve python-can virtual bus `channel` on ws://host:port from a daemon thread.

    Port 0 picks a free port: read it from `server.server_port`. Stop with `stop_bus_server`.
    Every client gets its own virtual bus on `channel` inside this process, so a frame sent by one
    client reaches all the others (not itself), in order.
    """
    _quiet_remote_logging()
    # `kill -USR1 PID` writes every thread's stack to stderr: a server that will not stop shows why.
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    # The HIL runner stops its children with SIGINT; a child inherits an ignored or blocked SIGINT
    # from whatever started it (seen: a server started from the test suite's worker slept through it,
    # its only thread waiting in select).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    server = RemoteServer(host, port, interface="virtual", channel=channel)
    thread = threading.Thread(
        target=server.serve_forever,
        kwargs={"poll_interval": 0.05},
        name=f"bus-server-{channel}-{server.server_port}",
        daemon=True,
    )
    thread.start()
    return server, thread


def stop_bus_server(server: RemoteServer, thread: threading.Thread, timeout_s: float = 5.0) -> None:
    """Stop a server started by serve_virtual_bus and wait for its thread."""
    server.shutdown()
    server.server_close()
    thread.join(timeout_s)


def run_bus_server(port: int, channel: str, host: str = "127.0.0.1") -> None:
    """Serve virtual bus `channel` on ws://host:port until interrupted (`bywire bus serve`)."""
    _quiet_remote_logging()
    # `kill -USR1 PID` writes every thread's stack to stderr: a server that will not stop shows why.
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    # The HIL runner stops its children with SIGINT; a child inherits an ignored or blocked SIGINT
    # from whatever started it (seen: a server started from the test suite's worker slept through it,
    # its only thread waiting in select).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    server: RemoteServer | None = None
    try:  # from the server's creation on: an interrupt as soon as its port is open still closes it
        server = RemoteServer(host, port, interface="virtual", channel=channel)
        log.warning("serving virtual CAN bus %r on remote:ws://%s:%d", channel, host, server.server_port)
        server.serve_forever(poll_interval=0.1)
    except KeyboardInterrupt:
        pass
    finally:
        if server is not None:
            server.server_close()


def wait_for_port(host: str, port: int, timeout_s: float = 5.0) -> None:
    """Block until a TCP server accepts connections on host:port; TimeoutError after timeout_s."""
    deadline = time.monotonic() + timeout_s
    last_error: OSError | None = None
    while True:
        try:
            with socket.create_connection((host, port), timeout=0.2):
                return
        except OSError as exc:
            last_error = exc
        if time.monotonic() >= deadline:
            raise TimeoutError(
                f"nothing accepts connections on {host}:{port} after {timeout_s} s: {last_error}"
            )
        time.sleep(0.02)
