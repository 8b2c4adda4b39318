"""Differential fuzzing of the V2X decoder's fast path: `asn1_decode(..., fast=True)` against asn1tools
alone on datagrams mutated at the bit and byte level (flips, overwritten, cut, appended, inserted,
deleted and duplicated bytes, random bytes), seeded from real CAMs off the air and asn1tools' boundary
vectors (shared data, read in place) and from CAMs and iCLCMs our encoder made, under both CAM schemas
and the iCLCM's.

Every datagram must get the same verdict both ways: the same value (as `repr` writes it: types and
member order count) or the same refusal, reason and message word for word; and never any exception but
a V2xDecodeError. The hypothesis tests of test_v2x_fast_uper hold the decoder on a few hundred
structured examples each; this sends hundreds of thousands, where a bit-level disagreement in a rare
branch (an extension bit, a length at its bound) shows. The default suite sends 30 000 datagrams; the
campaign (`-m slow`) 10^6.
"""

from __future__ import annotations

import base64
import json
import math
import random
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from shared_data import shared_data_dir

from bywire.protocol.v2x import codec
from bywire.protocol.v2x.codec import (
    DriveDirection,
    V2xDecodeError,
    V2xEncodeError,
    VehicleState,
    asn1_decode,
)
from bywire.protocol.v2x.etsi_cam import cam_value
from bywire.protocol.v2x.iclcm import TYPE_NAME as ICLCM
from bywire.protocol.v2x.iclcm import ControllerType, CooperativeState, iclcm_value
from bywire.protocol.v2x.schemas import SchemaSet, compiled

VECTORS = shared_data_dir() / "v2x_asn1"
VECTOR_FILES = ("cam_uper_real_vectors_from_issue_threads.json", "cam_uper_test_vectors_from_asn1tools.json")


def real_cams() -> list[bytes]:
    """The CAMs of the shared data (none where it is absent: the built seeds still run)."""
    out: list[bytes] = []
    for name in VECTOR_FILES:
        path = VECTORS / name
        if path.is_file():
            for v in json.loads(path.read_text())["vectors"]:
                out.append(bytes.fromhex(v["hex"]) if "hex" in v else base64.b64decode(v["base64"]))
    return out


def _maybe(rng: random.Random, lo: float, hi: float) -> float | None:
    return None if rng.random() < 0.15 else rng.uniform(lo, hi)


def _encoded(type_name: str, spec: Any, value: Callable[[int], Any], n: int) -> list[bytes]:
    """`n` values our encoder takes (those it refuses left out)."""
    out = []
    for i in range(n):
        try:
            out.append(codec.asn1_encode(spec, type_name, value(i), type_name))
        except V2xEncodeError:
            continue
    return out


def built_cams(rng: random.Random, n: int) -> list[bytes]:
    """CAMs our encoder makes of random states (each field unavailable now and then)."""

    def value(i: int) -> Any:
        state = VehicleState(
            station_id=rng.randrange(1 << 32),
            generation_time_s=rng.uniform(1.1e9, 3.9e9),
            lat_deg=_maybe(rng, -90.0, 90.0),
            lon_deg=_maybe(rng, -180.0, 180.0),
            heading_rad=_maybe(rng, -math.pi, math.pi),
            speed_mps=_maybe(rng, 0.0, 163.0),
            yaw_rate_radps=_maybe(rng, -5.0, 5.0),
            accel_mps2=_maybe(rng, -15.0, 15.0),
            length_m=_maybe(rng, 0.1, 100.0),
            width_m=_maybe(rng, 0.1, 6.0),
            drive_direction=rng.choice((None, DriveDirection.FORWARD, DriveDirection.BACKWARD)),
            lane_position=rng.choice((None, -1, 0, 1, 2, 14)),
            station_type=rng.choice((0, 5, 8, 15)),
        )
        return cam_value(state, low_frequency=i % 3 == 0)

    return _encoded("CAM", compiled(SchemaSet.CAM_V2), value, n)


def built_iclcms(rng: random.Random, n: int) -> list[bytes]:
    def value(_: int) -> Any:
        return iclcm_value(
            CooperativeState(
                station_id=rng.randrange(1 << 32),
                generation_time_s=rng.uniform(1.6e9, 1.8e9),
                controller_type=rng.choice(list(ControllerType)),
                target_accel_mps2=_maybe(rng, -10.0, 10.0),
                time_headway_s=_maybe(rng, 0.0, 2.0),
                cruise_speed_mps=_maybe(rng, 0.0, 49.0),
                lane=rng.choice((None, 1, 2, 3)),
                participants_ready=rng.choice((None, True, False)),
            )
        )

    return _encoded(ICLCM, compiled(SchemaSet.ICLCM), value, n)


def mutated(rng: random.Random, data: bytes) -> bytes:
    """One to three rounds of one byte- or bit-level change."""
    b = bytearray(data)
    for _ in range(rng.choice((1, 1, 1, 2, 3))):
        k = rng.random()
        if k < 0.45 and b:
            for _ in range(rng.choice((1, 1, 1, 2, 3, 5, 8))):
                i = rng.randrange(8 * len(b))
                b[i // 8] ^= 0x80 >> (i % 8)
        elif k < 0.55 and b:
            b[rng.randrange(len(b))] = rng.randrange(256)
        elif k < 0.65:
            del b[rng.randrange(len(b) + 1) :]
        elif k < 0.72:
            b += rng.randbytes(rng.randint(1, 6))
        elif k < 0.79 and b:
            i = rng.randrange(len(b))
            b[i:i] = rng.randbytes(rng.randint(1, 4))
        elif k < 0.86 and b:
            i = rng.randrange(len(b))
            del b[i : i + rng.randint(1, 4)]
        elif k < 0.93 and len(b) > 2:
            i, j = sorted(rng.sample(range(len(b)), 2))
            b[i:i] = b[i:j]
        else:
            b = bytearray(rng.randbytes(rng.randint(0, 80)))
    return bytes(b)


def verdict(spec: Any, type_name: str, data: bytes, fast: bool) -> tuple[str, ...]:
    try:
        return ("value", repr(asn1_decode(spec, type_name, data, type_name, fast=fast)))
    except V2xDecodeError as e:
        return ("refused", str(e.reason), str(e))
    except Exception as e:  # any other exception is the finding
        return ("raised", type(e).__name__, str(e))


@dataclass
class Tally:
    sent: int = 0
    decoded_fast: int = 0  # the fast path gave the value (the rest went to asn1tools)
    refused: int = 0
    disagreements: list[str] | None = None


def campaign(seed: int, n: int) -> Tally:
    """`n` mutated datagrams, round-robin over CAM v2, CAM v1 and iCLCM."""
    rng = random.Random(seed)
    cams = real_cams() + built_cams(rng, 120)
    iclcms = built_iclcms(rng, 80)
    targets = [
        (compiled(SchemaSet.CAM_V2), "CAM", cams),
        (compiled(SchemaSet.CAM_V1), "CAM", cams),
        (compiled(SchemaSet.ICLCM), ICLCM, iclcms),
    ]
    tally = Tally(disagreements=[])
    fast_decoder = codec._fast_decoder
    for i in range(n):
        spec, type_name, seeds = targets[i % len(targets)]
        data = mutated(rng, rng.choice(seeds))
        mine = verdict(spec, type_name, data, fast=True)
        reference = verdict(spec, type_name, data, fast=False)
        tally.sent += 1
        if mine[0] == "value":
            try:
                fast_decoder(spec, type_name)(data)
                tally.decoded_fast += 1
            except codec.Unsupported:
                pass
        else:
            tally.refused += 1
        if mine != reference or mine[0] == "raised":
            assert tally.disagreements is not None
            tally.disagreements.append(
                f"{type_name} {data.hex()}: fast {mine!r}, asn1tools alone {reference!r}"
            )
    return tally


def _judge(tally: Tally) -> None:
    assert not tally.disagreements, "\n".join(tally.disagreements[:10])
    # Not vacuous: the fast path decoded a good share itself, and a good share was refused.
    assert tally.decoded_fast > tally.sent // 10
    assert tally.refused > tally.sent // 10


def test_mutated_datagrams_get_the_verdict_of_asn1tools_alone() -> None:
    _judge(campaign(seed=1, n=30_000))


def _chunks() -> Iterator[int]:
    yield from range(10)


@pytest.mark.slow
@pytest.mark.parametrize("seed", list(_chunks()))
def test_a_million_mutated_datagrams_get_the_verdict_of_asn1tools_alone(seed: int) -> None:
    _judge(campaign(seed=100 + seed, n=100_000))


def test_the_campaign_finds_a_decoder_that_disagrees(monkeypatch: pytest.MonkeyPatch) -> None:
    """The judge fails a fast path that gives one wrong value (a speed off by one unit)."""
    real = codec._fast_decoder

    def off_by_one(spec: Any, type_name: str) -> Any:
        decode = real(spec, type_name)

        def wrong(data: bytes) -> Any:
            value = decode(data)
            if type_name == "CAM":
                hf = value["cam"]["camParameters"]["highFrequencyContainer"][1]
                hf["speed"]["speedValue"] ^= 1
            return value

        return wrong

    monkeypatch.setattr(codec, "_fast_decoder", off_by_one)
    tally = campaign(seed=3, n=300)
    assert tally.disagreements
