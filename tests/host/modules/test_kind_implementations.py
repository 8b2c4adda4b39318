"""Every module kind says where it is implemented, so that the host imports it before the run."""

from __future__ import annotations

import dis
import importlib

from bywire.host.modules import IMPLEMENTATIONS, KINDS


def _imported_by(func: object) -> set[str]:
    code = getattr(func, "__code__", None)
    assert code is not None
    return {i.argval for i in dis.get_instructions(code) if i.opname == "IMPORT_NAME"}


def test_every_kind_lists_the_modules_its_builder_imports() -> None:
    assert set(IMPLEMENTATIONS) == set(KINDS)
    for kind, names in IMPLEMENTATIONS.items():
        for name in names:
            importlib.import_module(name)
        imported = {n for n in _imported_by(KINDS[kind].build) if n.startswith("bywire.host.modules")}
        assert imported <= set(names), (kind, imported - set(names))
