"""The host modules of the spine, by kind: what a host configuration file can name.

Each kind has a default declaration (inputs, outputs, rate, deadline) and a builder that makes a
fresh instance from the configuration's parameters and the host's resources (the ECU link, the
sensor bus, the trace). Kinds that need no resources can run in a worker process of their own.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import can

from bywire.hil.scenario import Scenario
from bywire.hil.trace import TraceWriter
from bywire.host.modules import messages as m
from bywire.host.runtime.module import Module
from bywire.host.runtime.topics import SAFETY_LIMIT, STOP_REQUEST
from bywire.protocol.canopen_node import HostMaster


@dataclass
class HostResources:
    """What modules share that is not data: adapters owned by the host process."""

    scenario: Scenario
    t0_s: float
    link: HostMaster | None = None
    sensor_bus: can.BusABC | None = None
    trace: TraceWriter | None = None


Builder = Callable[[Mapping[str, Any], "HostResources | None"], Module]


@dataclass(frozen=True)
class ModuleKind:
    kind: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    period_s: float
    deadline_s: float
    build: Builder
    needs_resources: bool = True
    doc: str = ""
    always_release: bool = False  # see ModuleSpec.always_release


def _mission(params: Mapping[str, Any], res: HostResources | None) -> Module:
    from bywire.host.modules.mission import ScenarioMission

    assert res is not None
    return ScenarioMission(res.scenario, res.t0_s)


def _ecu_rx(params: Mapping[str, Any], res: HostResources | None) -> Module:
    from bywire.host.modules.ecu_link import EcuRx

    assert res is not None and res.link is not None
    return EcuRx(res.link)


def _ecu_tx(params: Mapping[str, Any], res: HostResources | None) -> Module:
    from bywire.host.modules.ecu_link import EcuTx

    assert res is not None and res.link is not None
    return EcuTx(res.link, res.trace, res.t0_s)


def _odometry(params: Mapping[str, Any], res: HostResources | None) -> Module:
    from bywire.host.modules.odometry import OdometryModule

    return OdometryModule()


def _radar(params: Mapping[str, Any], res: HostResources | None) -> Module:
    from bywire.host.modules.perception import RadarIo

    return RadarIo(res.sensor_bus if res is not None else None)


def _lead_tracker(params: Mapping[str, Any], res: HostResources | None) -> Module:
    from bywire.host.modules.perception import LeadTracker

    return LeadTracker()


def _longitudinal(params: Mapping[str, Any], res: HostResources | None) -> Module:
    from bywire.host.modules.control import LongitudinalModule

    return LongitudinalModule(dict(params))


KINDS: dict[str, ModuleKind] = {
    k.kind: k
    for k in (
        ModuleKind("scenario_mission", (), (m.MISSION,), 0.02, 0.010, _mission, doc="the scenario's script"),
        ModuleKind("ecu_rx", (), (m.ECU_STATUS,), 0.02, 0.010, _ecu_rx, doc="ECU status from the link"),
        ModuleKind(
            "odometry", (m.ECU_STATUS,), (m.ODOMETRY,), 0.02, 0.010, _odometry, False, "distance driven"
        ),
        ModuleKind("radar_io", (), (m.RADAR,), 0.02, 0.010, _radar, doc="radar frames off the sensor bus"),
        ModuleKind(
            "lead_tracker",
            (m.RADAR, m.ODOMETRY),
            (m.LEAD,),
            0.02,
            0.010,
            _lead_tracker,
            False,
            "lead vehicle",
        ),
        ModuleKind(
            "longitudinal",
            (m.MISSION, m.ODOMETRY, m.LEAD, SAFETY_LIMIT),
            (m.CONTROL,),
            0.02,
            0.010,
            _longitudinal,
            False,
            "seed 000 11.2 override controller",
        ),
        ModuleKind(
            "ecu_tx",
            (m.CONTROL, m.MISSION, m.ECU_STATUS, m.ODOMETRY, STOP_REQUEST),
            (m.ECU_REQUEST,),
            0.02,
            0.010,
            _ecu_tx,
            doc="requests and heartbeat to the ECU",
            always_release=True,
        ),
    )
}
