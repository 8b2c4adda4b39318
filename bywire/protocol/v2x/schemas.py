"""The ASN.1 modules we speak (`asn1/`, shipped with their licences in asn1/LICENSES.md), compiled for UPER.

Four sets, each compiled once per process on first use (asn1tools, pyparsing: 0.1-0.4 s each):

- `CAM_V2`: CAM EN 302 637-2 v1.4.1 + CDD TS 102 894-2 v1.3.1, protocolVersion 2: what we send.
- `CAM_V1`: CAM v1.3.2 + ITS-Container v1.2.1, protocolVersion 1: what older stacks send.
- `ROADSIDE`: SPATEM / MAPEM (ETSI TS 103 301) over ISO TS 19091 DSRC, with the CDD v1.3.1 header.
- `ICLCM`: the GCDC 2016 iCLCM v1.0.

A frame decodes only with the set of its own protocolVersion (the same type names differ in layout).
"""

from __future__ import annotations

import functools
from enum import StrEnum
from pathlib import Path
from typing import Any, Final

import asn1tools

ASN1_DIR: Final = Path(__file__).with_name("asn1")


class SchemaSet(StrEnum):
    CAM_V2 = "cam-v2"
    CAM_V1 = "cam-v1"
    ROADSIDE = "roadside"
    ICLCM = "iclcm"


SCHEMA_FILES: Final = {
    SchemaSet.CAM_V2: ("EN302637-2-v1.4.1-CAM.asn", "TS102894-2-v1.3.1-CDD.asn"),
    SchemaSet.CAM_V1: ("EN302637-2-v1.3.2-CAM.asn", "TS102894-2-v1.2.1-CDD.asn"),
    SchemaSet.ROADSIDE: (
        "TS103301-MAPEM-PDU-Descriptions.asn",
        "ISO-TS-19091-DSRC.asn",
        "TS102894-2-v1.3.1-CDD.asn",
        "bywire-dsrc-companions.asn",
    ),
    SchemaSet.ICLCM: ("iCLCM.asn",),
}


@functools.cache
def compiled(schema: SchemaSet) -> Any:
    """One schema set compiled for UPER (cached per process)."""
    return asn1tools.compile_files([str(ASN1_DIR / name) for name in SCHEMA_FILES[SchemaSet(schema)]], "uper")


def compile_all() -> None:
    """Compile every set now (a process about to run in real time: not inside its first cycle)."""
    for schema in SchemaSet:
        compiled(schema)
