"""The ECU's CANopen object dictionary (`ecu.eds`): its indices, the firmware's bounds on the values
a host may write, the SDO abort codes (CiA 301 table 22), and the PDO layouts the EDS defines.

DESIGN section 3: PDOs for cyclic data, SDO for parameters and calibration, the EDS the single
source of the objects both ends speak; section 4: every watchdog time is bounded by the firmware
itself (the `MAX_*_MS` below), not only by configuration. Kammel et al. 2008 (seed 000) Sec. 3:
the control requests and status the main computer and the ECU exchange are the request record
(0x2000, RPDO1) and the status record (0x2100, TPDO1..3).
"""

from __future__ import annotations

import configparser
import functools
import io
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import canopen
from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord, ODVariable, datatypes
from canopen.objectdictionary.datatypes import INTEGER_TYPES

from bywire.protocol.host_link import REQUEST_FIELDS, REQUEST_INDEX, STATUS_FIELDS, STATUS_INDEX

EDS_RESOURCE = "ecu.eds"  # package data of bywire.protocol
# Where the packaged EDS lives, for messages and tools; loading goes through importlib.resources,
# because inside the ECU firmware image (a zip) the file is not on disk.
EDS_PATH = Path(str(resources.files("bywire.protocol").joinpath(EDS_RESOURCE)))
ECU_NODE_ID = 0x10
HOST_NODE_ID = 0x01

ERROR_REGISTER_INDEX = 0x1001
EMCY_COB_INDEX = 0x1014
CONSUMER_HEARTBEAT_INDEX = 0x1016
PRODUCER_HEARTBEAT_INDEX = 0x1017
SDO_SERVER_INDEX = 0x1200
RPDO_COMM_BASE = 0x1400
RPDO_MAP_BASE = 0x1600
TPDO_COMM_BASE = 0x1800
TPDO_MAP_BASE = 0x1A00
PDO_EVENT_TIMER_SUB = 5
CALIBRATION_INDEX = 0x2200
CALIBRATION_VERSION_SUB = 1
CALIBRATION_CRC_SUB = 2
CALIBRATION_BLOB_SUB = 3
COMMAND_INDEX = 0x2300
UNLATCH_SUB = 1
REFUSAL_INDEX = 0x2400

PDO_NOT_VALID = 1 << 31
# Every time a watchdog depends on is bounded by the firmware itself, not only by configuration
# (DESIGN section 4: a host can never widen its own leash), and may be changed only while the ECU does
# not actuate. The EDS states the same bounds as HighLimit; `load_ecu_od` refuses an EDS that differs.
#
# The host's control loop and the host process are watched with the same bound. DESIGN section 4 has
# the host send at 25 .. 100 Hz: 200 ms is five periods of the slowest host, enough for a loaded host
# computer, and at the 2 m/s^2 request limit a request replayed that long after the host hung (seed
# 000 section 12) adds at most 0.4 m/s before the controlled stop begins.
MAX_REQUEST_DEADLINE_MS = 200  # 0x1400sub5, RPDO1 event timer: a request older than this is stale
MAX_HOST_HEARTBEAT_TIMEOUT_MS = 200  # 0x1016sub1 bits 0-15: the host heartbeat consumer time
# The host watches the ECU with a 100 ms consumer time (HostMaster's ecu_timeout_s): the ECU's own
# heartbeat must come at least twice in that window, and its status at least once.
MAX_PRODUCER_HEARTBEAT_MS = 50  # 0x1017
MAX_TPDO_EVENT_TIMER_MS = 100  # 0x1800..0x1802 sub5
MAX_CALIBRATION_BYTES = 256 * 1024
MAX_REFUSAL_CHARS = 200

# SDO abort codes (CiA 301 table 22).
ABORT_OUT_OF_MEMORY = 0x05040005
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_TOO_HIGH = 0x06090031
ABORT_VALUE_TOO_LOW = 0x06090032
ABORT_GENERAL = 0x08000000
ABORT_CANNOT_STORE = 0x08000020
ABORT_LOCAL_CONTROL = 0x08000021
ABORT_DEVICE_STATE = 0x08000022
SDO_RESPONSE_ABORTED = 0x80  # command byte of an SDO abort frame (command specifier 4, bits 5-7)


def load_ecu_od(node_id: int = ECU_NODE_ID, eds_path: str | Path | None = None) -> ObjectDictionary:
    """Import the ECU's EDS for `node_id` ($NODEID COB-IDs resolved); ValueError names the file.

    `eds_path` None reads the packaged `ecu.eds` through importlib.resources (works inside a zip)."""
    if not 1 <= node_id <= 127:
        raise ValueError(f"CANopen node id {node_id} is outside 1..127")
    label = str(EDS_PATH if eds_path is None else eds_path)
    try:
        if eds_path is None:
            text = resources.files("bywire.protocol").joinpath(EDS_RESOURCE).read_text(encoding="utf-8")
        else:
            text = Path(eds_path).read_text(encoding="utf-8")
        source = io.StringIO(text)
        source.name = EDS_RESOURCE  # canopen picks the format from the name's suffix
        return canopen.import_od(source, node_id)
    except (OSError, UnicodeDecodeError, configparser.Error, ValueError, KeyError) as exc:
        raise ValueError(f"{label}: cannot import the EDS: {exc}") from exc


def od_var(od: ObjectDictionary, index: int, subindex: int | None = None) -> ODVariable:
    obj = od[index]
    if isinstance(obj, (ODRecord, ODArray)):
        return obj[subindex if subindex is not None else 0]
    return obj


def od_default(od: ObjectDictionary, index: int, subindex: int | None = None) -> Any:
    """The EDS value of an object (ParameterValue, else DefaultValue); ValueError if it has none."""
    try:
        var = od_var(od, index, subindex)
    except KeyError:
        raise ValueError(f"EDS has no object {od_where(index, subindex)}") from None
    value = var.value if var.value is not None else var.default
    if value is None:
        raise ValueError(f"EDS object {od_where(index, subindex)} ({var.name}) has no DefaultValue")
    return value


def od_where(index: int, subindex: int | None) -> str:
    return f"0x{index:04X}" if subindex is None else f"0x{index:04X}sub{subindex:X}"


# struct codes of the CiA 301 integer types a PDO can map whole.
_STRUCT_CODES: dict[int, str] = {
    datatypes.INTEGER8: "b",
    datatypes.INTEGER16: "h",
    datatypes.INTEGER32: "i",
    datatypes.INTEGER64: "q",
    datatypes.UNSIGNED8: "B",
    datatypes.UNSIGNED16: "H",
    datatypes.UNSIGNED32: "I",
    datatypes.UNSIGNED64: "Q",
}


@dataclass(frozen=True)
class PdoEntry:
    """One object mapped into a PDO, at a whole-byte offset."""

    index: int
    subindex: int
    byte_offset: int
    n_bytes: int
    var: ODVariable = field(compare=False, repr=False)

    @property
    def key(self) -> tuple[int, int]:
        return (self.index, self.subindex)


@dataclass(frozen=True)
class PdoLayout:
    """A PDO as the EDS defines it: COB-ID, event timer and the mapped objects, in frame order."""

    number: int  # 1-based TPDOn / RPDOn
    is_tx: bool  # TPDO of the ECU (True) or RPDO of the ECU (False)
    cob_id: int
    transmission_type: int
    event_timer_ms: int
    entries: tuple[PdoEntry, ...]

    @property
    def n_bytes(self) -> int:
        return sum(e.n_bytes for e in self.entries)

    @property
    def name(self) -> str:
        return f"{'TPDO' if self.is_tx else 'RPDO'}{self.number}"

    @functools.cached_property
    def keys(self) -> tuple[tuple[int, int], ...]:
        return tuple(e.key for e in self.entries)

    def pack(self, data_by_key: Mapping[tuple[int, int], bytes]) -> bytes:
        """Frame from each mapped object's raw OD bytes."""
        out = bytearray()
        for entry in self.entries:
            data = data_by_key[entry.key]
            if len(data) != entry.n_bytes:
                raise ValueError(
                    f"{self.name}: {od_where(*entry.key)} holds {len(data)} bytes, "
                    f"mapping says {entry.n_bytes}"
                )
            out += data
        return bytes(out)

    @functools.cached_property
    def _frame_struct(self) -> struct.Struct | None:
        """The whole frame as one struct (little-endian, in mapping order), when every mapped object
        is a plain integer type: one unpack per frame instead of one OD lookup per object."""
        codes = []
        for e in self.entries:
            code = None if e.var.data_type is None else _STRUCT_CODES.get(e.var.data_type)
            if code is None or struct.calcsize("<" + code) != e.n_bytes:
                return None
            codes.append(code)
        return struct.Struct("<" + "".join(codes))

    def encode(self, values: Mapping[tuple[int, int], int]) -> bytes:
        """Frame from each mapped object's integer value; ValueError if one does not fit its type."""
        packer = self._frame_struct
        if packer is None:
            return self.pack({e.key: e.var.encode_raw(values[e.key]) for e in self.entries})
        try:
            return packer.pack(*(int(values[e.key]) for e in self.entries))
        except struct.error as exc:
            raise ValueError(f"{self.name}: a value does not fit its object's type: {exc}") from None

    def decode(self, data: bytes | bytearray) -> dict[tuple[int, int], int]:
        """Frame -> each mapped object's integer value; ValueError on a wrong frame length."""
        if len(data) != self.n_bytes:
            raise ValueError(f"{self.name} has {len(data)} data bytes, mapping says {self.n_bytes}")
        unpacker = self._frame_struct
        if unpacker is not None:
            return dict(zip(self.keys, unpacker.unpack(data), strict=True))
        values: dict[tuple[int, int], int] = {}
        for e in self.entries:
            values[e.key] = int(e.var.decode_raw(bytes(data[e.byte_offset : e.byte_offset + e.n_bytes])))
        return values


def read_pdo_layout(od: ObjectDictionary, number: int, is_tx: bool) -> PdoLayout | None:
    """PDO `number` (1-based) from the EDS; None if the EDS has no such PDO or it is disabled."""
    comm_index = (TPDO_COMM_BASE if is_tx else RPDO_COMM_BASE) + number - 1
    map_index = (TPDO_MAP_BASE if is_tx else RPDO_MAP_BASE) + number - 1
    if comm_index not in od:
        return None
    cob_word = int(od_default(od, comm_index, 1))
    if cob_word & PDO_NOT_VALID:
        return None
    comm = od[comm_index]
    has_timer = isinstance(comm, ODRecord) and PDO_EVENT_TIMER_SUB in comm
    event_timer = int(od_default(od, comm_index, PDO_EVENT_TIMER_SUB)) if has_timer else 0
    entries: list[PdoEntry] = []
    offset = 0
    for sub in range(1, int(od_default(od, map_index, 0)) + 1):
        word = int(od_default(od, map_index, sub))
        index, subindex, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
        where = od_where(map_index, sub)
        try:
            var = od_var(od, index, subindex)
        except KeyError:
            raise ValueError(f"EDS {where} maps {od_where(index, subindex)}, which does not exist") from None
        if var.data_type not in INTEGER_TYPES:
            raise ValueError(f"EDS {where} maps {od_where(index, subindex)}, which is not an integer object")
        if bits != len(var) or bits % 8:
            raise ValueError(
                f"EDS {where} maps {od_where(index, subindex)} with {bits} bits; only whole objects "
                f"({len(var)} bits) are supported"
            )
        entries.append(PdoEntry(index, subindex, offset, bits // 8, var))
        offset += bits // 8
    if offset > 8:
        raise ValueError(f"EDS {od_where(map_index, None)} maps {offset} bytes, a CAN frame holds 8")
    return PdoLayout(
        number=number,
        is_tx=is_tx,
        cob_id=cob_word & 0x7FF,
        transmission_type=int(od_default(od, comm_index, 2)),
        event_timer_ms=event_timer,
        entries=tuple(entries),
    )


def read_pdo_layouts(od: ObjectDictionary, is_tx: bool) -> tuple[PdoLayout, ...]:
    """All enabled TPDOs (is_tx) or RPDOs of the ECU, by number."""
    layouts = (read_pdo_layout(od, n, is_tx) for n in range(1, 513))
    return tuple(layout for layout in layouts if layout is not None)


def request_layout(od: ObjectDictionary) -> PdoLayout:
    for layout in read_pdo_layouts(od, is_tx=False):
        if {key[0] for key in layout.keys} == {REQUEST_INDEX}:
            wanted = {(REQUEST_INDEX, spec.subindex) for spec in REQUEST_FIELDS}
            if set(layout.keys) != wanted:
                raise ValueError(
                    f"EDS {layout.name} maps {layout.keys}, the host request needs {sorted(wanted)}"
                )
            return layout
    raise ValueError(f"EDS has no RPDO mapping the host request record 0x{REQUEST_INDEX:04X}")


def status_layouts(od: ObjectDictionary) -> tuple[PdoLayout, ...]:
    """TPDOs mapping the status record, in sending order: the one carrying `state` last."""
    layouts = [t for t in read_pdo_layouts(od, is_tx=True) if any(k[0] == STATUS_INDEX for k in t.keys)]
    mapped = {key for t in layouts for key in t.keys}
    missing = [spec.name for spec in STATUS_FIELDS if (STATUS_INDEX, spec.subindex) not in mapped]
    if missing:
        raise ValueError(f"EDS TPDOs do not map status fields {missing}")
    state_key = (STATUS_INDEX, STATUS_FIELDS[0].subindex)
    return tuple(sorted(layouts, key=lambda t: (state_key in t.keys, t.number)))
