"""The host's end of the host <-> ECU link: `HostMaster`, requests out, status / heartbeat / EMCY in.

Kammel et al. 2008 (seed 000) Sec. 2.1 and 3: the main computer sends the ECU its control requests
and reads back its status; Sec. 12: the host watches the ECU's heartbeat as the ECU watches its own.
DESIGN section 3: NMT master, heartbeat producer and consumer, the request RPDO, the status TPDOs,
SDO tools for calibration and the E-stop unlatch, EMCY. Parallel to `ecu_node`, the other end; the
ECU firmware image never holds this module.

The status spans TPDO1..3: the ECU sends TPDO1 (state, faults) last in each event, and the host
publishes a new EcuStatus when TPDO1 arrives, from the latest TPDO2/TPDO3 (TPDO2 repeats the status
counter so a mixed snapshot is counted). An SDO write the ECU refuses raises `EcuRefusedError` with
the abort code and the reason the ECU left in 0x2400.
"""

from __future__ import annotations

import collections
import contextlib
import queue
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.objectdictionary import ObjectDictionary
from canopen.sdo import SdoAbortedError, SdoClient, SdoCommunicationError
from canopen.sdo.exceptions import SdoError

from bywire.clock import Clock
from bywire.protocol.canopen_link.dictionary import (
    CALIBRATION_BLOB_SUB,
    CALIBRATION_CRC_SUB,
    CALIBRATION_INDEX,
    CALIBRATION_VERSION_SUB,
    COMMAND_INDEX,
    ECU_NODE_ID,
    EMCY_COB_INDEX,
    HOST_NODE_ID,
    REFUSAL_INDEX,
    SDO_RESPONSE_ABORTED,
    SDO_SERVER_INDEX,
    UNLATCH_SUB,
    PdoLayout,
    load_ecu_od,
    od_default,
    od_where,
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
)
from bywire.protocol.host_link import (
    REQUEST_FIELDS,
    REQUEST_INDEX,
    STATUS_FIELDS,
    STATUS_INDEX,
    EcuStatus,
    EmcyRecord,
    HostRequest,
    decode_emcy,
)


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


class EcuRefusedError(RuntimeError):
    """The ECU answered an SDO request with an abort; carries the abort code and the ECU's reason."""

    def __init__(self, what: str, index: int, subindex: int, abort_code: int, reason: str) -> None:
        text = SdoAbortedError.CODES.get(abort_code, "unknown abort code")
        super().__init__(
            f"ECU refused {what} ({od_where(index, subindex)}): SDO abort 0x{abort_code:08X} ({text})"
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
            if response[0] == SDO_RESPONSE_ABORTED:
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
        self.rpdo = request_layout(self.od)
        self.tpdos = status_layouts(self.od)
        self._commit_tpdo = self.tpdos[-1].number

        self.network = network_without_threads(bus)
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
        # Ticked once per request (the ECU link's period is the heartbeat's): half a period early
        # still counts, so the scheduler's jitter never turns one period into two.
        self._hb_timer = EventTimer(period_ms, early_ms=period_ms / 2)
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
        _, errors = drain(self._bus, self.network, 0.0, self._max_frames)
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
        _, errors = drain(self._bus, self.network, 0.0 if self._sdo_idle else 0.001, self._max_frames)
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
            send_frame(self.network, cob_id, data)
