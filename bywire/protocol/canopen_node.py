"""The CANopen host <-> ECU link: the ECU's node (0x10) and the host's master (0x01), pumped not threaded.

Kammel et al. 2008 (seed 000) Sec. 2.1 and 3: the main computer and the low-level ECU exchange
control requests and status over a dedicated link; Sec. 12: a hung process that its watchdog could
not see stopped the car in the final, so liveness here is explicit both ways (heartbeats with
consumer timeouts) and every request carries an alive counter.

Both sides sit on the `canopen` package (object dictionary from `ecu.eds`, LocalNode with its SDO
server, RemoteNode with its SDO client) but run WITHOUT canopen's can.Notifier thread and without
python-can periodic send tasks: the owner pumps `poll(now_s)` (drain the bus with recv(timeout=0)
and call network.notify) and `tick(now_s)` (heartbeat producer, PDO event timers, timeouts). So the
link steps deterministically in lockstep SIL on a SimClock, and every receive time is the pump's
`now_s`, never a frame's wall-clock timestamp.

What this adds to canopen, and the CANopen choices made:
- Heartbeat consumer with a timeout (canopen has none, its issue #543), `HeartbeatConsumer`.
  The ECU counts the host as alive only while its heartbeat is fresh AND reports OPERATIONAL:
  the host reports PRE-OPERATIONAL while starting up or when its supervisor takes it out of the
  loop, and that must stop the car just like silence. The host counts the ECU as alive on any
  fresh heartbeat and reads its NMT state separately.
- TPDOs carry the object dictionary's values (canopen's LocalNode does not tie TPDO mappings to its
  OD, issue #558): at each event the ECU reads every mapped object through `LocalNode.get_data`
  (so read callbacks and SDO writes are honoured) and packs the frame.
- RPDO1 deadline monitoring (CiA 301 event timer of an RPDO, 0x1400 sub5): a request older than it
  is stale. Requests are also rejected when repeated (same alive counter), out of sequence (counter
  jump > MAX_COUNTER_DELTA), malformed (wrong length), invalid (undefined flag bits) or received
  outside OPERATIONAL; each kind is counted.
- NMT: boot-up then PRE-OPERATIONAL; START/STOP/ENTER PRE-OP from the host; PDOs only in
  OPERATIONAL, SDO and EMCY in PRE-OPERATIONAL and OPERATIONAL, heartbeat always. Deviation: RESET
  NODE acts like RESET COMMUNICATION (communication objects back to EDS defaults, boot-up); the
  application keeps its calibration.
- The status spans TPDO1..3. TPDO1 (state, faults) is sent last in each event, and the host
  publishes a new EcuStatus when TPDO1 arrives, from the latest TPDO2/TPDO3 (TPDO2 repeats the
  status counter so a mixed snapshot is counted).
- SDO writes the ECU refuses get an abort code (CiA 301 table 22) and the reason text in 0x2400.
"""

from __future__ import annotations

import collections
import configparser
import contextlib
import functools
import io
import logging
import math
import queue
import struct
import time
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from importlib import resources
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord, ODVariable, datatypes
from canopen.objectdictionary.datatypes import INTEGER_TYPES
from canopen.sdo import SdoAbortedError, SdoClient, SdoCommunicationError
from canopen.sdo.exceptions import SdoError

from bywire.clock import Clock
from bywire.protocol.ecu_types import Fault
from bywire.protocol.host_link import (
    EMCY_ERROR_RESET,
    REQUEST_FIELDS,
    REQUEST_INDEX,
    STATUS_FIELDS,
    STATUS_INDEX,
    EcuStatus,
    EmcyRecord,
    HostRequest,
    decode_emcy,
    emcy_code_for,
    encode_emcy,
    error_register_for,
)
from bywire.protocol.timebase import data_frame, rx_time_s

log = logging.getLogger(__name__)

EDS_RESOURCE = "ecu.eds"  # package data of bywire.protocol
# Where the packaged EDS lives, for messages and tools; loading goes through importlib.resources,
# because inside the ECU firmware image (a zip) the file is not on disk.
EDS_PATH = Path(str(resources.files("bywire.protocol").joinpath(EDS_RESOURCE)))
ECU_NODE_ID = 0x10
HOST_NODE_ID = 0x01

NMT_COB_ID = 0x000
HEARTBEAT_COB_BASE = 0x700

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
# The host sends 25-100 Hz: a jump of 3 is at most 30 ms of lost requests at 100 Hz, well inside
# the 100 ms deadline. A larger jump is a replayed, restarted or foreign stream: refuse and resync.
MAX_COUNTER_DELTA = 3
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
DEFAULT_MAX_FRAMES_PER_POLL = 256

# SDO abort codes (CiA 301 table 22).
ABORT_OUT_OF_MEMORY = 0x05040005
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_TOO_HIGH = 0x06090031
ABORT_VALUE_TOO_LOW = 0x06090032
ABORT_GENERAL = 0x08000000
ABORT_CANNOT_STORE = 0x08000020
ABORT_LOCAL_CONTROL = 0x08000021
ABORT_DEVICE_STATE = 0x08000022
_SDO_RESPONSE_ABORTED = 0x80
_SDO_ABORT = struct.Struct("<BHBL")


class NmtState(IntEnum):
    """NMT states as carried in heartbeat frames (CiA 301 table 51)."""

    INITIALISING = 0  # the boot-up frame
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


# Heartbeats arrive every few ms on both sides: a dict lookup instead of NmtState(byte)'s enum call.
_NMT_STATES: dict[int, NmtState] = {int(m): m for m in NmtState}
# Read in every cycle: a module constant costs less than the enum class's attribute lookup.
_OPERATIONAL = NmtState.OPERATIONAL
_OPERATIONAL_ONLY = (NmtState.OPERATIONAL,)


class NmtCommand(IntEnum):
    """NMT command specifiers (CiA 301 section 7.2.8.3.1)."""

    START = 1
    STOP = 2
    ENTER_PRE_OPERATIONAL = 128
    RESET_NODE = 129
    RESET_COMMUNICATION = 130


def _us(t_s: float) -> int:
    # Integer microseconds make timer and timeout boundaries exact on a SimClock stepped in ms.
    return round(t_s * 1_000_000)


def parse_heartbeat(data: bytes | bytearray) -> NmtState:
    """Heartbeat data -> NMT state; ValueError for a wrong length or an undefined state."""
    if len(data) != 1:
        raise ValueError(f"heartbeat has {len(data)} data bytes, expected 1")
    state = _NMT_STATES.get(data[0])
    if state is None:
        raise ValueError(f"heartbeat state 0x{data[0]:02X} is not an NMT state")
    return state


class RefusedWrite(Exception):
    """Raised by an ECU write handler (calibration, unlatch) to refuse an SDO write.

    `abort_code` is the SDO abort code sent (default 0x08000020, data cannot be stored); use
    ABORT_DEVICE_STATE (0x08000022) for "not now" (e.g. the E-stop still says DISABLE).
    `reason` goes to object 0x2400 for the host to read.
    """

    def __init__(self, reason: str, abort_code: int = ABORT_CANNOT_STORE) -> None:
        super().__init__(reason)
        self.reason = reason
        self.abort_code = abort_code


# --- object dictionary and PDO layouts ---------------------------------------------------------


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


def _od_var(od: ObjectDictionary, index: int, subindex: int | None = None) -> ODVariable:
    obj = od[index]
    if isinstance(obj, (ODRecord, ODArray)):
        return obj[subindex if subindex is not None else 0]
    return obj


def od_default(od: ObjectDictionary, index: int, subindex: int | None = None) -> Any:
    """The EDS value of an object (ParameterValue, else DefaultValue); ValueError if it has none."""
    try:
        var = _od_var(od, index, subindex)
    except KeyError:
        raise ValueError(f"EDS has no object {_where(index, subindex)}") from None
    value = var.value if var.value is not None else var.default
    if value is None:
        raise ValueError(f"EDS object {_where(index, subindex)} ({var.name}) has no DefaultValue")
    return value


def _where(index: int, subindex: int | None) -> str:
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
                    f"{self.name}: {_where(*entry.key)} holds {len(data)} bytes, mapping says {entry.n_bytes}"
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
        where = _where(map_index, sub)
        try:
            var = _od_var(od, index, subindex)
        except KeyError:
            raise ValueError(f"EDS {where} maps {_where(index, subindex)}, which does not exist") from None
        if var.data_type not in INTEGER_TYPES:
            raise ValueError(f"EDS {where} maps {_where(index, subindex)}, which is not an integer object")
        if bits != len(var) or bits % 8:
            raise ValueError(
                f"EDS {where} maps {_where(index, subindex)} with {bits} bits; only whole objects "
                f"({len(var)} bits) are supported"
            )
        entries.append(PdoEntry(index, subindex, offset, bits // 8, var))
        offset += bits // 8
    if offset > 8:
        raise ValueError(f"EDS {_where(map_index, None)} maps {offset} bytes, a CAN frame holds 8")
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


def _request_layout(od: ObjectDictionary) -> PdoLayout:
    for layout in read_pdo_layouts(od, is_tx=False):
        if {key[0] for key in layout.keys} == {REQUEST_INDEX}:
            wanted = {(REQUEST_INDEX, spec.subindex) for spec in REQUEST_FIELDS}
            if set(layout.keys) != wanted:
                raise ValueError(
                    f"EDS {layout.name} maps {layout.keys}, the host request needs {sorted(wanted)}"
                )
            return layout
    raise ValueError(f"EDS has no RPDO mapping the host request record 0x{REQUEST_INDEX:04X}")


def _status_layouts(od: ObjectDictionary) -> tuple[PdoLayout, ...]:
    """TPDOs mapping the status record, in sending order: the one carrying `state` last."""
    layouts = [t for t in read_pdo_layouts(od, is_tx=True) if any(k[0] == STATUS_INDEX for k in t.keys)]
    mapped = {key for t in layouts for key in t.keys}
    missing = [spec.name for spec in STATUS_FIELDS if (STATUS_INDEX, spec.subindex) not in mapped]
    if missing:
        raise ValueError(f"EDS TPDOs do not map status fields {missing}")
    state_key = (STATUS_INDEX, STATUS_FIELDS[0].subindex)
    return tuple(sorted(layouts, key=lambda t: (state_key in t.keys, t.number)))


# --- timers and the heartbeat consumer ---------------------------------------------------------


class EventTimer:
    """A period on the pump's clock: `due(now_s)` is True once per period, without drift."""

    def __init__(self, period_ms: int) -> None:
        self.period_ms = period_ms
        self._next_us: int | None = None

    @property
    def period_ms(self) -> int:
        return self._period_us // 1000

    @period_ms.setter
    def period_ms(self, period_ms: int) -> None:
        if period_ms < 1:
            raise ValueError(f"event timer period {period_ms} ms must be >= 1 ms")
        self._period_us = period_ms * 1000

    def reset(self) -> None:
        """Make the next `due` fire at once."""
        self._next_us = None

    def next_s(self) -> float:
        """Before this instant `due` is surely False (a microsecond early; -inf: due at once)."""
        return -math.inf if self._next_us is None else (self._next_us - 1) * 1e-6

    def due(self, now_s: float) -> bool:
        next_us = self._next_us
        if next_us is not None and now_s * 1e6 < next_us - 1:
            return False  # clearly not yet: spares the exact integer conversion on most calls
        now_us = _us(now_s)
        if self._next_us is None:
            self._next_us = now_us + self._period_us
            return True
        if now_us < self._next_us:
            return False
        self._next_us += self._period_us
        if self._next_us <= now_us:
            # More than a period behind (pump stalled): resynchronise instead of sending a burst.
            self._next_us = now_us + self._period_us
        return True


class HeartbeatConsumer:
    """Watches one node's heartbeat (CiA 301 section 7.2.8.3.2.2): fresh for timeout_ms after a frame.

    Fresh means `now - last_rx <= timeout`, in integer microseconds: with a 100 ms consumer time a
    heartbeat at t is still fresh at exactly t + 100 ms and stale from t + 100.001 ms.
    """

    def __init__(self, node_id: int, timeout_ms: int) -> None:
        self.node_id = node_id
        self.timeout_ms = timeout_ms
        self.state: NmtState | None = None
        self.last_rx_s: float | None = None
        self.received = 0
        self.rejected = 0  # wrong length or undefined state byte
        self.bootups = 0
        self.timeouts = 0  # fresh -> stale transitions seen by update()
        self._was_fresh = False
        self._last_rx_us = 0

    @property
    def cob_id(self) -> int:
        return HEARTBEAT_COB_BASE + self.node_id

    def on_frame(self, data: bytes | bytearray, now_s: float) -> bool:
        try:
            state = parse_heartbeat(data)
        except ValueError:
            self.rejected += 1
            return False
        self.received += 1
        if state is NmtState.INITIALISING:
            self.bootups += 1
        self.state = state
        self.last_rx_s = now_s
        self._last_rx_us = _us(now_s)
        return True

    def fresh(self, now_s: float) -> bool:
        if self.last_rx_s is None:
            return False
        return _us(now_s) - self._last_rx_us <= self.timeout_ms * 1000

    def alive(self, now_s: float, states: tuple[NmtState, ...] | None = None) -> bool:
        """Fresh, and (if `states` is given) last reporting one of `states`."""
        return self.fresh(now_s) and (states is None or self.state in states)

    def update(self, now_s: float) -> None:
        fresh = self.fresh(now_s)
        if self._was_fresh and not fresh:
            self.timeouts += 1
        self._was_fresh = fresh


@dataclass
class RequestStats:
    """What happened to each RPDO1 frame the ECU saw (every frame counts once in `received`)."""

    received: int = 0
    accepted: int = 0
    repeated: int = 0  # alive counter did not advance
    out_of_sequence: int = 0  # alive counter jumped by more than MAX_COUNTER_DELTA (or went back)
    malformed: int = 0  # wrong data length
    invalid: int = 0  # undefined flag bits
    not_operational: int = 0  # arrived while the ECU was not OPERATIONAL (CiA 301: not processed)
    lost: int = 0  # requests skipped inside accepted counter jumps
    deadline_misses: int = 0  # fresh -> stale transitions of the latest request (seen by tick)

    @property
    def rejected(self) -> int:
        return self.repeated + self.out_of_sequence + self.malformed + self.invalid + self.not_operational


@dataclass
class StatusStats:
    """What happened to each status TPDO frame the host saw."""

    received: int = 0
    accepted: int = 0  # EcuStatus snapshots published
    malformed: int = 0  # wrong data length
    invalid: int = 0  # undefined state or fault bits
    incomplete: int = 0  # TPDO1 before every other status TPDO was seen once
    incoherent: int = 0  # snapshot mixes status counters (published anyway)

    @property
    def rejected(self) -> int:
        return self.malformed + self.invalid + self.incomplete


def _drain(
    bus: can.BusABC,
    network: canopen.Network,
    first_timeout_s: float,
    max_frames: int,
    now_s: float | None = None,
) -> tuple[int, int]:
    """Feed up to max_frames frames from the bus to the network; returns (frames, handler errors).

    With `now_s`, each handler gets the frame's receive time on the clock of `now_s` (the bus's
    stamp, never later than `now_s`), so a frame that waited in the queue while the owner stalled is
    judged by when it arrived, not by when it was polled."""
    frames = errors = 0
    timeout = first_timeout_s
    while frames < max_frames:
        msg = bus.recv(timeout=timeout)
        timeout = 0.0
        if msg is None:
            break
        frames += 1
        # CANopen speaks 11-bit data frames; 29-bit ids with the same number belong to someone else.
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            continue
        if now_s is None:
            stamp = msg.timestamp
        else:
            stamp = rx_time_s(msg, now_s)
            if not stamp <= now_s:  # a stamp from the future (or NaN) cannot be trusted
                stamp = now_s
        try:
            network.notify(msg.arbitration_id, msg.data, stamp)
        except Exception:
            # A handler bug must not stop the cyclic executive: counted and logged, frame dropped.
            errors += 1
            log.exception(
                "CANopen handler failed on frame 0x%03X %s", msg.arbitration_id, bytes(msg.data).hex()
            )
    return frames, errors


def _send_frame(network: canopen.Network, cob_id: int, data: bytes) -> None:
    """`network.send_message(cob_id, data)` without its generic parts: an 11-bit data frame,
    under the network's send lock; there is no Notifier thread whose error `check` could raise."""
    msg = data_frame(cob_id, bytearray(data))
    bus = network.bus
    assert bus is not None, "a CANopen network without a bus"
    with network.send_lock:
        bus.send(msg)


def _network_without_threads(bus: can.BusABC) -> canopen.Network:
    network = canopen.Network(bus)  # no connect(): no can.Notifier thread
    # LSS is not used; its handler queues every 0x7E4 frame forever.
    network.unsubscribe(network.lss.LSS_RX_COBID)
    return network


# --- the ECU side ------------------------------------------------------------------------------


class EcuNode:
    """The ECU's CANopen node, stepped by the cyclic executive.

    Per cycle: `poll(now_s)` first (requests, host heartbeat, NMT, SDO), then the control step,
    then `publish_status(status, now_s)` and `tick(now_s)` (heartbeat, TPDO events, timeouts).
    The node boots (boot-up frame, PRE-OPERATIONAL) in the constructor; the host starts it.
    """

    def __init__(
        self,
        bus: can.BusABC,
        clock: Clock,
        node_id: int = ECU_NODE_ID,
        host_node_id: int = HOST_NODE_ID,
        on_calibration_write: Callable[[bytes], int | None] | None = None,
        on_unlatch: Callable[[], None] | None = None,
        *,
        actuating: Callable[[], str | None] | None = None,
        eds_path: str | Path | None = None,
        max_frames_per_poll: int = DEFAULT_MAX_FRAMES_PER_POLL,
    ) -> None:
        self._bus = bus
        self._clock = clock
        self.node_id = node_id
        self.host_node_id = host_node_id
        self._on_calibration_write = on_calibration_write
        self._on_unlatch = on_unlatch
        # The application's state name while it actuates (writes to watchdog times are refused
        # then), None while it does not.
        self._actuating = actuating
        self._eds_path = Path(eds_path) if eds_path is not None else EDS_PATH
        self._max_frames = max_frames_per_poll
        self.od = load_ecu_od(node_id, eds_path)
        self._packers: dict[tuple[int, int], Callable[[Any], bytes]] = {}
        self.rpdo = _request_layout(self.od)
        self.tpdos = _status_layouts(self.od)
        self._request_keys = tuple(((REQUEST_INDEX, spec.subindex), spec.name) for spec in REQUEST_FIELDS)
        self._status_keys = tuple((spec.subindex, spec.name) for spec in STATUS_FIELDS)
        self.emcy_cob_id = int(od_default(self.od, EMCY_COB_INDEX))

        self.network = _network_without_threads(bus)
        self.node = canopen.LocalNode(node_id, self.od)
        self.network[node_id] = self.node  # associates the node with the network
        # canopen's NMT slave would start a python-can periodic thread for the heartbeat (on boot
        # and on 0x1017 writes), and its NMT/SDO handlers raise on short frames: replace them.
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.network.unsubscribe(NMT_COB_ID, self.node.nmt.on_command)
        self.network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        self.node.add_write_callback(self._on_sdo_write)  # type: ignore[no-untyped-call]  # canopen untyped
        self.network.subscribe(NMT_COB_ID, self._on_nmt)
        self.network.subscribe(self.node.sdo.rx_cobid, self._on_sdo_request)
        self.network.subscribe(self.rpdo.cob_id, self._on_rpdo)

        self.request_stats = RequestStats()
        self.nmt_rejected = 0
        self.sdo_rejected = 0
        self.dispatch_errors = 0
        self._latest: tuple[HostRequest, float] | None = None
        self._latest_us = 0
        self._last_counter: int | None = None
        self._request_was_fresh = False
        self._reported_faults = Fault.NONE
        self._rx_now_s = clock.now()
        self._rx_frames = 0  # frames polled so far
        self._quiet_until_s = -math.inf  # `tick` has nothing to do before then (without new frames)
        self._quiet_rx_frames = 0
        self._nmt_state = NmtState.INITIALISING
        self.host_heartbeat = HeartbeatConsumer(host_node_id, 0)
        self._load_communication_parameters()
        self.network.subscribe(self.host_heartbeat.cob_id, self._on_host_heartbeat)
        self._store(REFUSAL_INDEX, 0, "none")
        self._boot()

    # -- communication parameters (EDS defaults, changed by SDO writes) --

    def _load_communication_parameters(self) -> None:
        for index in list(self.node.data_store):
            if 0x1000 <= index <= 0x1FFF:
                del self.node.data_store[index]
        producer_ms = int(od_default(self.od, PRODUCER_HEARTBEAT_INDEX))
        consumer = int(od_default(self.od, CONSUMER_HEARTBEAT_INDEX, 1))
        node, timeout_ms = (consumer >> 16) & 0xFF, consumer & 0xFFFF
        if node != self.host_node_id:
            raise ValueError(
                f"{self._eds_path}: 0x1016sub1 = 0x{consumer:08X} must watch host node "
                f"0x{self.host_node_id:02X}"
            )
        # The EDS's defaults obey the same bounds as an SDO write: a configuration cannot start the
        # ECU with a watchdog the firmware would refuse.
        defaults = [
            (producer_ms, "producer heartbeat time", "0x1017"),
            (timeout_ms, "consumer heartbeat time", "0x1016sub1"),
            (
                self.rpdo.event_timer_ms,
                "request deadline",
                f"0x{RPDO_COMM_BASE + self.rpdo.number - 1:04X}sub5",
            ),
        ]
        defaults += [
            (t.event_timer_ms, "TPDO event timer", f"0x{TPDO_COMM_BASE + t.number - 1:04X}sub5")
            for t in self.tpdos
        ]
        for value_ms, what, where in defaults:
            try:
                _check_time(value_ms, what, "switch it off")
            except RefusedWrite as exc:
                raise ValueError(f"{self._eds_path}: {where} default: {exc.reason}") from None
        self._hb_timer = EventTimer(producer_ms)
        self.host_heartbeat.timeout_ms = timeout_ms
        self.request_deadline_ms = self.rpdo.event_timer_ms
        self._tpdo_timers = {t.number: EventTimer(t.event_timer_ms) for t in self.tpdos}

    def _boot(self) -> None:
        self._send(HEARTBEAT_COB_BASE + self.node_id, b"\x00")
        self._set_state(NmtState.PRE_OPERATIONAL)
        self._hb_timer.reset()

    # -- public API --

    @property
    def nmt_state(self) -> NmtState:
        return self._nmt_state

    def poll(self, now_s: float | None = None) -> int:
        """Drain the bus (up to max_frames_per_poll frames) and handle each; returns frames read."""
        self._rx_now_s = now = self._clock.now() if now_s is None else now_s
        frames, errors = _drain(self._bus, self.network, 0.0, self._max_frames, now)
        self.dispatch_errors += errors
        self._rx_frames += frames
        return frames

    def tick(self, now_s: float | None = None) -> None:
        """Heartbeat producer, TPDO event timers, and the timeout counters."""
        now = self._clock.now() if now_s is None else now_s
        if now < self._quiet_until_s and self._rx_frames == self._quiet_rx_frames:
            return  # no timer due, nothing expiring, no frame since the last full tick
        if self._hb_timer.due(now):
            self._send(HEARTBEAT_COB_BASE + self.node_id, bytes([self._nmt_state]))
        self.host_heartbeat.update(now)
        fresh = self.request_fresh(now)
        if self._request_was_fresh and not fresh:
            self.request_stats.deadline_misses += 1
        self._request_was_fresh = fresh
        self._service_tpdos(now)
        quiet = min(self._hb_timer.next_s(), self.freshness_horizon_s(now))
        if self._nmt_state is _OPERATIONAL:
            for timer in self._tpdo_timers.values():
                quiet = min(quiet, timer.next_s())
        self._quiet_until_s = quiet
        self._quiet_rx_frames = self._rx_frames

    def latest_request(self) -> tuple[HostRequest, float] | None:
        """The last accepted host request and its receive time (None after boot / leaving OPERATIONAL)."""
        return self._latest

    def request_fresh(self, now_s: float) -> bool:
        """A request was accepted within the RPDO1 deadline (0x1400 sub5, default 100 ms)."""
        if self._latest is None:
            return False
        return _us(now_s) - self._latest_us <= self.request_deadline_ms * 1000

    def host_alive(self, now_s: float) -> bool:
        """Host heartbeat fresh within 0x1016's time AND the host reports OPERATIONAL."""
        return self.host_heartbeat.alive(now_s, _OPERATIONAL_ONLY)

    def freshness_horizon_s(self, now_s: float) -> float:
        """Until when (without new frames) `host_alive` and `request_fresh` keep their value at
        `now_s`: the earliest expiry of what is fresh now, a microsecond early (inf: nothing
        fresh, nothing to expire)."""
        horizon = math.inf
        hb = self.host_heartbeat
        if hb.fresh(now_s):
            horizon = (hb._last_rx_us + hb.timeout_ms * 1000 - 1) * 1e-6
        if self.request_fresh(now_s):
            horizon = min(horizon, (self._latest_us + self.request_deadline_ms * 1000 - 1) * 1e-6)
        return horizon

    def publish_status(self, status: EcuStatus, now_s: float | None = None) -> None:
        """Write the status record (0x2100) and error register (0x1001) into the OD; send due TPDOs."""
        now = self._clock.now() if now_s is None else now_s
        raw = status.to_raw()
        for subindex, name in self._status_keys:
            self._store(STATUS_INDEX, subindex, raw[name])
        self._store(ERROR_REGISTER_INDEX, 0, error_register_for(status.faults))
        self._service_tpdos(now)

    def emcy(self, error_code: int, fault_bits: Fault) -> bool:
        """Send one EMCY (code, error register from fault_bits, fault bits); False if NMT forbids it."""
        register = error_register_for(fault_bits)
        self._store(ERROR_REGISTER_INDEX, 0, register)
        if self._nmt_state not in (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL):
            return False
        if self.emcy_cob_id & PDO_NOT_VALID:
            return False
        self._send(self.emcy_cob_id & 0x7FF, encode_emcy(EmcyRecord(error_code, register, fault_bits)))
        return True

    def report_faults(self, faults: Fault) -> bool:
        """EMCY for newly set fault bits (code of the lowest new bit), error reset when all clear."""
        new = faults & ~self._reported_faults
        sent = False
        if new:
            sent = self.emcy(emcy_code_for(new), faults)
        elif not faults and self._reported_faults:
            sent = self.emcy(EMCY_ERROR_RESET, Fault.NONE)
        self._reported_faults = faults
        return sent

    def set_calibration(self, blob: bytes, version: int) -> None:
        """Publish the active calibration in 0x2200 (at boot; SDO writes update it themselves)."""
        self._store(CALIBRATION_INDEX, CALIBRATION_BLOB_SUB, bytes(blob))
        self._store(CALIBRATION_INDEX, CALIBRATION_CRC_SUB, zlib.crc32(blob))
        self._store(CALIBRATION_INDEX, CALIBRATION_VERSION_SUB, version)

    # -- handlers (called from network.notify inside poll) --

    def _on_nmt(self, can_id: int, data: bytes | bytearray, timestamp: float) -> None:
        if len(data) != 2:
            self.nmt_rejected += 1
            return
        command, target = data[0], data[1]
        if target not in (0, self.node_id):
            return
        try:
            cmd = NmtCommand(command)
        except ValueError:
            self.nmt_rejected += 1
            return
        if cmd is NmtCommand.START:
            self._set_state(NmtState.OPERATIONAL)
        elif cmd is NmtCommand.STOP:
            self._set_state(NmtState.STOPPED)
        elif cmd is NmtCommand.ENTER_PRE_OPERATIONAL:
            self._set_state(NmtState.PRE_OPERATIONAL)
        else:
            self._set_state(NmtState.INITIALISING)
            self._load_communication_parameters()
            self._boot()

    def _on_host_heartbeat(self, can_id: int, data: bytes | bytearray, timestamp: float) -> None:
        # Judged by its receive time: a heartbeat queued during a stall is as old as it is.
        self.host_heartbeat.on_frame(data, timestamp)

    def _on_rpdo(self, can_id: int, data: bytes | bytearray, timestamp: float) -> None:
        stats = self.request_stats
        stats.received += 1
        if self._nmt_state is not NmtState.OPERATIONAL:
            stats.not_operational += 1
            return
        try:
            values = self.rpdo.decode(data)
        except ValueError:
            stats.malformed += 1
            return
        raw = {name: values[key] for key, name in self._request_keys}
        try:
            request = HostRequest.from_raw(raw)
        except ValueError:
            stats.invalid += 1
            return
        if self._last_counter is not None:
            delta = (request.counter - self._last_counter) % 256
            if delta == 0:
                stats.repeated += 1
                return
            if delta > MAX_COUNTER_DELTA:
                stats.out_of_sequence += 1
                self._last_counter = request.counter
                return
            stats.lost += delta - 1
        self._last_counter = request.counter
        stats.accepted += 1
        self._latest = (request, timestamp)
        self._latest_us = _us(timestamp)
        for (index, subindex), name in self._request_keys:
            self._store(index, subindex, raw[name])

    def _on_sdo_request(self, can_id: int, data: bytes | bytearray, timestamp: float) -> None:
        if self._nmt_state not in (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL):
            return
        if len(data) != 8:
            self.sdo_rejected += 1
            return
        command = data[0]
        index, subindex = struct.unpack_from("<HB", data, 1)
        # Initiate segmented download with size: refuse an oversized calibration before it arrives.
        if command & 0xE3 == 0x21 and (index, subindex) == (CALIBRATION_INDEX, CALIBRATION_BLOB_SUB):
            (size,) = struct.unpack_from("<L", data, 4)
            if size > MAX_CALIBRATION_BYTES:
                self._note_refusal(f"calibration of {size} bytes exceeds {MAX_CALIBRATION_BYTES} bytes")
                self._send(
                    self.node.sdo.tx_cobid,
                    _SDO_ABORT.pack(_SDO_RESPONSE_ABORTED, index, subindex, ABORT_OUT_OF_MEMORY),
                )
                return
        try:
            self.node.sdo.on_request(can_id, data, timestamp)  # type: ignore[no-untyped-call]
        except Exception as exc:
            # canopen's server raises from its own abort path when a segment arrives with no
            # transfer open (its index is still None): answer with a general abort instead.
            self.sdo_rejected += 1
            log.debug("SDO request %s failed in the server: %r", bytes(data).hex(), exc)
            self._send(
                self.node.sdo.tx_cobid, _SDO_ABORT.pack(_SDO_RESPONSE_ABORTED, index, subindex, ABORT_GENERAL)
            )

    def _on_sdo_write(self, index: int, subindex: int, od: ODVariable, data: bytes, **_: Any) -> None:
        try:
            self._check_write(index, subindex, bytes(data))
        except RefusedWrite as exc:
            self._note_refusal(exc.reason)
            raise SdoAbortedError(exc.abort_code) from exc

    def _check_write(self, index: int, subindex: int, data: bytes) -> None:
        if index == PRODUCER_HEARTBEAT_INDEX:
            (period_ms,) = struct.unpack("<H", data)
            _check_time(period_ms, "producer heartbeat time", "silence the ECU heartbeat")
            self._check_not_actuating("producer heartbeat time")
            self._hb_timer.period_ms = period_ms
        elif index == CONSUMER_HEARTBEAT_INDEX and subindex == 1:
            (word,) = struct.unpack("<L", data)
            node, timeout_ms = (word >> 16) & 0xFF, word & 0xFFFF
            if word >> 24 or node != self.host_node_id:
                raise RefusedWrite(
                    f"consumer heartbeat must watch host node 0x{self.host_node_id:02X}, got 0x{word:08X}",
                    ABORT_VALUE_RANGE,
                )
            _check_time(timeout_ms, "consumer heartbeat time", "switch the host watchdog off")
            self._check_not_actuating("consumer heartbeat time")
            self.host_heartbeat.timeout_ms = timeout_ms
        elif index == RPDO_COMM_BASE + self.rpdo.number - 1 and subindex == PDO_EVENT_TIMER_SUB:
            (deadline_ms,) = struct.unpack("<H", data)
            _check_time(deadline_ms, "request deadline", "switch request monitoring off")
            self._check_not_actuating("request deadline")
            self.request_deadline_ms = deadline_ms
        elif TPDO_COMM_BASE <= index < TPDO_MAP_BASE and subindex == PDO_EVENT_TIMER_SUB:
            (period_ms,) = struct.unpack("<H", data)
            _check_time(period_ms, "TPDO event timer", "stop the status")
            self._check_not_actuating("TPDO event timer")
            number = index - TPDO_COMM_BASE + 1
            if number in self._tpdo_timers:
                self._tpdo_timers[number].period_ms = period_ms
        elif index == REQUEST_INDEX:
            raise RefusedWrite(
                "the host request is written by RPDO only (SDO would bypass its alive counter)",
                ABORT_LOCAL_CONTROL,
            )
        elif (index, subindex) == (CALIBRATION_INDEX, CALIBRATION_BLOB_SUB):
            self._write_calibration(data)
        elif (index, subindex) == (COMMAND_INDEX, UNLATCH_SUB):
            self._unlatch(data)

    def _check_not_actuating(self, what: str) -> None:
        state = self._actuating() if self._actuating is not None else None
        if state is not None:
            raise RefusedWrite(
                f"{what} cannot change while the ECU actuates ({state}): a watchdog's time is "
                "set before engaging, never during",
                ABORT_DEVICE_STATE,
            )

    def _write_calibration(self, data: bytes) -> None:
        if len(data) > MAX_CALIBRATION_BYTES:
            raise RefusedWrite(
                f"calibration of {len(data)} bytes exceeds {MAX_CALIBRATION_BYTES} bytes", ABORT_OUT_OF_MEMORY
            )
        if self._on_calibration_write is None:
            raise RefusedWrite("this ECU node has no calibration handler", ABORT_LOCAL_CONTROL)
        version = _call_handler(self._on_calibration_write, data, what="calibration")
        self._store(CALIBRATION_INDEX, CALIBRATION_CRC_SUB, zlib.crc32(data))
        if isinstance(version, int):
            self._store(CALIBRATION_INDEX, CALIBRATION_VERSION_SUB, version)

    def _unlatch(self, data: bytes) -> None:
        if data[0] != 1:
            raise RefusedWrite(
                f"write 1 to unlatch an E-stop DISABLE; {data[0]} means nothing", ABORT_VALUE_RANGE
            )
        if self._on_unlatch is None:
            raise RefusedWrite("this ECU node has no unlatch handler", ABORT_LOCAL_CONTROL)
        handler = self._on_unlatch
        _call_handler(lambda _: handler(), data, what="unlatch")

    # -- helpers --

    def _set_state(self, state: NmtState) -> None:
        old, self._nmt_state = self._nmt_state, state
        self._quiet_until_s = -math.inf  # timers restart: the next tick does everything
        if old is NmtState.OPERATIONAL and state is not NmtState.OPERATIONAL:
            # Requests are processed only in OPERATIONAL: forget the last one and resync counters.
            self._latest = None
            self._last_counter = None
        if state is NmtState.OPERATIONAL and old is not NmtState.OPERATIONAL:
            for timer in self._tpdo_timers.values():
                timer.reset()

    def _service_tpdos(self, now_s: float) -> None:
        if self._nmt_state is not _OPERATIONAL:
            return
        for layout in self.tpdos:
            if self._tpdo_timers[layout.number].due(now_s):
                # Read through the OD at transmit time (the canopen #558 gap). Without read
                # callbacks that is the data store, else canopen's own lookup (EDS value, default).
                node = self.node
                store = None if node._read_callbacks else node.data_store
                data = {}
                for key in layout.keys:
                    stored = store.get(key[0]) if store is not None else None
                    raw = stored.get(key[1]) if stored is not None else None
                    data[key] = raw if raw is not None else node.get_data(*key)
                self._send(layout.cob_id, layout.pack(data))

    def _store(self, index: int, subindex: int, value: int | str | bytes) -> None:
        # Straight into the data store: internal updates must not run the SDO write checks.
        # The status record is stored every 20 ms: resolve each object once.
        key = (index, subindex)
        pack = self._packers.get(key)
        if pack is None:
            pack = self._packers[key] = _raw_encoder(_od_var(self.od, index, subindex))
        self.node.data_store.setdefault(index, {})[subindex] = pack(value)

    def _note_refusal(self, reason: str) -> None:
        log.warning("ECU node 0x%02X refused an SDO write: %s", self.node_id, reason)
        text = reason.encode("ascii", "replace").decode("ascii")[:MAX_REFUSAL_CHARS] or "refused"
        self._store(REFUSAL_INDEX, 0, text)

    def _send(self, cob_id: int, data: bytes) -> None:
        if cob_id > 0x7FF:  # not ours to shortcut (canopen sends it as a 29-bit frame)
            self.network.send_message(cob_id, data)
        else:
            _send_frame(self.network, cob_id, data)


def _raw_encoder(var: ODVariable) -> Callable[[Any], bytes]:
    """`bytes(var.encode_raw(value))` as one function per object. For an integer object without
    limits (the status record, the request record, the error register) that is canopen's own
    struct packer on int(value); anything else goes through canopen."""
    packer = var.STRUCT_TYPES.get(var.data_type) if var.data_type in INTEGER_TYPES else None
    if packer is None or var.min is not None or var.max is not None:
        return lambda value: bytes(var.encode_raw(value))
    pack = packer.pack

    def encode(value: Any) -> bytes:
        if isinstance(value, (bytes, bytearray)):
            return bytes(value)
        try:
            return pack(int(value))
        except struct.error:
            raise ValueError("Value does not fit in specified type") from None

    return encode


# The bound of each bounded time, by the name `_check_time` is given.
_TIME_BOUNDS_MS = {
    "producer heartbeat time": MAX_PRODUCER_HEARTBEAT_MS,
    "consumer heartbeat time": MAX_HOST_HEARTBEAT_TIMEOUT_MS,
    "request deadline": MAX_REQUEST_DEADLINE_MS,
    "TPDO event timer": MAX_TPDO_EVENT_TIMER_MS,
}


def _check_time(value_ms: int, what: str, zero_would: str) -> None:
    """A watchdog time within 1 .. its firmware bound, else the CiA 301 abort for too low / too high."""
    if value_ms == 0:
        raise RefusedWrite(f"{what} 0 would {zero_would}", ABORT_VALUE_TOO_LOW)
    bound = _TIME_BOUNDS_MS[what]
    if value_ms > bound:
        raise RefusedWrite(
            f"{what} {value_ms} ms exceeds the firmware's bound of {bound} ms", ABORT_VALUE_TOO_HIGH
        )


def _call_handler(handler: Callable[[bytes], Any], data: bytes, what: str) -> Any:
    try:
        return handler(data)
    except RefusedWrite:
        raise
    except (ValueError, KeyError, TypeError) as exc:
        raise RefusedWrite(f"{what} rejected: {exc}", ABORT_CANNOT_STORE) from exc
    except Exception as exc:
        log.exception("%s handler failed", what)
        raise RefusedWrite(f"{what} handler failed: {exc!r}", ABORT_GENERAL) from exc


# --- the host side ------------------------------------------------------------------------------


class EcuRefusedError(RuntimeError):
    """The ECU answered an SDO request with an abort; carries the abort code and the ECU's reason."""

    def __init__(self, what: str, index: int, subindex: int, abort_code: int, reason: str) -> None:
        text = SdoAbortedError.CODES.get(abort_code, "unknown abort code")
        super().__init__(
            f"ECU refused {what} ({_where(index, subindex)}): SDO abort 0x{abort_code:08X} ({text})"
            + (f": {reason}" if reason else "")
        )
        self.index = index
        self.subindex = subindex
        self.abort_code = abort_code
        self.reason = reason


@dataclass(frozen=True)
class ReceivedEmcy:
    """An EMCY of the ECU and when the host pump saw it."""

    record: EmcyRecord
    rx_s: float


class _PumpedSdoClient(SdoClient):
    """canopen's SDO client, waiting for replies by pumping the bus itself (no Notifier thread)."""

    def __init__(
        self, rx_cobid: int, tx_cobid: int, od: ObjectDictionary, pump: Callable[[], None], timeout_s: float
    ) -> None:
        super().__init__(rx_cobid, tx_cobid, od)  # type: ignore[no-untyped-call]
        self._pump = pump
        self.RESPONSE_TIMEOUT = timeout_s

    def read_response(self) -> bytes:
        deadline = time.monotonic() + self.RESPONSE_TIMEOUT
        while True:
            try:
                response = self.responses.get_nowait()
            except queue.Empty:
                if time.monotonic() >= deadline:
                    raise SdoCommunicationError(f"no SDO response within {self.RESPONSE_TIMEOUT} s") from None
                self._pump()
                continue
            if len(response) != 8:
                continue  # not an SDO frame: ignore, keep waiting
            if response[0] == _SDO_RESPONSE_ABORTED:
                (abort_code,) = struct.unpack_from("<L", response, 4)
                raise SdoAbortedError(abort_code)
            return bytes(response)


class HostMaster:
    """The host's end of the link: requests out, status / heartbeat / EMCY in, NMT and SDO tools.

    Per cycle: `poll(now_s)` (latest EcuStatus), `send_request(request)`, `tick(now_s)`.
    The host's own heartbeat reports `nmt_state`, PRE-OPERATIONAL until `set_nmt_state(OPERATIONAL)`:
    the ECU treats anything but an OPERATIONAL host heartbeat as a lost host.
    """

    def __init__(
        self,
        bus: can.BusABC,
        clock: Clock,
        ecu_node_id: int = ECU_NODE_ID,
        node_id: int = HOST_NODE_ID,
        *,
        heartbeat_period_s: float = 0.02,
        ecu_timeout_s: float = 0.1,
        sdo_timeout_s: float = 1.0,
        eds_path: str | Path | None = None,
        max_frames_per_poll: int = DEFAULT_MAX_FRAMES_PER_POLL,
        max_emcys: int = 1000,
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"host node id {node_id} is outside 1..127")
        period_ms = round(heartbeat_period_s * 1000)
        timeout_ms = round(ecu_timeout_s * 1000)
        if not 1 <= period_ms <= 0xFFFF or not 1 <= timeout_ms <= 0xFFFF:
            raise ValueError(
                f"heartbeat period {heartbeat_period_s} s / ECU timeout {ecu_timeout_s} s "
                "must be 1 ms .. 65.535 s"
            )
        self._bus = bus
        self._clock = clock
        self.node_id = node_id
        self.ecu_node_id = ecu_node_id
        self._max_frames = max_frames_per_poll
        self.od = load_ecu_od(ecu_node_id, eds_path)
        self.rpdo = _request_layout(self.od)
        self.tpdos = _status_layouts(self.od)
        self._commit_tpdo = self.tpdos[-1].number

        self.network = _network_without_threads(bus)
        self.node = canopen.RemoteNode(ecu_node_id, self.od)
        sdo_rx = int(od_default(self.od, SDO_SERVER_INDEX, 1))
        sdo_tx = int(od_default(self.od, SDO_SERVER_INDEX, 2))
        self._sdo = _PumpedSdoClient(sdo_rx, sdo_tx, self.od, self._pump_for_sdo, sdo_timeout_s)
        self.node.sdo = self._sdo
        self.node.sdo_channels = [self._sdo]
        self.network.add_node(self.node)
        # canopen's heartbeat/EMCY/NMT handlers raise on short frames; ours count them instead.
        self.network.unsubscribe(HEARTBEAT_COB_BASE + ecu_node_id, self.node.nmt.on_heartbeat)
        self.network.unsubscribe(0x80 + ecu_node_id, self.node.emcy.on_emcy)
        self.network.unsubscribe(NMT_COB_ID, self.node.nmt.on_command)

        self.ecu_heartbeat = HeartbeatConsumer(ecu_node_id, timeout_ms)
        self.network.subscribe(self.ecu_heartbeat.cob_id, self._on_ecu_heartbeat)
        self.emcy_cob_id = int(od_default(self.od, EMCY_COB_INDEX)) & 0x7FF
        self.network.subscribe(self.emcy_cob_id, self._on_emcy)
        for layout in self.tpdos:
            self.network.subscribe(layout.cob_id, self._tpdo_handler(layout))

        self.status_stats = StatusStats()
        self.emcy_rejected = 0
        self.dispatch_errors = 0
        self.emcys: collections.deque[ReceivedEmcy] = collections.deque(maxlen=max_emcys)
        self._status_values: dict[tuple[int, int], int] = {}
        self._tpdos_seen: set[int] = set()
        self._tpdo_counter: dict[int, int] = {}
        self._latest: tuple[EcuStatus, float] | None = None
        self._rx_now_s = clock.now()
        self._sdo_idle: Callable[[], object] | None = None
        self._hb_timer = EventTimer(period_ms)
        self._nmt_state = NmtState.PRE_OPERATIONAL
        self._send(HEARTBEAT_COB_BASE + node_id, b"\x00")  # boot-up

    # -- cyclic API --

    @property
    def nmt_state(self) -> NmtState:
        """The state this host reports in its heartbeat."""
        return self._nmt_state

    def set_nmt_state(self, state: NmtState) -> None:
        """OPERATIONAL: in control (the ECU may engage); PRE-OPERATIONAL / STOPPED: out of the loop."""
        if state is NmtState.INITIALISING:
            raise ValueError("the host cannot report INITIALISING except in its boot-up frame")
        self._nmt_state = state

    def poll(self, now_s: float | None = None) -> tuple[EcuStatus, float] | None:
        """Drain the bus; returns the latest EcuStatus and its receive time (None before the first)."""
        self._rx_now_s = self._clock.now() if now_s is None else now_s
        _, errors = _drain(self._bus, self.network, 0.0, self._max_frames)
        self.dispatch_errors += errors
        return self._latest

    def latest_status(self) -> tuple[EcuStatus, float] | None:
        return self._latest

    def tick(self, now_s: float | None = None) -> None:
        """The host heartbeat producer and the ECU heartbeat timeout counter."""
        now = self._clock.now() if now_s is None else now_s
        if self._hb_timer.due(now):
            self._send(HEARTBEAT_COB_BASE + self.node_id, bytes([self._nmt_state]))
        self.ecu_heartbeat.update(now)

    def send_request(self, request: HostRequest) -> None:
        """Send the request as the ECU's RPDO1."""
        raw = request.to_raw()
        self._send(
            self.rpdo.cob_id,
            self.rpdo.encode({(REQUEST_INDEX, spec.subindex): raw[spec.name] for spec in REQUEST_FIELDS}),
        )

    def ecu_alive(self, now_s: float) -> bool:
        """The ECU heartbeat is fresh (any NMT state; see ecu_nmt_state)."""
        return self.ecu_heartbeat.fresh(now_s)

    def ecu_nmt_state(self, now_s: float) -> NmtState | None:
        """The ECU's NMT state from its fresh heartbeat; None when the heartbeat is stale."""
        return self.ecu_heartbeat.state if self.ecu_heartbeat.fresh(now_s) else None

    def pop_emcys(self) -> list[ReceivedEmcy]:
        """EMCYs received since the last call, oldest first."""
        out = list(self.emcys)
        self.emcys.clear()
        return out

    # -- NMT master --

    def send_nmt(self, command: NmtCommand) -> None:
        self._send(NMT_COB_ID, bytes([command, self.ecu_node_id]))

    def start_ecu(self) -> None:
        self.send_nmt(NmtCommand.START)

    def stop_ecu(self) -> None:
        self.send_nmt(NmtCommand.STOP)

    def enter_pre_operational_ecu(self) -> None:
        self.send_nmt(NmtCommand.ENTER_PRE_OPERATIONAL)

    def reset_ecu_communication(self) -> None:
        self.send_nmt(NmtCommand.RESET_COMMUNICATION)

    # -- blocking SDO tools (wall-clock timeout; `idle` runs between bus polls, e.g. the ECU's pump
    # when both ends share one process) --

    def sdo_read(
        self, index: int, subindex: int, *, what: str = "a read", idle: Callable[[], object] | None = None
    ) -> bytes:
        return bytes(self._sdo_call(lambda: self._sdo.upload(index, subindex), index, subindex, what, idle))

    def sdo_write(
        self,
        index: int,
        subindex: int,
        data: bytes,
        *,
        what: str = "a write",
        idle: Callable[[], object] | None = None,
    ) -> None:
        self._sdo_call(lambda: self._sdo.download(index, subindex, bytes(data)), index, subindex, what, idle)

    def read_calibration(self, idle: Callable[[], object] | None = None) -> bytes:
        """The ECU's active calibration file bytes (0x2200 sub3)."""
        return self.sdo_read(CALIBRATION_INDEX, CALIBRATION_BLOB_SUB, what="calibration upload", idle=idle)

    def write_calibration(self, data: bytes, idle: Callable[[], object] | None = None) -> None:
        """Download a calibration file; EcuRefusedError (with the ECU's reason) when it is refused."""
        self.sdo_write(CALIBRATION_INDEX, CALIBRATION_BLOB_SUB, data, what="calibration download", idle=idle)

    def calibration_info(self, idle: Callable[[], object] | None = None) -> tuple[int, int]:
        """(version, crc32) of the ECU's active calibration."""
        version = self.sdo_read(
            CALIBRATION_INDEX, CALIBRATION_VERSION_SUB, what="calibration version", idle=idle
        )
        crc = self.sdo_read(CALIBRATION_INDEX, CALIBRATION_CRC_SUB, what="calibration CRC", idle=idle)
        return int.from_bytes(version, "little"), int.from_bytes(crc, "little")

    def unlatch(self, idle: Callable[[], object] | None = None) -> None:
        """The manual unlatch of an E-stop DISABLE (write 1 to 0x2300 sub1)."""
        self.sdo_write(COMMAND_INDEX, UNLATCH_SUB, b"\x01", what="unlatch", idle=idle)

    def last_refusal(self, idle: Callable[[], object] | None = None) -> str:
        """Why the ECU last refused an SDO write (0x2400)."""
        return self.sdo_read(REFUSAL_INDEX, 0, what="last refusal", idle=idle).decode("ascii", "replace")

    # -- internals --

    def _sdo_call(
        self, call: Callable[[], Any], index: int, subindex: int, what: str, idle: Callable[[], object] | None
    ) -> Any:
        self._sdo_idle = idle
        try:
            try:
                return call()
            except SdoAbortedError as exc:
                reason = ""
                if (index, subindex) != (REFUSAL_INDEX, 0):
                    with contextlib.suppress(SdoError):
                        reason = self._sdo.upload(REFUSAL_INDEX, 0).decode("ascii", "replace")
                raise EcuRefusedError(what, index, subindex, exc.code, reason) from exc
        finally:
            self._sdo_idle = None

    def _pump_for_sdo(self) -> None:
        self._rx_now_s = self._clock.now()
        # Block briefly on the bus unless something else (the in-process ECU) must run meanwhile.
        _, errors = _drain(self._bus, self.network, 0.0 if self._sdo_idle else 0.001, self._max_frames)
        self.dispatch_errors += errors
        if self._sdo_idle is not None:
            self._sdo_idle()

    def _on_ecu_heartbeat(self, can_id: int, data: bytes | bytearray, timestamp: float) -> None:
        self.ecu_heartbeat.on_frame(data, self._rx_now_s)

    def _on_emcy(self, can_id: int, data: bytes | bytearray, timestamp: float) -> None:
        try:
            record = decode_emcy(data)
        except ValueError:
            self.emcy_rejected += 1
            return
        self.emcys.append(ReceivedEmcy(record, self._rx_now_s))

    def _tpdo_handler(self, layout: PdoLayout) -> Callable[[int, bytes | bytearray, float], None]:
        counter_key = (STATUS_INDEX, STATUS_FIELDS[-1].subindex)

        def handle(can_id: int, data: bytes | bytearray, timestamp: float) -> None:
            stats = self.status_stats
            stats.received += 1
            try:
                values = layout.decode(data)
            except ValueError:
                stats.malformed += 1
                return
            self._status_values.update(values)
            self._tpdos_seen.add(layout.number)
            if counter_key in values:
                self._tpdo_counter[layout.number] = values[counter_key]
            if layout.number == self._commit_tpdo:
                self._commit()

        return handle

    def _commit(self) -> None:
        stats = self.status_stats
        if len(self._tpdos_seen) < len(self.tpdos):
            stats.incomplete += 1
            return
        raw = {spec.name: self._status_values[(STATUS_INDEX, spec.subindex)] for spec in STATUS_FIELDS}
        try:
            status = EcuStatus.from_raw(raw)
        except ValueError:
            stats.invalid += 1
            return
        if len(set(self._tpdo_counter.values())) > 1:
            stats.incoherent += 1
        stats.accepted += 1
        self._latest = (status, self._rx_now_s)

    def _send(self, cob_id: int, data: bytes) -> None:
        if cob_id > 0x7FF:  # not ours to shortcut (canopen sends it as a 29-bit frame)
            self.network.send_message(cob_id, data)
        else:
            _send_frame(self.network, cob_id, data)
