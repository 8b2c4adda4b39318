"""The distribution as a user installs it: a wheel built from the checkout, installed in a clean venv.

The wheel must hold the package `bywire` and its data (the DBC, the EDS, the ASN.1 module, the
calibration, the scenarios with their road networks, the host configurations, the Passat FMU's
sources), nothing of the checkout's top-level links, and work from outside the checkout.
"""

from __future__ import annotations

import ast
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import venv
import zipfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

DATA = (
    "bywire/protocol/vehicle.dbc",
    "bywire/protocol/ecu.eds",
    "bywire/ecu/calibrations/passat.json",
    "bywire/hil/scenarios/demo.yaml",
    "bywire/hil/scenarios/networks/cross.rndf",
    "bywire/host/configs/default.yaml",
    "bywire/vehicle_models/passat/modelDescription.xml",
)

# Runs inside the clean venv, in an empty folder: the package as installed, not the checkout.
PROBE = """
import json, sys
import bywire
from importlib import resources
from bywire.ecu.calibration import default_calibration
from bywire.hil.scenario import builtin_scenarios, load_scenario
from bywire.host.config import load_host_config, shipped_configs
from bywire.protocol.vehicle_can import VehicleCodec
assert default_calibration() is not None
print(json.dumps({
    "file": bywire.__file__,
    "scenarios": len(builtin_scenarios()),
    "demo": load_scenario("demo").name,
    "configs": sorted(shipped_configs()),
    "dbc_messages": len(VehicleCodec().messages),
    "asn": resources.files("bywire.protocol.v2x").joinpath("asn1", "EN302637-2-v1.4.1-CAM.asn").is_file(),
}))
"""


def _source_copy(dest: Path) -> Path:
    """What a source distribution holds, copied: building in the checkout would leave build/ there."""
    dest.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, dest / name)
    shutil.copytree(ROOT / "bywire", dest / "bywire", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return dest


def test_a_wheel_installs_in_a_clean_venv_and_runs_outside_the_checkout(tmp_path: Path) -> None:
    dist = tmp_path / "dist"
    source = _source_copy(tmp_path / "source")
    build = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "-w",
            str(dist),
            str(source),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stderr[-3000:]
    warnings = build.stdout + build.stderr
    assert "would be ignored" not in warnings and "same name as your package" not in warnings, warnings
    (wheel,) = dist.glob("bywire-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for data in DATA:
        assert data in names, data
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names), "the MIT licence travels with it"
    tops = {n.split("/")[0] for n in names}
    assert tops == {"bywire", *(t for t in tops if t.endswith(".dist-info"))}, tops

    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    site = Path(
        subprocess.check_output(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], text=True
        ).strip()
    )
    # The wheel's files, unpacked as an installer does (the venv has no pip: nothing else gets in) ...
    zipfile.ZipFile(wheel).extractall(site)
    # ... and its dependencies from the test's own environment, which holds no bywire of its own
    # on this path (the checkout is an editable install: a separate path entry, not used here).
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    probe = subprocess.run(
        [str(python), "-c", PROBE], capture_output=True, text=True, timeout=120, cwd=work, env=env
    )
    assert probe.returncode == 0, probe.stderr[-3000:]
    doc = json.loads(probe.stdout.strip().splitlines()[-1])
    assert Path(doc["file"]).is_relative_to(site), doc["file"]
    from bywire.hil.scenario import builtin_scenarios

    assert doc["scenarios"] == len(builtin_scenarios()) and doc["demo"] == "demo"
    assert {"default", "gcdc", "urban"} <= set(doc["configs"])
    assert doc["dbc_messages"] > 5 and doc["asn"]


# -- what pyproject.toml declares is what the package holds and imports ---------------------------------


def _pyproject() -> dict[str, Any]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def _dist_name(requirement: str) -> str:
    """`python-can>=4.4` -> `python-can` (PEP 503 normalised)."""
    match = re.match(r"[A-Za-z0-9][A-Za-z0-9._-]*", requirement)
    assert match is not None, requirement
    return re.sub(r"[-_.]+", "-", match.group(0)).lower()


def test_every_package_data_pattern_matches_a_file() -> None:
    """A pattern for a folder that does not exist, or that matches nothing, ships nothing and hides
    the file someone meant to ship."""
    patterns = _pyproject()["tool"]["setuptools"]["package-data"]
    for package, globs in patterns.items():
        folder = ROOT / package.replace(".", "/")
        assert folder.is_dir(), f"package-data names {package}, and there is no {folder}"
        for pattern in globs:
            assert any(p.is_file() for p in folder.glob(pattern)), f"{package}: {pattern} matches no file"


class _Imports(ast.NodeVisitor):
    """The top-level names a module imports: `eager` when importing the module runs the import,
    `lazy` when a function runs it, or it is optional (`try: ... except ImportError`); imports only
    for type checkers are neither."""

    def __init__(self) -> None:
        self.eager: set[str] = set()
        self.lazy: set[str] = set()
        self.eager_modules: set[str] = set()  # in full: `bywire.host.runtime.live_view`
        self._depth = 0  # functions and optional imports we are inside

    def _add(self, name: str) -> None:
        (self.lazy if self._depth else self.eager).add(name.split(".")[0])
        if not self._depth:
            self.eager_modules.add(name)

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            self._add(alias.name)

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.level == 0 and node.module is not None:
            self._add(node.module)
            for alias in node.names:  # `from bywire.host.runtime import live_view`
                if not self._depth:
                    self.eager_modules.add(f"{node.module}.{alias.name}")

    def _nested(self, node: ast.AST) -> None:
        self._depth += 1
        self.generic_visit(node)
        self._depth -= 1

    visit_FunctionDef = visit_AsyncFunctionDef = visit_Lambda = _nested

    def visit_If(self, node: ast.If) -> None:
        test = node.test
        if (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
            isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
        ):
            for child in node.orelse:
                self.visit(child)
            return
        self.generic_visit(node)

    def visit_Try(self, node: ast.Try) -> None:
        optional = any(
            isinstance(h.type, ast.Name) and h.type.id in ("ImportError", "ModuleNotFoundError")
            for h in node.handlers
        )
        if optional:
            self._nested(node)
        else:
            self.generic_visit(node)


def _distributions_by_module() -> dict[str, list[str]]:
    """Top-level module -> the installed distributions that provide it: importlib.metadata's table,
    plus the extension modules lying at the top of site-packages, which it leaves out before Python
    3.12 (ruckig is one `ruckig.cpython-311-x86_64-linux-gnu.so`)."""
    from importlib import machinery, metadata

    found = {name: list(dists) for name, dists in metadata.packages_distributions().items()}
    for dist in metadata.distributions():
        for file in dist.files or ():
            if len(file.parts) != 1:
                continue
            for suffix in machinery.EXTENSION_SUFFIXES:
                if file.name.endswith(suffix):
                    found.setdefault(file.name[: -len(suffix)], []).append(dist.metadata["Name"])
    return found


# Modules that belong to an extra: they import it when they load, and the package imports them only
# where the extra's feature is used (checked below).
EXTRA_MODULES = {"bywire.host.runtime.live_view": "live"}


def _scan_package() -> dict[str, _Imports]:
    """Module name -> what it imports, for every module of bywire/."""
    found: dict[str, _Imports] = {}
    for path in sorted((ROOT / "bywire").rglob("*.py")):
        imports = _Imports()
        imports.visit(ast.parse(path.read_text(encoding="utf-8"), str(path)))
        parts = path.relative_to(ROOT).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = imports
    return found


def _third_party_imports() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """Distribution -> the modules of bywire/ that import it, eagerly and lazily."""
    dists_of = _distributions_by_module()
    eager: dict[str, set[str]] = {}
    lazy: dict[str, set[str]] = {}
    unknown: set[str] = set()
    for where, found in _scan_package().items():
        eager_names = set() if where in EXTRA_MODULES else found.eager
        lazy_names = found.lazy | found.eager if where in EXTRA_MODULES else found.lazy
        for names, into in ((eager_names, eager), (lazy_names, lazy)):
            for name in names:
                if name in sys.stdlib_module_names or name in ("__future__", "bywire", "benchmarks"):
                    continue
                if name not in dists_of:
                    unknown.add(f"{name} ({where})")
                    continue
                for dist in dists_of[name]:
                    into.setdefault(_dist_name(dist), set()).add(where)
    assert not unknown, f"imported, but no installed distribution provides it: {sorted(unknown)}"
    return eager, lazy


def test_runtime_dependencies_are_what_the_runtime_imports() -> None:
    """Every runtime dependency is imported by the package, every import of the package is declared,
    and what only tests or benchmarks need (oracles such as cvxpy) sits in an extra, imported where it
    is used, never when a module loads."""
    project = _pyproject()["project"]
    runtime = {_dist_name(r) for r in project["dependencies"]}
    extras = {
        _dist_name(r)
        for reqs in project["optional-dependencies"].values()
        for r in reqs
        if "bywire[" not in r
    }
    eager, lazy = _third_party_imports()
    undeclared_eager = {d: sorted(w) for d, w in eager.items() if d not in runtime}
    assert not undeclared_eager, (
        f"imported when a module loads, but no runtime dependency: {undeclared_eager}"
    )
    undeclared = {d: sorted(w) for d, w in lazy.items() if d not in runtime | extras}
    assert not undeclared, f"imported, but declared nowhere: {undeclared}"
    unused = runtime - set(eager) - set(lazy)
    assert not unused, f"runtime dependencies the package never imports (an extra, or nothing): {unused}"
    # the follow QP's oracle: a second at every host's start, for a test's sake
    assert "cvxpy" not in runtime and "cvxpy" in lazy and "cvxpy" not in eager
    assert "pynmea2" not in runtime


def test_the_modules_of_an_extra_load_only_where_it_is_used() -> None:
    eager_importers = {
        module: sorted(m for m, found in _scan_package().items() if module in found.eager_modules)
        for module in EXTRA_MODULES
    }
    assert eager_importers == {module: [] for module in EXTRA_MODULES}
