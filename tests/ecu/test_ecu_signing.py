"""Signed firmware: key pairs, detached and embedded Ed25519 signatures, the store's trust policy and
its rules, flashing only what a trusted key signed, and the boot supervisor checking the signature of
the slot it boots on every boot. Every key here is made by the test (none is committed)."""

from __future__ import annotations

import base64
import hashlib
import json
import stat
import zipfile
from pathlib import Path

import pytest
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import ec
from ecu_test_images import fake_ecu_image, key_pair

from bywire.ecu import boot, cli, flash, signing, store
from bywire.ecu.flash import FlashError
from bywire.ecu.signing import PublicKey, SigningError, SigningKey
from bywire.ecu.store import StoreError, TrustPolicy
from bywire.ecu.trust import DEVELOPMENT, TrustChange, TrustError, plan_trust

FAKE_APP = """
import time
from bywire.ecu.store import report_boot

def main(argv):
    store = argv[argv.index("--store") + 1]
    report_boot(store, "OFF", healthy_s=0.0, host_link_up=True)
    return int(argv[argv.index("--exit-now") + 1]) if "--exit-now" in argv else 0
"""


@pytest.fixture(scope="module")
def images(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("images")
    return {name: fake_ecu_image(d / f"{name}.pyz", FAKE_APP + f"# {name}\n") for name in ("one", "two")}


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[SigningKey, PublicKey, Path, Path]]:
    d = tmp_path_factory.mktemp("keys")
    return {name: key_pair(d / name) for name in ("release", "other", "new")}


def tampered(data: bytes) -> bytes:
    """`data` (a zip without a comment) with a one-byte zip comment: still a valid, runnable image,
    but not the bytes that were signed."""
    assert data[-2:] == b"\0\0"
    return data[:-2] + b"\x01\x00" + b"x"


def snapshot(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name != "lock"
    }


class Log(list[str]):
    def __call__(self, msg: str) -> None:
        self.append(msg)

    def text(self) -> str:
        return "\n".join(self)


# --- keys and signatures --------------------------------------------------------------------------


def test_keygen_writes_a_private_key_only_its_owner_can_read_and_never_overwrites(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "keys"
    assert cli.main(["keygen", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    private, public = out / signing.PRIVATE_KEY_NAME, out / signing.PUBLIC_KEY_NAME
    assert str(private) in printed and str(public) in printed
    assert stat.S_IMODE(private.stat().st_mode) == 0o600
    assert private.read_bytes().startswith(b"-----BEGIN PRIVATE KEY-----")
    key, pub = signing.load_signing_key(private), signing.load_public_key(public)
    assert key.public.raw == pub.raw and pub.key_id in printed
    before = private.read_bytes(), public.read_bytes()
    assert cli.main(["keygen", "--out", str(out)]) == 1
    assert "already exists; refusing to overwrite a key" in capsys.readouterr().err
    assert (private.read_bytes(), public.read_bytes()) == before


def test_signature_is_64_raw_bytes_over_the_exact_bytes(keys: dict) -> None:
    key, pub, *_ = keys["release"]
    data = b"firmware" * 1000
    sig = key.sign(data)
    assert len(sig) == signing.SIGNATURE_BYTES
    assert signing.verify(pub.raw, sig, data)
    assert not signing.verify(pub.raw, sig, data + b"\0")
    assert not signing.verify(keys["other"][1].raw, sig, data)
    assert signing.verifying_key(
        {pub.key_id: pub.raw, keys["other"][1].key_id: keys["other"][1].raw}, sig, data
    ) == (pub.key_id)


def test_cli_sign_writes_a_detached_signature_and_an_embedded_one(
    tmp_path: Path, images: dict[str, Path], keys: dict, capsys: pytest.CaptureFixture[str]
) -> None:
    _, pub, private, _ = keys["release"]
    image = tmp_path / "ecu.pyz"
    image.write_bytes(images["one"].read_bytes())
    assert cli.main(["sign", "--key", str(private), str(image)]) == 0
    sig = (tmp_path / "ecu.pyz.sig").read_bytes()
    assert signing.verify(pub.raw, sig, image.read_bytes())
    assert cli.main(["sign", "--key", str(private), "--embed", str(image)]) == 0
    signed = (tmp_path / "ecu.signed.pyz").read_bytes()
    unsigned, embedded = signing.split_embedded_signature(signed)
    assert (
        unsigned == image.read_bytes()
        and embedded is not None
        and signing.verify(pub.raw, embedded, unsigned)
    )
    with zipfile.ZipFile(tmp_path / "ecu.signed.pyz") as zf:  # still a zip (and a zipapp) to everyone
        assert zf.testzip() is None
    capsys.readouterr()
    assert cli.main(["sign", "--key", str(private), "--embed", str(tmp_path / "ecu.signed.pyz")]) == 1
    assert "already has a zip comment" in capsys.readouterr().err


def test_key_and_signature_files_are_refused_naming_the_file(tmp_path: Path, keys: dict) -> None:
    _, _, private, public = keys["release"]
    with pytest.raises(SigningError, match="this is a private key"):
        signing.load_public_key(private)
    with pytest.raises(SigningError, match="not a PEM private key"):
        signing.load_signing_key(public)
    ec_key = ec.generate_private_key(ec.SECP256R1())
    ec_pem = tmp_path / "ec.pem"
    ec_pem.write_bytes(
        ec_key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )
    with pytest.raises(SigningError, match=r"ec\.pem: an Ed25519 private key is needed"):
        signing.load_signing_key(ec_pem)
    encrypted = tmp_path / "enc.pem"
    encrypted.write_bytes(
        keys["release"][0].key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.BestAvailableEncryption(b"secret"),
        )
    )
    with pytest.raises(SigningError, match="encrypted"):
        signing.load_signing_key(encrypted)
    short = tmp_path / "x.sig"
    short.write_bytes(b"\0" * 63)
    with pytest.raises(SigningError, match=r"x\.sig: a signature file is exactly 64 raw bytes"):
        signing.read_signature_file(short)
    with pytest.raises(SigningError, match="no such signature file"):
        signing.read_signature_file(tmp_path / "none.sig")


# --- the trust rules (pure) -----------------------------------------------------------------------


def test_trust_rules(tmp_path: Path, keys: dict) -> None:
    release, other, new = keys["release"][1], keys["other"][1], keys["new"][1]
    signed = TrustPolicy(keys={release.key_id: release.raw})
    dev = TrustPolicy(allow_unsigned=True)
    s = tmp_path
    # A store without a policy takes either, once.
    assert plan_trust(None, TrustChange(add=(release,)), s) == signed
    assert plan_trust(None, DEVELOPMENT, s) == dev
    assert plan_trust(None, TrustChange(), s) is None
    with pytest.raises(TrustError, match="not both"):
        plan_trust(None, TrustChange(add=(release,), allow_unsigned=True), s)
    # Development stays development; signed stays signed.
    assert plan_trust(dev, DEVELOPMENT, s) == dev
    with pytest.raises(TrustError, match="never becomes a signed store"):
        plan_trust(dev, TrustChange(add=(release,)), s)
    with pytest.raises(TrustError, match="never accepts unsigned firmware"):
        plan_trust(signed, DEVELOPMENT, s)
    # Re-trusting a trusted key changes nothing; a new key needs a trusted key's endorsement.
    assert plan_trust(signed, TrustChange(add=(release,)), s) == signed
    with pytest.raises(TrustError, match="needs --trust-key-signature"):
        plan_trust(signed, TrustChange(add=(new,)), s)
    by_other = keys["other"][0].sign(new.pem)
    with pytest.raises(TrustError, match="does not verify with any trusted key"):
        plan_trust(signed, TrustChange(add=(new,), endorsement=by_other), s)
    endorsed = keys["release"][0].sign(new.pem)
    both = plan_trust(signed, TrustChange(add=(new,), endorsement=endorsed), s)
    assert both is not None and set(both.keys) == {release.key_id, new.key_id}
    with pytest.raises(TrustError, match="one key at a time"):
        plan_trust(signed, TrustChange(add=(new, other), endorsement=endorsed), s)
    # Revocation: never the last key, never an unknown one.
    assert plan_trust(both, TrustChange(revoke=(release.key_id,)), s) == TrustPolicy(
        keys={new.key_id: new.raw}
    )
    with pytest.raises(TrustError, match="would leave no trusted key"):
        plan_trust(signed, TrustChange(revoke=(release.key_id,)), s)
    with pytest.raises(TrustError, match="is not trusted by this store"):
        plan_trust(signed, TrustChange(revoke=(other.key_id,)), s)


# --- flashing signed firmware ---------------------------------------------------------------------


def signed_store(root: Path, image: Path, keys: dict) -> Path:
    """A store that trusts the release key, with `image` signed by it in slot a."""
    key, pub, *_ = keys["release"]
    flash.flash_firmware(root, image, signing_key=key, trust=TrustChange(add=(pub,)), selftest=False)
    return root


def test_signed_store_takes_a_detached_an_embedded_or_a_made_signature(
    tmp_path: Path, images: dict[str, Path], keys: dict, capsys: pytest.CaptureFixture[str]
) -> None:
    key, pub, private, public = keys["release"]
    root = tmp_path / "ecu"
    image = images["one"]
    sig = tmp_path / "one.sig"
    sig.write_bytes(key.sign(image.read_bytes()))
    argv = ["--store", str(root), "--no-selftest"]
    assert (
        flash.main([*argv, "--trust-key", str(public), "--image", str(image), "--signature", str(sig)]) == 0
    )
    assert f"signed by key {pub.key_id}" in capsys.readouterr().out
    manifest = store.read_manifest(root, "a")
    assert manifest.key_id == pub.key_id and manifest.signature == sig.read_bytes()
    assert store.layout(root).image("a").read_bytes() == image.read_bytes()

    embedded = tmp_path / "two.signed.pyz"
    embedded.write_bytes(
        signing.embed_signature(images["two"].read_bytes(), key.sign(images["two"].read_bytes()))
    )
    assert flash.main([*argv, "--image", str(embedded)]) == 0
    # The slot holds exactly the signed bytes (the image without its comment).
    assert store.layout(root).image("b").read_bytes() == images["two"].read_bytes()
    assert store.slot_usable(root, "b") is None

    assert flash.main([*argv, "--image", str(images["one"]), "--key", str(private)]) == 0
    assert store.slot_usable(root, "b") is None
    assert json.loads(store.layout(root).trust.read_text())["keys"] == {
        pub.key_id: {"ed25519": base64.b64encode(pub.raw).decode()}
    }


@pytest.mark.parametrize("how", ["unsigned", "other key", "tampered", "signed here with an untrusted key"])
def test_signed_store_refuses_what_a_trusted_key_did_not_sign_in_one_line(
    tmp_path: Path, images: dict[str, Path], keys: dict, capsys: pytest.CaptureFixture[str], how: str
) -> None:
    root = signed_store(tmp_path / "ecu", images["one"], keys)
    before = snapshot(root)
    image = tmp_path / "two.pyz"
    data = images["two"].read_bytes()
    image.write_bytes(data)
    argv = ["--store", str(root), "--image", str(image), "--no-selftest"]
    sig = tmp_path / "two.sig"
    if how == "other key":
        sig.write_bytes(keys["other"][0].sign(data))
        argv += ["--signature", str(sig)]
    elif how == "tampered":
        sig.write_bytes(keys["release"][0].sign(data))
        image.write_bytes(tampered(data))
        argv += ["--signature", str(sig)]
    elif how == "signed here with an untrusted key":
        argv += ["--key", str(keys["other"][2])]
    assert flash.main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    if how == "unsigned":
        assert err == f"error: {image}: no signature given and the store requires signed firmware"
    else:
        assert err.startswith(f"error: {image}: signature does not verify with any trusted key"), err
    assert snapshot(root) == before


def test_a_new_store_needs_a_trust_decision(tmp_path: Path, images: dict[str, Path]) -> None:
    with pytest.raises(FlashError, match="no firmware trust policy"):
        flash.flash_firmware(tmp_path / "ecu", images["one"], selftest=False)
    assert not (tmp_path / "ecu").exists()


def test_adding_and_revoking_keys_through_the_cli(
    tmp_path: Path, images: dict[str, Path], keys: dict, capsys: pytest.CaptureFixture[str]
) -> None:
    root = signed_store(tmp_path / "ecu", images["one"], keys)
    _, new_pub, _, new_public = keys["new"]
    assert flash.main(["--store", str(root), "--trust-key", str(new_public)]) == 1
    assert "needs --trust-key-signature" in capsys.readouterr().err
    endorsement = tmp_path / "new.pub.sig"
    assert cli.main(["sign", "--key", str(keys["release"][2]), str(new_public), "-o", str(endorsement)]) == 0
    argv = ["--store", str(root), "--trust-key", str(new_public), "--trust-key-signature", str(endorsement)]
    assert flash.main(argv) == 0
    policy = store.read_trust(root)
    assert policy is not None and new_pub.key_id in policy.keys
    release_id = keys["release"][1].key_id
    assert flash.main(["--store", str(root), "--revoke-key", release_id]) == 0
    policy = store.read_trust(root)
    assert policy is not None and set(policy.keys) == {new_pub.key_id}
    # The slot signed only by the revoked key does not boot any more.
    assert "signature does not verify with any trusted key" in (store.slot_usable(root, "a") or "")
    assert flash.main(["--store", str(root), "--revoke-key", new_pub.key_id]) == 1
    assert "would leave no trusted key" in capsys.readouterr().err
    assert flash.main(["--store", str(root), "--allow-unsigned"]) == 1
    assert "never accepts unsigned firmware" in capsys.readouterr().err


def test_cli_usage_errors(
    tmp_path: Path, images: dict[str, Path], keys: dict, capsys: pytest.CaptureFixture[str]
) -> None:
    root = str(tmp_path / "ecu")
    for argv, problem in (
        (["--firmware", "--signature", "x.sig"], "--signature goes with --image"),
        (["--image", str(images["one"]), "--signature", "x", "--key", "k"], "not both"),
        (["--trust-key", "a.pem", "--allow-unsigned"], "not both"),
        (["--trust-key-signature", "s"], "exactly one --trust-key"),
        (["--key", "k"], "--key signs firmware"),
    ):
        assert flash.main(["--store", root, *argv]) == 2, argv
        assert problem in capsys.readouterr().err, argv
    assert not Path(root).exists()


# --- booting signed firmware -----------------------------------------------------------------------


def test_boot_checks_the_signature_every_boot_and_falls_back(
    tmp_path: Path, images: dict[str, Path], keys: dict
) -> None:
    root = signed_store(tmp_path / "ecu", images["one"], keys)
    flash.flash_firmware(root, images["two"], signing_key=keys["release"][0], selftest=False)
    store.write_boot_record(root, store.BootRecord(active="b", previous="a"))
    assert boot.boot(root, ["--exit-now", "0"], log=Log()) == 0
    record = store.read_boot_record(root)
    assert record is not None and record.active == "b"

    # Slot b's bytes and its manifest's size and sha256 changed together (they alone would pass): the
    # signature no longer verifies, so b is rejected like a torn image and a boots.
    lay = store.layout(root)
    data = tampered(lay.image("b").read_bytes())
    lay.image("b").write_bytes(data)
    manifest = store.read_manifest(root, "b")
    forged = {**manifest.to_dict(), "sha256": hashlib.sha256(data).hexdigest(), "size_bytes": len(data)}
    store.write_json_atomic(lay.manifest("b"), forged)
    log = Log()
    assert boot.boot(root, ["--exit-now", "0"], log=log) == 0
    record = store.read_boot_record(root)
    assert record is not None and record.active == "a"
    assert "signature does not verify with any trusted key" in record.rejected["b"]
    assert "!!! slot b REJECTED" in log.text()


def test_boot_refuses_a_store_without_trust_and_an_old_store_is_upgraded(
    tmp_path: Path, images: dict[str, Path], keys: dict
) -> None:
    # A store from before signed firmware: layout 1, no trust.json, an unsigned image in slot a.
    root = tmp_path / "ecu"
    flash.flash_firmware(root, images["one"], selftest=False, trust=DEVELOPMENT)
    lay = store.layout(root)
    lay.trust.unlink()
    lay.marker.write_text(json.dumps({"format": store.STORE_FORMAT, "layout": 1}))
    old_manifest = {
        k: v for k, v in store.read_manifest(root, "a").to_dict().items() if k not in ("signature", "key_id")
    }
    store.write_json_atomic(lay.manifest("a"), old_manifest)
    assert store.read_trust(root) is None and store.store_layout_version(root) == 1
    log = Log()
    assert boot.boot(root, log=log) == boot.EXIT_NO_IMAGE
    assert "no firmware trust policy" in log.text() and "--trust-key" in log.text()
    # Trusting a key makes it a layout 2 store (which a supervisor without signatures refuses); its
    # unsigned slot does not boot, the newly flashed signed one does.
    key, pub, *_ = keys["release"]
    flash.flash_firmware(root, images["two"], signing_key=key, trust=TrustChange(add=(pub,)), selftest=False)
    assert store.store_layout_version(root) == 2
    assert "no signature given" in (store.slot_usable(root, "a") or "")
    assert store.slot_usable(root, "b") is None


def test_trust_file_errors_name_the_field(tmp_path: Path, keys: dict) -> None:
    pub = keys["release"][1]
    good = TrustPolicy(keys={pub.key_id: pub.raw}).to_dict()
    assert TrustPolicy.from_dict(good, "t.json").keys == {pub.key_id: pub.raw}
    wrong_id = {**good, "keys": {"0" * 16: good["keys"][pub.key_id]}}
    for doc, field in (
        ({**good, "format": "x"}, "format"),
        ({**good, "allow_unsigned": True}, "allow_unsigned"),
        ({**good, "keys": {}}, "keys"),
        (wrong_id, f"keys.{'0' * 16}"),
        ({**good, "keys": {pub.key_id: {"ed25519": "!!"}}}, f"keys.{pub.key_id}.ed25519"),
    ):
        with pytest.raises(StoreError) as e:
            TrustPolicy.from_dict(doc, "t.json")
        assert str(e.value).startswith(f"t.json: {field}:"), (field, str(e.value))
