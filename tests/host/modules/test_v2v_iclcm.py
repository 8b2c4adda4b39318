"""The iCLCM from and to the host (host/modules/io/v2v.py): what the platoon says goes on the air beside the
CAM and comes back out of another host's receiver as the same values; the CAM leaves first and untouched;
the platoon's topics are sampled (never ordered behind, held for or restarted with their producers); the
ETSI profile's CAMs follow EN 302 637-2's rules and carry no iCLCM; bad parameters are named."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import pytest
from module_harness import Harness

from bywire.host.config import load_host_config
from bywire.host.geo import LocalFrame
from bywire.host.modules import KINDS
from bywire.host.modules.gcdc_messages import (
    PLATOON,
    POSE,
    V2V_ICLCM_SENT,
    V2V_RECEIVED,
    V2V_SENT,
    WORLD_LEADS,
    Lead,
    LeadSet,
    PlatoonStatus,
    PoseReport,
)
from bywire.host.modules.io.v2v import PASSAT_REAR_AXLE_M, V2vRxIo, V2vTxIo
from bywire.host.modules.messages import ECU_STATUS, EcuStatusReport
from bywire.host.runtime.module import ModuleContext, ModuleSpec, dependants, dependency_order
from bywire.host.runtime.store import ObjectStore, StoreError
from bywire.protocol.ecu_types import EcuState
from bywire.protocol.v2x.codec import VehicleState
from bywire.protocol.v2x.iclcm import ControllerType, CooperativeState
from bywire.protocol.v2x.transport import MemV2xTransport
from bywire.protocol.v2x.wire import decode, encode

EPOCH = 1305374400.0
FRAME = LocalFrame(51.4708, 5.6230)


def _pose(t: float, x: float = 100.0, speed: float = 25.0) -> PoseReport:
    lat, lon = FRAME.to_geodetic(x, 0.0)
    return PoseReport(
        t, True, x, 0.0, 0.0, speed, 0.3, 0.0, lat, lon, 0.02, True, True, False, False, 4, 0, 0
    )


def _platoon(t: float, accel: float = -1.23, mode: str = "platoon") -> PlatoonStatus:
    return PlatoonStatus(t, accel, mode, 1, 101, 1, True, 24.5, math.nan, math.nan, 0.6)


def _ecu(t: float, state: EcuState = EcuState.ENGAGED) -> EcuStatusReport:
    return EcuStatusReport(t, True, True, t, int(state), 0, True, 25.0, 0.3, 10.0, 0.0, 0.0)


def _world(t: float, gap: float = 18.0, lead_speed: float = 24.0, station: int = 101) -> LeadSet:
    grid = (0.0, 0.1, 0.2)  # its rear bumper from our front bumper at t (we drive 25 m/s)
    lead = Lead(
        station, "v2v", "high", gap, lead_speed, -0.5, 4.5, grid,
        tuple(gap + lead_speed * s for s in grid), (lead_speed,) * 3,
    )  # fmt: skip
    return LeadSet(t, True, 0, 300.0, (lead,), (), math.nan, station, True, 1, 0, 0)


class _Recorder:
    """A V2X link that keeps what is sent, and when in the release (a log shared with the context)."""

    def __init__(self, log: list[str]) -> None:
        self.log = log
        self.sent: list[bytes] = []

    def send(self, payload: bytes) -> bool:
        self.log.append(f"send {decode(payload, EPOCH).__class__.__name__}")
        self.sent.append(payload)
        return True


class _LoggingContext(ModuleContext):
    def __init__(self, spec: ModuleSpec, store: ObjectStore, log: list[str]) -> None:
        super().__init__(spec, store, {}, 1)
        self.log = log

    def latest(self, topic: str) -> Any | None:
        self.log.append(f"read {topic}")
        return super().latest(topic)


def _tx(transport: Any, **kw: Any) -> Harness:
    return Harness("v2v_tx", V2vTxIo(transport, lambda s: EPOCH + s, FRAME, station_id=7, **kw))


def _feed(h: Harness, t: float, **world: Any) -> None:
    h.publish(POSE, _pose(t))
    h.publish(PLATOON, _platoon(t - 0.03))
    h.publish(ECU_STATUS, _ecu(t - 0.01))
    h.publish(WORLD_LEADS, _world(t - 0.05, **world))


def test_an_iclcm_with_the_platoons_values_is_decoded_by_another_host_into_the_same() -> None:
    now = {"t": 0.0}
    link_tx = MemV2xTransport("mem://iclcm", receive=False)
    link_rx = MemV2xTransport("mem://iclcm", clock=lambda: EPOCH + now["t"] + 0.02)
    try:
        tx = _tx(link_tx, profile="gcdc", platoon_id=1)
        rx = Harness("v2v_rx", V2vRxIo(link_rx, lambda s: EPOCH + s, own_station_id=2))
        for k in range(1, 4):
            now["t"] = t = 0.1 * k
            _feed(tx, t)
            tx.step(t)
            rx.publish(POSE, _pose(t, x=80.0))
            rx.step(t + 0.02)
            batch = rx.latest(V2V_RECEIVED)
            assert [v.station_id for v in batch.vehicles] == [7]
            assert len(batch.cooperative) == 1, batch
            got = batch.cooperative[0]
            sent = tx.latest(V2V_ICLCM_SENT)
            assert sent.sent and sent.count == k and sent.iclcm is not None
            # the platoon's values, in the iCLCM's resolutions
            assert got.station_id == 7 and got.controller_type == "cacc" and got.platoon_id == 1
            assert got.target_accel_mps2 == pytest.approx(-1.23, abs=0.005)
            assert got.time_headway_s == pytest.approx(0.6, abs=0.05)
            assert got.cruise_speed_mps == pytest.approx(24.5, abs=0.005)
            assert got.rear_axle_m == pytest.approx(PASSAT_REAR_AXLE_M, abs=0.005)
            # the lead, 50 ms on: 18 m closing at 1 m/s
            assert got.mio_station_id == 101
            assert got.mio_range_m == pytest.approx(18.0 - 0.05, abs=0.006)
            assert got.mio_range_rate_mps == pytest.approx(-1.0, abs=0.006)
            assert math.isnan(got.mio_bearing_rad) and got.lane == 0
            assert got.t_gen_s == pytest.approx(t, abs=1e-3) and got.t_rx_s == pytest.approx(t + 0.02)
            # what we say we sent is what was received, but for the air's resolution and the receive time
            ours = dataclasses.replace(sent.iclcm, t_rx_s=got.t_rx_s)
            for f in dataclasses.fields(got):
                a, b = getattr(ours, f.name), getattr(got, f.name)
                assert a == pytest.approx(b, abs=0.05, nan_ok=True), f.name
        assert batch.accepted == 6 and batch.rejected == ()
    finally:
        link_tx.close()
        link_rx.close()


def test_the_cam_is_sent_first_and_unchanged_before_anything_of_the_iclcm_is_read() -> None:
    log: list[str] = []
    with_iclcm, without = _Recorder(log), _Recorder([])
    a, b = _tx(with_iclcm, profile="gcdc"), _tx(without, profile="gcdc", iclcm=False)
    a.ctx = _LoggingContext(a.spec, a.store, log)
    for k in range(1, 4):
        for h in (a, b):
            _feed(h, 0.1 * k)
            h.step(0.1 * k)
        assert a.latest(V2V_SENT) == b.latest(V2V_SENT)
    assert with_iclcm.sent[0::2] == without.sent  # the same CAM bytes, first in every release
    assert len(with_iclcm.sent) == 6
    release = log[: log.index("send CooperativeState") + 1]
    assert release[:2] == ["read /ego/pose", "send VehicleState"]
    assert set(release[2:-1]) == {"read /platoon/status", "read /ecu/status", "read /world/leads"}


@pytest.mark.parametrize(
    ("change", "controller"),
    [
        ({"ecu": EcuState.READY}, ControllerType.MANUAL),  # the driver drives
        ({"mode": "script"}, ControllerType.MANUAL),  # a test script's requests, not the controller's
        ({"platoon_age": 0.3}, ControllerType.MANUAL),  # the platoon silent: the link stops the car
        ({}, ControllerType.CACC),
    ],
)
def test_the_controller_type_says_whether_the_platoon_drives(
    change: dict[str, Any], controller: ControllerType
) -> None:
    rec = _Recorder([])
    h = _tx(rec, profile="gcdc")
    h.publish(POSE, _pose(1.0))
    h.publish(PLATOON, _platoon(1.0 - change.get("platoon_age", 0.04), mode=change.get("mode", "platoon")))
    h.publish(ECU_STATUS, _ecu(0.99, change.get("ecu", EcuState.ENGAGED)))
    h.step(1.0)
    msg = decode(rec.sent[1], EPOCH + 1.0)
    assert isinstance(msg, CooperativeState) and msg.controller_type is controller
    if controller is ControllerType.CACC:
        assert msg.target_accel_mps2 == pytest.approx(-1.23)
    else:  # no controller's request to feed forward
        assert msg.target_accel_mps2 is None
    # no world model: no most important object
    assert msg.mio_station_id == 0 and msg.mio_range_m is None and msg.mio_range_rate_mps is None


def test_without_the_platoon_an_iclcm_still_goes_and_says_nothing_it_does_not_know() -> None:
    rec = _Recorder([])
    h = _tx(rec, profile="gcdc")
    h.publish(POSE, _pose(0.5))
    h.step(0.5)
    cam, iclcm = (decode(p, EPOCH + 0.5) for p in rec.sent)
    assert isinstance(iclcm, CooperativeState)
    assert iclcm.controller_type is ControllerType.MANUAL and iclcm.platoon_id == 0
    assert (iclcm.target_accel_mps2, iclcm.time_headway_s, iclcm.cruise_speed_mps) == (None, None, None)
    assert iclcm.generation_time_s == pytest.approx(cam.generation_time_s)


def test_platoon_topics_are_sampled_outside_the_data_flow() -> None:
    cfg = load_host_config("gcdc")
    specs = [m.spec for m in cfg.modules]
    tx = next(s for s in specs if s.name == "v2v_tx")
    assert set(tx.sampled) == {"/platoon/status", "/world/leads", "/ecu/status"}
    assert tx.inputs == ("/ego/pose",)
    # ordered as if it read the pose only, and restarted with none of the platoon's producers
    alone = [dataclasses.replace(s, sampled=()) if s is tx else s for s in specs]
    assert [s.name for s in dependency_order(specs)] == [s.name for s in dependency_order(alone)]
    for producer in ("platoon", "world_model", "ecu_rx"):
        assert "v2v_tx" not in dependants(specs, producer)
    # a sampled topic reads through the context; one neither input nor sampled is a wiring mistake
    store = ObjectStore()
    store.publish(PLATOON, _platoon(0.0))
    ctx = ModuleContext(tx, store, {}, 1)
    ctx.release(0.1)
    assert ctx.latest(PLATOON) == _platoon(0.0)
    with pytest.raises(StoreError, match="not among its inputs"):
        ctx.latest("/control/request")
    with pytest.raises(StoreError):
        ctx.new(PLATOON)  # sampled: the newest only, no subscription
    with pytest.raises(ValueError, match="both inputs and sampled"):
        ModuleSpec("x", inputs=(POSE,), sampled=(POSE,), period_s=0.1)


def test_the_etsi_profile_follows_en_302_637_2_and_sends_no_iclcm() -> None:
    rec = _Recorder([])
    h = _tx(rec)  # the default
    sent_at = []
    for k in range(31):  # standing still: a CAM a second
        t = 0.1 * k
        h.publish(POSE, _pose(t, x=100.0, speed=0.0))
        h.publish(PLATOON, _platoon(t))
        h.step(t)
        if h.latest(V2V_SENT).sent:
            sent_at.append(round(t, 6))
        assert not h.latest(V2V_ICLCM_SENT).sent and h.latest(V2V_ICLCM_SENT).iclcm is None
    assert sent_at == [0.0, 1.0, 2.0, 3.0]
    assert all(isinstance(decode(p, EPOCH), VehicleState) for p in rec.sent)
    moving = _Recorder([])
    h = _tx(moving)
    for k in range(11):  # 100 km/h: every 200 ms
        h.publish(POSE, _pose(0.1 * k, x=100.0 + 2.778 * k, speed=27.78))
        h.step(0.1 * k)
    assert len(moving.sent) == 6


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"profile": "fast"}, "profile must be one of etsi, gcdc"),
        ({"iclcm": "yes"}, "iclcm must be true or false"),
        ({"platoon_id": 256}, "platoon_id must be an integer in 0..255"),
        ({"rear_axle_m": -1.0}, "rear_axle_m must be a number in 0..40.95"),
        ({"rate_hz": 25}, r"unknown params \['rate_hz'\]"),
    ],
)
def test_bad_parameters_are_named(params: dict[str, Any], message: str) -> None:
    from bywire.host.inputs import HostInputs
    from bywire.host.modules import HostResources

    res = HostResources(HostInputs(), 0.0)
    res._frame = FRAME
    with pytest.raises(ValueError, match=message):
        KINDS["v2v_tx"].build(params, res)


def test_received_iclcms_pass_the_receivers_hardening_before_the_topic() -> None:
    link_in = MemV2xTransport("mem://iclcm-rx", clock=lambda: EPOCH + 1.0)
    link_out = MemV2xTransport("mem://iclcm-rx", receive=False)
    try:
        rx = Harness("v2v_rx", V2vRxIo(link_in, lambda s: EPOCH + s, own_station_id=1))
        good = CooperativeState(9, EPOCH + 0.98, ControllerType.ACC, 1.0, 1.2, 30.0)
        link_out.send(encode(good))
        link_out.send(encode(good))  # the same generation time again: a replay
        hard = dataclasses.replace(good, generation_time_s=EPOCH + 0.99, target_accel_mps2=-9.99)
        link_out.send(encode(hard))  # the wire's extreme, within the receiver's physical limit
        link_out.send(encode(dataclasses.replace(good, station_id=1, generation_time_s=EPOCH + 0.995)))
        link_out.send(encode(dataclasses.replace(good, generation_time_s=EPOCH - 5.0)))
        rx.step(1.0)
        b = rx.latest(V2V_RECEIVED)
        got = [(c.station_id, c.target_accel_mps2) for c in b.cooperative]
        assert got == [(9, 1.0), (9, pytest.approx(-9.99))]
        assert {r.reason: r.count for r in b.rejected} == {"replayed": 1, "own_station": 1, "too_old": 1}
        assert b.cooperative[0].controller_type == "acc" and b.cooperative[0].t_gen_s == pytest.approx(0.98)
    finally:
        link_in.close()
        link_out.close()
