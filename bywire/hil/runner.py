"""HIL runner: the bus servers, the plant, the ECU and the host as separate processes (DESIGN section 1).

Start-up is two-phase so that slow imports on a loaded 2-core machine cannot eat into a scenario:
each child loads everything (FMU, DBC, EDS), prints `ready`, and waits on stdin for the common
start instant t0 on CLOCK_MONOTONIC, which the runner sends once all are ready. Scenario faults
that concern the host process itself (SIGSTOP freeze, SIGKILL) are applied here at t0 + at_s.
Every process writes its own trace; the runner records every frame on the buses it can see.

A scenario with a world (cooperative driving) also gets its non-CAN links, all on this machine: the V2X
radio as UDP broadcast on loopback (`v2x://127.255.255.255:PORT`, a free port per run), and the GPS
receiver's serial line as a pseudo-terminal pair the runner creates and holds for the run: the plant
inherits the master (`--gps-fd`), the host opens the slave like a real port (`--gps-serial`). The plant
writes the world's per-vehicle trace (`traffic.csv`) and its bookkeeping (`world.json`); the host adds its
V2V counters to its summary (`gcdc`).

An urban scenario gets its object link as loopback UDP (`udp://127.0.0.1:PORT`, a free port per
run): the plant sends our pose and the object list, the host's `urban_io` reads them; the plant writes its
bookkeeping to `urban.json`, the host its state history into its summary (`urban`).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import can

from bywire.hil.machine_probe import merge_summaries
from bywire.hil.recording import Recorder, is_mcap, merge_recordings, wall_run_clock
from bywire.hil.scenario import Scenario
from bywire.hil.service_tool import ServiceTool
from bywire.hil.sil import RunResult
from bywire.hil.stall_report import culprits
from bywire.hil.trace import PLANT_COLUMNS
from bywire.hil.world.traffic import TRAFFIC_COLUMNS
from bywire.host.trace import HOST_COLUMNS, read_trace
from bywire.protocol.bus_url import open_bus, wait_for_port

READY_TIMEOUT_S = 90.0  # four Python processes importing numpy/fmpy/canopen at once on 2 cores
START_MARGIN_S = 0.5
SHUTDOWN_GRACE_S = 10.0
# SCHED_FIFO priorities on one 2-core machine: the ECU (80) above the buses it depends on (75) and
# the host (72). The plant, the busiest of all and only the simulator, runs at normal priority
# (nice -10): with it at SCHED_FIFO the real-time tasks used up the kernel's RT budget
# (sched_rt_runtime_us, 95 %) and were all throttled for tens of ms ("sched: RT throttling
# activated"), tripping the ECU's watchdogs. As a normal task it steps with a longer dt instead.
BUS_RT_PRIORITY = 75
HOST_RT_PRIORITY = 72


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Child:
    """One child process with its output captured to a log file and a line-based ready handshake."""

    def __init__(
        self, name: str, argv: list[str], log_path: Path, wants_t0: bool, pass_fds: tuple[int, ...] = ()
    ) -> None:
        self.name = name
        self.log_path = log_path
        self.wants_t0 = wants_t0
        self._log = open(log_path, "w", encoding="utf-8")  # noqa: SIM115 - closed in close()
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
            pass_fds=pass_fds,
        )
        self.ready = threading.Event()
        self._thread = threading.Thread(target=self._pump, args=(self.proc.stdout,), daemon=True)
        self._thread.start()

    def _pump(self, stream: IO[str] | None) -> None:
        if stream is None:
            return
        for line in stream:
            self._log.write(line)
            self._log.flush()
            if line.strip() == "ready" or line.startswith("ready "):
                self.ready.set()

    def send_t0(self, t0: float) -> None:
        if self.proc.stdin is not None:
            with contextlib.suppress(BrokenPipeError):
                self.proc.stdin.write(f"{t0!r}\n")
                self.proc.stdin.flush()

    def signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(sig)

    def stop(self, timeout_s: float = SHUTDOWN_GRACE_S) -> int | None:
        if self.proc.poll() is None:
            self.signal(signal.SIGCONT)
            self.signal(signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._thread.join(2)
        return self.proc.returncode

    def close(self) -> None:
        self._log.close()

    def tail(self, n: int = 15) -> str:
        try:
            return "".join(self.log_path.read_text(encoding="utf-8").splitlines(keepends=True)[-n:])
        except OSError:
            return ""


MACHINE_PROBE_FILE = "machine_probe_cpu{cpu}.json"  # bywire.hil.machine_probe: did a CPU itself stall?
HOST_TOPICS_PART = "host_topics.mcap"  # the host process records its store here
FRAMES_PART = "frames.mcap"  # the runner records the buses here; both are merged into --record


def _cli() -> list[str]:
    return [sys.executable, "-m", "bywire"]


def run_hil(
    scenario: Scenario,
    run_dir: Path,
    record: Path | None = None,
    host_link: str = "remote",
    progress: Callable[[float], None] | None = None,
    ecu_store: Path | None = None,
    leader_profile: Path | None = None,
    ecu_cpu: int | None = None,
) -> RunResult:
    """Run `scenario` as real processes on loopback virtual buses; traces and logs land in `run_dir`.

    `ecu_cpu` pins the ECU to one CPU (`bywire ecu run --cpu`): with the machine's other work kept off
    that CPU it is the partition README "When a process falls behind" measures."""
    run_dir.mkdir(parents=True, exist_ok=True)
    children: list[Child] = []
    pty: Any = None
    plant_world_args: list[str] = []
    host_world_args: list[str] = []
    plant_fds: tuple[int, ...] = ()
    if scenario.world is not None:
        from bywire.hil.world.pty_link import PtyLink

        v2x_url = f"v2x://127.255.255.255:{free_udp_port()}"
        plant_world_args = ["--v2x", v2x_url, "--traffic-trace", str(run_dir / "traffic.csv")]
        plant_world_args += ["--world-summary", str(run_dir / "world.json")]
        host_world_args = ["--v2x", v2x_url]
        if scenario.world.gps.enabled:
            pty = PtyLink()
            plant_world_args += ["--gps-fd", str(pty.master_fd)]
            plant_fds = (pty.master_fd,)
            host_world_args += ["--gps-serial", pty.slave_path]
        if leader_profile is not None:
            plant_world_args += ["--leader-profile", str(leader_profile)]
    if scenario.urban is not None:
        objects_url = f"udp://127.0.0.1:{free_udp_port()}"
        plant_world_args += ["--objects", objects_url, "--urban-summary", str(run_dir / "urban.json")]
        host_world_args += ["--objects", objects_url]
        perception = scenario.urban.perception
        plant_world_args += ["--perception", perception]
        host_world_args += ["--perception", perception]
        if perception == "lidar":
            scans_url = f"tcp://127.0.0.1:{free_port()}"
            plant_world_args += ["--scans", scans_url]
            host_world_args += ["--scans", scans_url]
    vehicle_port = free_port()
    vehicle_url = f"remote:ws://127.0.0.1:{vehicle_port}/"
    children.append(
        Child(
            "bus-vehicle",
            [
                *_cli(),
                "bus",
                "serve",
                "--port",
                str(vehicle_port),
                "--channel",
                "vehicle",
                "--rt-priority",
                str(BUS_RT_PRIORITY),
            ],
            run_dir / "bus-vehicle.log",
            False,
        )
    )
    if host_link == "remote":
        link_port = free_port()
        ecu_link = host_link_url = f"remote:ws://127.0.0.1:{link_port}/"
        children.append(
            Child(
                "bus-link",
                [
                    *_cli(),
                    "bus",
                    "serve",
                    "--port",
                    str(link_port),
                    "--channel",
                    "host_link",
                    "--rt-priority",
                    str(BUS_RT_PRIORITY),
                ],
                run_dir / "bus-link.log",
                False,
            )
        )
    elif host_link == "udp":
        ecu_port, host_port = free_udp_port(), free_udp_port()
        ecu_link = f"udp://127.0.0.1:{ecu_port}?peer=127.0.0.1:{host_port}"
        host_link_url = f"udp://127.0.0.1:{host_port}?peer=127.0.0.1:{ecu_port}"
    else:
        raise ValueError(f"host link must be 'remote' or 'udp', not {host_link!r}")
    recorder: Recorder | None = None
    stop_recording = threading.Event()
    rec_thread: threading.Thread | None = None
    result_extra: dict[str, Any] = {"host_link": host_link}
    service: ServiceTool | None = None
    service_bus: can.BusABC | None = None
    # First, so that they watch the start-up too; stopped last (children stop in reverse order).
    probes = [_machine_probe(run_dir, cpu) for cpu in sorted(os.sched_getaffinity(0))]
    children[:0] = probes
    try:
        wait_for_port("127.0.0.1", vehicle_port, 30.0)
        if host_link == "remote":
            wait_for_port("127.0.0.1", link_port, 30.0)
        scenario_file = scenario.source
        ecu_argv = [
            *_cli(),
            "ecu",
            "run",
            "--vehicle-bus",
            vehicle_url,
            "--host-link",
            ecu_link,
            "--stats-json",
            str(run_dir / "ecu_stats.json"),
            "--ready-line",
            "--vehicle-profile",
            scenario.vehicle_profile,
        ]
        if ecu_cpu is not None:
            ecu_argv += ["--cpu", str(ecu_cpu)]
        if ecu_store is not None:
            ecu_argv += ["--store", str(ecu_store)]
        else:
            cal_path = _calibration_argument(scenario, run_dir)
            if cal_path is not None:
                ecu_argv += ["--calibration", str(cal_path)]
        ecu = Child("ecu", ecu_argv, run_dir / "ecu.log", False)
        children.append(ecu)
        plant = Child(
            "plant",
            [
                *_cli(),
                "hil",
                "plant",
                scenario_file,
                "--vehicle-bus",
                vehicle_url,
                "--trace",
                str(run_dir / "plant.csv"),
                "--t0",
                "-",
                "--duration",
                repr(scenario.duration_s),
                "--vehicle-profile",
                scenario.vehicle_profile,
                "--stalls",
                str(run_dir / "plant_stalls.json"),
                *plant_world_args,
            ],
            run_dir / "plant.log",
            True,
            **({"pass_fds": plant_fds} if plant_fds else {}),
        )
        children.append(plant)
        host = Child(
            "host",
            [
                *_cli(),
                "host",
                "run",
                "--scenario",
                scenario_file,
                "--summary",
                str(run_dir / "host_runtime.json"),
                *(
                    ["--record", str(run_dir / HOST_TOPICS_PART)]
                    if record is not None and is_mcap(record)
                    else []
                ),
                "--host-link",
                host_link_url,
                "--sensor-bus",
                vehicle_url,
                "--trace",
                str(run_dir / "host.csv"),
                "--t0",
                "-",
                "--seconds",
                repr(scenario.duration_s + 2.0),
                "--rt-priority",
                str(HOST_RT_PRIORITY),
                *host_world_args,
            ],
            run_dir / "host.log",
            True,
        )
        children.append(host)
        deadline = time.monotonic() + READY_TIMEOUT_S
        for child in (*probes, ecu, plant, host):
            while not child.ready.wait(0.2):
                if child.proc.poll() is not None:
                    raise RuntimeError(f"{child.name} exited during start-up:\n{child.tail()}")
                if time.monotonic() > deadline:
                    raise RuntimeError(
                        f"{child.name} not ready after {READY_TIMEOUT_S:.0f} s:\n{child.tail()}"
                    )
        if record is not None:
            buses = {"vehicle": open_bus(vehicle_url)}
            if host_link == "remote":
                buses["host_link"] = open_bus(host_link_url)
            frames_to = run_dir / FRAMES_PART if is_mcap(record) else record
            recorder = Recorder(frames_to, buses, run_clock=wall_run_clock)
            rec_thread = threading.Thread(target=_record_loop, args=(recorder, stop_recording), daemon=True)
            rec_thread.start()
        if scenario.faults_of("unlatch"):
            if host_link != "remote":
                raise RuntimeError("an 'unlatch' fault needs the shared host link (--host-link remote)")
            service_bus = open_bus(host_link_url)
            service = ServiceTool(service_bus)
        t0 = time.monotonic() + START_MARGIN_S
        for child in (plant, host):
            child.send_t0(t0)
        wall0 = time.monotonic()
        _supervise(scenario, t0, host, plant, progress, ecu=ecu, service=service)
        if service is not None:
            result_extra["service_tool"] = service.summary()
        result_extra["wall_s"] = round(time.monotonic() - wall0, 2)
        result_extra["real_time_factor"] = round(scenario.duration_s / max(1e-9, time.monotonic() - t0), 3)
    finally:
        stop_recording.set()
        if rec_thread is not None:
            rec_thread.join(5)
        if recorder is not None:
            recorder.close()
            result_extra["recorded_frames"] = recorder.frames
            for b in recorder.buses.values():
                b.shutdown()
        if service_bus is not None:
            with contextlib.suppress(OSError):  # the bus server may be gone already
                service_bus.shutdown()
        codes = {}
        for child in reversed(children):
            codes[child.name] = child.stop()
            child.close()
        result_extra["exit_codes"] = codes
        if pty is not None:
            pty.close()
    if record is not None and is_mcap(record):
        parts = [run_dir / HOST_TOPICS_PART, run_dir / FRAMES_PART]
        result_extra["recording"] = merge_recordings(record, parts)
        if all(state == "ok" for state in result_extra["recording"]["parts"].values()):
            for part in parts:
                part.unlink()  # all in `record` now; a part that had trouble stays for a post-mortem
    stalls: dict[str, Any] = {}
    runtime_path = run_dir / "host_runtime.json"
    if runtime_path.exists():
        runtime = json.loads(runtime_path.read_text(encoding="utf-8"))
        gcdc = runtime.pop("gcdc", None)
        if gcdc is not None:
            result_extra["gcdc"] = gcdc
        urban_host = runtime.pop("urban", None)
        if urban_host is not None:
            result_extra["urban_host"] = urban_host
        host_stalls = runtime.pop("stalls", None)
        if host_stalls is not None:
            stalls["host"] = host_stalls
        result_extra["host_runtime"] = runtime
    plant_stalls = run_dir / "plant_stalls.json"
    if plant_stalls.exists():
        stalls["plant"] = json.loads(plant_stalls.read_text(encoding="utf-8"))
    urban_path = run_dir / "urban.json"
    if urban_path.exists():
        result_extra["urban"] = json.loads(urban_path.read_text(encoding="utf-8"))
    world_path = run_dir / "world.json"
    if world_path.exists():
        result_extra["world"] = json.loads(world_path.read_text(encoding="utf-8"))
    stats_path = run_dir / "ecu_stats.json"
    if stats_path.exists():
        loop = json.loads(stats_path.read_text(encoding="utf-8"))
        health = loop.pop("health", None)
        if health is not None:
            result_extra["ecu_health"] = health
        result_extra["ecu_loop"] = loop
    plant_trace = read_trace(run_dir / "plant.csv", PLANT_COLUMNS)
    host_path = run_dir / "host.csv"
    host_trace = read_trace(host_path, HOST_COLUMNS) if host_path.exists() else None
    traffic_path = run_dir / "traffic.csv"
    traffic = read_trace(traffic_path, TRAFFIC_COLUMNS) if traffic_path.exists() else None
    result_extra["stalls"] = {
        process: {"count": len(summary.get("stalls", [])) + summary.get("dropped", 0), **summary}
        for process, summary in stalls.items()
    }
    machine = _machine_probe_summary(sorted(run_dir.glob(MACHINE_PROBE_FILE.format(cpu="*"))), t0)
    if machine is not None:
        result_extra["machine"] = machine
    # Which process fell behind when a watchdog fired (run time: the host trace's clock).
    result_extra["watchdog_culprits"] = culprits(host_trace, stalls, t0, scenario.duration_s, machine)
    return RunResult(plant=plant_trace, host=host_trace, extra=result_extra, traffic=traffic)


def _machine_probe(run_dir: Path, cpu: int) -> Child:
    out = run_dir / MACHINE_PROBE_FILE.format(cpu=cpu)
    argv = [sys.executable, "-m", "bywire.hil.machine_probe", "--cpu", str(cpu), "--out", str(out)]
    return Child(f"machine-probe-{cpu}", argv, run_dir / f"machine-probe-{cpu}.log", False)


def _machine_probe_summary(paths: list[Path], t0: float) -> dict[str, Any] | None:
    """The machine probes' summary with their stalls in run time (seconds after t0), or None when no
    probe wrote anything (none could start, or they were killed)."""
    docs = []
    for path in paths:
        with contextlib.suppress(OSError, ValueError):
            docs.append(json.loads(path.read_text(encoding="utf-8")))
    return merge_summaries(docs, t0) if docs else None


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _calibration_argument(scenario: Scenario, run_dir: Path) -> Path | None:
    from bywire.hil.run_calibration import run_calibration_file

    return run_calibration_file(scenario, run_dir)


def _record_loop(recorder: Recorder, stop: threading.Event) -> None:
    while not stop.is_set():
        if recorder.pump() == 0:
            time.sleep(0.002)


def _supervise(
    scenario: Scenario,
    t0: float,
    host: Child,
    plant: Child,
    progress: Callable[[float], None] | None,
    *,
    ecu: Child | None = None,
    service: ServiceTool | None = None,
) -> None:
    """Wait for the plant to finish the scenario, applying the process faults on time: the host's
    freeze and kill, the ECU's loop stall (SIGSTOP, then SIGCONT after duration_s), and a service
    tool's unlatch on the host link."""
    actions = sorted((f.at_s, f.kind) for f in scenario.faults if f.kind in ("host_freeze", "host_kill"))
    for f in scenario.faults_of("loop_stall"):
        actions += [(f.at_s, "ecu_stop"), (f.at_s + f.duration_s, "ecu_cont")]
    actions += [(f.at_s, "unlatch") for f in scenario.faults_of("unlatch")]
    actions.sort()
    end = t0 + scenario.duration_s
    limit = end + max(30.0, scenario.hil_timeout_s)
    last_report = -1
    while plant.proc.poll() is None:
        now = time.monotonic()
        while actions and now >= t0 + actions[0][0]:
            at_s, kind = actions.pop(0)
            if kind == "ecu_stop" and ecu is not None:
                ecu.signal(signal.SIGSTOP)
            elif kind == "ecu_cont" and ecu is not None:
                ecu.signal(signal.SIGCONT)
            elif kind == "unlatch" and service is not None:
                service.send_unlatch(at_s)
            elif kind in ("host_freeze", "host_kill"):
                host.signal(signal.SIGSTOP if kind == "host_freeze" else signal.SIGKILL)
        if service is not None:
            service.poll(now - t0)
        if progress is not None and now >= t0:
            pct = int(min(1.0, (now - t0) / scenario.duration_s) * 20)
            if pct != last_report:
                last_report = pct
                progress(pct / 20)
        if now > limit:
            raise RuntimeError(
                f"plant did not finish {scenario.duration_s} s scenario in time:\n{plant.tail()}"
            )
        # Wake on time for the next action (a stall's SIGCONT is timed to a few ms), else poll at 50 Hz.
        wait = 0.02 if not actions else min(0.02, t0 + actions[0][0] - time.monotonic())
        time.sleep(max(wait, 0.0))
    if plant.proc.returncode != 0:
        raise RuntimeError(f"plant failed with exit code {plant.proc.returncode}:\n{plant.tail()}")
