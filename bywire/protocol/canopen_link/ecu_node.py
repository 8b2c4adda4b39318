"""The ECU's end of the host <-> ECU link: `EcuNode`, stepped by the cyclic executive.

Kammel et al. 2008 (seed 000) Sec. 2.1 and 3: the ECU takes the main computer's control requests
and reports its status; Sec. 12: every request carries an alive counter. DESIGN section 3 (NMT,
heartbeat, PDOs, SDO, EMCY) and section 4 (the host's watchdog times are bounded by the firmware
and change only while the ECU does not actuate). Parallel to `host_master`, the other end.

- RPDO1 deadline monitoring (CiA 301 event timer of an RPDO, 0x1400 sub5): a request older than it
  is stale. Requests are also rejected when repeated (same alive counter), out of sequence (counter
  jump > MAX_COUNTER_DELTA), malformed (wrong length), invalid (undefined flag bits) or received
  outside OPERATIONAL; each kind is counted.
- NMT: boot-up then PRE-OPERATIONAL; START/STOP/ENTER PRE-OP from the host; PDOs only in
  OPERATIONAL, SDO and EMCY in PRE-OPERATIONAL and OPERATIONAL, heartbeat always. Deviation: RESET
  NODE acts like RESET COMMUNICATION (communication objects back to EDS defaults, boot-up); the
  application keeps its calibration.
- TPDOs carry the object dictionary's values (canopen's LocalNode does not tie TPDO mappings to its
  OD): at each event the ECU reads every mapped object through `LocalNode.get_data` (so read
  callbacks and SDO writes are honoured) and packs the frame. TPDO1 (state, faults) is sent last.
- SDO writes the ECU refuses get an abort code (CiA 301 table 22) and the reason text in 0x2400.
"""

from __future__ import annotations

import logging
import math
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.objectdictionary.datatypes import INTEGER_TYPES
from canopen.sdo import SdoAbortedError

from bywire.clock import Clock
from bywire.protocol.canopen_link.dictionary import (
    ABORT_CANNOT_STORE,
    ABORT_DEVICE_STATE,
    ABORT_GENERAL,
    ABORT_LOCAL_CONTROL,
    ABORT_OUT_OF_MEMORY,
    ABORT_VALUE_RANGE,
    ABORT_VALUE_TOO_HIGH,
    ABORT_VALUE_TOO_LOW,
    CALIBRATION_BLOB_SUB,
    CALIBRATION_CRC_SUB,
    CALIBRATION_INDEX,
    CALIBRATION_VERSION_SUB,
    COMMAND_INDEX,
    CONSUMER_HEARTBEAT_INDEX,
    ECU_NODE_ID,
    EDS_PATH,
    EMCY_COB_INDEX,
    ERROR_REGISTER_INDEX,
    HOST_NODE_ID,
    MAX_CALIBRATION_BYTES,
    MAX_HOST_HEARTBEAT_TIMEOUT_MS,
    MAX_PRODUCER_HEARTBEAT_MS,
    MAX_REFUSAL_CHARS,
    MAX_REQUEST_DEADLINE_MS,
    MAX_TPDO_EVENT_TIMER_MS,
    PDO_EVENT_TIMER_SUB,
    PDO_NOT_VALID,
    PRODUCER_HEARTBEAT_INDEX,
    REFUSAL_INDEX,
    RPDO_COMM_BASE,
    SDO_RESPONSE_ABORTED,
    TPDO_COMM_BASE,
    TPDO_MAP_BASE,
    UNLATCH_SUB,
    load_ecu_od,
    od_default,
    od_var,
    request_layout,
    status_layouts,
)
from bywire.protocol.canopen_link.nmt import (
    HEARTBEAT_COB_BASE,
    NMT_COB_ID,
    HeartbeatConsumer,
    NmtCommand,
    NmtState,
)
from bywire.protocol.canopen_link.pump import (
    DEFAULT_MAX_FRAMES_PER_POLL,
    EventTimer,
    drain,
    network_without_threads,
    send_frame,
    to_us,
)
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
    emcy_code_for,
    encode_emcy,
    error_register_for,
)
from bywire.rhythm import GapHistogram

log = logging.getLogger(__name__)

# The host sends 25-100 Hz: a jump of 3 is at most 30 ms of lost requests at 100 Hz, well inside
# the 100 ms deadline. A larger jump is a replayed, restarted or foreign stream: refuse and resync.
MAX_COUNTER_DELTA = 3
# An SDO abort frame: command byte, index, subindex, abort code.
_SDO_ABORT = struct.Struct("<BHBL")
# Read in every cycle: a module constant costs less than the enum class's attribute lookup.
_OPERATIONAL = NmtState.OPERATIONAL
_OPERATIONAL_ONLY = (NmtState.OPERATIONAL,)


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
        self.rpdo = request_layout(self.od)
        self.tpdos = status_layouts(self.od)
        self._request_keys = tuple(((REQUEST_INDEX, spec.subindex), spec.name) for spec in REQUEST_FIELDS)
        self._status_keys = tuple((spec.subindex, spec.name) for spec in STATUS_FIELDS)
        self.emcy_cob_id = int(od_default(self.od, EMCY_COB_INDEX))

        self.network = network_without_threads(bus)
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
        # The host's rhythm as this node hears it (receive stamps): what the watchdogs judge.
        self.heartbeat_gaps = GapHistogram()
        self.request_gaps = GapHistogram()
        self._heartbeat_rx_s: float | None = None
        self._request_rx_s: float | None = None
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
        frames, errors = drain(self._bus, self.network, 0.0, self._max_frames, now)
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
        return to_us(now_s) - self._latest_us <= self.request_deadline_ms * 1000

    def host_rhythm(self) -> dict[str, Any]:
        """The gaps between the host's heartbeats and between its accepted requests, as received
        (ms: count, p50, p99, p999, max, when the longest ended on the node's clock, and the bins)."""
        return {
            "heartbeat_gap_ms": self.heartbeat_gaps.to_json(),
            "request_gap_ms": self.request_gaps.to_json(),
        }

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
        if not self.host_heartbeat.on_frame(data, timestamp):
            return
        if self.host_heartbeat.state is NmtState.INITIALISING:  # a boot-up: the rhythm starts anew
            self._heartbeat_rx_s = None
            return
        if self._heartbeat_rx_s is not None:
            self.heartbeat_gaps.add(timestamp - self._heartbeat_rx_s, timestamp)
        self._heartbeat_rx_s = timestamp

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
        if self._request_rx_s is not None:
            self.request_gaps.add(timestamp - self._request_rx_s, timestamp)
        self._request_rx_s = timestamp
        self._latest = (request, timestamp)
        self._latest_us = to_us(timestamp)
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
                    _SDO_ABORT.pack(SDO_RESPONSE_ABORTED, index, subindex, ABORT_OUT_OF_MEMORY),
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
                self.node.sdo.tx_cobid, _SDO_ABORT.pack(SDO_RESPONSE_ABORTED, index, subindex, ABORT_GENERAL)
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
            pack = self._packers[key] = _raw_encoder(od_var(self.od, index, subindex))
        self.node.data_store.setdefault(index, {})[subindex] = pack(value)

    def _note_refusal(self, reason: str) -> None:
        log.warning("ECU node 0x%02X refused an SDO write: %s", self.node_id, reason)
        text = reason.encode("ascii", "replace").decode("ascii")[:MAX_REFUSAL_CHARS] or "refused"
        self._store(REFUSAL_INDEX, 0, text)

    def _send(self, cob_id: int, data: bytes) -> None:
        if cob_id > 0x7FF:  # not ours to shortcut (canopen sends it as a 29-bit frame)
            self.network.send_message(cob_id, data)
        else:
            send_frame(self.network, cob_id, data)


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
