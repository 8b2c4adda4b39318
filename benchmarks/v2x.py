"""`bywire bench v2x`: the state-message codec and the hardened receiver, timed per message (seed 003
section III: V2V communication and receiver hardening).

Rows, measured interleaved in one run so that machine load hits them alike (median / p99 / max, us):

- encode: `wire.encode(VehicleState)` (dataclass -> range checks -> a CAM in asn1tools UPER) against the
  `struct.pack` of the same fields as integers (what a hand-written fixed layout would cost);
- decode: `wire.decode` (header peek, asn1tools UPER, canonical re-encode check, dataclass) against
  `struct.unpack` + building the same dataclass; also asn1tools' decode alone, to show what the strict
  canonical check adds;
- receiver, valid: `V2vReceiver.check` on a consistent 10 Hz stream of 20 vehicles (full pipeline: decode,
  time, replay, range, physics, jump checks);
- receiver, hostile: the same on a fuzz mix (`fuzz.V2xFuzzer`), quarantine on (as deployed) and off
  (every datagram reaches the decoder or the deeper checks);
- etsi_cam: `from_etsi_cam` on the real protocolVersion 1 and 2 CAMs of other stacks (shipped schemas).

Ratios are ours / baseline medians. Contract (``--json``): {"rows": {name: {"median_us", "p99_us",
"max_us", "n"}}, "ratios": {...}, "seconds": ..}.
"""

from __future__ import annotations

import argparse
import base64
import dataclasses
import math
import struct
import time
from collections.abc import Callable
from typing import Any

from benchmarks.timed import add_timed_arguments, run_timed
from bywire.protocol.v2x.codec import (
    DriveDirection,
    VehicleState,
    timestamp_its_to_unix,
    unix_to_timestamp_its,
)
from bywire.protocol.v2x.etsi_cam import from_etsi_cam
from bywire.protocol.v2x.fuzz import V2xFuzzer
from bywire.protocol.v2x.meter import percentile
from bywire.protocol.v2x.receiver import GeoPoint, ReceiverParams, V2vReceiver
from bywire.protocol.v2x.schemas import SchemaSet, compiled
from bywire.protocol.v2x.wire import decode, encode

DEFAULT_SECONDS = 6.0
T0_S = 1_700_000_000.0
OWN = GeoPoint(49.0, 8.4)
# Baseline layout: station u32, TimestampIts u64, lat i32, lon i32, heading u16, speed u16, direction u8,
# yaw rate i16, accel i16, length u16, width u8: the same integers as the UPER message, byte-aligned.
BASELINE = struct.Struct(">IQiiHHBhhHB")


def _state(i: int, t: float) -> VehicleState:
    return VehicleState(
        station_id=1000 + i % 20,
        generation_time_s=t,
        lat_deg=49.0 + 1e-5 * (i % 20),
        lon_deg=8.4 + 1e-5 * (i % 20),
        heading_rad=0.3,
        speed_mps=25.0,
        yaw_rate_radps=0.01,
        accel_mps2=-0.5,
        length_m=4.5,
        width_m=1.8,
        drive_direction=DriveDirection.FORWARD,
    )


def _baseline_pack(v: VehicleState) -> bytes:
    assert v.lat_deg is not None and v.lon_deg is not None and v.heading_rad is not None
    assert v.speed_mps is not None and v.yaw_rate_radps is not None and v.accel_mps2 is not None
    assert v.length_m is not None and v.width_m is not None
    return BASELINE.pack(
        v.station_id,
        unix_to_timestamp_its(v.generation_time_s),
        round(v.lat_deg * 1e7),
        round(v.lon_deg * 1e7),
        round((math.degrees(math.pi / 2 - v.heading_rad) % 360.0) * 10.0) % 3600,
        round(v.speed_mps * 100.0),
        0,
        round(math.degrees(v.yaw_rate_radps) * 100.0),
        round(v.accel_mps2 * 10.0),
        round(v.length_m * 10.0),
        round(v.width_m * 10.0),
    )


def _baseline_unpack(data: bytes) -> VehicleState:
    sid, ts, lat, lon, hdg, spd, _d, yaw, acc, length, width = BASELINE.unpack(data)
    return VehicleState(
        sid,
        timestamp_its_to_unix(ts),
        lat / 1e7,
        lon / 1e7,
        math.pi / 2 - math.radians(hdg / 10.0),
        spd / 100.0,
        math.radians(yaw / 100.0),
        acc / 10.0,
        length / 10.0,
        width / 10.0,
        DriveDirection.FORWARD,
    )


def _stats(samples_ns: list[int]) -> dict[str, float]:
    s = sorted(x / 1e3 for x in samples_ns)
    return {"median_us": percentile(s, 50.0), "p99_us": percentile(s, 99.0), "max_us": s[-1], "n": len(s)}


def _interleaved(fns: dict[str, Callable[[int], object]], seconds: float, min_n: int = 200) -> dict[str, Any]:
    """Call each fn(i) in turn until `seconds` passed; per-call perf_counter_ns samples per name."""
    samples: dict[str, list[int]] = {k: [] for k in fns}
    clock = time.perf_counter_ns
    deadline = time.perf_counter() + seconds
    i = 0
    while time.perf_counter() < deadline or i < min_n:
        for name, fn in fns.items():
            t0 = clock()
            fn(i)
            samples[name].append(clock() - t0)
        i += 1
    return {k: _stats(v) for k, v in samples.items()}


def _bench_codec(seconds: float) -> dict[str, Any]:
    states = [_state(i, T0_S + 0.1 * i) for i in range(1000)]
    frames = [encode(v) for v in states]
    packed = [_baseline_pack(v) for v in states]
    spec = compiled(SchemaSet.CAM_V2)
    return _interleaved(
        {
            "encode": lambda i: encode(states[i % 1000]),
            "encode_struct_baseline": lambda i: _baseline_pack(states[i % 1000]),
            "decode": lambda i: decode(frames[i % 1000], T0_S + 0.1 * (i % 1000)),
            "decode_asn1tools_only": lambda i: spec.decode("CAM", frames[i % 1000]),
            "decode_struct_baseline": lambda i: _baseline_unpack(packed[i % 1000]),
        },
        seconds,
    )


def _bench_receiver(seconds: float) -> dict[str, Any]:
    # Enough datagrams for each row's share of the time at ~100 us each (generating them is not timed).
    n = min(20_000, max(500, int(seconds / 3 * 15_000)))
    # 20 vehicles at 10 Hz moving 25 m/s, in time order: every datagram passes every check.
    valid = []
    for k in range(n):
        i, slot = k % 20, k // 20
        t = T0_S + 0.1 * slot + 1e-3 * i
        v = _state(i, t)
        assert v.lat_deg is not None
        valid.append((encode(dataclasses.replace(v, lat_deg=v.lat_deg + slot * 2.5 / 111_195.0)), t))
    fz = V2xFuzzer(7, center=OWN, own_station_id=1)
    hostile = [(fz.next(T0_S + 1e-3 * k)[1], T0_S + 1e-3 * k) for k in range(n)]
    receivers = {
        "receiver_valid": (V2vReceiver(own_station_id=1), valid),
        "receiver_hostile": (V2vReceiver(own_station_id=1), hostile),
        "receiver_hostile_no_quarantine": (
            V2vReceiver(ReceiverParams(strike_threshold=1e12), own_station_id=1),
            hostile,
        ),
    }
    # Each receiver sees its stream in order, once: the per-sender state must evolve as in real use.
    rows: dict[str, Any] = {}
    for name, (rx, stream) in receivers.items():
        clock = time.perf_counter_ns
        samples = []
        deadline = time.perf_counter() + seconds / len(receivers)
        for data, t in stream:
            t0 = clock()
            rx.check(data, t, OWN)
            samples.append(clock() - t0)
            if time.perf_counter() > deadline and len(samples) >= 200:
                break
        rows[name] = _stats(samples) | {"accepted": rx.accepted, "rejected": rx.v2v_rejected()}
    return rows


def _bench_etsi(seconds: float) -> dict[str, Any]:
    v2 = bytes.fromhex(
        "02020000D900B1E74059D824554CC4C2D79FFFFFFC2230D41E58622FC0000082B88A800FFD01FFF8807FE013C0400009FFFF7FFFD8CE00"
    )
    v1 = base64.b64decode("AQIEs52FxB4AWpesRQ3QCjmf///8I7d0PgDSr8FN/j/p7QczyX9f/7A=")
    from_etsi_cam(v1, T0_S)
    from_etsi_cam(v2, T0_S)  # compile both schema sets before timing
    return _interleaved(
        {
            "etsi_cam_v1_decode": lambda i: from_etsi_cam(v1, T0_S),
            "etsi_cam_v2_decode": lambda i: from_etsi_cam(v2, T0_S),
        },
        seconds,
        min_n=50,
    )


def run(seconds: float = DEFAULT_SECONDS) -> dict[str, Any]:
    rows = _bench_codec(0.4 * seconds) | _bench_receiver(0.4 * seconds) | _bench_etsi(0.2 * seconds)

    def ratio(a: str, b: str) -> float:
        return rows[a]["median_us"] / rows[b]["median_us"] if a in rows and b in rows else math.nan

    return {
        "rows": rows,
        "ratios": {
            "encode_vs_struct": ratio("encode", "encode_struct_baseline"),
            "decode_vs_struct": ratio("decode", "decode_struct_baseline"),
            "decode_vs_asn1tools_only": ratio("decode", "decode_asn1tools_only"),
            "receiver_valid_vs_decode": ratio("receiver_valid", "decode"),
            "receiver_hostile_vs_decode": ratio("receiver_hostile", "decode"),
        },
        "message_bytes": len(encode(_state(0, T0_S))),
        "struct_baseline_bytes": BASELINE.size,
        "seconds": seconds,
    }


def _print_table(doc: dict[str, Any]) -> None:
    print(f"{'':34} {'median us':>10} {'p99 us':>10} {'max us':>10} {'n':>8}")
    for name, r in doc["rows"].items():
        if "median_us" in r:
            print(f"{name:34} {r['median_us']:10.2f} {r['p99_us']:10.2f} {r['max_us']:10.1f} {r['n']:8d}")
        else:
            print(f"{name:34} {r}")
    print("ratios (medians): " + ", ".join(f"{k} {v:.1f}x" for k, v in doc["ratios"].items()))
    print(f"message: {doc['message_bytes']} B UPER vs {doc['struct_baseline_bytes']} B struct")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_timed_arguments(p, DEFAULT_SECONDS, "the measuring takes")


def main(args: argparse.Namespace) -> int:
    return run_timed(args, "v2x", DEFAULT_SECONDS, run, _print_table)
