"""`bywire ecu ...`: run the firmware (from the installation or from a flashed store), flash it, and
make and use the keys that sign it (`keygen`, `sign`; docs/firmware_store.md).

This module is also what a firmware image's `run` dispatches to, so it imports only the ECU and
the protocol (never host or HIL code).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path


def build_parser() -> argparse.ArgumentParser:
    from bywire.ecu import app, boot, flash

    parser = argparse.ArgumentParser(
        prog="bywire ecu", description="the ECU firmware: run it, flash it, and service it over the host link"
    )
    sub = parser.add_subparsers(dest="ecu_command", required=True, metavar="COMMAND")
    run = sub.add_parser("run", help="run the ECU at 1 kHz (from a flashed store with --store)")
    app.add_run_arguments(run)
    boot.add_supervisor_arguments(run)
    flash.add_flash_arguments(
        sub.add_parser("flash", help="write signed firmware, a calibration and/or trusted keys into a store")
    )
    keygen = sub.add_parser("keygen", help="make a new Ed25519 key pair for signing firmware")
    keygen.add_argument(
        "--out", required=True, type=Path, help="directory for the private (0600) and public key PEM files"
    )
    sign = sub.add_parser(
        "sign", help="sign a firmware image (or a public key file, to endorse it) with a private key"
    )
    sign.add_argument("--key", required=True, type=Path, help="the Ed25519 private key (PEM)")
    sign.add_argument("file", type=Path, metavar="IMAGE", help="the file to sign (its exact bytes)")
    sign.add_argument(
        "-o",
        "--output",
        type=Path,
        default=None,
        help="where to write (default IMAGE.sig; with --embed, IMAGE with .signed before its suffix)",
    )
    sign.add_argument(
        "--embed",
        action="store_true",
        help="write a copy of the image with the signature inside (its zip comment) instead of IMAGE.sig",
    )
    unlatch = sub.add_parser(
        "unlatch", help="the manual unlatch of an E-stop DISABLE, over the host link (SDO)"
    )
    unlatch.add_argument(
        "--host-link", required=True, help="bus URL of the host link (a CAN bus, not udp://)"
    )
    unlatch.add_argument("--timeout", type=float, default=2.0, help="SDO timeout in seconds")
    calibrate = sub.add_parser(
        "calibrate", help="write a calibration into a running ECU over the host link (SDO)"
    )
    calibrate.add_argument("calibration", type=Path, help="calibration file (JSON)")
    calibrate.add_argument(
        "--host-link", required=True, help="bus URL of the host link (a CAN bus, not udp://)"
    )
    calibrate.add_argument("--timeout", type=float, default=5.0, help="SDO timeout in seconds")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    if args.ecu_command == "flash":
        from bywire.ecu.flash import cmd_flash

        return cmd_flash(args)
    if args.ecu_command == "keygen":
        return _keygen(args.out)
    if args.ecu_command == "sign":
        return _sign(args.key, args.file, args.output, embed=args.embed)
    if args.ecu_command == "unlatch":
        return _service(args.host_link, args.timeout, "unlatch", None)
    if args.ecu_command == "calibrate":
        return _service(args.host_link, args.timeout, "calibrate", args.calibration)
    if args.store is not None:
        from bywire.ecu.boot import SUPERVISOR_OPTIONS, cmd_run_from_store

        # The image's app gets every option but the boot loader's own (and the buses, which
        # cmd_run_from_store forwards itself).
        app_args = _strip_options(
            argv[1:], {**SUPERVISOR_OPTIONS, "--vehicle-bus": True, "--host-link": True}
        )
        args.app_args = app_args
        return cmd_run_from_store(args)
    from bywire.ecu.app import main as app_main

    # Without --store there is no supervisor: its options must not reach the app's parser.
    return app_main(_strip_options(argv[1:], {"--ready-timeout": True, "--confirm-after": True}))


def _keygen(out: Path) -> int:
    """`bywire ecu keygen --out DIR`: a new key pair; refuses to overwrite one."""
    from bywire.ecu.signing import SigningError, generate_key_pair

    try:
        private, public, kid = generate_key_pair(out)
    except SigningError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"private key: {private} (mode 0600; keep it secret, sign with `bywire ecu sign --key {private}`)")
    print(
        f"public key:  {public} (key id {kid};"
        f" trust it with `bywire ecu flash --store DIR --trust-key {public}`)"
    )
    return 0


def _sign(key_path: Path, path: Path, output: Path | None, *, embed: bool) -> int:
    """`bywire ecu sign --key PRIVATE.pem FILE [-o OUT] [--embed]`: a detached signature of FILE's
    exact bytes (64 raw bytes), or with --embed a copy of the image carrying it in its zip comment."""
    from bywire.ecu.signing import SigningError, embed_signature, load_signing_key
    from bywire.ecu.store import os_error_text, write_atomic

    if output is None:
        output = (
            path.with_name(f"{path.stem}.signed{path.suffix}")
            if embed
            else path.with_name(path.name + ".sig")
        )
    try:
        key = load_signing_key(key_path)
        try:
            data = path.read_bytes()
        except OSError as e:
            raise SigningError(f"{path}: cannot read: {os_error_text(e)}") from None
        signature = key.sign(data)
        try:
            out_data = embed_signature(data, signature) if embed else signature
        except SigningError as e:
            raise SigningError(f"{path}: {e}") from None
        try:
            write_atomic(output, out_data)
        except OSError as e:
            raise SigningError(f"{output}: cannot write: {os_error_text(e)}") from None
    except SigningError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    what = "signed image" if embed else "signature"
    print(f"{what}: {output} ({path} signed with key {key.public.key_id})")
    return 0


def _strip_options(argv: list[str], takes_value: dict[str, bool]) -> list[str]:
    out: list[str] = []
    skip = False
    for item in argv:
        if skip:
            skip = False
            continue
        name = item.split("=", 1)[0]
        if name in takes_value:
            skip = takes_value[name] and "=" not in item
            continue
        out.append(item)
    return out


SERVICE_TOOL_NODE_ID = 0x7E  # not the host's 0x01: the tool's boot-up must not look like a host reboot


def _service(url: str, timeout_s: float, what: str, calibration: Path | None) -> int:
    """A service tool's SDO request to a running ECU: the DISABLE unlatch, or a new calibration.

    A calibration is checked here first (so a bad file is refused with its field named before
    anything is sent), then validated again by the ECU, which stores it in its non-volatile
    store when it runs from one and refuses it while it actuates.
    """
    from bywire.clock import WallClock
    from bywire.ecu.calibration import CalibrationError, loads_calibration
    from bywire.protocol.bus_url import open_bus
    from bywire.protocol.canopen_link.host_master import EcuRefusedError, HostMaster

    data = b""
    if calibration is not None:
        try:
            data = calibration.read_bytes()
            loads_calibration(data, str(calibration))
        except (OSError, CalibrationError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
    bus = open_bus(url)
    try:
        tool = HostMaster(bus, WallClock(), node_id=SERVICE_TOOL_NODE_ID, sdo_timeout_s=timeout_s)
        if calibration is None:
            tool.unlatch()
        else:
            tool.write_calibration(data)
    except EcuRefusedError as exc:
        print(f"error: the ECU refused the {what}: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # no answer: wrong bus, ECU off
        print(f"error: no {what} acknowledgement from the ECU on {url}: {exc}", file=sys.stderr)
        return 1
    finally:
        bus.shutdown()
    if calibration is None:
        print(
            "unlatch acknowledged: the ECU leaves DISABLED when the safety driver presses the arm "
            "button on the car (the unlatch alone never re-arms it)"
        )
    else:
        print(f"calibration {calibration} accepted by the ECU")
    return 0
