"""What the ECU's safety authority is, in files, and which tests are its spec.

One list for both tools that test the tests (`safety_coverage.py`, `mutation.py`), so that a file
added to the authority, or a spec test file added beside the others, is measured by both at once.

The authority is DESIGN section 4's: the state machine, the pure core, the E2E counter logic and
the receivers/watchdogs that feed it, and the transmit guard (opendbc's `tx_hook`). Some of its
files also hold code that is not safety logic (the receiver's read-only views, NMT, the rest of the
ECU's CANopen node); for those the `parts` name the classes and functions that are, and reports
show the part as the file's safety scope beside the whole file.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class SafetySource:
    path: str  # relative to the repository root, as a folder in the checkout (not the import name)
    parts: tuple[str, ...] = ()  # qualified names inside the file that are the authority; () = all
    optional: bool = False  # not written yet: measured once it exists, not an error while it does not


SAFETY_SOURCES: tuple[SafetySource, ...] = (
    SafetySource("bywire/ecu/safety.py"),
    SafetySource("bywire/ecu/core.py"),
    SafetySource("bywire/ecu/tx_guard.py", optional=True),
    SafetySource("bywire/protocol/e2e.py"),
    SafetySource("bywire/protocol/vehicle_rx.py", parts=("VehicleRx",)),
    SafetySource("bywire/protocol/canopen_link/nmt.py", parts=("HeartbeatConsumer",)),
    SafetySource(
        "bywire/protocol/canopen_link/ecu_node.py", parts=("EcuNode.request_fresh", "EcuNode._on_rpdo")
    ),
)

# The spec tests: the fixed files, plus every file of the two families that are still growing.
SPEC_TEST_FILES: tuple[str, ...] = (
    "tests/ecu/test_safety.py",
    "tests/ecu/test_ecu_core_properties.py",
    "tests/protocol/test_e2e.py",
    "tests/protocol/test_vehicle_can.py",
    "tests/protocol/test_vehicle_pq.py",
    "tests/protocol/test_canopen_link.py",
    "tests/ecu/test_ecu_app.py",
)
SPEC_TEST_GLOBS: tuple[str, ...] = ("tests/ecu/test_safety*.py", "tests/ecu/test_tx_guard*.py")
# Measured for coverage, not run for every mutant: the gear shift's branches of the core, and the
# application-level attacks (some of them on the wall clock, which a mutant run must not depend on).
COVERAGE_ONLY_TESTS: tuple[str, ...] = ("tests/ecu/test_reverse.py", "tests/ecu/test_ecu_safety_app.py")

# Mutation testing runs where a mutant is cheap to judge: the state machine and the guard.
DEFAULT_MUTATE: tuple[str, ...] = ("bywire/ecu/safety.py", "bywire/ecu/tx_guard.py")


class ScopeError(RuntimeError):
    """The list above no longer matches the tree: a file was renamed or removed. Fail loudly, since
    a tool that silently stops measuring a safety file is worse than one that stops the build."""


def safety_sources(root: Path = ROOT) -> list[SafetySource]:
    found: list[SafetySource] = []
    for src in SAFETY_SOURCES:
        if (root / src.path).is_file():
            found.append(src)
        elif not src.optional:
            raise ScopeError(f"{src.path}: listed as a safety file in tools/safety_scope.py but missing")
    return found


def spec_test_files(root: Path = ROOT) -> list[str]:
    missing = [f for f in SPEC_TEST_FILES if not (root / f).is_file()]
    if missing:
        raise ScopeError(f"spec test files listed in tools/safety_scope.py but missing: {', '.join(missing)}")
    files = set(SPEC_TEST_FILES)
    for pattern in SPEC_TEST_GLOBS:
        files.update(p.relative_to(root).as_posix() for p in root.glob(pattern))
    return sorted(files)


def package_dirs(root: Path = ROOT) -> dict[str, str]:
    """Import name -> folder of the package the tools stage and measure: `bywire` is the folder
    bywire/ (the path a reader sees is the path Python imports)."""
    if not (root / "bywire" / "__init__.py").is_file():
        raise ScopeError(f"{root}: no bywire/ package folder")
    return {"bywire": "bywire"}


def module_name(path: str, root: Path = ROOT) -> str:
    """The import name of a file path: bywire/ecu/safety.py -> bywire.ecu.safety."""
    rel = Path(path).with_suffix("")
    best: tuple[int, str] | None = None
    for package, folder in package_dirs(root).items():
        folder_parts = Path(folder).parts
        if rel.parts[: len(folder_parts)] == folder_parts and (best is None or len(folder_parts) > best[0]):
            rest = rel.parts[len(folder_parts) :]
            best = (len(folder_parts), ".".join((package, *rest)))
    if best is None:
        raise ScopeError(f"{path} is in no folder that pyproject.toml maps onto a package")
    return best[1]


def coverage_test_files(root: Path = ROOT) -> list[str]:
    """The spec tests plus those measured for coverage only."""
    missing = [f for f in COVERAGE_ONLY_TESTS if not (root / f).is_file()]
    if missing:
        listed = "listed in tools/safety_scope.py but missing"
        raise ScopeError(f"coverage test files {listed}: {', '.join(missing)}")
    return sorted({*spec_test_files(root), *COVERAGE_ONLY_TESTS})


def qualified_ranges(source: str) -> dict[str, tuple[int, int]]:
    """Qualified name (Class.method) -> first and last line, decorators included: how both tools
    find a file's safety parts and name the function a line is in."""
    ranges: dict[str, tuple[int, int]] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
                name = f"{prefix}{child.name}"
                first = min([child.lineno, *(d.lineno for d in child.decorator_list)])
                ranges.setdefault(name, (first, child.end_lineno or child.lineno))
                visit(child, f"{name}.")

    visit(ast.parse(source), "")
    return ranges
