"""Build source FMUs (modelDescription.xml + C sources) into cached binary ``.fmu`` files.

`ensure_fmu` hashes the model's sources (SHA-256 over modelDescription.xml and everything under
``sources/``, plus this module's build recipe version) and returns the cached FMU of that hash,
building it with fmpy's CMake project (cmake + the system C compiler) only when it is missing.
Concurrent callers, in threads or processes, serialise on an ``fcntl`` lock per model, and a
finished FMU appears under its final name only by an atomic rename, so a reader never sees a
half-written file. Old FMUs of other hashes are left in the cache (another process may still be
about to open one); delete the cache directory to reclaim them.

Cache directory: the ``cache_dir`` argument, else ``$BYWIRE_CACHE_DIR``, else
``~/.cache/bywire/fmu``.

Run ``python -m bywire.vehicle_models.build [model]`` to build and print the FMU's path.
Not from the papers: tooling for the FMU plant of DESIGN.md section 1.
"""

from __future__ import annotations

import argparse
import fcntl
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import fmpy
from fmpy.build import create_cmake_settings
from fmpy.util import create_zip_archive
from fmpy.validation import validate_fmu

MODELS_DIR = Path(__file__).resolve().parent
# Bump when the build recipe below changes in a way that changes the binary.
BUILD_RECIPE_VERSION = "1"
# fmpy's CMakeLists.txt does not link libm; the models call sin/cos/exp.
_CMAKE_OPTIONS = {"CMAKE_C_STANDARD_LIBRARIES:STRING": "-lm"}
_OUTPUT_TAIL_CHARS = 4000


class BuildError(RuntimeError):
    """The model's sources are missing or do not compile into a valid FMU."""


def default_cache_dir() -> Path:
    env = os.environ.get("BYWIRE_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "bywire" / "fmu"


def model_dir(model: str | Path) -> Path:
    """A bundled model's directory (``"passat"``), or ``model`` itself if it is a path."""
    is_path = isinstance(model, Path) or os.sep in model
    path = Path(model).resolve() if is_path else MODELS_DIR / model
    if not (path / "modelDescription.xml").is_file():
        available = sorted(p.name for p in MODELS_DIR.iterdir() if (p / "modelDescription.xml").is_file())
        raise BuildError(
            f"{path}: no modelDescription.xml; not a source FMU directory"
            f" (bundled models: {', '.join(available) or 'none'})"
        )
    return path


def source_files(directory: Path) -> list[Path]:
    """The files that define the FMU: modelDescription.xml and everything under sources/."""
    sources = directory / "sources"
    files = [directory / "modelDescription.xml"]
    if sources.is_dir():
        files += sorted(p for p in sources.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    return files


def source_digest(directory: Path) -> str:
    """SHA-256 over the model's source files (names and contents) and the build recipe version."""
    digest = hashlib.sha256(f"bywire-fmu-build {BUILD_RECIPE_VERSION}\n".encode())
    for path in source_files(directory):
        data = path.read_bytes()
        digest.update(f"{path.relative_to(directory).as_posix()}\0{len(data)}\0".encode())
        digest.update(data)
    return digest.hexdigest()


def ensure_fmu(model: str | Path = "passat", cache_dir: Path | None = None) -> Path:
    """Path of the cached FMU built from ``model``'s current sources; builds it if missing.

    ``model`` is a bundled model name or a source FMU directory. Prints one line to stderr when
    it builds. Raises `BuildError` with the compiler output when the build fails.
    """
    directory = model_dir(model)
    name = directory.name
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    digest = source_digest(directory)
    target = cache / f"{name}-{digest[:20]}-{fmpy.platform}.fmu"
    if target.is_file():
        return target
    cache.mkdir(parents=True, exist_ok=True)
    with open(cache / f"{name}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        # Another process may have built it while we waited for the lock.
        if not target.is_file():
            print(f"building {name} FMU ({digest[:12]}) into {cache} ...", file=sys.stderr, flush=True)
            _build(directory, digest, target)
    return target


def _build(directory: Path, digest: str, target: Path) -> None:
    # The temporary directory lives in the cache so the final rename stays on one file system.
    with tempfile.TemporaryDirectory(dir=target.parent, prefix=f".{target.stem}-") as tmp:
        unzipdir = Path(tmp) / "fmu"
        build_dir = Path(tmp) / "cmake"
        build_dir.mkdir()
        for path in source_files(directory):
            dest = unzipdir / path.relative_to(directory)
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, dest)
        if source_digest(unzipdir) != digest:
            raise BuildError(f"{directory}: sources changed while building; try again")

        create_cmake_settings(unzipdir, build_dir, cmake_options=dict(_CMAKE_OPTIONS))
        c_code = Path(fmpy.__file__).parent / "c-code"
        _run(["cmake", "-S", str(c_code), "-B", str(build_dir)], directory)
        _run(["cmake", "--build", str(build_dir), "--target", "install", "--config", "Release"], directory)
        shutil.rmtree(build_dir)

        problems = validate_fmu(str(unzipdir))
        if problems:
            raise BuildError(f"{directory}: the FMU does not validate:\n  " + "\n  ".join(problems))
        staged = Path(tmp) / "out.fmu"
        create_zip_archive(staged, unzipdir)
        os.replace(staged, target)


def _run(command: list[str], directory: Path) -> None:
    try:
        result = subprocess.run(command, capture_output=True, text=True, check=False)
    except FileNotFoundError as exc:
        raise BuildError(f"{directory}: cannot run {command[0]!r}; install cmake and a C compiler") from exc
    if result.returncode != 0:
        output = (result.stdout + result.stderr)[-_OUTPUT_TAIL_CHARS:]
        raise BuildError(
            f"{directory}: {' '.join(command)} failed with exit code {result.returncode}:\n{output}"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Build a bywire vehicle FMU and print its path.")
    parser.add_argument("model", nargs="?", default="passat", help="bundled model name or source directory")
    parser.add_argument("--cache-dir", type=Path, default=None)
    args = parser.parse_args(argv)
    try:
        print(ensure_fmu(args.model, args.cache_dir))
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
