"""`fast_uper`'s encoder against asn1tools (the reference) on random messages: the CAMs and iCLCMs our
builders make, in every shape they take, encode to asn1tools' bytes without falling back; values changed
anywhere (a field out of its range, of the wrong Python type, missing, added, an alternative unknown) are
either left to asn1tools or, when they are still valid, encoded to its bytes too. So `asn1_encode` with
the fast path gives the same bytes and raises the same errors as without it."""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import asn1tools
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from bywire.protocol.v2x.codec import V2xEncodeError, asn1_encode
from bywire.protocol.v2x.etsi_cam import cam_value
from bywire.protocol.v2x.fast_uper import Unsupported, compile_decoder, compile_encoder
from bywire.protocol.v2x.iclcm import TYPE_NAME as ICLCM
from bywire.protocol.v2x.iclcm import iclcm_value
from bywire.protocol.v2x.schemas import SchemaSet, compiled
from tests.protocol.v2x.test_v2x_canonical_memo import cooperative_states
from tests.protocol.v2x.test_v2x_codec import vehicle_states

CAM_SPEC = compiled(SchemaSet.CAM_V2)
ICLCM_SPEC = compiled(SchemaSet.ICLCM)
FAST_CAM = compile_encoder(CAM_SPEC.types["CAM"])
FAST_ICLCM = compile_encoder(ICLCM_SPEC.types[ICLCM])


def _reference(spec: Any, type_name: str, value: Any) -> bytes | None:
    """asn1tools' bytes, None where it refuses the value."""
    try:
        return bytes(spec.encode(type_name, value, check_constraints=True))
    except Exception:
        return None


def _cam(state: Any, low_frequency: bool) -> dict[str, Any]:
    try:
        return cam_value(state, low_frequency=low_frequency)
    except V2xEncodeError:
        assume(False)
        raise


@given(vehicle_states(), st.booleans())
@settings(max_examples=300, deadline=None)
def test_every_cam_we_build_encodes_to_asn1tools_bytes(state: Any, low_frequency: bool) -> None:
    value = _cam(state, low_frequency)
    assert FAST_CAM(value) == _reference(CAM_SPEC, "CAM", value)


@given(cooperative_states)
@settings(max_examples=300, deadline=None)
def test_every_iclcm_we_build_encodes_to_asn1tools_bytes(msg: Any) -> None:
    try:
        value = iclcm_value(msg)
    except V2xEncodeError:
        assume(False)
        raise
    assert FAST_ICLCM(value) == _reference(ICLCM_SPEC, ICLCM, value)


def _paths(value: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every node of an asn1tools value, as the keys and indexes leading to it."""
    out = [prefix]
    if isinstance(value, dict):
        for k, v in value.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(value, tuple) and len(value) == 2 and isinstance(value[0], str):
        out += _paths(value[1], (*prefix, 1))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            out += _paths(v, (*prefix, i))
    return out


def _replace(value: Any, path: tuple[Any, ...], new: Any) -> Any:
    if not path:
        return new
    head, rest = path[0], path[1:]
    if isinstance(value, dict):
        out = dict(value)
        out[head] = _replace(value[head], rest, new)
        return out
    if isinstance(value, tuple):
        return (value[0], _replace(value[1], rest, new))
    out_list = list(value)
    out_list[head] = _replace(value[head], rest, new)
    return out_list


_odd_leaves = st.one_of(
    st.integers(-(2**40), 2**40),
    st.integers(-3, 70_000),
    st.booleans(),
    st.floats(-10.0, 10.0),
    st.text(max_size=12),
    st.sampled_from(["unavailable", "default", "forward", "noTrailerPresent", "yawRateUsed", "x"]),
    st.tuples(st.binary(max_size=3), st.integers(0, 26)),
    st.tuples(
        st.sampled_from(["basicVehicleContainerHighFrequency", "rsuContainerHighFrequency", "x"]), st.just({})
    ),
    st.just([]),
    st.just({}),
    st.none(),
)


def _mutate(value: Any, draw: Callable[..., Any]) -> Any:
    paths = _paths(value)
    path = draw(st.sampled_from(paths))
    kind = draw(st.sampled_from(["nudge", "nudge", "leaf", "leaf", "drop", "add"]))
    leaf = value
    for k in path:
        leaf = leaf[k]
    if kind == "nudge" and type(leaf) is int:  # mostly still valid: the encoder's own bits, not a refusal
        return _replace(value, path, leaf + draw(st.sampled_from([-1, 1, -2, 2, -leaf, 3 - leaf])))
    if kind in ("leaf", "nudge") or not path:
        return _replace(value, path, draw(_odd_leaves))
    parent_path, key = path[:-1], path[-1]
    parent = value
    for k in parent_path:
        parent = parent[k]
    if not isinstance(parent, dict):
        return _replace(value, path, draw(_odd_leaves))
    new_parent = dict(parent)
    if kind == "drop":
        del new_parent[key]
    else:
        new_parent[
            draw(st.sampled_from(["lanePosition", "performanceClass", "unknownField", "cenDsrcTollingZone"]))
        ] = draw(_odd_leaves)
    return _replace(value, parent_path, new_parent)


def _agrees(fast: Any, spec: Any, type_name: str, value: Any) -> None:
    reference = _reference(spec, type_name, value)
    try:
        mine = fast(value)
    except Unsupported:
        return  # left to asn1tools: its bytes or its error, as before
    assert reference is not None, "encoded a value asn1tools refuses"
    assert mine == reference


@given(st.data(), vehicle_states(), st.booleans())
@settings(max_examples=500, deadline=None)
def test_changed_cams_are_encoded_as_asn1tools_does_or_left_to_it(
    data: st.DataObject, state: Any, low_frequency: bool
) -> None:
    value = _cam(state, low_frequency)
    for _ in range(data.draw(st.integers(1, 3))):
        value = _mutate(value, data.draw)
    _agrees(FAST_CAM, CAM_SPEC, "CAM", value)


@given(st.data(), cooperative_states)
@settings(max_examples=400, deadline=None)
def test_changed_iclcms_are_encoded_as_asn1tools_does_or_left_to_it(data: st.DataObject, msg: Any) -> None:
    try:
        value = iclcm_value(msg)
    except V2xEncodeError:
        assume(False)
        raise
    for _ in range(data.draw(st.integers(1, 3))):
        value = _mutate(value, data.draw)
    _agrees(FAST_ICLCM, ICLCM_SPEC, ICLCM, value)


def test_asn1_encode_refuses_what_asn1tools_refuses_with_its_message() -> None:
    from bywire.protocol.v2x.codec import VehicleState

    value = cam_value(VehicleState(7, 1.5e9, 52.0, 5.0, 0.3, 10.0, 0.01, 0.5, 4.5, 1.8), low_frequency=True)
    bad = copy.deepcopy(value)
    bad["cam"]["generationDeltaTime"] = 70_000
    with pytest.raises(V2xEncodeError) as fast:
        asn1_encode(CAM_SPEC, "CAM", bad, "CAM", fast=True)
    with pytest.raises(asn1tools.ConstraintsError) as reference:
        CAM_SPEC.encode("CAM", bad, check_constraints=True)
    assert str(fast.value) == f"CAM: {reference.value}"
    assert asn1_encode(CAM_SPEC, "CAM", value, "CAM", fast=True) == asn1_encode(CAM_SPEC, "CAM", value, "CAM")


# ---------------------------------------------------------------------------------------------- decoding

FAST_CAM_DECODE = compile_decoder(CAM_SPEC.types["CAM"])
FAST_ICLCM_DECODE = compile_decoder(ICLCM_SPEC.types[ICLCM])


def _decoded(spec: Any, type_name: str, data: bytes) -> Any:
    """asn1tools' value as `repr` writes it (types and member order count), None where it refuses."""
    try:
        return repr(spec.decode(type_name, data, check_constraints=True))
    except Exception:
        return None


def _decodes_alike(fast: Any, spec: Any, type_name: str, data: bytes) -> bool:
    """Whether the fast decoder decoded `data` (rather than leaving it to asn1tools); asserts that what it
    decoded is asn1tools' value."""
    reference = _decoded(spec, type_name, data)
    try:
        mine = fast(data)
    except Unsupported:
        return False
    assert reference is not None, "decoded a datagram asn1tools refuses"
    assert repr(mine) == reference
    return True


def _flipped(data: bytes, draw: Callable[..., Any]) -> bytes:
    kind = draw(st.sampled_from(["flip", "flip", "append", "cut", "random"]))
    if kind == "append":
        return data + draw(st.binary(min_size=1, max_size=3))
    if kind == "cut":
        return data[: draw(st.integers(0, max(len(data) - 1, 0)))]
    if kind == "random":
        return draw(st.binary(max_size=len(data) + 4))
    b = bytearray(data)
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, 8 * len(b) - 1))
        b[i // 8] ^= 0x80 >> (i % 8)
    return bytes(b)


@given(st.data(), vehicle_states(), st.booleans())
@settings(max_examples=400, deadline=None)
def test_cam_datagrams_decode_to_asn1tools_values(
    data: st.DataObject, state: Any, low_frequency: bool
) -> None:
    sent = FAST_CAM(_cam(state, low_frequency))
    assert _decodes_alike(FAST_CAM_DECODE, CAM_SPEC, "CAM", sent)  # ours: always decoded here
    _decodes_alike(FAST_CAM_DECODE, CAM_SPEC, "CAM", _flipped(sent, data.draw))


@given(st.data(), cooperative_states)
@settings(max_examples=400, deadline=None)
def test_iclcm_datagrams_decode_to_asn1tools_values(data: st.DataObject, msg: Any) -> None:
    try:
        sent = FAST_ICLCM(iclcm_value(msg))
    except V2xEncodeError:
        assume(False)
        raise
    assert _decodes_alike(FAST_ICLCM_DECODE, ICLCM_SPEC, ICLCM, sent)
    _decodes_alike(FAST_ICLCM_DECODE, ICLCM_SPEC, ICLCM, _flipped(sent, data.draw))


def test_asn1_decode_with_the_fast_path_gives_the_same_values_and_errors() -> None:
    from bywire.protocol.v2x.codec import V2xDecodeError, VehicleState, asn1_decode

    sent = asn1_encode(
        CAM_SPEC,
        "CAM",
        cam_value(VehicleState(7, 1.5e9, 52.0, 5.0, 0.3, 10.0, 0.01, 0.5, 4.5, 1.8), low_frequency=True),
        "CAM",
    )
    assert repr(asn1_decode(CAM_SPEC, "CAM", sent, "CAM", fast=True)) == repr(
        asn1_decode(CAM_SPEC, "CAM", sent, "CAM")
    )
    for bad in (sent[:9], sent[:6] + b"\xff" * 30):
        with pytest.raises(V2xDecodeError) as fast:
            asn1_decode(CAM_SPEC, "CAM", bad, "CAM", fast=True)
        with pytest.raises(V2xDecodeError) as reference:
            asn1_decode(CAM_SPEC, "CAM", bad, "CAM")
        assert (fast.value.reason, str(fast.value)) == (reference.value.reason, str(reference.value))


CAM_V1_SPEC = compiled(SchemaSet.CAM_V1)
FAST_CAM_V1 = compile_encoder(CAM_V1_SPEC.types["CAM"])
FAST_CAM_V1_DECODE = compile_decoder(CAM_V1_SPEC.types["CAM"])


@given(st.data(), vehicle_states(), st.booleans())
@settings(max_examples=300, deadline=None)
def test_protocol_version_1_cams_decode_and_encode_as_asn1tools_does(
    data: st.DataObject, state: Any, low_frequency: bool
) -> None:
    """The older CAM schema a receiver also reads: our CAM's value in version 1, encoded by asn1tools,
    then altered or not."""
    value = _cam(state, low_frequency)
    value["header"]["protocolVersion"] = 1
    sent = _reference(CAM_V1_SPEC, "CAM", value)
    assert sent is not None and FAST_CAM_V1(value) == sent
    assert _decodes_alike(FAST_CAM_V1_DECODE, CAM_V1_SPEC, "CAM", sent)
    altered = _flipped(sent, data.draw)
    if _decodes_alike(FAST_CAM_V1_DECODE, CAM_V1_SPEC, "CAM", altered):
        _agrees(FAST_CAM_V1, CAM_V1_SPEC, "CAM", CAM_V1_SPEC.decode("CAM", altered))


CLOSURE_CAM = compile_encoder(CAM_SPEC.types["CAM"], generated=False)
CLOSURE_CAM_DECODE = compile_decoder(CAM_SPEC.types["CAM"], generated=False)


@given(st.data(), vehicle_states(), st.booleans())
@settings(max_examples=200, deadline=None)
def test_the_generated_codec_equals_the_tree_of_closures(
    data: st.DataObject, state: Any, low_frequency: bool
) -> None:
    """The two forms of one codec: the same bytes, values and refusals."""

    def outcome(f: Any, arg: Any) -> Any:
        try:
            return repr(f(arg))
        except Unsupported:
            return Unsupported

    value = _cam(state, low_frequency)
    changed = _mutate(value, data.draw)
    for v in (value, changed):
        assert outcome(FAST_CAM, v) == outcome(CLOSURE_CAM, v)
    sent = FAST_CAM(value)
    for datagram in (sent, _flipped(sent, data.draw)):
        assert outcome(FAST_CAM_DECODE, datagram) == outcome(CLOSURE_CAM_DECODE, datagram)


def _asn1tools_only(spec: Any, type_name: str) -> Any:
    def refuse(_: Any) -> Any:
        raise Unsupported

    return refuse


def _verdict(datagram: bytes, reference_s: float) -> Any:
    from bywire.protocol.v2x.codec import V2xDecodeError
    from bywire.protocol.v2x.wire import decode

    try:
        return decode(datagram, reference_s)
    except V2xDecodeError as e:
        return (e.reason, str(e))


@given(st.data(), st.one_of(vehicle_states(), cooperative_states), st.booleans())
@settings(max_examples=300, deadline=None)
def test_a_reception_gets_the_verdict_of_asn1tools_alone(
    data: st.DataObject, msg: Any, remembered: bool
) -> None:
    """End to end (decode, the canonical check, the conversion to SI), with our own encodings remembered
    (SIL) or not: the message or the refusal, word for word, that asn1tools alone gives."""
    from bywire.protocol.v2x import codec
    from bywire.protocol.v2x.wire import encode

    codec.remember_own_encodings(remembered)
    try:
        try:
            sent = encode(msg)
        except V2xEncodeError:
            assume(False)
            raise
        received = sent if data.draw(st.booleans()) else _flipped(sent, data.draw)
        reference_s = msg.generation_time_s + 0.1
        fast = _verdict(received, reference_s)
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(codec, "_fast_encoder", _asn1tools_only)
            patch.setattr(codec, "_fast_decoder", _asn1tools_only)
            codec._ENCODED.clear()
            assert _verdict(received, reference_s) == fast
    finally:
        codec.remember_own_encodings(False)
