"""Which firmware a store boots: the rules for changing its trust policy (DIR/trust.json).

No paper section: DESIGN section 4, "firmware is signed". The policy itself (`TrustPolicy`: trusted
Ed25519 keys, or allow-unsigned) lives in store.py and is checked on every flash and every boot;
this module decides how it may change (`plan_trust`, pure), in the terms a functional-safety
reviewer checks:

- a store's policy is set once, when it gets its first firmware trust: `--trust-key PUBLIC.pem`
  (a signed store) or `--allow-unsigned` (a development store); until then no firmware can be
  flashed into it or boot from it;
- a signed store never becomes a development store, and a development store never becomes a signed
  one: a production ECU gets a new store, so nothing flashed unsigned can be left in its slots;
- a key is added to a signed store only with `--trust-key-signature FILE`: a signature of the new
  public key file, by a key the store already trusts (`bywire ecu sign --key OLD.pem NEW.pub.pem`);
  one key per flash, so each addition is endorsed on its own;
- `--revoke-key ID` removes a key, never the last one (a store without keys would look like a new
  one and accept anybody's); slots signed only by a revoked key stop booting at once;
- whoever can write the store directory can change anything in it: the policy protects against the
  wrong image and the wrong key through the flash tool, not against root (that needs secure boot).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from bywire.ecu.signing import PublicKey, verifying_key
from bywire.ecu.store import StorePath, TrustPolicy, layout


class TrustError(Exception):
    """A trust change is not allowed; one line naming the store or the file and why."""


@dataclass(frozen=True)
class TrustChange:
    """What a flash changes in the store's trust policy (see the module docstring for the rules)."""

    add: tuple[PublicKey, ...] = ()
    endorsement: bytes | None = None  # a trusted key's signature over add[0]'s file bytes
    endorsement_source: str = "--trust-key-signature"
    revoke: tuple[str, ...] = ()  # key ids
    allow_unsigned: bool = False

    @property
    def empty(self) -> bool:
        return not (self.add or self.revoke or self.allow_unsigned)


DEVELOPMENT = TrustChange(allow_unsigned=True)


# --- rules --------------------------------------------------------------------------------------


def plan_trust(current: TrustPolicy | None, change: TrustChange, store: StorePath) -> TrustPolicy | None:
    """Pure: the policy after `change` (None: still none); TrustError, one line, if not allowed."""
    root = os.fspath(layout(store).root)
    if change.allow_unsigned and change.add:
        raise TrustError(f"{root}: give --trust-key or --allow-unsigned, not both")
    if current is None:
        if change.revoke:
            raise TrustError(f"{root}: the store trusts no key; nothing to revoke")
        if change.allow_unsigned:
            return TrustPolicy(allow_unsigned=True)
        if change.add:
            return TrustPolicy(keys={k.key_id: k.raw for k in change.add})
        return None
    if current.allow_unsigned:
        if change.add:
            raise TrustError(
                f"{root}: a development store (--allow-unsigned) never becomes a signed store;"
                " flash a new store with --trust-key"
            )
        if change.revoke:
            raise TrustError(f"{root}: a development store trusts no key; nothing to revoke")
        return current
    if change.allow_unsigned:
        raise TrustError(
            f"{root}: the store requires signed firmware and never accepts unsigned firmware;"
            " a development store is a new store created with --allow-unsigned"
        )
    keys = dict(current.keys)
    new = [k for k in change.add if k.key_id not in keys]
    if new:
        if len(new) > 1:
            raise TrustError(f"{root}: add one key at a time to a store that trusts keys")
        key = new[0]
        if change.endorsement is None:
            raise TrustError(
                f"{key.source}: the store already trusts keys; a new one needs --trust-key-signature:"
                " this file signed by a trusted key (bywire ecu sign --key TRUSTED.pem FILE)"
            )
        if verifying_key(keys, change.endorsement, key.pem) is None:
            raise TrustError(
                f"{change.endorsement_source}: signature of {key.source} does not verify with any trusted key"
            )
        keys[key.key_id] = key.raw
    for kid in change.revoke:
        if kid not in keys:
            raise TrustError(
                f"{root}: key {kid} is not trusted by this store (trusted: {', '.join(sorted(keys))})"
            )
        del keys[kid]
    if not keys:
        raise TrustError(
            f"{root}: revoking {', '.join(change.revoke)} would leave no trusted key; trust the new key first"
        )
    return TrustPolicy(keys=keys)


def describe_policy(policy: TrustPolicy) -> str:
    if policy.allow_unsigned:
        return "development store, accepts UNSIGNED firmware"
    return "firmware must be signed by key " + " or ".join(sorted(policy.keys))
