"""Pose server (cooperative driving): local frame, the dead-reckoning EKF through RTK loss, bridge outages (no
fix and frozen fixes), jumps and latency, and the receiver emulator -> pseudo-terminal -> pyserial -> pose
server round trip with corrupted bytes."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import pynmea2
import pytest
import serial

from bywire.hil.world.pty_link import PtyLink
from bywire.host.geo import LocalFrame, wrap_angle
from bywire.host.world.nmea import FixQuality, NmeaStream
from bywire.host.world.nmea_emulator import EmulatorConfig, Outage, ReceiverEmulator, TruthState
from bywire.host.world.pose import Pose, PoseFilter, PoseServer, PoseServerConfig
from bywire.host.world.serial_link import SerialSource

ORIGIN = (51.4708, 5.6230)
ODO_DT_S = 0.01  # the ECU's wheel speed and yaw rate at 100 Hz


def test_local_frame_round_trip_and_metric() -> None:
    fr = LocalFrame(*ORIGIN)
    assert fr.to_local(*ORIGIN) == pytest.approx((0.0, 0.0), abs=1e-6)
    lat, lon = fr.to_geodetic(1234.5, -678.9)
    assert fr.to_local(lat, lon) == pytest.approx((1234.5, -678.9), abs=1e-6)
    # 1 arc minute of latitude: M * pi / 10800 with WGS84's meridian radius of curvature
    # M = a (1 - e^2) / (1 - e^2 sin^2 phi)^1.5 at the arc's middle latitude.
    a, e2 = 6378137.0, 6.69437999014e-3
    phi = math.radians(ORIGIN[0] + 0.5 / 60.0)
    m = a * (1 - e2) / (1 - e2 * math.sin(phi) ** 2) ** 1.5
    _, y = fr.to_local(ORIGIN[0] + 1.0 / 60.0, ORIGIN[1])
    assert y == pytest.approx(m * math.pi / 10800.0, abs=0.01)


@pytest.mark.parametrize("origin", [(49.0, 8.4), (34.58, -117.37), (-33.9, 151.2), (60.1, 24.9)])
def test_local_frame_is_proj_from_the_crs_bit_for_bit_without_its_database(
    origin: tuple[float, float],
) -> None:
    """The frame's written-out pipeline is what PROJ builds from EPSG:4326 and the tmerc definition,
    to the bit; unlike that one it needs no database lookup on a thread's first call."""
    import threading

    import pyproj

    lat, lon = origin
    frame = LocalFrame(lat, lon)
    crs = pyproj.CRS.from_proj4(
        f"+proj=tmerc +lat_0={lat!r} +lon_0={lon!r} +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"
    )
    fwd = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    inv = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    rng = np.random.default_rng(3)
    la, lo = lat + rng.uniform(-0.05, 0.05, 200), lon + rng.uniform(-0.05, 0.05, 200)
    x, y = frame.to_local_many(la, lo)
    assert np.array_equal((x, y), fwd.transform(lo, la))
    assert np.array_equal(frame.to_geodetic_many(x, y), inv.transform(x, y)[::-1])
    seen: list[tuple[float, float]] = []
    t = threading.Thread(target=lambda: seen.append(frame.to_local(lat + 0.01, lon + 0.01)))
    t.start()
    t.join()
    assert seen == [fwd.transform(lon + 0.01, lat + 0.01)]
    # A pipeline without CRSs: a thread's first call builds it without looking anything up in proj.db.
    assert frame._fwd.source_crs is None and frame._inv.source_crs is None


def test_heading_conversion_with_meridian_convergence() -> None:
    fr = LocalFrame(*ORIGIN)
    assert fr.heading_from_true_azimuth(0.0, *ORIGIN) == pytest.approx(math.pi / 2)
    assert fr.heading_from_true_azimuth(90.0, *ORIGIN) == pytest.approx(0.0, abs=1e-12)
    # 7 km east of the origin true north is rotated in the grid; check against the projected meridian.
    lat, lon = fr.to_geodetic(7000.0, 0.0)
    x0, y0 = fr.to_local(lat, lon)
    x1, y1 = fr.to_local(lat + 1e-4, lon)
    north_on_grid = math.atan2(y1 - y0, x1 - x0)
    assert abs(north_on_grid - math.pi / 2) > 1e-3  # the effect is real (0.07 deg)
    assert fr.heading_from_true_azimuth(0.0, lat, lon) == pytest.approx(north_on_grid, abs=1e-7)
    az = fr.true_azimuth_from_heading(0.3, lat, lon)
    assert fr.heading_from_true_azimuth(az, lat, lon) == pytest.approx(0.3, abs=1e-12)


@dataclass
class Drive:
    """A car on a circle arc at constant speed, its ECU's odometry (scale error, gyro bias, noise) and a
    receiver emulator; runs the pose server and records errors."""

    speed_mps: float = 15.0
    yaw_rate_radps: float = 0.02
    odo_scale: float = 1.005  # true speed / wheel speed
    gyro_bias_radps: float = 0.002
    emulator: EmulatorConfig = field(default_factory=EmulatorConfig)
    server_config: PoseServerConfig = field(default_factory=PoseServerConfig)
    seed: int = 1
    bytes_hook: object = None

    def run(self, duration_s: float) -> tuple[PoseServer, list[tuple[float, float, Pose]]]:
        emu = ReceiverEmulator(self.emulator, seed=self.seed)
        srv = PoseServer(
            LocalFrame(self.emulator.origin_lat_deg, self.emulator.origin_lon_deg), self.server_config
        )
        rng = np.random.default_rng(self.seed + 100)
        x = y = psi = 0.0
        out = []
        for i in range(round(duration_s / ODO_DT_S) + 1):
            t = i * ODO_DT_S
            data = emu.update(t, TruthState(t, x, y, psi, self.speed_mps))
            if data:
                srv.feed(data, t)
            srv.odometry(
                t,
                self.speed_mps / self.odo_scale + rng.normal(0.0, 0.05),
                self.yaw_rate_radps + self.gyro_bias_radps + rng.normal(0.0, 0.005),
            )
            p = srv.pose(t) if i % 5 == 0 else None  # sampled at 20 Hz, as a controller would
            if p is not None:
                out.append((math.hypot(p.x_m - x, p.y_m - y), wrap_angle(p.heading_rad - psi), p))
            w = self.yaw_rate_radps
            x += self.speed_mps * math.cos(psi + w * ODO_DT_S / 2) * ODO_DT_S
            y += self.speed_mps * math.sin(psi + w * ODO_DT_S / 2) * ODO_DT_S
            psi += w * ODO_DT_S
        return srv, out


def test_rtk_tracking_accuracy_and_flags() -> None:
    srv, out = Drive().run(20.0)
    settled = [e for e in out if e[2].t_s > 5.0]
    assert max(e[0] for e in settled) < 0.08  # RTK fixed: cm-level
    assert max(abs(e[1]) for e in settled) < math.radians(0.3)
    last = settled[-1][2]
    assert last.rtk and last.gnss and not last.dead_reckoning and not last.stale
    assert last.fix_quality == FixQuality.RTK_FIXED
    assert last.speed_mps == pytest.approx(15.0, abs=0.15)
    # The yaw rate is the newest gyro sample (0.005 rad/s noise) minus the learnt bias: unbiased on average.
    assert np.mean([e[2].yaw_rate_radps for e in out[-100:]]) == pytest.approx(0.02, abs=0.0015)
    assert last.lat_deg == pytest.approx(LocalFrame(*ORIGIN).to_geodetic(last.x_m, last.y_m)[0])
    # The filter learns the odometer scale and gyro bias from RTK.
    assert srv.filter.x[3] == pytest.approx(1.005, abs=0.002)
    assert srv.filter.x[4] == pytest.approx(0.002, abs=0.0007)


def test_ten_second_bridge_outage_at_15_mps_stays_within_half_a_metre() -> None:
    # Stated bound: after 10 s (150 m) of dead reckoning, with a 0.5 % odometer error and 0.002 rad/s gyro
    # bias learnt beforehand, the position error stays below 0.5 m and inside 3 sigma of the filter.
    emu = EmulatorConfig(outages=(Outage(20.0, 30.0, "no_fix"),))
    srv, out = Drive(emulator=emu).run(35.0)
    during = [e for e in out if 20.0 + srv.filter.cfg.fix_timeout_s < e[2].t_s < 30.0]
    assert all(e[2].dead_reckoning and not e[2].gnss and not e[2].rtk for e in during)
    worst = max(during, key=lambda e: e[0])
    assert worst[0] < 0.5
    assert all(e[0] < 3.0 * e[2].position_std_m for e in during)
    stds = [e[2].position_std_m for e in during]
    assert stds[-1] > 5 * stds[0]  # uncertainty grows while dead reckoning
    after = [e for e in out if e[2].t_s > 31.0]
    assert after[-1][0] < 0.08 and after[-1][2].rtk
    assert srv.stats()["fix_invalid"] == 100  # 10 s of GGA at 10 Hz with quality 0


def test_frozen_receiver_under_a_bridge_is_detected_and_dead_reckoned() -> None:
    emu = EmulatorConfig(outages=(Outage(20.0, 30.0, "frozen"),))
    srv, out = Drive(emulator=emu).run(32.0)
    stats = srv.stats()
    assert stats["fix_frozen"] >= 99
    assert stats["frozen_receiver_dropped"] >= 190  # its frozen RMC and HDT as well
    during = [e for e in out if 20.5 < e[2].t_s < 30.0]
    assert all(e[2].dead_reckoning for e in during)
    assert max(e[0] for e in during) < 0.5
    # With the UTC field frozen too, the repeats are caught as repeated epochs.
    emu2 = EmulatorConfig(outages=(Outage(20.0, 30.0, "frozen", freeze_time=True),))
    srv2, out2 = Drive(emulator=emu2).run(32.0)
    assert srv2.stats()["fix_repeated"] >= 99
    assert max(e[0] for e in out2 if 20.5 < e[2].t_s < 30.0) < 0.5


def test_rtk_loss_degrades_accuracy_and_flag() -> None:
    emu = EmulatorConfig(outages=(Outage(10.0, 25.0, "rtk_loss", quality=FixQuality.GPS),))
    _, out = Drive(emulator=emu).run(30.0)
    rtk = [e[2] for e in out if 5.0 < e[2].t_s < 10.0]
    degraded = [e[2] for e in out if 15.0 < e[2].t_s < 25.0]
    assert all(p.rtk for p in rtk) and not any(p.rtk for p in degraded)
    assert all(p.gnss and p.fix_quality == FixQuality.GPS for p in degraded)
    assert np.median([p.position_std_m for p in degraded]) > 5 * np.median([p.position_std_m for p in rtk])
    assert max(e[0] for e in out if 15.0 < e[2].t_s < 25.0) < 3.0


def test_jumping_fix_rejected_then_reset_when_persistent() -> None:
    f = PoseFilter()
    f.update_odometry(0.0, 10.0, 0.0)
    f.update_position(0.0, 0.0, 0.0, 0.03, 0.03, FixQuality.RTK_FIXED)
    f.update_heading(0.0, 0.0, math.radians(0.1))
    for k in range(1, 11):
        f.update_odometry(0.01 * k, 10.0, 0.0)
    assert f.update_position(0.1, 1.0, 0.0, 0.03, 0.03, FixQuality.RTK_FIXED)
    assert not f.update_position(0.1, 31.0, 0.0, 0.03, 0.03, FixQuality.RTK_FIXED)  # 30 m jump
    assert f.counts["fix_rejected_jump"] == 1
    t = 0.1
    for _ in range(f.cfg.reset_after_rejections):  # the receiver insists: the filter must be wrong
        t += 0.1
        f.update_odometry(t, 10.0, 0.0)
        f.update_position(t, 30.0 + 10.0 * t, 0.0, 0.03, 0.03, FixQuality.RTK_FIXED)
    assert f.counts["filter_reset"] == 1
    pose = f.pose(t)
    assert pose is not None and pose.x_m == pytest.approx(30.0 + 10.0 * t, abs=0.1)


def test_latency_is_compensated_by_back_dating() -> None:
    emu = EmulatorConfig(latency_s=0.08)
    # Without compensation the fixes lag 1.2 m at 15 m/s; the filter would be pulled back.
    _, out_raw = Drive(emulator=emu).run(12.0)
    _, out_comp = Drive(emulator=emu, server_config=PoseServerConfig(fix_latency_s=0.08)).run(12.0)
    err_raw = np.median([e[0] for e in out_raw if e[2].t_s > 5.0])
    err_comp = np.median([e[0] for e in out_comp if e[2].t_s > 5.0])
    assert err_comp < 0.05 < 0.5 < err_raw


def test_stale_without_odometry_and_no_pose_before_heading() -> None:
    f = PoseFilter()
    f.update_position(0.0, 1.0, 2.0, 0.03, 0.03, FixQuality.RTK_FIXED)
    assert f.pose(0.0) is None  # no heading yet
    f.update_odometry(0.0, 0.0, 0.0)
    f.update_heading(0.0, 1.0, 0.01)
    p = f.pose(0.1)
    assert p is not None and not p.stale and (p.x_m, p.y_m, p.heading_rad) == pytest.approx((1.0, 2.0, 1.0))
    p = f.pose(1.0)
    assert p is not None and p.stale and p.dead_reckoning


def test_odometry_rejects_nonfinite_and_out_of_order() -> None:
    f = PoseFilter()
    f.update_odometry(1.0, 5.0, 0.0)
    f.update_odometry(0.5, 5.0, 0.0)
    f.update_odometry(1.1, math.nan, 0.0)
    assert f.counts == {"odometry_out_of_order": 1, "odometry_nonfinite": 1}


def test_emulator_is_deterministic_parses_with_pynmea2_and_respects_rates() -> None:
    def stream(seed: int) -> bytes:
        emu = ReceiverEmulator(EmulatorConfig(vtg_hz=5.0), seed=seed)
        return b"".join(
            emu.update(k * 0.01, TruthState(k * 0.01, 0.15 * k, 0.0, 0.0, 15.0)) for k in range(201)
        )

    a, b, c = stream(3), stream(3), stream(4)
    assert a == b and a != c
    lines = a.decode().split("\r\n")[:-1]
    kinds = [ln[3:6] for ln in lines]
    assert kinds.count("GGA") == 21 and kinds.count("RMC") == 21 and kinds.count("HDT") == 21
    assert kinds.count("VTG") == 11 and kinds.count("GST") == 3
    for ln in lines:
        pynmea2.parse(ln, check=True)  # an independent parser agrees on checksums and layout
    gga = pynmea2.parse(lines[0])
    assert gga.gps_qual == 4 and gga.timestamp.hour == 12


def test_emulator_noise_statistics() -> None:
    cfg = EmulatorConfig(quality=FixQuality.GPS, hdt_hz=0.0, gst_hz=0.0, rmc_hz=0.0)
    emu = ReceiverEmulator(cfg, seed=7)
    fr = LocalFrame(cfg.origin_lat_deg, cfg.origin_lon_deg)
    stream = NmeaStream()
    xs = []
    for k in range(0, 36000, 10):  # an hour at 10 Hz: several bias time constants (300 s)
        t = k * 0.01
        for rec in stream.feed(emu.update(t, TruthState(t, 0.0, 0.0, 0.0, 0.0))):
            xs.append(fr.to_local(rec.lat_deg, rec.lon_deg))  # type: ignore[union-attr]
    err = np.asarray(xs)
    expected = math.hypot(1.0, 1.5)  # white 1 m + bias 1.5 m per axis
    assert np.std(err[:, 0]) == pytest.approx(expected, rel=0.35)
    # The bias drifts slowly: successive fixes are strongly correlated, unlike white noise.
    d = np.diff(err[:, 0])
    assert np.std(d) == pytest.approx(math.sqrt(2.0) * 1.0, rel=0.1)


def test_emulator_rejects_rates_the_line_cannot_carry() -> None:
    with pytest.raises(ValueError, match="baud"):
        EmulatorConfig(gga_hz=20.0, rmc_hz=20.0, hdt_hz=20.0, baud=9600)
    with pytest.raises(ValueError, match="ends"):
        EmulatorConfig(outages=(Outage(5.0, 5.0, "no_fix"),))


def test_corrupted_bytes_are_survived_and_counted() -> None:
    emu = EmulatorConfig(byte_error_rate=2e-3)
    srv, out = Drive(emulator=emu).run(20.0)
    stats = srv.stats()
    dropped = sum(v for k, v in stats.items() if k.startswith("drop_"))
    assert dropped > 20 and stats.get("drop_checksum", 0) > 10
    assert stats["nmea_GGA"] > 100
    assert max(e[0] for e in out if e[2].t_s > 5.0) < 0.1


def test_pty_round_trip_emulator_to_pyserial_to_pose_server() -> None:
    cfg = EmulatorConfig(byte_error_rate=1e-3)
    emu = ReceiverEmulator(cfg, seed=11)
    with PtyLink() as link:
        srv = PoseServer(LocalFrame(cfg.origin_lat_deg, cfg.origin_lon_deg))
        t_sim = [0.0]
        with SerialSource(link.slave_path, baudrate=115200) as port:
            x = 0.0
            deadline = time.monotonic() + 20.0
            for k in range(301):  # 3 s of simulated driving, 15 m/s straight east
                t = k * 0.01
                t_sim[0] = t
                link.write(emu.update(t, TruthState(t, x, 0.0, 0.0, 15.0)))
                port.poll(srv.feed, clock=lambda: t_sim[0])
                srv.odometry(t, 15.0, 0.0)
                x += 0.15
                assert time.monotonic() < deadline
            end = time.monotonic() + 2.0
            while port.bytes_read < link.bytes_written and time.monotonic() < end:
                port.poll(srv.feed, clock=lambda: t_sim[0])
                time.sleep(0.01)
        assert link.overrun_bytes == 0
        assert port.bytes_read == link.bytes_written > 5000
    stats = srv.stats()
    assert stats["nmea_GGA"] >= 25 and stats["fix_accepted"] >= 25
    pose = srv.pose(3.0)
    assert pose is not None and pose.rtk
    assert pose.x_m == pytest.approx(x - 0.15, abs=0.1) and pose.y_m == pytest.approx(0.0, abs=0.1)


def test_serial_source_reports_a_missing_port() -> None:
    with pytest.raises(OSError, match="cannot open GPS/INS serial port '/dev/nonexistent-gps'"):
        SerialSource("/dev/nonexistent-gps")


def test_pty_overrun_is_counted_not_blocking() -> None:
    with PtyLink() as link:
        with serial.Serial(link.slave_path, timeout=0):
            chunk = b"$" + b"A" * 4095
            for _ in range(200):  # nobody reads: the kernel buffer fills
                link.write(chunk)
        assert link.overrun_bytes > 0
        assert link.bytes_written + link.overrun_bytes == 200 * 4096
