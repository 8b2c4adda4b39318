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


def test_the_kernels_a_start_would_compile_are_compiled_before_the_run() -> None:
    """A start that compiles numba kernels for seconds is judged hung: the host compiles (or loads)
    them when it prepares its world, once per kernel module, before any module starts."""
    import sys
    import types

    from bywire.host.inputs import HostInputs
    from bywire.host.modules import WARM_UPS, HostResources

    calls: list[str] = []
    fakes = {
        name: types.SimpleNamespace(warm_up=lambda n=name: calls.append(n))
        for k in WARM_UPS
        for name in WARM_UPS[k]
    }
    saved = {name: sys.modules.get(name) for name in fakes}
    sys.modules.update(fakes)  # type: ignore[arg-type]
    try:
        mods = [
            types.SimpleNamespace(kind=k, params={}) for k in ("lidar_perception", "lidar_io", "odometry")
        ]
        HostResources(HostInputs(), 0.0).prepare_world(mods + mods)
    finally:
        for name, mod in saved.items():
            if mod is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = mod
    assert calls == list(WARM_UPS["lidar_perception"])  # once, though the kind came twice
    assert {n for names in WARM_UPS.values() for n in names} == {
        "bywire.host.perception.grid",
        "bywire.host.perception.lane_markers",
        "bywire.host.navigation.hybrid_astar",
    }
    for names in WARM_UPS.values():
        for name in names:
            assert callable(importlib.import_module(name).warm_up)
