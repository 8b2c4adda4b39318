"""The ECU link's sending module (`ecu_tx`): a control request older than its configured maximum age
is not sent; the ECU is asked for a controlled stop instead (the heartbeat goes on either way)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from bywire.host.inputs import NoFaults
from bywire.host.modules import KINDS
from bywire.host.modules.messages import CONTROL, ControlRequest
from bywire.host.runtime.module import ModuleContext, ModuleSpec
from bywire.host.runtime.store import ObjectStore
from bywire.protocol.ecu_types import RequestFlags


class _Link:
    def __init__(self) -> None:
        self.sent: list[Any] = []
        self.ticks = 0

    def send_request(self, request: Any) -> None:
        self.sent.append(request)

    def tick(self, now_s: float) -> None:
        self.ticks += 1

    def start_ecu(self) -> None:
        pass


def _module(params: dict[str, Any]) -> tuple[Any, _Link, ModuleContext, ObjectStore]:
    link = _Link()
    res = SimpleNamespace(link=link, trace=None, t0_s=0.0, faults=NoFaults(), heartbeat_sent=None)
    kind = KINDS["ecu_tx"]
    module = kind.build(params, res)  # type: ignore[arg-type]
    spec = ModuleSpec("ecu_tx", kind.inputs, kind.outputs, period_s=kind.period_s, deadline_s=kind.deadline_s)
    store = ObjectStore()
    return module, link, ModuleContext(spec, store, params, 1), store


@pytest.mark.parametrize(
    ("max_age_ms", "age_s", "sent_as_asked"),
    [(None, 0.09, True), (None, 0.15, False), (250, 0.15, True), (250, 0.3, False)],
)
def test_a_request_older_than_the_maximum_age_becomes_a_stop(
    max_age_ms: float | None, age_s: float, sent_as_asked: bool
) -> None:
    module, link, ctx, store = _module({} if max_age_ms is None else {"request_max_age_ms": max_age_ms})
    store.publish(
        CONTROL, ControlRequest(1.0, 1.5, 0.0, int(RequestFlags.ENGAGE), "velocity", 20.0, float("nan"))
    )
    ctx.release(1.0 + age_s)
    module.step(ctx)
    (request,) = link.sent
    assert link.ticks == 1  # the heartbeat, whatever the request
    if sent_as_asked:
        assert request.accel_mps2 == 1.5 and request.flags == RequestFlags.ENGAGE
    else:
        assert request.accel_mps2 == 0.0 and request.flags & RequestFlags.STOP


@pytest.mark.parametrize("params", [{"request_max_age_ms": 5}, {"request_max_age_ms": "100"},
                                    {"request_max_age_ms": True}, {"max_age": 100}])  # fmt: skip
def test_bad_params_are_refused_with_the_field_named(params: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match="ecu_tx"):
        _module(params)
