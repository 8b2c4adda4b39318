"""The plant's Velodyne: a revolution of the urban world at the sensor's rate, cast and sent to the host.

`LidarSender.revolution(world, t)` takes what it needs of the world at `t` (our pose, the moving cars
as boxes) and casts the revolution from it (`urban_scene.UrbanLidar`), stamped `t`, then sends its
`scan_message` bytes (`protocol.lidar.scan_link`).

Inline (SIL, lockstep): the cast happens in the step that asked for it, so runs are deterministic.
Threaded (HIL): a cast takes 15-20 ms and the plant's loop runs every millisecond, so the cast goes to a
worker thread on the snapshot taken in the step. Embree and numpy release the GIL while they work;
measured on a 2-core machine, a 1 ms sleep loop beside a thread casting without pause woke 0.1 ms
late (median), 0.7 ms (p99). One cast is in flight at most: a revolution due while the last is still
being cast is dropped and counted, as a sensor whose host link is full drops packets.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bywire.hil.lidar.mesh import Mesh
from bywire.hil.lidar.urban_scene import UrbanLidar, moving_vehicle_meshes
from bywire.hil.lidar.velodyne import EgoPose
from bywire.hil.lidar.wire import encode_scan
from bywire.hil.world.urban import UrbanWorld
from bywire.hil.world.urban_spec import LidarSpec


class LidarSender:
    """See the module docstring. `send` takes one revolution's bytes."""

    def __init__(
        self,
        world: UrbanWorld,
        spec: LidarSpec,
        send: Callable[[bytes], Any],
        seed: int,
        threaded: bool = False,
    ) -> None:
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
        self._threaded = threaded
        self._job: tuple[EgoPose, list[Mesh], float] | None = None
        self._wake = threading.Condition()
        self._busy = False
        self._closed = False
        self._thread: threading.Thread | None = None
        if threaded:
            self._thread = threading.Thread(target=self._run, name="lidar-cast", daemon=True)
            self._thread.start()

    def due(self, t_s: float) -> bool:
        return t_s >= self._next_s - 1e-9

    def revolution(self, world: UrbanWorld, t_s: float) -> None:
        """Cast (or hand to the worker) the revolution of `world` as it is at `t_s`."""
        self._next_s = max(self._next_s + self.period_s, t_s)
        pose = self.lidar.ego_pose()
        moving = moving_vehicle_meshes(world, self.lidar.scene.ground)
        if not self._threaded:
            self._cast(pose, moving, t_s)
            return
        with self._wake:
            if self._busy:
                self.dropped += 1
                return
            self._busy = True
            self._job = (pose, moving, t_s)
            self._wake.notify()

    def _cast(self, pose: EgoPose, moving: list[Mesh], t_s: float) -> None:
        start = time.perf_counter()
        self.lidar.scene.set_moving(moving)
        scan = self.lidar.sensor.scan(pose, t_s)
        data = encode_scan(scan)
        self.cast_s.append(time.perf_counter() - start)
        self.points += len(scan)
        self.revolutions += 1
        self.send(data)

    def _run(self) -> None:
        while True:
            with self._wake:
                while self._job is None and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                job, self._job = self._job, None
            assert job is not None
            try:
                self._cast(*job)
            finally:
                with self._wake:
                    self._busy = False

    def close(self) -> None:
        with self._wake:
            self._closed = True
            self._wake.notify()
        if self._thread is not None:
            self._thread.join(timeout=1.0)

    def summary(self) -> dict[str, Any]:
        """What the sensor did (JSON-able): revolutions cast and sent, dropped, points, cast time (ms;
        wall time, informational)."""
        ms = np.asarray(self.cast_s) * 1e3
        return {
            "revolutions": self.revolutions,
            "dropped": self.dropped,
            "points_per_revolution": round(self.points / self.revolutions) if self.revolutions else 0,
            "cast_ms": {
                "p50": round(float(np.percentile(ms, 50)), 2) if len(ms) else None,
                "p99": round(float(np.percentile(ms, 99)), 2) if len(ms) else None,
                "max": round(float(ms.max()), 2) if len(ms) else None,
            },
        }


__all__ = ["LidarSender"]
