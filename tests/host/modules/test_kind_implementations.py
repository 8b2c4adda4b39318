"""Every module kind says where it is implemented, so that the host imports it before the run."""

from __future__ import annotations

import importlib

from bywire.host.modules import IMPLEMENTATIONS, KINDS


def test_every_kind_names_modules_that_exist_and_hold_what_its_builder_makes() -> None:
    assert set(IMPLEMENTATIONS) == set(KINDS)
    for kind, names in IMPLEMENTATIONS.items():
        modules = [importlib.import_module(n) for n in names]
        built = KINDS[kind].build
        # The builder's lazy import names its class's module: it must be among the listed ones.
        lazy = [c for c in built.__code__.co_consts if isinstance(c, tuple) and c and isinstance(c[0], str)]
        assert modules and lazy is not None
