"""Test firmware images and signing keys for the store, flash, boot and signing tests.

A test image is shaped like the real one (bywire's ECU app as the entry, the generated __main__.py,
the ECU's core modules: what `bywire ecu flash` checks before it accepts an image), but its
bywire/ecu/app.py is a stand-in given by the test, and it carries only the boot machinery and the
files the flash check asks for (never imported by the stand-in), so that these tests do not depend
on the state of the rest of the firmware. The real image is built and booted in its own tests.

Keys are made per test session, in memory or in a temporary directory: no private key is committed.
"""

from __future__ import annotations

import functools
from pathlib import Path

from bywire.ecu import firmware
from bywire.ecu.firmware import ImageContents
from bywire.ecu.signing import PublicKey, SigningKey, generate_key_pair, load_public_key, load_signing_key

# The flash/boot machinery and what it imports, plus what makes an image an ECU image.
MECHANICS = {
    "bywire/__init__.py",
    "bywire/clock.py",
    "bywire/protocol/__init__.py",
    "bywire/protocol/ecu_types.py",
    "bywire/protocol/vehicle.dbc",
    "bywire/ecu/__init__.py",
    "bywire/ecu/boot.py",
    "bywire/ecu/calibration.py",
    "bywire/ecu/calibrations/passat.json",
    "bywire/ecu/firmware.py",
    "bywire/ecu/flash.py",
    "bywire/ecu/health.py",
    "bywire/ecu/signing.py",
    "bywire/ecu/store.py",
    "bywire/ecu/trust.py",
    *firmware.ECU_IMAGE_FILES,
}
APP = "bywire/ecu/app.py"


@functools.cache
def mechanics_contents() -> ImageContents:
    full = firmware.collect_image_contents()
    files = {k: v for k, v in full.files.items() if not k.startswith("bywire/") or k in MECHANICS}
    missing = MECHANICS - set(files)
    assert not missing, missing
    return ImageContents(files, full.distributions, full.skipped_extensions, full.entry_points)


def fake_ecu_image(path: Path, app_source: str) -> Path:
    """An ECU-shaped image at `path` whose app (bywire.ecu.app:main) is `app_source`."""
    firmware.write_image(path, mechanics_contents(), extra_files={APP: app_source.encode()})
    return path


def key_pair(directory: Path) -> tuple[SigningKey, PublicKey, Path, Path]:
    """A new key pair written to `directory`: (signing key, public key, private PEM, public PEM)."""
    private, public, _ = generate_key_pair(directory)
    return load_signing_key(private), load_public_key(public), private, public
