"""`bywire ecu ...`: run the firmware (from the installation or from a flashed store) and flash it.

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
    run.add_argument(
        "--ready-timeout",
        dest="ready_timeout_s",
        type=float,
        default=boot.DEFAULT_READY_TIMEOUT_S,
        help="with --store: seconds a newly flashed image has to come up before falling back",
    )
    flash.add_flash_arguments(sub.add_parser("flash", help="write firmware and/or calibration into a store"))
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
    if args.ecu_command == "unlatch":
        return _service(args.host_link, args.timeout, "unlatch", None)
    if args.ecu_command == "calibrate":
        return _service(args.host_link, args.timeout, "calibrate", args.calibration)
    if args.store is not None:
        from bywire.ecu.boot import cmd_run_from_store

        # The image's app gets every option but the boot loader's own.
        app_args = _strip_options(
            argv[1:], {"--store": True, "--ready-timeout": True, "--vehicle-bus": True, "--host-link": True}
        )
        args.app_args = app_args
        return cmd_run_from_store(args)
    from bywire.ecu.app import main as app_main

    return app_main(argv[1:])


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
    from bywire.protocol.canopen_node import EcuRefusedError, HostMaster

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
        print("unlatch acknowledged; the ECU leaves DISABLED once the E-stop radio no longer says DISABLE")
    else:
        print(f"calibration {calibration} accepted by the ECU")
    return 0
