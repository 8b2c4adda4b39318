"""ECU firmware images: one self-contained, reproducible zip application per firmware version.

No paper section (AnnieWAY's ECU was a dSPACE-style unit flashed by its vendor tool); this is our
deployment unit for `bywire ecu flash`. An image is a zipapp holding:

- the parts of bywire the ECU runs: `bywire/__init__.py`, `bywire/clock.py`, `bywire.protocol` (its
  top level and the ECU's end of the CANopen link, never the host's master) and `bywire.ecu` (all
  modules), with their package data (`*.dbc`, `*.eds`, `calibrations/*.json`);
- the pure-Python distributions they import at run time (`RUNTIME_DISTRIBUTIONS` and their
  requirements, found with importlib.metadata), with their `*.dist-info` metadata so that entry
  points (python-can's `can.interface` plugins, e.g. python-can-remote's `remote`) resolve from the
  zip; plus a `bywire-<version>.dist-info` carrying bywire's own `can.interface` entry points;
- `bywire/_image.json` (version, entry, distributions, skipped extension modules) and `__main__.py`.

Deviations and choices:
- Compiled extension modules are left out (wrapt, msgpack, bitstruct ship pure-Python fallbacks),
  so an image is portable across machines with the same Python minor version. `selftest` proves the
  image imports without them; run it under `python -I -S` so nothing outside the zip is visible.
- Sources only, no .pyc: CPython's marshal output is not byte-reproducible across runs (frozenset
  constants follow hash randomisation), and reproducibility is worth the ~1 s of compile at start.
- A requirement with an environment marker (other than `extra == ...`) is included when it is
  installed here, instead of evaluating the marker (that would need `packaging`, and `ecu` imports
  only the stdlib): the build machine is the ECU's platform.
- Deterministic: entries sorted, fixed timestamps and modes, fixed compression level, no shebang;
  the same sources give the same sha256. The version is `bywire.__version__` + "+" + the first 12
  hex digits of a hash over the content, so two different images never share a version.

What makes a file an ECU image (`check_ecu_image`, run by flash on every image before anything
else): a zip with `_image.json` in our format, the generated `__main__.py` byte for byte (it is what
`python IMAGE run` executes), bywire's ECU app as the entry, and `ECU_IMAGE_FILES`, the modules the
ECU cannot run or be booted without. A zipapp whose own self-test says "ok" is not enough. This is a
check against the wrong file, not against a forger: authenticity is the signature (signing.py).

The image's `__main__` dispatches: `run ARGS...` -> the entry (`bywire.ecu.app:main(ARGS)`),
`selftest`, `version`, `info`. `selftest` (run by flash under `python -I -S`, before a slot is
touched) imports every bywire module and each distribution's top-level package, resolves the entry
and the `can.interface` plugins, reads and parses every package data file through
importlib.resources (DBC with cantools, EDS with canopen, calibrations with bywire.ecu.calibration),
calls `default_calibration()` and the entry module's optional `selftest()` hook, refuses any use of
`__file__` in bywire's modules (package data is not on disk inside a zip), and checks that nothing
was imported from outside the image and the standard library. It prints one JSON line and exits
0 / 1.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import importlib.metadata as md
import importlib.resources
import io
import json
import os
import re
import subprocess
import sys
import sysconfig
import tokenize
import zipfile
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bywire.ecu.store import ImageManifest

IMAGE_FORMAT = "bywire-ecu-image"
DEFAULT_ENTRY = "bywire.ecu.app:main"
IMAGE_INFO_NAME = "bywire/_image.json"
# An optional function of the entry module that `selftest` calls after importing everything: the
# app's chance to exercise its start-up paths (codecs, object dictionary) without opening buses.
SELFTEST_HOOK = "selftest"
# The distributions the ECU imports at run time (DESIGN section 2: `protocol` may import python-can,
# canopen and cantools; python-can-remote provides the `remote:` bus between processes).
RUNTIME_DISTRIBUTIONS: tuple[str, ...] = ("python-can", "python-can-remote", "canopen", "cantools")

# Files of bywire itself, per package: glob patterns relative to the package directory.
_BYWIRE_PARTS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("bywire", ("__init__.py", "clock.py", "realtime.py", "rhythm.py")),
    # The protocol's top level, and of its subpackages only what the ECU's end of the CANopen link
    # needs. The host's (canopen_link/host_master.py: the host's master; protocol/v2x: V2V messages,
    # which the ECU never speaks, and whose asn1tools is not among the image's distributions) stay out.
    ("bywire.protocol", ("*.py", "*.dbc", "*.eds", "*.LICENSE")),
    ("bywire.protocol.canopen_link", ("__init__.py", "dictionary.py", "nmt.py", "pump.py", "ecu_node.py")),
    ("bywire.ecu", ("**/*.py", "calibrations/*.json")),
)
# DBCs the self-test loads with cantools' strict checks off (protocol.vehicle_can.LENIENT_DBCS, named
# here so that an image without bywire's protocol still checks its data): opendbc's vw_pq.dbc.
LENIENT_DBCS = frozenset({"vw_pq.dbc"})
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # the earliest date a zip entry can carry
_ZIP_LEVEL = 6  # zlib default: 1 % larger than 9, 2.5x faster to build
_EXTENSION_SUFFIXES = (".so", ".pyd", ".dylib", ".dll")
_SKIP_SUFFIXES = (".pyc", ".pyo", ".pyi", ".exe", *_EXTENSION_SUFFIXES)
# dist-info files an image keeps: enough for importlib.metadata (name, version, entry points) and
# the licences (python-can is LGPL-3: its licence travels with it). RECORD would list files we drop.
_DIST_INFO_KEEP = re.compile(
    r"^(METADATA|entry_points\.txt|top_level\.txt|(LICEN[CS]E|COPYING|NOTICE|AUTHORS).*|licenses/.*)$"
)
_REQ_NAME = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)")

# The ECU's core modules (zip entry names): its app, safety authority, executive, calibration schema,
# and the store and image modules through which it is booted and reports.
ECU_IMAGE_FILES: tuple[str, ...] = (
    "bywire/__init__.py",
    "bywire/clock.py",
    "bywire/protocol/__init__.py",
    "bywire/ecu/__init__.py",
    "bywire/ecu/app.py",
    "bywire/ecu/core.py",
    "bywire/ecu/safety.py",
    "bywire/ecu/executive.py",
    "bywire/ecu/calibration.py",
    "bywire/ecu/store.py",
    "bywire/ecu/firmware.py",
)

_MAIN_PY = b'''"""Entry of a bywire ECU firmware image (generated by bywire.ecu.firmware)."""
import sys

from bywire.ecu.firmware import image_main

sys.exit(image_main(sys.argv[1:]))
'''


class FirmwareError(Exception):
    """An image cannot be built, read or does not pass its self-test."""


@dataclass(frozen=True)
class ImageContents:
    """Everything an image holds except its version-dependent parts (`_image.json`, dist-info)."""

    files: Mapping[str, bytes]  # zip entry name -> bytes
    distributions: Mapping[str, Mapping[str, Any]]  # name -> {"version", "top_level"}
    skipped_extensions: tuple[str, ...]  # compiled modules left out (pure fallbacks used)
    entry_points: tuple[tuple[str, str], ...]  # bywire's can.interface plugins: (name, "module:attr")


# --- collecting files (build machine) -----------------------------------------------------------


def _package_dir(package: str) -> Path:
    """The folder an installed package's files are read from to build an image."""
    return Path(str(importlib.resources.files(package)))


def _bywire_files() -> dict[str, bytes]:
    files: dict[str, bytes] = {}
    for package, patterns in _BYWIRE_PARTS:
        root = _package_dir(package)
        prefix = PurePosixPath(*package.split("."))
        for pattern in patterns:
            for path in sorted(root.glob(pattern)):
                rel = path.relative_to(root)
                # Dot files are editor / atomic-write temporaries, never sources.
                if not path.is_file() or "__pycache__" in rel.parts or rel.name.startswith("."):
                    continue
                # A .py outside a package (a generator script next to package data, such as
                # calibrations/make_passat.py) is a build tool, not firmware.
                if path.suffix == ".py" and not all(
                    (root / Path(*rel.parts[:i]) / "__init__.py").is_file() for i in range(len(rel.parts))
                ):
                    continue
                files[str(prefix / rel.as_posix())] = path.read_bytes()
    return files


def _requirement_names(dist: md.Distribution) -> list[str]:
    names = []
    for req in dist.requires or []:
        spec, _, marker = req.partition(";")
        if "extra" in marker:
            continue
        m = _REQ_NAME.match(spec)
        if m is None:
            raise FirmwareError(f"{dist.metadata['Name']}: cannot parse requirement {req!r}")
        if marker.strip():
            try:
                md.distribution(m.group(1))
            except md.PackageNotFoundError:
                continue
        names.append(m.group(1))
    return names


def _normalize(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _distribution_closure(roots: Iterable[str]) -> list[md.Distribution]:
    seen: dict[str, md.Distribution] = {}
    todo = list(roots)
    while todo:
        name = todo.pop()
        key = _normalize(name)
        if key in seen:
            continue
        try:
            dist = md.distribution(name)
        except md.PackageNotFoundError:
            raise FirmwareError(f"distribution {name!r} needed by the ECU image is not installed") from None
        seen[key] = dist
        todo.extend(_requirement_names(dist))
    return [seen[k] for k in sorted(seen)]


def _distribution_files(
    dist: md.Distribution,
) -> tuple[dict[str, bytes], list[str], list[str]]:
    """(zip entries, top-level import names, skipped extension modules) of one distribution."""
    name = dist.metadata["Name"]
    if dist.files is None:
        raise FirmwareError(f"distribution {name}: no RECORD, cannot list its files")
    files: dict[str, bytes] = {}
    skipped: list[str] = []
    for f in dist.files:
        parts = PurePosixPath(str(f)).parts
        if not parts or parts[0] == ".." or "__pycache__" in parts:
            continue
        rel = "/".join(parts)
        if parts[0].endswith(".dist-info"):
            if len(parts) > 1 and _DIST_INFO_KEEP.match("/".join(parts[1:])):
                files[rel] = Path(str(f.locate())).read_bytes()
            continue
        if parts[0].endswith(".egg-info") or parts[0].endswith(".data"):
            continue
        if rel.endswith(_EXTENSION_SUFFIXES):
            skipped.append(rel)
            continue
        if rel.endswith(_SKIP_SUFFIXES):
            continue
        files[rel] = Path(str(f.locate())).read_bytes()
    top_level = sorted(
        {rel.removesuffix(".py") for rel in files if "/" not in rel and rel.endswith(".py")}
        | {rel.split("/")[0] for rel in files if rel.count("/") == 1 and rel.endswith("/__init__.py")}
    )
    return files, top_level, skipped


def _bywire_entry_points() -> tuple[tuple[str, str], ...]:
    """bywire's declared can.interface entry points: (name, "module:attr")."""
    try:
        eps = md.distribution("bywire").entry_points
    except md.PackageNotFoundError:
        return ()
    return tuple(sorted((ep.name, ep.value) for ep in eps.select(group="can.interface")))


def _entry_points_txt(entry_points: Iterable[tuple[str, str]], files: Mapping[str, bytes]) -> str:
    # Only plugins whose module is in the image: a dangling entry point would break python-can's
    # interface lookup for every bus, not only for that plugin.
    lines = []
    for name, value in entry_points:
        module_path = value.split(":")[0].replace(".", "/")
        if f"{module_path}.py" in files or f"{module_path}/__init__.py" in files:
            lines.append(f"{name} = {value}")
    return "[can.interface]\n" + "\n".join(lines) + "\n" if lines else ""


def collect_image_contents(distributions: Iterable[str] = RUNTIME_DISTRIBUTIONS) -> ImageContents:
    """Read the files an image is made of from the installed bywire and its runtime distributions."""
    files = _bywire_files()
    dists: dict[str, dict[str, Any]] = {}
    skipped: list[str] = []
    for dist in _distribution_closure(distributions):
        dist_files, top_level, dist_skipped = _distribution_files(dist)
        for rel in dist_files:
            if rel in files:
                raise FirmwareError(f"file {rel} is provided twice (distribution {dist.metadata['Name']})")
        files.update(dist_files)
        skipped.extend(dist_skipped)
        dists[dist.metadata["Name"]] = {"version": dist.version, "top_level": top_level}
    return ImageContents(files, dists, tuple(sorted(skipped)), _bywire_entry_points())


# --- writing images -----------------------------------------------------------------------------


def _content_hash(files: Mapping[str, bytes]) -> str:
    h = hashlib.sha256()
    for name in sorted(files):
        data = files[name]
        h.update(name.encode() + b"\0" + len(data).to_bytes(8, "little"))
        h.update(data)
    return h.hexdigest()


def _zip_bytes(files: Mapping[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name in sorted(files):
            info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
            info.create_system = 3  # unix, whatever the build host is
            info.external_attr = 0o644 << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, files[name], compresslevel=_ZIP_LEVEL)
    return buf.getvalue()


def _check_entry(entry: str, files: Mapping[str, bytes]) -> None:
    module, sep, func = entry.partition(":")
    if not sep or not module or not func.isidentifier():
        raise FirmwareError(f"entry {entry!r}: expected 'package.module:function'")
    path = module.replace(".", "/")
    if f"{path}.py" not in files and f"{path}/__init__.py" not in files:
        raise FirmwareError(f"entry {entry!r}: module {module} is not in the image")


def write_image(
    out_path: str | os.PathLike[str],
    contents: ImageContents,
    *,
    version: str | None = None,
    entry: str = DEFAULT_ENTRY,
    extra_files: Mapping[str, bytes] | None = None,
) -> ImageManifest:
    """Write `contents` (+ `extra_files`, e.g. a test app) as an image; its manifest (not written)."""
    from bywire import __version__
    from bywire.ecu.store import ImageManifest, write_atomic

    files = dict(contents.files)
    for name, data in (extra_files or {}).items():
        if name.startswith("/") or ".." in PurePosixPath(name).parts:
            raise FirmwareError(f"extra file {name!r}: must be a relative path inside the image")
        files[name] = data
    files["__main__.py"] = _MAIN_PY
    _check_entry(entry, files)
    python = f"{sys.version_info.major}.{sys.version_info.minor}"
    meta = {"entry": entry, "python": python, "distributions": contents.distributions}
    content_sha = _content_hash({**files, "\0meta": json.dumps(meta, sort_keys=True).encode()})
    if version is None:
        version = f"{__version__}+{content_sha[:12]}"
    info = {
        "format": IMAGE_FORMAT,
        "version": version,
        "content_sha256": content_sha,
        "skipped_extensions": list(contents.skipped_extensions),
        **meta,
    }
    files[IMAGE_INFO_NAME] = (json.dumps(info, indent=2, sort_keys=True) + "\n").encode()
    dist_info = f"bywire-{_safe_version(version)}.dist-info"
    files[f"{dist_info}/METADATA"] = f"Metadata-Version: 2.1\nName: bywire\nVersion: {version}\n".encode()
    entry_points = _entry_points_txt(contents.entry_points, files)
    if entry_points:
        files[f"{dist_info}/entry_points.txt"] = entry_points.encode()
    data = _zip_bytes(files)
    write_atomic(out_path, data)
    return ImageManifest(
        version=version,
        sha256=hashlib.sha256(data).hexdigest(),
        size_bytes=len(data),
        built_utc=datetime.now(UTC).isoformat(timespec="seconds"),
        python=python,
        entry=entry,
    )


def _safe_version(version: str) -> str:
    # dist-info directory names use '_' for anything but letters, digits, '.' and '+'.
    return re.sub(r"[^A-Za-z0-9.+]", "_", version)


def build_image(
    out_path: str | os.PathLike[str],
    version: str | None = None,
    *,
    entry: str = DEFAULT_ENTRY,
    extra_files: Mapping[str, bytes] | None = None,
    distributions: Iterable[str] = RUNTIME_DISTRIBUTIONS,
) -> ImageManifest:
    """Build the ECU firmware image from the installed bywire into `out_path`; its manifest."""
    return write_image(
        out_path, collect_image_contents(distributions), version=version, entry=entry, extra_files=extra_files
    )


def read_image_info(image_path: str | os.PathLike[str]) -> dict[str, Any]:
    """The `_image.json` of an image file; FirmwareError naming the file if it is not an image."""
    try:
        with zipfile.ZipFile(image_path) as zf:
            raw = zf.read(IMAGE_INFO_NAME)
    except FileNotFoundError:
        raise FirmwareError(f"{os.fspath(image_path)}: no such file") from None
    except zipfile.BadZipFile as e:
        raise FirmwareError(f"{os.fspath(image_path)}: not a firmware image (bad zip: {e})") from None
    except KeyError:
        raise FirmwareError(f"{os.fspath(image_path)}: not a firmware image (no {IMAGE_INFO_NAME})") from None
    try:
        info = json.loads(raw)
    except json.JSONDecodeError as e:
        raise FirmwareError(f"{os.fspath(image_path)}: {IMAGE_INFO_NAME}: not valid JSON: {e}") from None
    if not isinstance(info, dict) or info.get("format") != IMAGE_FORMAT:
        raise FirmwareError(f"{os.fspath(image_path)}: {IMAGE_INFO_NAME}: format is not {IMAGE_FORMAT!r}")
    return info


def check_ecu_image(data: bytes, source: str) -> dict[str, Any]:
    """The `_image.json` of the image `data`, after checking that it is a bywire ECU image (see the
    module docstring); FirmwareError, one line naming `source`, if it is not."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            names = set(zf.namelist())
            raw_info = zf.read(IMAGE_INFO_NAME) if IMAGE_INFO_NAME in names else None
            main_py = zf.read("__main__.py") if "__main__.py" in names else None
    except zipfile.BadZipFile as e:
        raise FirmwareError(f"{source}: not a firmware image (bad zip: {e})") from None
    except (EOFError, ValueError, NotImplementedError, zlib.error) as e:
        # A damaged zip fails in more ways than BadZipFile: truncated or corrupt deflate streams,
        # compression methods zipfile does not implement.
        raise FirmwareError(
            f"{source}: not a firmware image (unreadable zip: {type(e).__name__}: {e})"
        ) from None
    if raw_info is None:
        raise FirmwareError(f"{source}: not a firmware image (no {IMAGE_INFO_NAME})")
    try:
        info = json.loads(raw_info)
    except json.JSONDecodeError as e:
        raise FirmwareError(f"{source}: {IMAGE_INFO_NAME}: not valid JSON: {e}") from None
    if not isinstance(info, dict) or info.get("format") != IMAGE_FORMAT:
        raise FirmwareError(f"{source}: {IMAGE_INFO_NAME}: format is not {IMAGE_FORMAT!r}")
    if info.get("entry") != DEFAULT_ENTRY:
        raise FirmwareError(
            f"{source}: not an ECU image: its entry is {info.get('entry')!r},"
            f" not bywire's ECU app {DEFAULT_ENTRY}"
        )
    if main_py != _MAIN_PY:
        raise FirmwareError(
            f"{source}: not an ECU image: its __main__.py is not the one the firmware builder writes"
        )
    missing = [name for name in ECU_IMAGE_FILES if name not in names]
    if missing:
        more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
        raise FirmwareError(f"{source}: not an ECU image: {missing[0]}{more} missing")
    return info


# --- self-test --------------------------------------------------------------------------------

# -I: ignore PYTHON* variables and the user site; -S: no site-packages. What the image needs must
# come from the zip (or the standard library).
ISOLATED_FLAGS: tuple[str, ...] = ("-I", "-S")


@dataclass(frozen=True)
class SelftestReport:
    ok: bool
    version: str | None
    problems: tuple[str, ...]
    output: str  # the child's stdout + stderr, for the log


def run_selftest(
    image_path: str | os.PathLike[str], *, python: str = sys.executable, timeout_s: float = 120.0
) -> SelftestReport:
    """Run `python -I -S IMAGE selftest` in a child; its parsed report."""
    cmd = [python, *ISOLATED_FLAGS, os.fspath(image_path), "selftest"]
    try:
        proc = subprocess.run(
            cmd, capture_output=True, text=True, timeout=timeout_s, cwd=os.path.dirname(os.fspath(image_path))
        )
    except subprocess.TimeoutExpired as e:
        out = _text(e.stdout) + _text(e.stderr)
        return SelftestReport(False, None, (f"selftest did not finish within {timeout_s:g} s",), out)
    output = proc.stdout + proc.stderr
    report: dict[str, Any] = {}
    for line in reversed(proc.stdout.splitlines()):
        with contextlib.suppress(json.JSONDecodeError):
            candidate = json.loads(line)
            if isinstance(candidate, dict) and "selftest" in candidate:
                report = candidate
                break
    problems = tuple(str(p) for p in report.get("problems", []))
    if proc.returncode != 0 and not problems:
        tail = output.strip().splitlines()[-1:] or ["(no output)"]
        problems = (f"selftest exited with {proc.returncode}: {tail[0]}",)
    ok = proc.returncode == 0 and report.get("selftest") == "ok"
    return SelftestReport(ok, report.get("version"), problems, output)


def _text(data: bytes | str | None) -> str:
    if data is None:
        return ""
    return data if isinstance(data, str) else data.decode(errors="replace")


def _module_name(entry: str) -> str:
    parts = entry.removesuffix(".py").split("/")
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _check_package_data(name: str, data: bytes) -> None:
    suffix = PurePosixPath(name).suffix
    if suffix == ".dbc":
        import cantools

        strict = PurePosixPath(name).name not in LENIENT_DBCS
        cantools.database.load_string(data.decode(), database_format="dbc", strict=strict)
    elif suffix == ".eds":
        import canopen

        fp = io.StringIO(data.decode())
        fp.name = PurePosixPath(name).name
        canopen.import_od(fp)
    elif suffix == ".json":
        if "/calibrations/" in name:
            from bywire.ecu.calibration import calibration_from_dict, loads_calibration

            obj = json.loads(data)
            if isinstance(obj, dict) and "crc32" in obj:
                loads_calibration(data, name)
            else:
                calibration_from_dict(obj, source=name)
        else:
            json.loads(data)


def _outside(path: str, roots: tuple[str, ...]) -> bool:
    real = os.path.realpath(path)
    return not any(real == r or real.startswith(r + os.sep) for r in roots)


def _file_relative_access(archive: str, sources: list[str]) -> list[str]:
    """Uses of `__file__` in bywire's modules: inside the image a module's directory is not on disk
    (`image.pyz/bywire/protocol/`), so package data found through it cannot be opened."""
    problems = []
    with zipfile.ZipFile(archive) as zf:
        for name in sorted(sources):
            tokens = tokenize.tokenize(io.BytesIO(zf.read(name)).readline)
            with contextlib.suppress(tokenize.TokenError, SyntaxError):
                for tok in tokens:
                    if tok.type == tokenize.NAME and tok.string == "__file__":
                        problems.append(
                            f"{name}:{tok.start[0]}: uses __file__; package data inside the image is not on "
                            "disk: read it with importlib.resources (files(...).joinpath(...).read_bytes())"
                        )
    return problems


def selftest(archive: str) -> list[str]:
    """Inside a running image: import and load everything the ECU needs; the problems found."""
    problems: list[str] = []
    before = set(sys.modules)
    with zipfile.ZipFile(archive) as zf:
        names = zf.namelist()
        info = json.loads(zf.read(IMAGE_INFO_NAME))
        data_files = {n: zf.read(n) for n in names if n.startswith("bywire/") and not n.endswith(".py")}
    modules = sorted({_module_name(n) for n in names if n.startswith("bywire/") and n.endswith(".py")})
    for dist in info["distributions"].values():
        modules.extend(dist["top_level"])
    for module in modules:
        try:
            importlib.import_module(module)
        except BaseException as e:  # SystemExit from a module is a failure too
            problems.append(f"import {module}: {type(e).__name__}: {e}")
    module_name, _, func = info["entry"].partition(":")
    try:
        entry_module = importlib.import_module(module_name)
        if not callable(getattr(entry_module, func)):
            problems.append(f"entry {info['entry']}: not callable")
        # The app's own deeper checks (build its codecs and object dictionary, ...), if it has any.
        hook = getattr(entry_module, SELFTEST_HOOK, None)
        if callable(hook):
            hook()
    except BaseException as e:
        problems.append(f"entry {info['entry']}: {type(e).__name__}: {e}")
    problems += _file_relative_access(
        archive, [n for n in names if n.startswith("bywire/") and n.endswith(".py")]
    )
    # The plugins python-can finds through entry points must resolve from the zip's dist-info.
    for dist in md.distributions(path=[archive]):
        for ep in dist.entry_points.select(group="can.interface"):
            try:
                ep.load()
            except Exception as e:
                problems.append(f"entry point can.interface {ep.name} = {ep.value}: {type(e).__name__}: {e}")
    for name, data in sorted(data_files.items()):
        if name == IMAGE_INFO_NAME:
            continue
        try:
            # Read through importlib.resources from the innermost package, as the ECU does.
            parts = name.split("/")
            depth = max(i for i in range(1, len(parts)) if "/".join(parts[:i]) + "/__init__.py" in names)
            package, rel = ".".join(parts[:depth]), parts[depth:]
            resource = importlib.resources.files(package).joinpath(*rel)
            if resource.read_bytes() != data:
                problems.append(f"{name}: importlib.resources returned different bytes")
            _check_package_data(name, data)
        except Exception as e:
            problems.append(f"{name}: {type(e).__name__}: {e}")
    if "bywire.ecu.calibration" in sys.modules:
        try:
            sys.modules["bywire.ecu.calibration"].default_calibration()
        except Exception as e:
            problems.append(f"default_calibration(): {type(e).__name__}: {e}")
    stdlib_roots = tuple(
        sorted({os.path.realpath(sysconfig.get_paths()[k]) for k in ("stdlib", "platstdlib")})
    )
    roots = (os.path.realpath(archive), *stdlib_roots)
    for name in sorted(set(sys.modules) - before):
        path = getattr(sys.modules[name], "__file__", None)
        if path and _outside(path, roots):
            problems.append(f"module {name} was imported from outside the image: {path}")
    return problems


def image_main(argv: list[str]) -> int:
    """`__main__` of an image: run | selftest | version | info."""
    archive = os.path.abspath(sys.argv[0])
    usage = "usage: python IMAGE {run ARGS... | selftest | version | info}"
    if not argv:
        print(usage, file=sys.stderr)
        return 2
    command, rest = argv[0], argv[1:]
    info = read_image_info(archive)
    if command == "version":
        print(info["version"])
        return 0
    if command == "info":
        print(json.dumps(info, indent=2, sort_keys=True))
        return 0
    if command == "selftest":
        problems = selftest(archive)
        for p in problems:
            print(f"selftest: {p}", file=sys.stderr)
        report = {
            "selftest": "ok" if not problems else "failed",
            "version": info["version"],
            "problems": problems,
        }
        print(json.dumps(report, sort_keys=True))
        return 0 if not problems else 1
    if command == "run":
        module_name, _, func = info["entry"].partition(":")
        main = getattr(importlib.import_module(module_name), func)
        return int(main(rest) or 0)
    print(f"unknown command {command!r}; {usage}", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    """`python -m bywire.ecu.firmware build OUT [--version V]`: build an image without flashing."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m bywire.ecu.firmware")
    sub = parser.add_subparsers(dest="command", required=True)
    build = sub.add_parser("build", help="build a firmware image")
    build.add_argument("out", type=Path)
    build.add_argument("--version", default=None)
    build.add_argument("--selftest", action="store_true", help="run the image's self-test after building")
    args = parser.parse_args(argv)
    try:
        manifest = build_image(args.out, args.version)
    except FirmwareError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(json.dumps(manifest.to_dict(), indent=2))
    if args.selftest:
        report = run_selftest(args.out)
        for p in report.problems:
            print(f"error: {args.out}: selftest: {p}", file=sys.stderr)
        return 0 if report.ok else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
