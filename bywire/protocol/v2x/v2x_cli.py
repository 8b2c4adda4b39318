"""`bywire v2x meter|echo|ping|fuzz`: the link tools of seed 003 Sec. III-B.3 over the V2X transport.

- `meter send` / `meter receive`: a sequence-numbered test stream and its loss / corruption /
  duplicate / reorder counts and rate (III-B.3 (1), "CALM Sender and Receiver").
- `echo`: the round-trip responder, answering every ping at once (III-B.3 (2)).
- `ping`: pings at a fixed interval, median / p99 / max round-trip time (the paper measured 1-50 ms).
- `fuzz`: floods an address with hostile datagrams for a bounded count and time (III-B.3 (3)).
- `encode STATE.json -o FILE`: the exact bytes of the CAM we would broadcast for a vehicle state in SI
  units; `decode FILE`: any message we receive (CAM, iCLCM, SPATEM, MAPEM) as JSON in the same units. The
  tools to debug interop with another stack.

Every command defaults to loopback broadcast (`v2x://127.255.255.255:47100`): nothing leaves the machine
unless you name a real interface's broadcast address. Exit status: 0 done, 1 the link failed its check
(no reply at all, or loss above --max-loss; `decode`: the bytes are not a message we take), 2 bad
arguments (argparse), an unusable input file, or the address cannot be used.
Standalone: `python -m bywire.protocol.v2x.v2x_cli COMMAND ...`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .transport import DEFAULT_URL, V2xTransport, V2xUrlError, parse_v2x_url


def _url(text: str) -> str:
    try:
        parse_v2x_url(text)
    except V2xUrlError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return value


def _count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 1")
    return value


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--url", type=_url, default=DEFAULT_URL, help=f"v2x://BROADCAST:PORT (default {DEFAULT_URL})"
    )
    p.add_argument("--json", type=Path, metavar="FILE", help="write the result as JSON")


def _write_json(path: Path | None, doc: dict[str, Any]) -> None:
    if path is not None:
        path.write_text(json.dumps(doc, indent=2, allow_nan=True) + "\n")


def _open(url: str, *, receive: bool) -> V2xTransport | None:
    try:
        return V2xTransport(url, receive=receive)
    except OSError as e:
        print(f"v2x: cannot open {url}: {e}", file=sys.stderr)
        return None


# ---------------------------------------------------------------------------------------------- meter


def add_meter_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("role", choices=("send", "receive"), help="send the test stream, or receive and count it")
    _common(p)
    p.add_argument("--count", type=_count, default=1000, help="datagrams to send / expected (default 1000)")
    p.add_argument("--rate", type=_positive_float, default=25.0, help="send rate in Hz (default 25)")
    p.add_argument("--size", type=int, default=64, help="datagram size in bytes, 28..1472 (default 64)")
    p.add_argument("--stream-id", type=int, default=None, help="stream id (send: default the PID)")
    p.add_argument(
        "--seconds", type=_positive_float, default=60.0, help="receive: give up after (default 60)"
    )
    p.add_argument("--idle", type=_positive_float, default=2.0, help="receive: stop after this silence (s)")
    p.add_argument("--max-loss", type=float, default=None, help="receive: exit 1 if loss ratio exceeds this")


def main_meter(args: argparse.Namespace) -> int:
    from .meter import LossMeter, receive_stream, send_stream

    tx = _open(args.url, receive=args.role == "receive")
    if tx is None:
        return 2
    with tx:
        if args.role == "send":
            stream_id = os.getpid() if args.stream_id is None else args.stream_id
            try:
                sent = send_stream(tx, stream_id, args.count, args.rate, args.size)
            except ValueError as e:
                print(f"v2x meter: {e}", file=sys.stderr)
                return 2
            print(
                f"sent {sent} of {args.count} datagrams (stream {stream_id}, {args.size} B, {args.rate:g} Hz)"
            )
            _write_json(args.json, {"sent": sent, "stream_id": stream_id, "send_errors": tx.send_errors})
            return 0 if sent == args.count else 1
        meter = LossMeter(stream_id=args.stream_id, expected=args.count)
        report = receive_stream(tx, meter, max_seconds=args.seconds, idle_s=args.idle)
        doc = report.as_json() | {"kernel_drops": tx.kernel_drops}
        print(
            f"stream {report.stream_id}: {report.unique}/{report.expected} received, lost {report.lost} "
            f"({100 * report.loss_ratio:.2f} %), corrupt {report.corrupt}, duplicated {report.duplicated}, "
            f"reordered {report.reordered}, foreign {report.foreign}, {report.rate_hz:.1f} Hz"
        )
        _write_json(args.json, doc)
        if report.valid == 0:
            return 1
        return 1 if args.max_loss is not None and report.loss_ratio > args.max_loss else 0


# ---------------------------------------------------------------------------------------------- echo/ping


def add_echo_arguments(p: argparse.ArgumentParser) -> None:
    _common(p)
    p.add_argument(
        "--seconds", type=_positive_float, default=None, help="stop after this long (default: never)"
    )
    p.add_argument("--count", type=_count, default=None, help="stop after this many echoes")


def main_echo(args: argparse.Namespace) -> int:
    from .meter import EchoResponder

    tx = _open(args.url, receive=True)
    if tx is None:
        return 2
    with tx:
        responder = EchoResponder(tx)
        try:
            echoed = responder.serve(duration_s=args.seconds, count=args.count)
        except KeyboardInterrupt:
            echoed = responder.echoed
        print(f"echoed {echoed} pings ({responder.ignored} other datagrams ignored)")
        _write_json(args.json, {"echoed": echoed, "ignored": responder.ignored})
    return 0


def add_ping_arguments(p: argparse.ArgumentParser) -> None:
    _common(p)
    p.add_argument("--count", type=_count, default=100, help="pings to send (default 100)")
    p.add_argument("--interval-ms", type=_positive_float, default=100.0, help="between pings (default 100)")
    p.add_argument("--size", type=int, default=64, help="datagram size in bytes, 28..1472 (default 64)")
    p.add_argument("--timeout", type=float, default=1.0, help="wait for late replies after the last ping (s)")
    p.add_argument("--id", type=int, default=None, help="pinger id (default: the PID)")


def main_ping(args: argparse.Namespace) -> int:
    from .meter import Pinger

    tx = _open(args.url, receive=True)
    if tx is None:
        return 2
    with tx:
        try:
            pinger = Pinger(tx, os.getpid() if args.id is None else args.id, args.size)
            report = pinger.run(args.count, args.interval_ms / 1e3, args.timeout)
        except ValueError as e:
            print(f"v2x ping: {e}", file=sys.stderr)
            return 2
    doc = report.as_json()
    print(
        f"{report.received}/{report.sent} replies, lost {report.lost}, dup {report.duplicates}; RTT median "
        f"{doc['median_ms']:.3f} ms, p99 {doc['p99_ms']:.3f} ms, max {doc['max_ms']:.3f} ms"
    )
    _write_json(args.json, doc)
    return 0 if report.received > 0 else 1


# ---------------------------------------------------------------------------------------------- fuzz


def add_fuzz_arguments(p: argparse.ArgumentParser) -> None:
    _common(p)
    p.add_argument("--count", type=_count, default=20_000, help="datagrams to send (default 20000)")
    p.add_argument("--seconds", type=_positive_float, default=5.0, help="spread them over (default 5 s)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--own-station-id", type=int, default=None, help="spoof this id too (the victim's own)")
    p.add_argument("--avoid", type=int, nargs="*", default=[], help="station ids never to use")
    p.add_argument("--center", type=float, nargs=2, metavar=("LAT", "LON"), default=None, help="fleet centre")


def main_fuzz(args: argparse.Namespace) -> int:
    from .fuzz import DEFAULT_CENTER, V2xFuzzer, flood
    from .receiver import GeoPoint

    center = DEFAULT_CENTER if args.center is None else GeoPoint(*args.center)
    fuzzer = V2xFuzzer(
        args.seed, center=center, own_station_id=args.own_station_id, avoid_station_ids=frozenset(args.avoid)
    )
    try:
        report = flood(args.url, args.count, args.seconds, fuzzer=fuzzer)
    except OSError as e:
        print(f"v2x fuzz: {args.url}: {e}", file=sys.stderr)
        return 2
    print(f"sent {report.sent} fuzz datagrams in {report.elapsed_s:.2f} s ({report.rate_hz:.0f}/s)")
    _write_json(
        args.json,
        {
            "sent": report.sent,
            "send_errors": report.send_errors,
            "elapsed_s": report.elapsed_s,
            "by_kind": report.by_kind,
        },
    )
    return 0


# ---------------------------------------------------------------------------------------------- encode/decode

STATE_KEYS = (
    "station_id", "time_unix_s", "lat_deg", "lon_deg", "heading_rad", "speed_mps", "yaw_rate_radps",
    "accel_mps2", "length_m", "width_m",
)  # fmt: skip
OPTIONAL_STATE_KEYS = ("drive_direction", "lane_position", "station_type")


class StateFileError(ValueError):
    """A vehicle-state file we cannot use; the text names the file and the field."""


def read_state(path: Path) -> Any:
    """A vehicle state in SI units from JSON (the keys of STATE_KEYS; null: unavailable) -> VehicleState."""
    from .codec import DriveDirection, VehicleState

    try:
        doc = json.loads(path.read_text())
    except OSError as e:
        raise StateFileError(f"{path}: {e.strerror or e}") from None
    except json.JSONDecodeError as e:
        raise StateFileError(f"{path}: line {e.lineno}, column {e.colno}: {e.msg}") from None
    if not isinstance(doc, dict):
        raise StateFileError(f"{path}: expected a JSON object with {', '.join(STATE_KEYS)}")
    if doc.get("message", "CAM") != "CAM":
        raise StateFileError(f"{path}: message: {doc['message']!r}, only a CAM's vehicle state encodes")
    missing = [k for k in STATE_KEYS if k not in doc]
    if missing:
        raise StateFileError(f"{path}: missing {', '.join(missing)}")
    unknown = sorted(set(doc) - set(STATE_KEYS) - set(OPTIONAL_STATE_KEYS) - {"message"})
    if unknown:
        raise StateFileError(f"{path}: unknown field {', '.join(unknown)} (fields: {', '.join(STATE_KEYS)})")
    if not isinstance(doc["time_unix_s"], int | float) or isinstance(doc["time_unix_s"], bool):
        raise StateFileError(f"{path}: time_unix_s: {doc['time_unix_s']!r} is not a number")
    direction = doc.get("drive_direction")
    try:
        drive = None if direction is None else DriveDirection(direction)
    except ValueError:
        raise StateFileError(f"{path}: drive_direction: {direction!r} is not forward or backward") from None
    extra: dict[str, Any] = {"drive_direction": drive, "lane_position": doc.get("lane_position")}
    if "station_type" in doc:
        extra["station_type"] = doc["station_type"]
    return VehicleState(doc["station_id"], doc["time_unix_s"], *(doc[k] for k in STATE_KEYS[2:]), **extra)


def message_json(msg: Any) -> dict[str, Any]:
    """A decoded message as JSON in SI units: its fields, `time_unix_s` for its generation time."""
    import dataclasses
    import enum

    from .wire import V2xMessage

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {("time_unix_s" if f.name == "generation_time_s" else f.name): plain(getattr(v, f.name))
                    for f in dataclasses.fields(v)}  # fmt: skip
        if isinstance(v, tuple):
            return [plain(x) for x in v]
        if isinstance(v, str):  # StrEnum members too
            return str(v)
        if isinstance(v, enum.IntEnum):
            return v.name.lower()
        return v

    names = {"VehicleState": "CAM", "CooperativeState": "iCLCM", "SignalPhases": "SPATEM", "RoadMap": "MAPEM"}
    assert isinstance(msg, V2xMessage)
    return {"message": names[type(msg).__name__], **plain(msg)}


def add_encode_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("state", type=Path, metavar="STATE.json", help="vehicle state in SI units (JSON)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FILE", help="write the CAM's bytes")
    p.add_argument(
        "--without-low-frequency",
        action="store_true",
        help="without the low-frequency container (a CAM within 500 ms of the last that had it)",
    )


def main_encode(args: argparse.Namespace) -> int:
    from .codec import V2xEncodeError
    from .wire import encode

    try:
        state = read_state(args.state)
        data = encode(state, low_frequency=not args.without_low_frequency)
    except StateFileError as e:
        print(f"v2x encode: {e}", file=sys.stderr)
        return 2
    except V2xEncodeError as e:
        print(f"v2x encode: {args.state}: {e}", file=sys.stderr)
        return 2
    try:
        args.output.write_bytes(data)
    except OSError as e:
        print(f"v2x encode: {args.output}: {e.strerror or e}", file=sys.stderr)
        return 2
    print(f"{args.output}: CAM of station {state.station_id}, {len(data)} bytes")
    return 0


def add_decode_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", type=Path, metavar="FILE", help="one datagram's bytes")
    p.add_argument(
        "--time",
        type=float,
        default=None,
        metavar="UNIX_S",
        help="receive time that resolves a CAM's/iCLCM's 65.536 s GenerationDeltaTime and a SPATEM's/MAPEM's "
        "year (default: now)",
    )


def main_decode(args: argparse.Namespace) -> int:
    import time

    from .codec import V2xDecodeError
    from .wire import decode

    try:
        data = args.file.read_bytes()
    except OSError as e:
        print(f"v2x decode: {args.file}: {e.strerror or e}", file=sys.stderr)
        return 2
    try:
        msg = decode(data, time.time() if args.time is None else args.time)
    except V2xDecodeError as e:
        print(f"v2x decode: {args.file}: {e}", file=sys.stderr)
        return 1
    print(json.dumps(message_json(msg), indent=2))
    return 0


# ---------------------------------------------------------------------------------------------- wiring

COMMANDS = {
    "meter": (
        add_meter_arguments,
        main_meter,
        "loss/corruption meter: a numbered test stream, sent or counted",
    ),
    "echo": (add_echo_arguments, main_echo, "round-trip responder: answers every ping at once"),
    "ping": (add_ping_arguments, main_ping, "round-trip times through an echo responder"),
    "fuzz": (add_fuzz_arguments, main_fuzz, "flood an address with hostile V2X datagrams (bounded)"),
    "encode": (add_encode_arguments, main_encode, "a vehicle state (SI, JSON) -> the bytes of our CAM"),
    "decode": (add_decode_arguments, main_decode, "a datagram (CAM, iCLCM, SPATEM, MAPEM) -> JSON in SI"),
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    """All v2x subcommands under `p` (dest v2x_command), for `bywire v2x ...`."""
    sub = p.add_subparsers(dest="v2x_command", required=True, metavar="COMMAND")
    for name, (add, _main, help_text) in COMMANDS.items():
        add(sub.add_parser(name, help=help_text, description=help_text))


def main(args: argparse.Namespace) -> int:
    return COMMANDS[args.v2x_command][1](args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bywire v2x", description=__doc__.splitlines()[0] if __doc__ else None
    )
    add_arguments(parser)
    return parser


def run(argv: Sequence[str]) -> int:
    """Parse and run one command line (tests, scripts)."""
    return main(build_parser().parse_args(list(argv)))


if __name__ == "__main__":
    sys.exit(main(build_parser().parse_args(sys.argv[1:] if len(sys.argv) > 1 else ["--help"])))
