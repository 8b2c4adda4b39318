"""The CANopen host <-> ECU link, pumped in lockstep on a SimClock over an in-process virtual bus
(and, for the round trip, over UdpCanBus and a python-can-remote bus on loopback)."""

from __future__ import annotations

import itertools
import json
import math
import struct
import threading
import time
import uuid
import zlib
from collections.abc import Callable, Iterator

import can
import canopen
import pytest
from canopen.sdo import SdoCommunicationError
from hypothesis import given
from hypothesis import strategies as st

from bywire.clock import SimClock
from bywire.protocol.bus_url import open_bus, serve_virtual_bus, stop_bus_server, wait_for_port
from bywire.protocol.canopen_link.dictionary import (
    ABORT_CANNOT_STORE,
    ABORT_DEVICE_STATE,
    ABORT_LOCAL_CONTROL,
    ABORT_OUT_OF_MEMORY,
    ABORT_VALUE_RANGE,
    ABORT_VALUE_TOO_HIGH,
    ABORT_VALUE_TOO_LOW,
    EDS_PATH,
    MAX_CALIBRATION_BYTES,
)
from bywire.protocol.canopen_link.ecu_node import EcuNode, RefusedWrite
from bywire.protocol.canopen_link.host_master import EcuRefusedError, HostMaster
from bywire.protocol.canopen_link.nmt import NmtCommand, NmtState, parse_heartbeat
from bywire.protocol.canopen_link.pump import EventTimer
from bywire.protocol.ecu_types import EcuState, Fault, RequestFlags
from bywire.protocol.host_link import (
    REQUEST_FIELDS,
    STATUS_FIELDS,
    EcuStatus,
    EmcyRecord,
    FieldSpec,
    HostRequest,
    decode_emcy,
    emcy_code_for,
    encode_emcy,
    encode_value,
    error_register_for,
    next_counter,
)

ECU_HB, HOST_HB, TPDO1, TPDO2, TPDO3, RPDO1, EMCY, SDO_RX = (
    0x710,
    0x701,
    0x190,
    0x290,
    0x390,
    0x210,
    0x090,
    0x610,
)


class Link:
    """ECU node and host master on one bus, stepped 1 ms at a time; a sniffer records every frame."""

    def __init__(
        self,
        ecu_bus: can.BusABC,
        host_bus: can.BusABC,
        sniffer: can.BusABC | None = None,
        **host_kwargs: object,
    ) -> None:
        self.clock = SimClock()
        self.t_ms = 0
        self.sniffer = sniffer
        self.frames: list[tuple[float, int, bytes]] = []
        self.calibrations: list[bytes] = []
        self.unlatches = 0
        self.unlatch_refusal: RefusedWrite | None = None
        self.ecu = EcuNode(
            ecu_bus, self.clock, on_calibration_write=self._on_calibration, on_unlatch=self._on_unlatch
        )
        self.host = HostMaster(host_bus, self.clock, **host_kwargs)  # type: ignore[arg-type]
        self.counter = 0
        self.sent: list[tuple[HostRequest, float]] = []
        self.published: list[tuple[EcuStatus, float]] = []
        self.status_counter = 0

    def _on_calibration(self, data: bytes) -> int:
        doc = json.loads(data)
        if "version" not in doc:
            raise RefusedWrite("calibration has no 'version' field")
        if not isinstance(doc["version"], int):
            raise ValueError(f"version {doc['version']!r} is not an integer")
        self.calibrations.append(data)
        return int(doc["version"])

    def _on_unlatch(self) -> None:
        if self.unlatch_refusal is not None:
            raise self.unlatch_refusal
        self.unlatches += 1

    def status(self) -> EcuStatus:
        t = self.clock.now()
        return EcuStatus(
            EcuState.READY,
            Fault.NONE,
            speed_mps=round(t, 2),
            accel_mps2=-0.25,
            throttle_pct=12.5,
            brake_bar=3.0,
            steer_angle_rad=0.05,
            lateness_p99_us=120.0,
            compute_max_us=450.0,
            overruns=2,
            counter=self.status_counter,
        )

    def send_request(self, counter: int | None = None, accel: float = 1.0) -> HostRequest:
        request = HostRequest(
            accel,
            -0.02,
            RequestFlags.ENGAGE | RequestFlags.STEER,
            self.counter if counter is None else counter,
        )
        self.host.send_request(request)
        self.sent.append((request, self.clock.now()))
        self.counter = next_counter(request.counter)
        return request

    def start(self) -> None:
        self.host.set_nmt_state(NmtState.OPERATIONAL)
        self.host.start_ecu()

    def run(
        self,
        duration_s: float,
        *,
        host_tick: bool = True,
        ecu_tick: bool = True,
        publish: bool = True,
        requests_every_ms: int | None = 10,
    ) -> None:
        end_ms = self.t_ms + round(duration_s * 1000)
        while self.t_ms < end_ms:
            self.t_ms += 1
            t = self.t_ms / 1000
            self.clock.advance_to(t)
            self.ecu.poll(t)
            if publish:
                status = self.status()
                self.ecu.publish_status(status, t)
                self.published.append((status, t))
                self.status_counter = next_counter(self.status_counter)
            if ecu_tick:
                self.ecu.tick(t)
            self.host.poll(t)
            if requests_every_ms and self.t_ms % requests_every_ms == 0:
                self.send_request()
            if host_tick:
                self.host.tick(t)
            self.sniff(t)

    def sniff(self, t: float) -> None:
        while self.sniffer is not None and (msg := self.sniffer.recv(timeout=0)) is not None:
            self.frames.append((t, msg.arbitration_id, bytes(msg.data)))

    def frames_on(self, cob_id: int, since_s: float = -1.0) -> list[tuple[float, bytes]]:
        return [(t, data) for t, c, data in self.frames if c == cob_id and t >= since_s]

    def pump(self) -> None:
        self.ecu.poll()


@pytest.fixture
def link() -> Iterator[Link]:
    name = f"link-{uuid.uuid4().hex}"
    buses = [can.Bus(interface="virtual", channel=name) for _ in range(3)]
    yield Link(buses[0], buses[1], buses[2])
    for bus in buses:
        bus.shutdown()


@pytest.fixture
def injector(link: Link) -> can.BusABC:
    assert link.sniffer is not None
    return link.sniffer  # same virtual channel: what it sends reaches ECU and host


def _inject(bus: can.BusABC, cob_id: int, data: bytes) -> None:
    bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))


# --- the EDS and host_link agree ----------------------------------------------------------------


def test_eds_imports_with_the_contracted_objects() -> None:
    od = canopen.import_od(str(EDS_PATH), 0x10)
    assert od[0x1017].default == 20
    assert od[0x1016][1].default == 0x00010064
    assert od[0x1014].default == 0x90
    assert [od[0x1800 + i][1].default for i in range(3)] == [0x190, 0x290, 0x390]
    assert [od[0x1800 + i][5].default for i in range(3)] == [20, 20, 20]
    assert od[0x1400][1].default == 0x210
    assert od[0x1018][1].name == "Vendor-ID"
    assert od[0x2200][3].data_type == 0x000F and od[0x2200][3].access_type == "rw"
    assert od[0x2300][1].access_type == "wo"


@pytest.mark.parametrize(("index", "fields"), [(0x2000, REQUEST_FIELDS), (0x2100, STATUS_FIELDS)])
def test_eds_scaling_matches_host_link(index: int, fields: tuple[FieldSpec, ...]) -> None:
    od = canopen.import_od(str(EDS_PATH), 0x10)
    record = od[index]
    assert sorted(s for s in record.subindices if s) == sorted(f.subindex for f in fields)
    for spec in fields:
        var = record[spec.subindex]
        assert var.data_type == spec.data_type, spec.name
        assert math.isclose(var.factor, spec.scale), spec.name
        assert var.unit == spec.unit, spec.name
        assert var.pdo_mappable, spec.name


# --- host_link: scaling, saturation, refusals ---------------------------------------------------


@given(st.floats(-32.7, 32.7), st.floats(-3.27, 3.27), st.integers(0, 15), st.integers(0, 255))
def test_request_scaling_round_trip(accel: float, steer: float, flags: int, counter: int) -> None:
    request = HostRequest(accel, steer, RequestFlags(flags), counter)
    back = HostRequest.from_raw(request.to_raw())
    assert abs(back.accel_mps2 - accel) <= 0.0005 + 1e-12
    assert abs(back.steer_angle_rad - steer) <= 0.00005 + 1e-12
    assert back.flags == request.flags and back.counter == counter
    assert HostRequest.from_raw(back.to_raw()) == back  # decoded values are fixed points


@given(
    st.sampled_from(list(EcuState)),
    st.integers(0, 0x7FF),
    st.lists(st.floats(allow_nan=False), min_size=7, max_size=7),
    st.integers(-5, 2**33),
    st.integers(0, 255),
)
def test_status_encoding_saturates_and_round_trips(
    state: EcuState, faults: int, values: list[float], overruns: int, counter: int
) -> None:
    status = EcuStatus(state, Fault(faults), *values, overruns=overruns, counter=counter)
    raw = status.to_raw()
    for spec in STATUS_FIELDS:
        assert spec.raw_min <= raw[spec.name] <= spec.raw_max, spec.name
    back = EcuStatus.from_raw(raw)
    assert back.state == state and back.faults == Fault(faults) and back.counter == counter
    assert back.overruns == min(max(overruns, 0), 2**32 - 1)
    for spec, value in zip(STATUS_FIELDS[2:9], values, strict=True):
        decoded = getattr(back, spec.name)
        assert spec.phys_min - 1e-9 <= decoded <= spec.phys_max + 1e-9
        if spec.phys_min <= value <= spec.phys_max:
            assert abs(decoded - value) <= spec.scale / 2 + 1e-9, spec.name


def test_saturation_at_the_wire_limits() -> None:
    raw = HostRequest(-40.0, math.inf, RequestFlags.NONE, 0).to_raw()
    assert raw["accel_mps2"] == -32768 and raw["steer_angle_rad"] == 32767
    status = EcuStatus(EcuState.OFF, Fault.NONE, -1.0, 0.0, 7000.0, -3.0, 0.0, 1e9, 70000.0, 0, 0)
    raw = status.to_raw()
    assert raw["speed_mps"] == -100 and raw["throttle_pct"] == 65535 and raw["brake_bar"] == 0
    assert raw["lateness_p99_us"] == 65535 and raw["compute_max_us"] == 65535


@pytest.mark.parametrize(
    "spec", [f for f in (*REQUEST_FIELDS, *STATUS_FIELDS) if f.scale != 1], ids=lambda f: f.name
)
def test_saturation_boundary_sweep(spec: FieldSpec) -> None:
    """Just inside, at and just beyond each end of the wire range: never outside it, never backwards."""
    offsets = [-2.0, -1.0, -0.6, -0.5, -0.4, 0.0, 0.4, 0.5, 0.6, 1.0, 2.0, 1e6]
    for end, sign in ((spec.raw_max, 1), (spec.raw_min, -1)):
        raws = [encode_value((end + sign * d) * spec.scale, spec, "sweep") for d in offsets]
        assert all(spec.raw_min <= r <= spec.raw_max for r in raws), (end, raws)
        assert raws == sorted(raws, reverse=sign < 0), (end, raws)
        assert raws[-6:] == [end] * 6, (end, raws)  # from the end outwards: saturated


def test_nan_and_undefined_values_are_refused_with_the_field_name() -> None:
    with pytest.raises(ValueError, match=r"HostRequest\.accel_mps2 is NaN"):
        HostRequest(math.nan, 0.0, RequestFlags.NONE, 0)
    with pytest.raises(ValueError, match=r"EcuStatus\.brake_bar is NaN"):
        EcuStatus(EcuState.OFF, Fault.NONE, 0.0, 0.0, 0.0, math.nan, 0.0, 0.0, 0.0, 0, 0)
    with pytest.raises(ValueError, match="counter 256"):
        HostRequest(0.0, 0.0, RequestFlags.NONE, 256)
    with pytest.raises(ValueError, match="0x20 of 0x21 are not defined in RequestFlags"):
        HostRequest(0.0, 0.0, RequestFlags(0x21), 0)
    raw = HostRequest(0.0, 0.0, RequestFlags.NONE, 0).to_raw()
    with pytest.raises(ValueError, match="not defined in RequestFlags"):
        HostRequest.from_raw({**raw, "flags": 0x80})
    with pytest.raises(ValueError, match="'counter' is missing"):
        HostRequest.from_raw({k: v for k, v in raw.items() if k != "counter"})
    with pytest.raises(ValueError, match="outside INTEGER16"):
        HostRequest.from_raw({**raw, "accel_mps2": 40000})
    status_raw = EcuStatus(EcuState.OFF, Fault.NONE, 0, 0, 0, 0, 0, 0, 0, 0, 0).to_raw()
    with pytest.raises(ValueError, match="9 is not a EcuState"):
        EcuStatus.from_raw({**status_raw, "state": 9})


def test_emcy_codes_register_and_codec() -> None:
    assert emcy_code_for(Fault.NONE) == 0x0000
    assert emcy_code_for(Fault.HOST_HEARTBEAT) == 0x8130
    assert emcy_code_for(Fault.OVERRUN | Fault.ESTOP_DISABLE) == 0x6100  # lowest bit wins
    assert error_register_for(Fault.NONE) == 0
    assert error_register_for(Fault.HOST_HEARTBEAT) == 0x11  # generic + communication
    assert error_register_for(Fault.OVERRUN) == 0x81  # generic + manufacturer
    record = EmcyRecord(0x8130, 0x11, Fault.HOST_HEARTBEAT | Fault.REQUEST_INVALID)
    data = encode_emcy(record)
    assert data == bytes([0x30, 0x81, 0x11, 0x01, 0x02, 0, 0, 0])
    assert decode_emcy(data) == record
    with pytest.raises(ValueError, match="7 data bytes"):
        decode_emcy(data[:7])
    with pytest.raises(ValueError, match="not defined in Fault"):
        decode_emcy(bytes([0, 0x10, 0x01, 0x00, 0x80, 0, 0, 0]))


def test_event_timer_and_heartbeat_parse() -> None:
    timer = EventTimer(20)
    fired = [ms for ms in range(0, 101) if timer.due(ms / 1000)]
    assert fired == [0, 20, 40, 60, 80, 100]
    assert not timer.due(0.1005)
    assert timer.due(0.5)  # stalled pump: one send, then a fresh schedule, no burst
    assert not timer.due(0.51) and timer.due(0.52)
    assert parse_heartbeat(b"\x05") is NmtState.OPERATIONAL
    with pytest.raises(ValueError, match="0x06 is not an NMT state"):
        parse_heartbeat(b"\x06")
    with pytest.raises(ValueError, match="2 data bytes"):
        parse_heartbeat(b"\x05\x05")


@given(st.lists(st.floats(-2.0, 2.0), min_size=50, max_size=50))
def test_a_timer_polled_by_a_loop_of_its_own_period_never_skips_one(jitter_ms: list[float]) -> None:
    """The host ticks its heartbeat once per 20 ms request: the loop's jitter (here +-2 ms around its
    grid) must never make a period look not yet due and double the gap the ECU's watchdog sees."""
    timer = EventTimer(20, early_ms=10.0)
    calls_s = [(20 * k + 5 + j) / 1000 for k, j in enumerate(jitter_ms)]
    fired = [t for t in calls_s if timer.due(t)]
    assert len(fired) == len(calls_s)


def test_without_the_allowance_a_late_first_tick_doubles_a_gap() -> None:
    strict = EventTimer(20)  # why the host's heartbeat timer has its allowance
    calls_s = [0.0053, 0.0251, 0.0452]  # the first call 0.3 ms late, the next 0.1 ms
    assert [strict.due(t) for t in calls_s] == [True, False, True]
    lenient = EventTimer(20, early_ms=10.0)
    assert [lenient.due(t) for t in calls_s] == [True, True, True]


# --- the link in lockstep ----------------------------------------------------------------------


def test_the_ecu_hears_the_hosts_rhythm_from_its_first_heartbeat(link: Link) -> None:
    """The node counts the gaps between the host's heartbeats and requests as received; the boot-up
    the host sends when it starts (long before its first heartbeat) starts the rhythm, not a gap."""
    link.run(0.4, requests_every_ms=None)  # a host that has booted but not yet ticked
    link.start()
    link.run(0.5)
    rhythm = link.ecu.host_rhythm()
    beats, requests = rhythm["heartbeat_gap_ms"], rhythm["request_gap_ms"]
    sent = [t for t, data in link.frames_on(HOST_HB) if data != b"\x00"]  # the heartbeats, not the boot-up
    assert beats["count"] == len(sent) - 1
    assert beats["max"] == pytest.approx(1e3 * max(b - a for a, b in itertools.pairwise(sent)), abs=0.2)
    assert beats["max"] < 25.0
    assert requests["count"] >= 20 and requests["p50"] == pytest.approx(requests["max"], abs=1.0)


def test_request_and_status_round_trip(link: Link) -> None:
    threads_before = threading.active_count()
    link.start()
    link.run(0.3)
    link.run(0.001, requests_every_ms=None)  # deliver the request sent in the last step
    assert link.ecu.nmt_state is NmtState.OPERATIONAL
    # The request sent at step t is polled by the ECU at step t + 1 ms.
    sent, sent_t = link.sent[-1]
    latest = link.ecu.latest_request()
    assert latest is not None
    assert latest[0] == HostRequest.from_raw(sent.to_raw())
    assert latest[1] == pytest.approx(sent_t + 0.001)
    assert link.ecu.request_stats.accepted == len(link.sent)
    assert link.ecu.request_stats.rejected == 0 and link.ecu.request_stats.lost == 0
    # The host publishes the status of the last TPDO event (every 20 ms from the start at 1 ms).
    status = link.host.latest_status()
    assert status is not None
    event_t = status[1]
    published = dict((t, s) for s, t in link.published)[event_t]
    assert status[0] == EcuStatus.from_raw(published.to_raw())
    assert link.host.status_stats.accepted == 16 and link.host.status_stats.rejected == 0
    assert link.host.status_stats.incoherent == 0
    assert link.ecu.host_alive(link.clock.now()) and link.host.ecu_alive(link.clock.now())
    assert link.host.ecu_nmt_state(link.clock.now()) is NmtState.OPERATIONAL
    # The OD holds the last accepted request (RPDO into 0x2000).
    assert link.ecu.node.sdo[0x2000][4].raw == sent.counter
    assert threading.active_count() == threads_before, "the link must not start threads"
    assert link.ecu.dispatch_errors == 0 and link.host.dispatch_errors == 0


def test_host_heartbeat_consumer_times_out_exactly_and_recovers(link: Link) -> None:
    link.start()
    link.run(0.2)
    hb = link.ecu.host_heartbeat
    assert link.ecu.host_alive(link.clock.now())
    last = hb.last_rx_s
    assert last is not None
    link.run(round(last + 0.1 - link.clock.now(), 3), host_tick=False)
    assert link.clock.now() == pytest.approx(last + 0.1)
    assert link.ecu.host_alive(link.clock.now())  # exactly 100 ms old: still fresh
    assert hb.timeouts == 0
    link.run(0.001, host_tick=False)
    assert not link.ecu.host_alive(link.clock.now())  # 101 ms: stale
    assert hb.timeouts == 1
    link.run(0.05, host_tick=False)
    assert hb.timeouts == 1  # one transition, counted once
    link.run(0.002)  # host heartbeat resumes at once (its timer is overdue)
    assert link.ecu.host_alive(link.clock.now())
    link.run(0.2)
    assert hb.timeouts == 1 and hb.rejected == 0


def test_host_must_report_operational_to_count_as_alive(link: Link) -> None:
    link.host.start_ecu()
    link.run(0.05)
    assert link.ecu.host_heartbeat.fresh(link.clock.now())
    assert link.ecu.host_heartbeat.state is NmtState.PRE_OPERATIONAL
    assert not link.ecu.host_alive(link.clock.now())
    link.host.set_nmt_state(NmtState.OPERATIONAL)
    link.run(0.021)
    assert link.ecu.host_alive(link.clock.now())
    link.host.set_nmt_state(NmtState.STOPPED)
    link.run(0.021)
    assert not link.ecu.host_alive(link.clock.now())


def test_consumer_time_is_writable_within_limits(link: Link) -> None:
    link.start()
    link.run(0.05)
    link.host.sdo_write(0x1016, 1, struct.pack("<L", 0x000100C8), idle=link.pump)  # 200 ms
    link.run(0.05)
    last = link.ecu.host_heartbeat.last_rx_s
    assert last is not None
    link.run(round(last + 0.2 - link.clock.now(), 3), host_tick=False)
    assert link.ecu.host_alive(link.clock.now())
    link.run(0.001, host_tick=False)
    assert not link.ecu.host_alive(link.clock.now())
    for word, code, reason in [
        (0x00010000, ABORT_VALUE_TOO_LOW, "off"),
        (0x000203E8, ABORT_VALUE_RANGE, "host node 0x01"),
        (0x000103E9, ABORT_VALUE_TOO_HIGH, "1001 ms"),
    ]:
        with pytest.raises(EcuRefusedError) as info:
            link.host.sdo_write(0x1016, 1, struct.pack("<L", word), idle=link.pump)
        assert info.value.abort_code == code and reason in info.value.reason
    assert link.ecu.host_heartbeat.timeout_ms == 200


def test_host_sees_ecu_heartbeat_time_out(link: Link) -> None:
    link.start()
    link.run(0.1)
    assert link.host.ecu_alive(link.clock.now())
    last = link.host.ecu_heartbeat.last_rx_s
    assert last is not None
    link.run(round(last + 0.1 - link.clock.now(), 3), ecu_tick=False)
    assert link.host.ecu_alive(link.clock.now())
    link.run(0.001, ecu_tick=False)
    assert not link.host.ecu_alive(link.clock.now())
    assert link.host.ecu_nmt_state(link.clock.now()) is None
    assert link.host.ecu_heartbeat.timeouts == 1


def test_tpdos_carry_the_object_dictionary_values(link: Link) -> None:
    """canopen issue #558: LocalNode does not tie TPDO mappings to its OD. Ours reads the OD at
    transmit time, so OD writes (local SDO, read callbacks) reach the host without publish_status."""
    link.start()
    link.run(0.05)
    link.ecu.node.sdo[0x2100][3].raw = 4242  # speed, raw 0.01 m/s
    link.ecu.node.sdo[0x2100][1].raw = int(EcuState.ENGAGED)
    link.ecu.node.add_read_callback(
        lambda index, subindex, od: 777 if (index, subindex) == (0x2100, 9) else None
    )
    link.run(0.05, publish=False)
    status = link.host.latest_status()
    assert status is not None
    assert status[0].speed_mps == pytest.approx(42.42)
    assert status[0].state is EcuState.ENGAGED
    assert status[0].compute_max_us == 777
    # And publish_status writes the OD that SDO clients read.
    link.run(0.001)
    assert link.host.sdo_read(0x2100, 5, idle=link.pump) == struct.pack("<H", 125)  # 12.5 % in 0.1 %


def test_tpdo_event_timers(link: Link) -> None:
    link.run(0.1)  # PRE-OPERATIONAL: no PDOs at all
    assert not link.frames_on(TPDO1) and not link.frames_on(TPDO2) and not link.frames_on(TPDO3)
    assert link.ecu.request_stats.not_operational == 9  # the 10th is still on the bus
    link.start()
    link.run(0.001)
    t0 = link.clock.now()  # the ECU saw START in this step's poll and sent the first event at once
    link.run(0.999)
    for cob in (TPDO1, TPDO2, TPDO3):
        times = [t for t, _ in link.frames_on(cob, since_s=t0)]
        assert len(times) == 50, hex(cob)
        assert all(round((b - a) * 1000) == 20 for a, b in itertools.pairwise(times)), hex(cob)
    # Within one event TPDO1 (state, faults) goes last: the host commits its snapshot on it.
    order = [c for t, c, _ in link.frames if t == t0 and c in (TPDO1, TPDO2, TPDO3)]
    assert order == [TPDO2, TPDO3, TPDO1]
    link.host.sdo_write(0x1800, 5, struct.pack("<H", 50), idle=link.pump)
    t1 = link.clock.now()
    link.run(1.0)
    assert len(link.frames_on(TPDO1, since_s=t1 + 0.001)) == 20
    assert len(link.frames_on(TPDO2, since_s=t1 + 0.001)) == 50
    with pytest.raises(EcuRefusedError) as info:
        link.host.sdo_write(0x1801, 5, struct.pack("<H", 0), idle=link.pump)
    assert info.value.abort_code == ABORT_VALUE_TOO_LOW


def test_heartbeat_producer_period_and_state(link: Link) -> None:
    link.run(0.1)
    boot, *beats = link.frames_on(ECU_HB)
    assert boot[1] == b"\x00"  # boot-up, sent by the constructor
    assert [data for _, data in beats] == [b"\x7f"] * 5  # PRE-OPERATIONAL every 20 ms
    assert [round(t * 1000) for t, _ in beats] == [1, 21, 41, 61, 81]
    link.start()
    link.run(0.1)
    assert link.frames_on(ECU_HB)[-1][1] == b"\x05"
    link.host.sdo_write(0x1017, 0, struct.pack("<H", 50), idle=link.pump)
    t1 = link.clock.now()
    link.run(1.0)
    assert len(link.frames_on(ECU_HB, since_s=t1 + 0.001)) == 20
    with pytest.raises(EcuRefusedError) as info:
        link.host.sdo_write(0x1017, 0, struct.pack("<H", 0), idle=link.pump)
    assert info.value.abort_code == ABORT_VALUE_TOO_LOW
    assert "silence" in link.host.last_refusal(idle=link.pump)


def test_emcy_on_new_faults_and_reset(link: Link, injector: can.BusABC) -> None:
    link.start()
    link.run(0.01)
    assert link.ecu.report_faults(Fault.HOST_HEARTBEAT)
    assert not link.ecu.report_faults(Fault.HOST_HEARTBEAT)  # nothing new: no EMCY
    assert link.ecu.report_faults(Fault.HOST_HEARTBEAT | Fault.OVERRUN)
    assert link.ecu.report_faults(Fault.NONE)  # error reset
    link.run(0.002)
    got = [(e.record.code, e.record.error_register, e.record.faults) for e in link.host.pop_emcys()]
    assert got == [
        (0x8130, 0x11, Fault.HOST_HEARTBEAT),
        (0x6100, 0x91, Fault.HOST_HEARTBEAT | Fault.OVERRUN),
        (0x0000, 0x00, Fault.NONE),
    ]
    assert link.host.pop_emcys() == []
    assert link.ecu.emcy(0x1000, Fault.DRIVER_OVERRIDE)
    link.run(0.002, publish=False)  # publish_status would set 0x1001 from the status' faults
    (emcy,) = link.host.pop_emcys()
    assert emcy.record == EmcyRecord(0x1000, 0x81, Fault.DRIVER_OVERRIDE) and not emcy.record.is_reset
    assert emcy.rx_s == pytest.approx(link.clock.now() - 0.001)
    assert link.host.sdo_read(0x1001, 0, idle=link.pump) == b"\x81"  # error register follows the EMCY
    _inject(injector, EMCY, b"\x00\x10\x01")
    link.host.stop_ecu()
    link.run(0.002)
    assert not link.ecu.emcy(0x1000, Fault.OVERRUN)  # STOPPED: no EMCY
    link.run(0.002)
    assert link.host.pop_emcys() == [] and link.host.emcy_rejected == 1


def test_calibration_download_upload_and_refusals(link: Link) -> None:
    link.run(0.01)  # SDO works in PRE-OPERATIONAL
    blob = json.dumps({"version": 7, "throttle_map": [[0.0, 0.0], [1.0, 18.5]] * 20}).encode()
    link.host.write_calibration(blob, idle=link.pump)
    assert link.calibrations == [blob]
    assert link.host.calibration_info(idle=link.pump) == (7, zlib.crc32(blob))
    assert link.host.read_calibration(idle=link.pump) == blob
    # Refused by the handler: abort with its reason; the active calibration stays.
    with pytest.raises(EcuRefusedError) as info:
        link.host.write_calibration(b'{"gains": [1, 2, 3]}', idle=link.pump)
    assert info.value.abort_code == ABORT_CANNOT_STORE
    assert "no 'version' field" in str(info.value) and "0x08000020" in str(info.value)
    assert link.host.read_calibration(idle=link.pump) == blob
    with pytest.raises(EcuRefusedError, match="calibration rejected: version 'x' is not an integer"):
        link.host.write_calibration(b'{"version": "x"}', idle=link.pump)
    with pytest.raises(EcuRefusedError, match="calibration rejected"):
        link.host.write_calibration(b"{}}", idle=link.pump)  # 3 bytes: expedited transfer, bad JSON
    assert link.host.calibration_info(idle=link.pump) == (7, zlib.crc32(blob))
    # Too big: refused when the transfer starts, before the data moves.
    link.sniff(link.clock.now())
    frames_before = len(link.frames)
    with pytest.raises(EcuRefusedError) as info:
        link.host.write_calibration(bytes(MAX_CALIBRATION_BYTES + 1), idle=link.pump)
    assert info.value.abort_code == ABORT_OUT_OF_MEMORY
    link.sniff(link.clock.now())
    # Initiate + abort, then the reason upload from 0x2400; the data itself would be ~37,000 segments.
    assert len(link.frames) - frames_before < 40


def test_calibration_without_handler_is_refused() -> None:
    name = f"nohandler-{uuid.uuid4().hex}"
    ecu_bus, host_bus = can.Bus(interface="virtual", channel=name), can.Bus(interface="virtual", channel=name)
    clock = SimClock()
    try:
        ecu = EcuNode(ecu_bus, clock)
        host = HostMaster(host_bus, clock)
        with pytest.raises(EcuRefusedError) as info:
            host.write_calibration(b'{"version": 1}', idle=ecu.poll)
        assert info.value.abort_code == ABORT_LOCAL_CONTROL
        with pytest.raises(EcuRefusedError) as info:
            host.unlatch(idle=ecu.poll)
        assert info.value.abort_code == ABORT_LOCAL_CONTROL and "no unlatch handler" in info.value.reason
    finally:
        ecu_bus.shutdown()
        host_bus.shutdown()


def test_unlatch_write(link: Link) -> None:
    link.start()
    link.run(0.01)
    link.host.unlatch(idle=link.pump)
    assert link.unlatches == 1
    link.unlatch_refusal = RefusedWrite("E-stop still reports DISABLE", ABORT_DEVICE_STATE)
    with pytest.raises(EcuRefusedError) as info:
        link.host.unlatch(idle=link.pump)
    assert info.value.abort_code == ABORT_DEVICE_STATE and info.value.reason == "E-stop still reports DISABLE"
    assert link.unlatches == 1
    with pytest.raises(EcuRefusedError) as info:
        link.host.sdo_write(0x2300, 1, b"\x02", idle=link.pump)
    assert info.value.abort_code == ABORT_VALUE_RANGE
    with pytest.raises(EcuRefusedError) as info:
        link.host.sdo_read(0x2300, 1, idle=link.pump)
    assert info.value.abort_code == 0x06010001  # write-only object


def test_request_record_is_not_writable_by_sdo(link: Link) -> None:
    with pytest.raises(EcuRefusedError) as info:
        link.host.sdo_write(0x2000, 1, struct.pack("<h", 1000), idle=link.pump)
    assert info.value.abort_code == ABORT_LOCAL_CONTROL and "RPDO only" in info.value.reason


def test_nmt_states(link: Link, injector: can.BusABC) -> None:
    link.host.start_ecu()
    link.host.set_nmt_state(NmtState.OPERATIONAL)
    link.run(0.05)
    assert link.ecu.latest_request() is not None
    link.host.stop_ecu()
    link.run(0.05)
    assert link.ecu.nmt_state is NmtState.STOPPED
    assert link.ecu.latest_request() is None
    assert link.frames_on(ECU_HB)[-1][1] == b"\x04"
    t_stop = link.clock.now() - 0.045
    assert not link.frames_on(TPDO1, since_s=t_stop)
    assert link.ecu.request_stats.not_operational >= 4
    host = HostMaster(link.host._bus, link.clock, sdo_timeout_s=0.05)
    with pytest.raises(SdoCommunicationError):  # STOPPED: the SDO server is silent
        host.sdo_read(0x1017, 0, idle=link.pump)
    link.host.enter_pre_operational_ecu()
    link.run(0.05)
    assert link.ecu.nmt_state is NmtState.PRE_OPERATIONAL
    assert link.host.sdo_read(0x1017, 0, idle=link.pump) == b"\x14\x00"
    link.host.sdo_write(0x1017, 0, struct.pack("<H", 50), idle=link.pump)
    _inject(injector, 0x000, bytes([NmtCommand.START, 0x22]))  # another node: ignored
    _inject(injector, 0x000, bytes([NmtCommand.START]))  # malformed
    _inject(injector, 0x000, bytes([0x55, 0x10]))  # undefined command
    link.run(0.01)
    assert link.ecu.nmt_state is NmtState.PRE_OPERATIONAL and link.ecu.nmt_rejected == 2
    link.host.reset_ecu_communication()
    link.run(0.002)
    assert (link.clock.now() - 0.001, b"\x00") in link.frames_on(ECU_HB)  # boot-up frame
    assert link.host.sdo_read(0x1017, 0, idle=link.pump) == b"\x14\x00"  # back to the EDS default
    _inject(injector, 0x000, bytes([NmtCommand.START, 0]))  # broadcast
    link.run(0.002)
    assert link.ecu.nmt_state is NmtState.OPERATIONAL


def test_request_validity_counters(link: Link, injector: can.BusABC) -> None:
    link.start()
    link.run(0.005, requests_every_ms=None)
    stats = link.ecu.request_stats

    def send(counter: int) -> None:
        link.send_request(counter)
        link.run(0.001, requests_every_ms=None)

    send(10)
    send(11)
    send(11)  # repeated
    assert (stats.accepted, stats.repeated) == (2, 1)
    send(13)  # one lost, accepted
    assert (stats.accepted, stats.lost) == (3, 1)
    send(30)  # jump: refused, resync on 30
    assert stats.out_of_sequence == 1 and link.ecu.latest_request()[0].counter == 13  # type: ignore[index]
    send(31)
    assert stats.accepted == 4 and link.ecu.latest_request()[0].counter == 31  # type: ignore[index]
    send(255)
    send(0)  # wraps
    _inject(injector, RPDO1, struct.pack("<hhBB", 0, 0, 0x20, 1))  # undefined flag bit
    _inject(injector, RPDO1, struct.pack("<hhB", 0, 0, 1))  # 5 bytes
    _inject(injector, RPDO1, struct.pack("<hhBBB", 0, 0, 1, 1, 0))  # 7 bytes
    link.run(0.001, requests_every_ms=None)
    assert (stats.invalid, stats.malformed, stats.out_of_sequence) == (1, 2, 2)
    assert stats.received == stats.accepted + stats.rejected
    # Deadline: stale exactly 100 ms after the last accepted request.
    send(1)
    rx = link.ecu.latest_request()[1]  # type: ignore[index]
    assert stats.deadline_misses == 0
    link.run(round(rx + 0.1 - link.clock.now(), 3), requests_every_ms=None)
    assert link.ecu.request_fresh(link.clock.now())
    link.run(0.001, requests_every_ms=None)
    assert not link.ecu.request_fresh(link.clock.now()) and stats.deadline_misses == 1


def test_status_snapshot_needs_every_tpdo_and_rejects_bad_frames(link: Link, injector: can.BusABC) -> None:
    _inject(injector, TPDO1, bytes(8))  # before TPDO2/TPDO3 were ever seen
    _inject(injector, TPDO2, bytes(3))  # wrong length
    _inject(injector, TPDO1, bytes([9]) + bytes(7))
    link.run(0.002)
    stats = link.host.status_stats
    assert (stats.incomplete, stats.malformed) == (2, 1)
    _inject(injector, TPDO2, bytes(6) + b"\x05\x00")
    _inject(injector, TPDO3, bytes(8))
    _inject(injector, TPDO1, bytes([9]) + bytes(7))  # state 9 is no EcuState
    _inject(injector, TPDO1, bytes(7) + b"\x06")  # counter differs from TPDO2's: incoherent
    link.run(0.002)
    assert stats.invalid == 1 and stats.incoherent == 1 and stats.accepted == 1
    assert link.host.latest_status() is not None


def _settle(link: Link, done: Callable[[], bool], wall_timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + wall_timeout_s
    while not done():
        assert time.monotonic() < deadline, "link did not settle"
        link.ecu.poll(link.clock.now())
        link.host.poll(link.clock.now())
        time.sleep(0.001)


@pytest.fixture(scope="module")
def remote_port() -> Iterator[int]:
    server, thread = serve_virtual_bus(0, f"link-{uuid.uuid4().hex}")
    wait_for_port("127.0.0.1", server.server_port, timeout_s=5.0)
    yield server.server_port
    stop_bus_server(server, thread)


def _free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("transport", ["udp", "remote"])
def test_the_same_link_over_other_transports(transport: str, remote_port: int) -> None:
    if transport == "udp":
        pe, ph = _free_udp_port(), _free_udp_port()
        urls = (f"udp://127.0.0.1:{pe}?peer=127.0.0.1:{ph}", f"udp://127.0.0.1:{ph}?peer=127.0.0.1:{pe}")
    else:
        urls = (f"remote:ws://127.0.0.1:{remote_port}",) * 2
    ecu_bus, host_bus = open_bus(urls[0]), open_bus(urls[1])
    try:
        link = Link(ecu_bus, host_bus)
        link.start()
        _settle(link, lambda: link.ecu.nmt_state is NmtState.OPERATIONAL)
        link.run(0.2)
        last_request = link.sent[-1][0]
        _settle(
            link,
            lambda: (r := link.ecu.latest_request()) is not None and r[0].counter == last_request.counter,
        )
        last_status = link.published[-1][0]
        link.run(0.02, publish=False)  # one more TPDO event, carrying the last published status
        _settle(
            link, lambda: (s := link.host.latest_status()) is not None and s[0].counter == last_status.counter
        )
        status = link.host.latest_status()
        assert status is not None and status[0] == EcuStatus.from_raw(last_status.to_raw())
        assert link.ecu.request_stats.rejected == 0
        assert link.ecu.host_alive(link.clock.now()) and link.host.ecu_alive(link.clock.now())
        blob = json.dumps({"version": 3, "pad": "x" * 300}).encode()
        link.host.write_calibration(blob, idle=link.pump)
        assert link.host.read_calibration(idle=link.pump) == blob
        link.unlatch_refusal = RefusedWrite("not now", ABORT_DEVICE_STATE)
        with pytest.raises(EcuRefusedError, match="not now"):
            link.host.unlatch(idle=link.pump)
    finally:
        ecu_bus.shutdown()
        host_bus.shutdown()
