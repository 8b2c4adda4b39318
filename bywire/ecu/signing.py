"""Ed25519 signatures over firmware images: key pairs, signing, verification, embedded signatures.

No paper section: DESIGN section 4 ("firmware is signed"). The scheme is the plainest one that an
auditor can check with standard tools:

- a signature is Ed25519 (RFC 8032, pure, no pre-hash) over the exact bytes of the image file as it
  is stored in the slot; on disk a detached signature is exactly its 64 raw bytes (no base64, no
  header), so `openssl pkeyutl -verify -rawin` can check it too;
- a key is identified by `key_id`: the first 16 hex digits of the sha256 of its 32 raw public bytes;
- private keys are PKCS#8 PEM files without encryption, written 0600 and never overwritten
  (`generate_key_pair`); public keys are SubjectPublicKeyInfo PEM files;
- an image may carry its signature inside: the zip archive comment (the last field of the zip, after
  everything the signature covers) is `EMBED_MAGIC` + the 64 raw signature bytes, and the signed
  bytes are the file with that comment removed (and the comment length set back to 0), i.e. exactly
  the unsigned image as built. Python's zipimport and zipfile read an image with a comment as one
  without, so a signed image still runs and can still be inspected.

The same signature also endorses a public key (the signature over the PEM file's bytes by an already
trusted key), which is how a key is added to a store that trusts keys (flash.py).

The `cryptography` package is imported inside the functions: this module is part of the firmware
image, which holds only pure-Python code, and the running ECU never verifies anything (the flasher
and the boot supervisor do, from the installation).
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

SIGNATURE_BYTES = 64  # RFC 8032 section 5.1.6: R (32 bytes) || S (32 bytes)
PUBLIC_KEY_BYTES = 32
KEY_ID_HEX = 16  # 64 bits of the key's sha256: a name for logs and files, not a security boundary
EMBED_MAGIC = b"bywire-ed25519-signature:"
PRIVATE_KEY_NAME = "ecu-firmware.key.pem"
PUBLIC_KEY_NAME = "ecu-firmware.pub.pem"

_EOCD_MAGIC = b"PK\x05\x06"
_EOCD_BYTES = 22  # end of central directory record without its comment (APPNOTE 4.3.16)
_MAX_COMMENT = 0xFFFF


class SigningError(Exception):
    """A key or signature file is unusable, or a signature cannot be made; names the file."""


def key_id(public_raw: bytes) -> str:
    return hashlib.sha256(public_raw).hexdigest()[:KEY_ID_HEX]


@dataclass(frozen=True)
class PublicKey:
    """A trusted (or to-be-trusted) Ed25519 public key, with the file it came from."""

    raw: bytes  # the 32 raw bytes
    source: str = "<memory>"
    pem: bytes = b""  # the file's exact bytes: what an endorsement signature covers

    @property
    def key_id(self) -> str:
        return key_id(self.raw)


@dataclass(frozen=True)
class SigningKey:
    """A loaded Ed25519 private key and the file it came from."""

    key: Ed25519PrivateKey
    source: str

    @property
    def public(self) -> PublicKey:
        from cryptography.hazmat.primitives import serialization

        raw = self.key.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
        return PublicKey(raw, self.source)

    def sign(self, data: bytes) -> bytes:
        return self.key.sign(data)


def verify(public_raw: bytes, signature: bytes, data: bytes) -> bool:
    """True when `signature` is `public_raw`'s Ed25519 signature over exactly `data`."""
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

    if len(signature) != SIGNATURE_BYTES or len(public_raw) != PUBLIC_KEY_BYTES:
        return False
    try:
        Ed25519PublicKey.from_public_bytes(public_raw).verify(signature, data)
    except (InvalidSignature, ValueError):
        return False
    return True


def verifying_key(keys: Mapping[str, bytes], signature: bytes, data: bytes) -> str | None:
    """The id of the first of `keys` (id -> raw) that verifies `signature` over `data`, else None."""
    for kid, raw in sorted(keys.items()):
        if verify(raw, signature, data):
            return kid
    return None


# --- key files ----------------------------------------------------------------------------------


def generate_key_pair(out_dir: str | os.PathLike[str]) -> tuple[Path, Path, str]:
    """A new key pair in `out_dir`: (private PEM path, public PEM path, key id).

    Refuses to overwrite either file: a lost private key cannot be recovered, and a replaced one
    would silently stop every store that trusts the old one from accepting new firmware."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    out = Path(out_dir)
    private_path, public_path = out / PRIVATE_KEY_NAME, out / PUBLIC_KEY_NAME
    for path in (private_path, public_path):
        if path.exists():
            raise SigningError(f"{path}: already exists; refusing to overwrite a key")
    try:
        out.mkdir(parents=True, exist_ok=True, mode=0o700)
    except OSError as e:
        raise SigningError(f"{out}: cannot create the directory: {e.strerror}") from None
    key = Ed25519PrivateKey.generate()
    private_pem = key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )
    public_raw = key.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    public_pem = key.public_key().public_bytes(
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
    )
    _write_new(private_path, private_pem, 0o600)
    try:
        _write_new(public_path, public_pem, 0o644)
    except SigningError:
        private_path.unlink(missing_ok=True)  # half a key pair is worse than none
        raise
    return private_path, public_path, key_id(public_raw)


def _write_new(path: Path, data: bytes, mode: int) -> None:
    # O_EXCL: another keygen racing us cannot be overwritten either. The mode is set on the open
    # file as well, since the one given to os.open is reduced by the umask.
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    except FileExistsError:
        raise SigningError(f"{path}: already exists; refusing to overwrite a key") from None
    except OSError as e:
        raise SigningError(f"{path}: cannot create: {e.strerror}") from None
    try:
        os.fchmod(fd, mode)
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        os.fsync(fd)
    except OSError as e:
        os.close(fd)
        path.unlink(missing_ok=True)
        raise SigningError(f"{path}: cannot write: {e.strerror}") from None
    os.close(fd)


def _read(path: str | os.PathLike[str], what: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise SigningError(f"{os.fspath(path)}: no such {what} file") from None
    except OSError as e:
        raise SigningError(f"{os.fspath(path)}: cannot read: {e.strerror}") from None


def load_signing_key(path: str | os.PathLike[str]) -> SigningKey:
    """An Ed25519 private key from a PEM file; SigningError naming the file if it is not one."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    source = os.fspath(path)
    data = _read(path, "private key")
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except TypeError:
        raise SigningError(f"{source}: the private key is encrypted; give an unencrypted PEM") from None
    except ValueError:
        raise SigningError(f"{source}: not a PEM private key") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise SigningError(f"{source}: an Ed25519 private key is needed, got {type(key).__name__}")
    return SigningKey(key, source)


def load_public_key(path: str | os.PathLike[str]) -> PublicKey:
    """An Ed25519 public key from a PEM file; SigningError naming the file if it is not one."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

    source = os.fspath(path)
    data = _read(path, "public key")
    if b"PRIVATE KEY" in data:
        # Trusting a private key file would copy nothing secret into the store, but it means the
        # secret is being handled where only the public half belongs.
        raise SigningError(f"{source}: this is a private key; trust the public key file instead")
    try:
        key = serialization.load_pem_public_key(data)
    except ValueError:
        raise SigningError(f"{source}: not a PEM public key") from None
    if not isinstance(key, Ed25519PublicKey):
        raise SigningError(f"{source}: an Ed25519 public key is needed, got {type(key).__name__}")
    raw = key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return PublicKey(raw, source, data)


def read_signature_file(path: str | os.PathLike[str]) -> bytes:
    """A detached signature: exactly 64 raw bytes."""
    data = _read(path, "signature")
    if len(data) != SIGNATURE_BYTES:
        raise SigningError(
            f"{os.fspath(path)}: a signature file is exactly {SIGNATURE_BYTES} raw bytes"
            f" (bywire ecu sign writes one), this one has {len(data)}"
        )
    return data


# --- signatures embedded in the zip comment ------------------------------------------------------


def _eocd_offset(data: bytes) -> int | None:
    """Offset of the end-of-central-directory record whose comment runs to the end of `data`."""
    start = max(0, len(data) - _EOCD_BYTES - _MAX_COMMENT)
    at = data.rfind(_EOCD_MAGIC, start)
    while at >= 0:
        if at + _EOCD_BYTES <= len(data):
            comment_len = int.from_bytes(data[at + 20 : at + 22], "little")
            if at + _EOCD_BYTES + comment_len == len(data):
                return at
        at = data.rfind(_EOCD_MAGIC, start, at)
    return None


def split_embedded_signature(data: bytes) -> tuple[bytes, bytes | None]:
    """(the signed bytes, the embedded signature) of an image; (data, None) when it carries none.

    Raises SigningError when the comment starts like a signature but is not a well-formed one."""
    at = _eocd_offset(data)
    if at is None:
        return data, None
    comment = data[at + _EOCD_BYTES :]
    if not comment.startswith(EMBED_MAGIC):
        return data, None
    signature = comment[len(EMBED_MAGIC) :]
    if len(signature) != SIGNATURE_BYTES:
        raise SigningError(f"embedded signature has {len(signature)} bytes, expected {SIGNATURE_BYTES}")
    unsigned = data[: at + 20] + b"\x00\x00"
    return unsigned, signature


def embed_signature(data: bytes, signature: bytes) -> bytes:
    """`data` (an image without a zip comment) with `signature` in its comment."""
    if len(signature) != SIGNATURE_BYTES:
        raise SigningError(f"signature has {len(signature)} bytes, expected {SIGNATURE_BYTES}")
    at = _eocd_offset(data)
    if at is None:
        raise SigningError("not a zip file (no end-of-central-directory record)")
    if at + _EOCD_BYTES != len(data):
        raise SigningError("the image already has a zip comment; sign the image as built")
    comment = EMBED_MAGIC + signature
    return data[: at + 20] + len(comment).to_bytes(2, "little") + comment
