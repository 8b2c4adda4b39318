"""One host module on a private store, stepped by hand: publish its inputs, release it at a time,
read its outputs (the module's kind from `KINDS` gives its inputs, outputs, rate and deadline)."""

from __future__ import annotations

from typing import Any

from bywire.host.modules import KINDS
from bywire.host.runtime.module import ModuleContext, ModuleSpec
from bywire.host.runtime.store import ObjectStore


class Harness:
    def __init__(self, kind: str, module: Any, params: dict[str, Any] | None = None) -> None:
        k = KINDS[kind]
        self.spec = ModuleSpec(
            kind, k.inputs, k.outputs, k.sampled, period_s=k.period_s, deadline_s=k.deadline_s
        )
        self.store = ObjectStore()
        self.module = module
        self.ctx = ModuleContext(self.spec, self.store, dict(params or {}), 1)

    def publish(self, topic: str, obj: object) -> None:
        self.store.publish(topic, obj)

    def step(self, now_s: float) -> None:
        self.ctx.release(now_s)
        self.module.step(self.ctx)

    def latest(self, topic: str) -> Any:
        return self.store.latest(topic)
