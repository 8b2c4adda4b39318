"""The plant's Velodyne: a revolution of the urban world at the sensor's rate, cast and sent to the host.

`LidarSender.revolution(world, t)` takes what it needs of the world at `t` (our pose, the moving cars
as boxes) and casts the revolution from it (`urban_scene.UrbanLidar`), stamped `t`, then sends its
`scan_message` bytes (`protocol.lidar.scan_link`).

Inline (SIL, lockstep): the cast happens in the step that asked for it, so runs are deterministic.
In its own process (`LidarProcess`, what the HIL plant uses): a cast takes 15-20 ms and the plant's
loop runs every millisecond, and a cast's Python parts hold the GIL (a worker thread in the plant left
the stall recorder naming the cast thread as the busiest when the step's gaps opened). The sensor is a
process, as a Velodyne is a device: the plant sends it a snapshot (the stamp, our pose, the moving cars'
boxes: a few hundred bytes) and the sensor casts and sends the revolution to the host itself, below the
plant's priority. What still stretches the plant's step in HIL (gaps up to 40-60 ms, against 24-27 ms with the
perception at normal priority) is the host's perception process at real-time priority taking a core: see
host/configs/urban_lidar.yaml. One cast is in flight at most: a revolution due while the last is still
being cast is dropped and counted, as a sensor whose host link is full drops packets.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bywire.hil.lidar.mesh import Mesh, Surface, box_mesh
from bywire.hil.lidar.urban_scene import VEHICLE_HEIGHT_M, UrbanLidar, moving_cars, moving_vehicle_meshes
from bywire.hil.lidar.velodyne import EgoPose
from bywire.hil.lidar.wire import encode_scan
from bywire.hil.world.urban import UrbanWorld
from bywire.hil.world.urban_spec import LidarSpec, UrbanSpec


class LidarSender:
    """Casts in the caller's step (see the module docstring). `send` takes one revolution's bytes."""

    def __init__(self, world: UrbanWorld, spec: LidarSpec, send: Callable[[bytes], Any], seed: int) -> None:
        self.lidar = UrbanLidar.build(
            world,
            azimuth_steps=spec.azimuth_steps,
            range_noise_m=spec.range_noise_m,
            dropout_probability=spec.dropout_probability,
            seed=seed,
        )
        self.period_s = 1.0 / spec.rate_hz
        self.send = send
        self._next_s = 0.0
        self.revolutions = 0
        self.dropped = 0
        self.points = 0
        self.cast_s: list[float] = []

    def due(self, t_s: float) -> bool:
        return t_s >= self._next_s - 1e-9

    def revolution(self, world: UrbanWorld, t_s: float) -> None:
        """Cast the revolution of `world` as it is at `t_s`, and send it."""
        self._next_s = max(self._next_s + self.period_s, t_s)
        self.cast(self.lidar.ego_pose(), moving_vehicle_meshes(world, self.lidar.scene.ground), t_s)

    def cast(self, pose: EgoPose, moving: list[Mesh], t_s: float) -> None:
        start = time.perf_counter()
        self.lidar.scene.set_moving(moving)
        scan = self.lidar.sensor.scan(pose, t_s)
        data = encode_scan(scan)
        self.cast_s.append(time.perf_counter() - start)
        self.points += len(scan)
        self.revolutions += 1
        self.send(data)

    def summary(self) -> dict[str, Any]:
        """What the sensor did (JSON-able): revolutions cast and sent, dropped, points, cast time (ms;
        wall time, informational)."""
        ms = np.asarray(self.cast_s) * 1e3

        def pct(q: float) -> float | None:
            return round(float(np.percentile(ms, q)), 2) if len(ms) else None

        return {
            "revolutions": self.revolutions,
            "dropped": self.dropped,
            "points_per_revolution": round(self.points / self.revolutions) if self.revolutions else 0,
            "cast_ms": {"p50": pct(50), "p99": pct(99), "max": pct(100)},
        }


Snapshot = tuple[float, tuple[float, float, float], list[tuple[float, float, float, float, float]]]


def _snapshot(world: UrbanWorld, t_s: float) -> Snapshot:
    """What the sensor needs of the world at `t_s`: our pose and the moving cars' boxes."""
    x, y, h = float(world.ego[0]), float(world.ego[1]), float(world.ego[2])
    cars = [(c.x_m, c.y_m, c.heading_rad, c.length_m, c.width_m) for c in moving_cars(world.cars)]
    return t_s, (x, y, h), cars


def _sensor_main(spec: UrbanSpec, seed: int, url: str, conn: Any) -> None:
    """The sensor process: build the static scene once, then cast each snapshot and send it."""
    import os

    from bywire.protocol.lidar.scan_link import open_scan_link

    try:  # below the plant: normal scheduling, lower than normal priority
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        os.setpriority(os.PRIO_PROCESS, 0, 5)
    except OSError:
        pass
    world = UrbanWorld(spec, seed)
    lidar = LidarSender(world, spec.lidar, open_scan_link(url, receiver=False).send, seed)
    ground = lidar.lidar.scene.ground
    conn.send("ready")
    while True:
        msg = conn.recv()
        if msg is None:
            break
        t_s, (x, y, h), cars = msg
        moving = [
            box_mesh(ground, cx, cy, ch, length, width, VEHICLE_HEIGHT_M, Surface.VEHICLE)
            for cx, cy, ch, length, width in cars
        ]
        lidar.cast(EgoPose.on_ground(ground, x, y, h), moving, t_s)
        conn.send(("done", t_s))
    conn.send(lidar.summary())


class LidarProcess:
    """The sensor as a process of its own (see the module docstring); `due`, `revolution`, `summary` and
    `close` as `LidarSender`'s. `url` is the scan link the sensor sends on."""

    def __init__(self, spec: UrbanSpec, seed: int, url: str) -> None:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_sensor_main, args=(spec, seed, url, child), name="lidar", daemon=True
        )
        self._proc.start()
        if not self._conn.poll(60.0) or self._conn.recv() != "ready":
            raise RuntimeError("lidar sensor process did not start within 60 s")
        self.period_s = 1.0 / spec.lidar.rate_hz
        self._next_s = 0.0
        self._busy = False
        self.dropped = 0
        self._summary: dict[str, Any] | None = None

    def due(self, t_s: float) -> bool:
        return t_s >= self._next_s - 1e-9

    def revolution(self, world: UrbanWorld, t_s: float) -> None:
        self._next_s = max(self._next_s + self.period_s, t_s)
        while self._conn.poll():
            self._conn.recv()
            self._busy = False
        if self._busy:
            self.dropped += 1
            return
        self._busy = True
        self._conn.send(_snapshot(world, t_s))

    def close(self) -> None:
        if self._summary is not None or not self._proc.is_alive():
            return
        try:
            self._conn.send(None)
            while self._conn.poll(5.0):
                msg = self._conn.recv()
                if isinstance(msg, dict):
                    self._summary = msg
                    break
        except (OSError, EOFError):
            pass
        self._proc.join(timeout=5.0)
        if self._proc.is_alive():
            self._proc.kill()

    def summary(self) -> dict[str, Any]:
        self.close()
        out = dict(self._summary or {"revolutions": 0, "dropped": 0, "points_per_revolution": 0})
        out["dropped"] = int(out.get("dropped", 0)) + self.dropped
        return out


__all__ = ["LidarProcess", "LidarSender"]
