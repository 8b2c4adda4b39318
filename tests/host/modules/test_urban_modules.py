"""The urban host modules (host/modules/urban.py) on a private store: the object link adapter counts what it
refuses and keeps the newest; the E-stop as the behaviour sees it; pose extrapolation on an exact arc; the
controller steers toward the stub, stops at the plan's stop point, holds on a stale plan or a backward leg
(no reverse gear); the shipped `urban` configuration loads."""

from __future__ import annotations

import math
from typing import Any

import pytest
from module_harness import Harness

from bywire.host.behaviour.situation import EStop
from bywire.host.config import load_host_config
from bywire.host.modules import KINDS
from bywire.host.modules.control.urban import UrbanControl
from bywire.host.modules.io.object_link import UrbanIo
from bywire.host.modules.messages import CONTROL, ECU_STATUS, MISSION, EcuStatusReport, MissionCommand
from bywire.host.modules.planning.urban_behaviour import estop_of, extrapolate
from bywire.host.modules.urban_log import UrbanLog
from bywire.host.modules.urban_messages import URBAN_OBJECTS, URBAN_PLAN, URBAN_POSE, UrbanPlan, UrbanPose
from bywire.protocol.ecu_types import EcuState, RequestFlags
from bywire.protocol.objects import EgoPoseRecord, MemObjectLink, ObjectList, ObjectRecord, encode


def _status(state: EcuState, valid: bool = True) -> EcuStatusReport:
    return EcuStatusReport(0.0, valid, True, 0.0, int(state), 0, True, 0.0, 0.0, 0.0, 0.0, 0.0)


def test_estop_as_the_behaviour_sees_it() -> None:
    assert estop_of(_status(EcuState.ENGAGED)) == EStop.RUN
    assert estop_of(_status(EcuState.DISABLED)) == EStop.DISABLE
    for state in (EcuState.OFF, EcuState.READY, EcuState.PAUSED, EcuState.SAFE_STOP, EcuState.MANUAL):
        assert estop_of(_status(state)) == EStop.PAUSE
    assert estop_of(None) == EStop.PAUSE and estop_of(_status(EcuState.ENGAGED, valid=False)) == EStop.PAUSE


def test_extrapolation_is_an_exact_arc() -> None:
    pose = UrbanPose(0.0, True, 0.0, 0.0, 0.0, 0.0, 10.0, 0.5, 0, 0)  # radius 20 m
    x, y, h = extrapolate(pose, math.pi)  # a quarter circle (0.5 rad/s for pi s)
    assert (x, y, h) == pytest.approx((20.0, 20.0, math.pi / 2), abs=1e-9)
    assert extrapolate(pose, 2.0 * math.pi)[:2] == pytest.approx((0.0, 40.0), abs=1e-9)
    straight = UrbanPose(0.0, True, 0.0, 1.0, 2.0, math.pi / 2, 4.0, 0.0, 0, 0)
    assert extrapolate(straight, 0.5) == pytest.approx((1.0, 4.0, math.pi / 2))
    assert extrapolate(straight, -1.0) == (1.0, 2.0, math.pi / 2)


def test_object_link_adapter_keeps_the_newest_and_counts_refusals() -> None:
    link = MemObjectLink("test-urban-io")
    io = Harness("urban_io", UrbanIo(link, UrbanLog()))
    link.send(
        encode(
            ObjectList(1.0, 1, EgoPoseRecord(1.0, 2.0, 0.1, 3.0, 0.0), (ObjectRecord(7, 5, 6, 0, 1, 4, 2),))
        )
    )
    link.send(encode(ObjectList(1.01, 2, EgoPoseRecord(1.1, 2.0, 0.1, 3.0, 0.0), (), has_objects=False)))
    link.send(b"garbage")
    io.step(0.5)
    pose = io.store.latest(URBAN_POSE)
    objs = io.store.latest(URBAN_OBJECTS)
    assert pose.valid and pose.x_m == 1.1 and pose.stamp_s == 1.01 and pose.rejected == 1
    assert [o.object_id for o in objs.objects] == ["v7"]  # a pose-only update keeps the last list
    io.step(0.51)  # nothing new: the same, republished
    assert io.store.latest(URBAN_POSE).x_m == 1.1 and io.store.latest(URBAN_POSE).t_s == 0.51
    link.close()


def _plan(
    t: float, y0: float = 0.0, direction: int = 1, stop_s: float = math.nan, speed: float = 5.0
) -> UrbanPlan:
    xs = tuple(float(x) for x in range(0, 31))
    zeros = tuple(0.0 for _ in xs)
    ys = tuple(y0 for _ in xs)
    nan = math.nan
    return UrbanPlan(t, True, "Drive/DriveOnLane", direction, speed, stop_s, 0.0, "", nan, nan, False, 0, (),
                     "", "test", (), xs, ys, zeros, zeros, xs)  # fmt: skip


def _control(plan: UrbanPlan | None, pose_y: float = 0.0, speed: float = 5.0, now: float = 1.0) -> Any:
    h = Harness("urban_control", UrbanControl({}))
    h.store.publish(URBAN_POSE, UrbanPose(now, True, now, 2.0, pose_y, 0.0, speed, 0.0, 1, 0))
    h.store.publish(MISSION, MissionCommand(now, "script", 0, 0, 0, False, True, False, False, math.nan))
    h.store.publish(ECU_STATUS, _status(EcuState.ENGAGED))
    if plan is not None:
        h.store.publish(URBAN_PLAN, plan)
    h.step(now)
    return h.store.latest(CONTROL)


def test_controller_steers_toward_the_stub_and_asks_for_steering() -> None:
    right_of_it = _control(_plan(1.0), pose_y=-0.5)
    left_of_it = _control(_plan(1.0), pose_y=0.5)
    assert right_of_it.steer_rad > 0.0 > left_of_it.steer_rad  # back toward y = 0 (left positive)
    assert (
        RequestFlags(right_of_it.flags) & RequestFlags.STEER
        and RequestFlags(right_of_it.flags) & RequestFlags.ENGAGE
    )
    on_it = _control(_plan(1.0), pose_y=0.0)
    assert on_it.steer_rad == pytest.approx(0.0, abs=1e-9) and on_it.controller == "velocity"


def test_controller_stops_at_the_stop_point_and_holds_without_a_plan() -> None:
    near_stop = _control(_plan(1.0, stop_s=6.0), speed=5.0)  # 4 m ahead of the rear axle at 5 m/s
    assert near_stop.accel_mps2 < -2.0 and near_stop.controller in ("stopping", "position")
    assert _control(None).accel_mps2 < 0.0 and _control(None).controller == "none"
    stale = _control(_plan(0.5), now=1.0)  # 0.5 s old
    assert stale.accel_mps2 < 0.0 and stale.controller == "none"
    # a backward leg drives in reverse: the REVERSE flag, the request along the direction of travel
    backward = _control(_plan(1.0, direction=-1), speed=0.0)
    assert backward.flags & RequestFlags.REVERSE and backward.accel_mps2 > 0.0
    forward = _control(_plan(1.0), speed=0.0)
    assert not forward.flags & RequestFlags.REVERSE


def test_the_urban_configuration_loads() -> None:
    cfg = load_host_config("urban")
    kinds = [m.kind for m in cfg.modules]
    assert {"urban_io", "urban_behaviour", "urban_control", "ecu_tx"} <= set(kinds)
    behaviour = cfg.module("behaviour")
    assert behaviour.spec.period_s == pytest.approx(0.05) and behaviour.spec.deadline_s == pytest.approx(
        0.045
    )
    assert not KINDS["urban_behaviour"].needs_resources and not KINDS["urban_control"].needs_resources
