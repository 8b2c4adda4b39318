"""The protocol table (docs/protocol.md), generated from the DBC and the EDS so that it cannot drift.

Data is the spec: `vehicle.dbc` defines vehicle CAN, `ecu.eds` the host <-> ECU CANopen link;
this module only renders them (plus the wire enums of `ecu_types` and the EMCY codes of
`host_link`) as Markdown. `tests/protocol/test_protocol_table.py` compares docs/protocol.md with a fresh
render; regenerate with `bywire protocol table > docs/protocol.md` (or `write_protocol_table`).
The vehicle profile pq (`vehicle_pq`) renders its two DBCs instead of `vehicle.dbc`: ours
(`vehicle_pq.dbc`) in full, and of the car's (`vw_pq.dbc`) the messages and signals the ECU reads, with
their checksum, counter and conversion into SI (docs/protocol_pq.md, `bywire protocol table --profile pq`).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from enum import Enum
from importlib import resources
from pathlib import Path
from typing import Any

import cantools
import cantools.database
from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord, ODVariable
from canopen.objectdictionary import datatypes as dt

from bywire.protocol.canopen_link.dictionary import (
    CALIBRATION_INDEX,
    COMMAND_INDEX,
    CONSUMER_HEARTBEAT_INDEX,
    ECU_NODE_ID,
    EMCY_COB_INDEX,
    MAX_CALIBRATION_BYTES,
    MAX_HOST_HEARTBEAT_TIMEOUT_MS,
    MAX_PRODUCER_HEARTBEAT_MS,
    MAX_REQUEST_DEADLINE_MS,
    MAX_TPDO_EVENT_TIMER_MS,
    PRODUCER_HEARTBEAT_INDEX,
    REFUSAL_INDEX,
    RPDO_COMM_BASE,
    SDO_SERVER_INDEX,
    TPDO_COMM_BASE,
    PdoLayout,
    load_ecu_od,
    od_default,
    read_pdo_layouts,
)
from bywire.protocol.canopen_link.ecu_node import MAX_COUNTER_DELTA
from bywire.protocol.canopen_link.nmt import HEARTBEAT_COB_BASE, NMT_COB_ID, NmtCommand, NmtState
from bywire.protocol.ecu_types import EcuState, EstopMode, Fault, RequestFlags
from bywire.protocol.host_link import (
    EMCY_CODE_BY_FAULT,
    REQUEST_INDEX,
    STATUS_INDEX,
    error_register_for,
)
from bywire.protocol.vehicle_can import CHECKSUM_NONE, VEHICLE_PROFILES, VehicleCodec, load_dbc
from bywire.protocol.vehicle_pq import STEERING_RATIO

DBC_RESOURCE = "vehicle.dbc"  # package data of bywire.protocol, read through importlib.resources
REGENERATE = "bywire protocol table > docs/protocol.md"
REGENERATE_PQ = "bywire protocol table --profile pq > docs/protocol_pq.md"

_TYPE_NAMES = {
    dt.BOOLEAN: "BOOLEAN",
    dt.INTEGER8: "INTEGER8",
    dt.INTEGER16: "INTEGER16",
    dt.INTEGER32: "INTEGER32",
    dt.UNSIGNED8: "UNSIGNED8",
    dt.UNSIGNED16: "UNSIGNED16",
    dt.UNSIGNED32: "UNSIGNED32",
    dt.REAL32: "REAL32",
    dt.VISIBLE_STRING: "VISIBLE_STRING",
    dt.OCTET_STRING: "OCTET_STRING",
    dt.DOMAIN: "DOMAIN",
    dt.INTEGER64: "INTEGER64",
    dt.UNSIGNED64: "UNSIGNED64",
    dt.REAL64: "REAL64",
}


def _num(x: float) -> str:
    # 10 significant digits: exact for every scale and range here, and free of float noise.
    return f"{x:.10g}"


def _cell(text: object) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _table(header: Sequence[str], rows: Iterable[Sequence[object]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return [*lines, ""]


def _hex_id(frame_id: int, extended: bool) -> str:
    return f"0x{frame_id:08X}" if extended else f"0x{frame_id:03X}"


# --- vehicle CAN ------------------------------------------------------------------------------


def _render_dbc(
    db: cantools.database.can.Database, title: str = "## 1. Vehicle CAN (`protocol/vehicle.dbc`)"
) -> list[str]:
    out = [
        title,
        "",
        "All signals little-endian (Intel); physical = raw * scale + offset. Every frame starts with a "
        "CRC8 and a 4-bit alive counter.",
        "",
    ]
    messages = sorted(db.messages, key=lambda m: m.frame_id)
    out += _table(
        ("id", "name", "sender", "DLC", "cycle", "receivers"),
        (
            (
                f"{_hex_id(m.frame_id, m.is_extended_frame)} ({m.frame_id})",
                m.name,
                ", ".join(m.senders),
                m.length,
                f"{m.cycle_time} ms" if m.cycle_time else "event",
                ", ".join(sorted({r for s in m.signals for r in s.receivers})),
            )
            for m in messages
        ),
    )
    for m in messages:
        out += [f"### {_hex_id(m.frame_id, m.is_extended_frame)} {m.name}", ""]
        if m.comment:
            out += [m.comment, ""]
        rows = []
        for s in sorted(m.signals, key=lambda s: s.start):
            values = (
                ", ".join(f"{int(v)}={name}" for v, name in sorted(s.choices.items())) if s.choices else ""
            )
            rng = "" if s.minimum is None or s.maximum is None else f"{_num(s.minimum)} .. {_num(s.maximum)}"
            rows.append(
                (
                    s.name,
                    s.start,
                    s.length,
                    "signed" if s.is_signed else "unsigned",
                    _num(s.scale),
                    _num(s.offset),
                    s.unit or "",
                    rng,
                    ", ".join(s.receivers),
                    values,
                    s.comment or "",
                )
            )
        out += _table(
            (
                "signal",
                "start bit",
                "bits",
                "sign",
                "scale",
                "offset",
                "unit",
                "range",
                "receivers",
                "values",
                "comment",
            ),
            rows,
        )
    return out


def _render_pq_car() -> list[str]:
    """The car's messages of profile pq: what the ECU reads of each, and how it is protected."""
    codec = VehicleCodec(profile="pq")
    car = [info for info in codec.messages if info.senders == ("CAR",)]
    out = [
        "## 1b. The car's own messages (`protocol/vw_pq.dbc`, from opendbc, MIT)",
        "",
        "The VW PQ35/PQ46 powertrain CAN as opendbc's `vw_pq.dbc` describes it; the signals the ECU reads "
        "and the field each becomes (SI units, `bywire.protocol.vehicle_pq`). Checksum: the XOR of the "
        "other data bytes, in the byte named; counter: the 4-bit alive counter at the bit named; a "
        "message without them is judged by its structure, ranges and age alone. Lenkhilfe_3's "
        f"steering-wheel angle becomes the road-wheel angle over the steering ratio {STEERING_RATIO:g}.",
        "",
    ]

    def protection(info: Any) -> tuple[str, str]:
        checksum = "-" if info.checksum == CHECKSUM_NONE else f"XOR, byte {info.checksum_byte}"
        counter = (
            "-" if info.counter_start is None else f"bits {info.counter_start}..{info.counter_start + 3}"
        )
        return checksum, counter

    out += _table(
        ("id", "name", "DLC", "cycle", "checksum", "counter", "typed frame"),
        (
            (
                f"{_hex_id(i.frame_id, False)} ({i.frame_id})",
                i.name,
                i.length,
                f"{round(i.cycle_time_s * 1000)} ms",
                *protection(i),
                f"`{i.frame_type.__name__}`",
            )
            for i in car
        ),
    )
    for info in car:
        out += [f"### {_hex_id(info.frame_id, False)} {info.name}", ""]
        if info.message.comment:
            out += [info.message.comment, ""]
        rows = []
        for sig in info.signals:
            dbc_sig = info.message.get_signal_by_name(sig.signal)
            if sig.kind == "mapped":
                meaning = ", ".join(f"{raw}={member.name}" for raw, member in sig.mapping) + ", else refused"
            elif sig.kind == "bool":
                meaning = "1 = true"
            else:
                sign = f", sign bit {sig.sign_start} (1 = negative)" if sig.kind == "magnitude" else ""
                meaning = f"raw * {_num(sig.scale)} {sig.unit}{sign}"
            rows.append(
                (
                    sig.signal,
                    dbc_sig.start,
                    dbc_sig.length,
                    _num(dbc_sig.scale),
                    dbc_sig.unit or "",
                    f"{_num(dbc_sig.minimum)} .. {_num(dbc_sig.maximum)}",
                    f"`{info.frame_type.__name__}.{sig.field}`",
                    meaning,
                    dbc_sig.comment or "",
                )
            )
        out += _table(
            ("signal", "start bit", "bits", "scale", "unit", "range", "field", "field value", "comment"), rows
        )
    return out


# --- host <-> ECU CANopen ----------------------------------------------------------------------


def _type_name(var: ODVariable) -> str:
    return _TYPE_NAMES.get(var.data_type or 0, f"0x{var.data_type or 0:04X}")


def _phys_range(var: ODVariable) -> str:
    if var.data_type not in dt.INTEGER_TYPES:
        return ""
    bits = len(var)
    lo, hi = (
        (-(1 << (bits - 1)), (1 << (bits - 1)) - 1)
        if var.data_type in dt.SIGNED_TYPES
        else (0, (1 << bits) - 1)
    )
    return f"{_num(lo * var.factor)} .. {_num(hi * var.factor)}"


def _limits(var: ODVariable) -> str:
    """The EDS's LowLimit .. HighLimit (packed words in hex, like their defaults)."""
    if var.min is None and var.max is None:
        return ""

    def show(x: int | None) -> str:
        if x is None:
            return ""
        return f"0x{x:08X}" if var.data_type == dt.UNSIGNED32 else str(x)

    return f"{show(var.min)} .. {show(var.max)}"


def _object_rows(od: ObjectDictionary, indices: Iterable[int]) -> list[tuple[object, ...]]:
    rows: list[tuple[object, ...]] = []
    for index in indices:
        obj = od[index]
        members: list[tuple[str, ODVariable]]
        if isinstance(obj, (ODRecord, ODArray)):
            members = [(f"0x{index:04X}sub{sub:X}", obj[sub]) for sub in sorted(obj.subindices) if sub != 0]
        else:
            members = [(f"0x{index:04X}", obj)]
        for where, var in members:
            default: object = var.default if var.default is not None else ""
            if isinstance(default, bytes):
                default = default.hex()
            elif isinstance(default, int) and var.data_type == dt.UNSIGNED32:
                default = f"0x{default:08X}"  # COB-IDs, mapping entries, packed words
            rows.append(
                (
                    where,
                    var.qualname,
                    _type_name(var),
                    var.access_type,
                    "yes" if var.pdo_mappable else "",
                    default,
                    _limits(var),
                    _num(var.factor) if var.pdo_mappable and var.data_type in dt.NUMBER_TYPES else "",
                    var.unit,
                    var.description,
                )
            )
    return rows


def _pdo_section(layout: PdoLayout, od: ObjectDictionary) -> list[str]:
    direction = "ECU -> host" if layout.is_tx else "host -> ECU"
    timer = (
        f"event timer {layout.event_timer_ms} ms"
        if layout.is_tx
        else f"deadline (event timer) {layout.event_timer_ms} ms"
    )
    out = [
        f"#### {layout.name}: COB-ID 0x{layout.cob_id:03X}, {direction}, {layout.n_bytes} bytes, "
        f"transmission type {layout.transmission_type}, {timer}",
        "",
    ]
    rows = []
    for e in layout.entries:
        var = e.var
        rows.append(
            (
                e.byte_offset if e.n_bytes == 1 else f"{e.byte_offset}-{e.byte_offset + e.n_bytes - 1}",
                f"0x{e.index:04X}sub{e.subindex:X}",
                var.name,
                _type_name(var),
                _num(var.factor),
                var.unit,
                _phys_range(var),
                var.description,
            )
        )
    out += _table(("bytes", "object", "name", "type", "factor", "unit", "range", "meaning"), rows)
    return out


def _enum_table(title: str, enum_type: type[Enum]) -> list[str]:
    rows = [(f"{m.value} (0x{m.value:X})", m.name) for m in enum_type]
    return [f"#### {title}", "", *_table(("value", "name"), rows)]


def _render_eds(od: ObjectDictionary, node_id: int) -> list[str]:
    tpdos = read_pdo_layouts(od, is_tx=True)
    rpdos = read_pdo_layouts(od, is_tx=False)
    consumer = int(od_default(od, CONSUMER_HEARTBEAT_INDEX, 1))
    host_id, consumer_ms = (consumer >> 16) & 0x7F, consumer & 0xFFFF
    producer_ms = int(od_default(od, PRODUCER_HEARTBEAT_INDEX))
    emcy_cob = int(od_default(od, EMCY_COB_INDEX)) & 0x7FF
    sdo_rx = int(od_default(od, SDO_SERVER_INDEX, 1))
    sdo_tx = int(od_default(od, SDO_SERVER_INDEX, 2))
    info = od.device_information
    rates = ", ".join(f"{r // 1000} kbit/s" for r in sorted(info.allowed_baudrates))
    out = [
        "## 2. Host <-> ECU CANopen link (`protocol/ecu.eds`)",
        "",
        f"{info.product_name} ({info.vendor_name}), CANopen node 0x{node_id:02X}; host agent node "
        f"0x{host_id:02X}. Bit rates: {rates}. The same frames run over CAN or over UDP "
        "(cannelloni format, `udp://` bus URLs).",
        "",
        "### COB-IDs",
        "",
    ]
    cobs: list[tuple[int, str, str, str]] = [
        (NMT_COB_ID, "NMT", "host -> ECU", "command specifier u8, node id u8 (0 = all)"),
        (emcy_cob, "EMCY", "ECU -> host", "error code u16, error register u8, Fault bits u16, 3 reserved"),
        (sdo_tx, "SDO server -> client", "ECU -> host", "SDO responses"),
        (sdo_rx, "SDO client -> server", "host -> ECU", "SDO requests (calibration, unlatch, parameters)"),
        (
            HEARTBEAT_COB_BASE + host_id,
            "heartbeat (host)",
            "host -> ECU",
            f"NMT state u8; consumed by the ECU, timeout {consumer_ms} ms (0x1016sub1)",
        ),
        (
            HEARTBEAT_COB_BASE + node_id,
            "heartbeat (ECU)",
            "ECU -> host",
            f"NMT state u8, every {producer_ms} ms (0x1017)",
        ),
    ]
    for layout in tpdos:
        cobs.append((layout.cob_id, layout.name, "ECU -> host", f"status, every {layout.event_timer_ms} ms"))
    for layout in rpdos:
        cobs.append(
            (layout.cob_id, layout.name, "host -> ECU", f"request, stale after {layout.event_timer_ms} ms")
        )
    out += _table(
        ("COB-ID", "service", "direction", "content"),
        ((f"0x{c:03X}", s, d, t) for c, s, d, t in sorted(cobs)),
    )

    out += [
        "### NMT and liveness",
        "",
        "- The ECU boots into PRE-OPERATIONAL (boot-up frame = heartbeat with state 0); the host starts it "
        "with NMT START. PDOs only in OPERATIONAL; SDO and EMCY in PRE-OPERATIONAL and OPERATIONAL; "
        "heartbeat always.",
        f"- The ECU counts the host as alive while the host heartbeat is at most {consumer_ms} ms old AND "
        "reports OPERATIONAL; a PRE-OPERATIONAL or STOPPED host is a lost host. 0x1016sub1 may be set to "
        f"1 .. {MAX_HOST_HEARTBEAT_TIMEOUT_MS} ms for node 0x{host_id:02X} only.",
        "- Every frame is judged by its receive time (the bus's stamp), not by when the ECU polled it: a "
        "heartbeat or request that waited in the queue while the ECU stalled is as old as it is.",
        "- A request is accepted when its alive counter advances by 1 .. "
        f"{MAX_COUNTER_DELTA}; it is stale when older than the RPDO deadline. Repeated, out-of-sequence, "
        "malformed (length), invalid (flag bits) and not-OPERATIONAL requests are counted and dropped.",
        "- The host publishes a status snapshot when the TPDO mapping the ECU state arrives; the ECU "
        "sends that TPDO last in each event.",
        "",
    ]
    out += [
        "### Watchdog bounds (the firmware's, not only the configuration's)",
        "",
        "A host can never widen its own leash (DESIGN section 4): every time a watchdog depends on is "
        "bounded by the firmware itself, a larger value is refused with abort 0x06090031 (value too "
        "high), 0 with 0x06090032 (value too low), and a change while the ECU actuates (ENGAGED, PAUSED, "
        "SAFE_STOP, DISABLED) with 0x08000022 (device state); calibrations are fixed then too. The EDS "
        "states the same bounds as HighLimit.",
        "",
    ]
    out += _table(
        ("object", "time", "bound", "why"),
        (
            (
                f"0x{RPDO_COMM_BASE:04X}sub5",
                "request deadline",
                f"1 .. {MAX_REQUEST_DEADLINE_MS} ms",
                "five periods of the slowest host (25 Hz); a request replayed that long at the 2 m/s^2 "
                "limit adds at most 0.4 m/s before the stop begins",
            ),
            (
                "0x1016sub1",
                "host heartbeat consumer time",
                f"1 .. {MAX_HOST_HEARTBEAT_TIMEOUT_MS} ms",
                "the same bound for a dead host process as for a hung control loop",
            ),
            (
                "0x1017",
                "ECU heartbeat producer time",
                f"1 .. {MAX_PRODUCER_HEARTBEAT_MS} ms",
                "at least twice within the host's 100 ms consumer time",
            ),
            (
                f"0x{TPDO_COMM_BASE:04X}..0x{TPDO_COMM_BASE + 2:04X} sub5",
                "status TPDO event timers",
                f"1 .. {MAX_TPDO_EVENT_TIMER_MS} ms",
                "the host sees the ECU's state at least once within its consumer time",
            ),
        ),
    )
    out += [
        "### Re-arming and engaging",
        "",
        "- Only a human re-arms: DISABLED is left on the safety driver's arm button (GW_Driver.SafetyArm, "
        f"from the gateway on vehicle CAN) after the service unlatch (1 into 0x{COMMAND_INDEX:04X}sub1, "
        "refused unless the ECU is DISABLED and the radio is heard saying RUN or PAUSE); MANUAL on the arm "
        "button alone. The host's REARM leaves only a SAFE_STOP, at standstill with no fault.",
        "- Engagement is an edge: READY -> ENGAGED needs ENGAGE to rise between two fresh requests while "
        "every precondition holds. After a latch, an ECU reset or an NMT restart a held ENGAGE engages "
        "nothing. REARM with ENGAGE from the hold of a SAFE_STOP goes straight to ENGAGED.",
        "",
    ]
    out += _enum_table("NMT states (heartbeat byte)", NmtState)
    out += _enum_table("NMT commands", NmtCommand)

    out += ["### PDO mappings", ""]
    for layout in (*rpdos, *tpdos):
        out += _pdo_section(layout, od)

    out += ["### Manufacturer objects", ""]
    manufacturer = [i for i in sorted(od) if 0x2000 <= i <= 0x5FFF]
    out += _table(
        ("object", "name", "type", "access", "PDO", "default", "limits", "factor", "unit", "description"),
        _object_rows(od, manufacturer),
    )
    out += [
        f"Calibration: the host downloads the file into 0x{CALIBRATION_INDEX:04X}sub3 (at most "
        f"{MAX_CALIBRATION_BYTES} bytes); the ECU validates it on write and, if it refuses, answers with an "
        f"SDO abort and puts the reason text into 0x{REFUSAL_INDEX:04X}. Writing 1 to "
        f"0x{COMMAND_INDEX:04X}sub1 is the manual unlatch of an E-stop DISABLE. The request record "
        f"0x{REQUEST_INDEX:04X} is written by RPDO only; 0x{STATUS_INDEX:04X} is what the TPDOs carry.",
        "",
        "### Communication objects",
        "",
    ]
    communication = [i for i in sorted(od) if 0x1000 <= i <= 0x1FFF]
    out += _table(
        ("object", "name", "type", "access", "PDO", "default", "limits", "factor", "unit", "description"),
        _object_rows(od, communication),
    )

    out += ["### EMCY codes", ""]
    out += _table(
        ("Fault bit", "Fault", "EMCY code", "error register (0x1001)"),
        (
            (f"0x{int(f):04X}", f.name, f"0x{EMCY_CODE_BY_FAULT[f]:04X}", f"0x{error_register_for(f):02X}")
            for f in Fault
            if f
        ),
    )
    out += ["Error reset (all faults cleared): EMCY code 0x0000, error register 0x00.", ""]
    return out


def _render_enums() -> list[str]:
    out = ["## 3. Wire enumerations (`bywire.protocol.ecu_types`)", ""]
    out += _enum_table("EcuState (status 0x2100sub1, DBW_Command.EcuState)", EcuState)
    out += _enum_table("Fault (status 0x2100sub2, EMCY bytes 3-4)", Fault)
    out += _enum_table("RequestFlags (request 0x2000sub3)", RequestFlags)
    out += _enum_table("EstopMode (ESTOP_Radio.EstopMode)", EstopMode)
    return out


def render_protocol_table(
    dbc_path: str | Path | None = None,
    eds_path: str | Path | None = None,
    node_id: int = ECU_NODE_ID,
    profile: str = "bywire",
) -> str:
    """The whole protocol table as Markdown (deterministic: no dates, sorted everywhere).

    None paths read the packaged vehicle.dbc / ecu.eds through importlib.resources; `profile` "pq"
    renders the PQ profile's vehicle CAN (our `vehicle_pq.dbc`, or `dbc_path`, and the car's messages)."""
    if profile not in VEHICLE_PROFILES:
        raise ValueError(f"vehicle profile {profile!r}: expected one of {', '.join(VEHICLE_PROFILES)}")
    if profile == "pq":
        return _render_pq_table(dbc_path, eds_path, node_id)
    if dbc_path is None:
        dbc_text = resources.files("bywire.protocol").joinpath(DBC_RESOURCE).read_text(encoding="utf-8")
    else:
        dbc_text = Path(dbc_path).read_text(encoding="utf-8")
    db = cantools.database.load_string(dbc_text, database_format="dbc")
    if not isinstance(db, cantools.database.can.Database):
        raise ValueError(f"{dbc_path or DBC_RESOURCE}: not a CAN database")
    od = load_ecu_od(node_id, eds_path)
    lines = [
        "# bywire protocol table",
        "",
        "Generated from `protocol/vehicle.dbc` and `protocol/ecu.eds` by `bywire.protocol.table`. "
        f"Do not edit: regenerate with `{REGENERATE}`.",
        "",
    ]
    lines += _render_dbc(db)
    lines += _render_eds(od, node_id)
    lines += _render_enums()
    while lines and lines[-1] == "":
        lines.pop()
    return "\n".join(lines) + "\n"


def _render_pq_table(dbc_path: str | Path | None, eds_path: str | Path | None, node_id: int) -> str:
    own = load_dbc(Path(dbc_path) if dbc_path is not None else None, "vehicle_pq.dbc")
    od = load_ecu_od(node_id, eds_path)
    lines = [
        "# bywire protocol table, vehicle profile pq",
        "",
        "Generated from `protocol/vehicle_pq.dbc`, `protocol/vw_pq.dbc` and `protocol/ecu.eds` by "
        f"`bywire.protocol.table`. Do not edit: regenerate with `{REGENERATE_PQ}`.",
        "",
        "A VW PQ35/PQ46 Passat reports itself in its own messages (section 1b); what stays bywire's own "
        "(section 1a) sits on frame ids the PQ bus does not use. The host <-> ECU link is the same in "
        "both profiles.",
        "",
    ]
    lines += _render_dbc(own, "## 1a. bywire's messages on the PQ bus (`protocol/vehicle_pq.dbc`)")
    lines += _render_pq_car()
    lines += _render_eds(od, node_id)
    lines += _render_enums()
    while lines and lines[-1] == "":
        lines.pop()
    return "\n".join(lines) + "\n"


def write_protocol_table(path: str | os.PathLike[str]) -> None:
    """Render the table and write it to `path` (the CLI's `bywire protocol table` backend)."""
    Path(path).write_text(render_protocol_table(), encoding="utf-8")
