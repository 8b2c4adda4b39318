"""Link tools (seed 003 III-B.3 (1)-(2)): probe format, the loss/corruption meter on known impaired
streams, echo/ping round trips and the `bywire v2x` CLI functions on loopback, and the benchmark's JSON."""

from __future__ import annotations

import argparse
import json
import socket
import threading
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bywire.cli import benchmark
from bywire.protocol.v2x import v2x_cli
from bywire.protocol.v2x.codec import VehicleState
from bywire.protocol.v2x.meter import (
    PROBE_MIN_BYTES,
    EchoResponder,
    LossMeter,
    Pinger,
    ProbeError,
    ProbeKind,
    make_probe,
    parse_probe,
    percentile,
    receive_stream,
    send_stream,
)
from bywire.protocol.v2x.transport import V2xTransport
from bywire.protocol.v2x.wire import encode

bench = benchmark("v2x")


def free_url() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"v2x://127.255.255.255:{s.getsockname()[1]}"


# ---------------------------------------------------------------------------------------------- probes


def test_probe_round_trip_and_checks() -> None:
    p = make_probe(ProbeKind.STREAM, 77, 12345, 999, 100)
    assert len(p) == 100
    got = parse_probe(p)
    assert (got.kind, got.stream_id, got.seq, got.t_ns, got.payload_len) == (
        ProbeKind.STREAM,
        77,
        12345,
        999,
        72,
    )
    flipped = bytearray(p)
    flipped[40] ^= 0x04
    cases = {
        b"BWLM": "short",
        b"XXXX" + p[4:]: "magic",
        p[:-1]: "length",
        bytes(flipped): "crc",
    }
    for data, reason in cases.items():
        with pytest.raises(ProbeError) as err:
            parse_probe(data)
        assert err.value.reason == reason
    with pytest.raises(ValueError, match="probe size"):
        make_probe(ProbeKind.PING, 1, 0, 0, PROBE_MIN_BYTES - 1)


def test_percentile_matches_numpy() -> None:
    values = sorted(np.random.default_rng(1).exponential(3.0, 257).tolist())
    for q in (0, 1, 50, 90, 99, 100):
        assert percentile(values, q) == pytest.approx(float(np.percentile(values, q)))
    assert np.isnan(percentile([], 50))


# ---------------------------------------------------------------------------------------------- loss meter


def test_loss_meter_known_impairments() -> None:
    stream = [make_probe(ProbeKind.STREAM, 5, seq, 0, 64) for seq in range(100)]
    lost = {10, 11, 50, 98, 99}  # two at the end: only visible because the count is known
    order = [s for s in range(100) if s not in lost]
    order[20], order[21] = order[21], order[20]  # one swap: the later-sent one is "reordered"
    order[60], order[62] = order[62], order[60]  # c, b, a: both b and a arrive below the highest (2)
    meter = LossMeter(expected=100)
    t = 0.0
    for seq in order:
        meter.feed(stream[seq], t)
        t += 0.01
    for seq in (3, 3, 40):  # three duplicates
        meter.feed(stream[seq], t)
    for seq in (7, 8):  # two corrupted copies (a flipped bit, a truncated tail)
        bad = bytearray(stream[seq])
        bad[30] ^= 1
        assert meter.feed(bytes(bad), t) == "corrupt"
    assert meter.feed(stream[9][:-4] + b"\x00\x00\x00\x00", t) == "corrupt"
    other = make_probe(ProbeKind.STREAM, 6, 0, 0, 64)
    state = encode(VehicleState(1, 1.7e9, 49.0, 8.4, 0.0, 1.0, 0.0, 0.0, 4.0, 1.8))
    assert meter.feed(other, t) == "foreign" and meter.feed(state, t) == "foreign"
    r = meter.report()
    assert r.stream_id == 5
    assert (r.expected, r.unique, r.lost) == (100, 95, 5)
    assert (r.duplicated, r.reordered, r.corrupt, r.foreign) == (3, 3, 3, 2)
    assert r.valid == 95 + 3 and r.datagrams == 95 + 3 + 3 + 2
    assert r.loss_ratio == pytest.approx(0.05)
    assert r.rate_hz == pytest.approx(100.0, rel=1e-6)  # 95 datagrams 10 ms apart
    assert json.loads(json.dumps(r.as_json()))["lost"] == 5


def test_loss_meter_without_count_sees_gaps_not_the_tail() -> None:
    meter = LossMeter()
    for seq in (0, 1, 2, 5, 6):
        meter.feed(make_probe(ProbeKind.STREAM, 9, seq, 0, 40), 0.1 * seq)
    r = meter.report()
    assert (r.expected, r.lost) == (7, 2)


def test_stream_over_loopback() -> None:
    url = free_url()
    with V2xTransport(url) as rx, V2xTransport(url, receive=False) as tx:
        meter = LossMeter(stream_id=3, expected=300)
        sender = threading.Thread(target=send_stream, args=(tx, 3, 300, 2000.0, 200))
        sender.start()
        report = receive_stream(rx, meter, max_seconds=10.0, idle_s=2.0)
        sender.join()
    assert (report.unique, report.lost, report.corrupt, report.duplicated) == (300, 0, 0, 0)


# ---------------------------------------------------------------------------------------------- echo / ping


def test_echo_and_ping_over_loopback() -> None:
    url = free_url()
    with V2xTransport(url) as echo_side, V2xTransport(url) as ping_side:
        responder = EchoResponder(echo_side)
        server = threading.Thread(target=responder.serve, kwargs={"count": 30, "duration_s": 10.0})
        server.start()
        report = Pinger(ping_side, 99, 128).run(30, 0.005, timeout_s=2.0)
        server.join()
    assert (report.sent, report.received, report.lost, report.duplicates) == (30, 30, 0, 0)
    stats = report.stats()
    assert 0 < stats["min_ms"] <= stats["median_ms"] <= stats["p99_ms"] <= stats["max_ms"]
    assert responder.echoed == 30
    # It hears its own pongs (broadcast loops back) and does not echo them: no loop. (It stops after the
    # 30th echo, so its last pong may still be unread.)
    assert responder.ignored >= 29


def test_ping_without_responder_reports_loss() -> None:
    with V2xTransport(free_url()) as side:
        report = Pinger(side, 1).run(3, 0.01, timeout_s=0.1)
    assert (report.sent, report.received, report.lost) == (3, 0, 3)
    assert np.isnan(report.stats()["median_ms"])


# ---------------------------------------------------------------------------------------------- CLI


def test_cli_meter_send_and_receive(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    url = free_url()
    out = tmp_path / "meter.json"
    codes: list[int] = []
    receiver = threading.Thread(
        target=lambda: codes.append(
            v2x_cli.run(
                ["meter", "receive", "--url", url, "--count", "200", "--seconds", "10", "--json", str(out)]
            )
        )
    )
    receiver.start()
    time.sleep(0.3)  # let it bind
    assert (
        v2x_cli.run(["meter", "send", "--url", url, "--count", "200", "--rate", "1000", "--stream-id", "8"])
        == 0
    )
    receiver.join(timeout=15)
    assert codes == [0]
    doc = json.loads(out.read_text())
    assert doc["stream_id"] == 8 and doc["unique"] == 200 and doc["lost"] == 0 and doc["kernel_drops"] == 0
    assert "200/200 received" in capsys.readouterr().out


def test_cli_receive_with_max_loss_fails_on_silence(tmp_path: Path) -> None:
    out = tmp_path / "m.json"
    code = v2x_cli.run(
        ["meter", "receive", "--url", free_url(), "--count", "5", "--seconds", "0.3", "--json", str(out)]
    )
    assert code == 1
    assert json.loads(out.read_text())["lost"] == 5


def test_cli_echo_and_ping(tmp_path: Path) -> None:
    url = free_url()
    out = tmp_path / "ping.json"
    echo = threading.Thread(
        target=v2x_cli.run, args=(["echo", "--url", url, "--count", "20", "--seconds", "10"],)
    )
    echo.start()
    time.sleep(0.3)
    code = v2x_cli.run(
        ["ping", "--url", url, "--count", "20", "--interval-ms", "10", "--size", "100", "--json", str(out)]
    )
    echo.join(timeout=15)
    assert code == 0
    doc = json.loads(out.read_text())
    assert doc["sent"] == doc["received"] == 20 and doc["max_ms"] >= doc["p99_ms"] >= doc["median_ms"] > 0


def test_cli_fuzz_json(tmp_path: Path) -> None:
    out = tmp_path / "fuzz.json"
    assert (
        v2x_cli.run(["fuzz", "--url", free_url(), "--count", "200", "--seconds", "0.2", "--json", str(out)])
        == 0
    )
    doc = json.loads(out.read_text())
    assert doc["sent"] == 200 and sum(doc["by_kind"].values()) == 200


def test_cli_rejects_bad_arguments(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        v2x_cli.run(["ping", "--url", "udp://1.2.3.4:5"])
    assert exit_.value.code == 2
    assert "scheme must be v2x://" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        v2x_cli.run(["meter", "send", "--count", "0"])
    assert v2x_cli.run(["meter", "send", "--url", free_url(), "--count", "1", "--size", "5"]) == 2
    # An address that is not this machine's: a clear message, exit 2.
    assert v2x_cli.run(["echo", "--url", "v2x://203.0.113.255:47100", "--count", "1"]) == 2
    assert "cannot open v2x://203.0.113.255:47100" in capsys.readouterr().err


def test_cli_wiring_parses_every_command() -> None:
    parser = argparse.ArgumentParser(prog="bywire v2x")
    v2x_cli.add_arguments(parser)
    for argv in (["meter", "send"], ["meter", "receive"], ["echo"], ["ping"], ["fuzz"]):
        args = parser.parse_args(argv)
        assert args.v2x_command == argv[0] and args.url == "v2x://127.255.255.255:47100"


# ---------------------------------------------------------------------------------------------- bench


def test_bench_runs_and_writes_its_contract(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    out = tmp_path / "bench.json"
    assert bench.main(parser.parse_args(["--seconds", "0.5", "--json", str(out)])) == 0
    doc = json.loads(out.read_text())
    for row in (
        "encode",
        "encode_struct_baseline",
        "decode",
        "decode_struct_baseline",
        "receiver_valid",
        "receiver_hostile",
    ):
        r = doc["rows"][row]
        assert 0 < r["median_us"] <= r["p99_us"] <= r["max_us"] and r["n"] >= 1
    assert doc["rows"]["receiver_valid"]["rejected"] == {}  # the valid stream is valid
    # a CAM with its low-frequency container
    assert doc["ratios"]["encode_vs_struct"] > 0 and doc["message_bytes"] == 43
    assert "ratios (medians)" in capsys.readouterr().out
    assert zlib.crc32(out.read_bytes()) is not None


@given(st.binary(max_size=200))
@settings(max_examples=300)
def test_probe_parser_and_meter_take_arbitrary_bytes(data: bytes) -> None:
    try:
        parse_probe(data)
    except ProbeError as e:
        assert e.reason in {"short", "magic", "length", "crc"}
    meter = LossMeter(expected=3)
    assert meter.feed(data, 0.0) in {"ok", "reordered", "duplicated", "corrupt", "foreign"}
    r = meter.report()
    assert r.datagrams == 1 == r.valid + r.corrupt + r.foreign


@given(st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1), st.integers(0, 2**64 - 1), st.integers(28, 200))
@settings(max_examples=200)
def test_mutated_probes_are_caught_by_the_crc(stream_id: int, seq: int, t_ns: int, size: int) -> None:
    good = make_probe(ProbeKind.STREAM, stream_id, seq, t_ns, size)
    assert parse_probe(good).seq == seq
    for bit in range(0, len(good) * 8, 7):
        bad = bytearray(good)
        bad[bit // 8] ^= 0x80 >> (bit % 8)
        with pytest.raises(ProbeError):
            parse_probe(bytes(bad))
