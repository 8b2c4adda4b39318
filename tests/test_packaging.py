"""The distribution as a user installs it: a wheel built from the checkout, installed in a clean venv.

The wheel must hold the package `bywire` and its data (the DBC, the EDS, the ASN.1 module, the
calibration, the scenarios with their road networks, the host configurations, the Passat FMU's
sources), nothing of the checkout's top-level links, and work from outside the checkout.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

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
    "asn": resources.files("bywire.protocol.v2x").joinpath("bywire_v2x.asn").is_file(),
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
