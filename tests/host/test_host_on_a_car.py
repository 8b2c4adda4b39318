"""`bywire host run` on a car's inputs alone: no scenario, no simulator in the host's process.

The test plays the car around the host process: the real ECU under its 1 kHz executive on the wall
clock (host link over UDP, as on the car's Ethernet), a gateway reporting a car standing still on
vehicle CAN, and the localisation's object link sending the car's pose at the DARPA sample mission's
first checkpoint. The host gets the real RNDF and MDF from the shared data. It must plan the route, engage
the ECU (the driver has armed nothing: the ECU boots READY) and request motion, and its process must
never have imported `bywire.hil`.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from ecu_rig import WallRig
from shared_data import shared_data_dir

from bywire.hil.runner import free_udp_port
from bywire.host.roadnet.network import load_network
from bywire.host.trace import HOST_COLUMNS, read_trace
from bywire.protocol.bus_url import open_bus
from bywire.protocol.ecu_types import EcuState
from bywire.protocol.objects import EgoPoseRecord, ObjectList, encode

SAMPLE = shared_data_dir() / "rndf" / "darpa_sample"
RNDF, MDF = SAMPLE / "Sample_RNDF.txt", SAMPLE / "Sample_MDF.txt"

# Runs the same entry point as the `bywire` command, then reports what the process imported.
HOST_WRAPPER = """
import json, sys
from bywire.cli import main
rc = main(sys.argv[2:])
with open(sys.argv[1], "w") as f:
    json.dump(sorted(m for m in sys.modules if m.startswith("bywire")), f)
sys.exit(rc)
"""


class Localisation:
    """The car's localisation at 50 Hz on the object link: it stands at `pose`, nothing around it.
    Called from the ECU's cycle (a millisecond clock), it also notes every state the ECU was in."""

    def __init__(self, port: int, pose: tuple[float, float, float]) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.addr = ("127.0.0.1", port)
        self.pose = EgoPoseRecord(*pose, 0.0, 0.0)
        self.seq = 0
        self.states: set[EcuState] = set()
        self.rig: WallRig | None = None

    def __call__(self, now_s: float) -> None:
        if self.rig is not None:
            self.states.add(self.rig.state)
        k = round(now_s * 1000)
        if k % 20 == 0:
            self.seq += 1
            self.sock.sendto(encode(ObjectList(now_s, self.seq, self.pose, ())), self.addr)


def test_host_drives_the_darpa_sample_mission_from_a_car_command_line(tmp_path: Path) -> None:
    if not RNDF.is_file() or not MDF.is_file():
        pytest.skip(f"the DARPA sample RNDF/MDF are not in the shared data ({SAMPLE})")
    graph, mission = load_network(RNDF, MDF)
    start = graph.vertex_pose(graph.checkpoint_vertex(mission.checkpoint_numbers[0]))
    assert start is not None
    ecu_port, host_port, objects_port = free_udp_port(), free_udp_port(), free_udp_port()
    summary, modules_file, trace = tmp_path / "summary.json", tmp_path / "modules.json", tmp_path / "host.csv"
    localisation = Localisation(objects_port, (start.x_m, start.y_m, start.heading_rad))
    ecu_link = open_bus(f"udp://127.0.0.1:{ecu_port}?peer=127.0.0.1:{host_port}")
    with WallRig(link_bus=ecu_link, step_hook=localisation) as car:
        # The car stands, unarmed, with the E-stop on RUN; the host on the other end of the link is
        # the process below, not the rig's own master.
        car.host_silent, car.speed_mps = True, 0.0
        localisation.rig = car
        proc = subprocess.run(
            [
                sys.executable,
                "-c",
                HOST_WRAPPER,
                str(modules_file),
                "host",
                "run",
                "urban",
                "--rndf",
                str(RNDF),
                "--mdf",
                str(MDF),
                "--host-link",
                f"udp://127.0.0.1:{host_port}?peer=127.0.0.1:{ecu_port}",
                "--objects",
                f"udp://127.0.0.1:{objects_port}",
                "--seconds",
                "6",
                "--summary",
                str(summary),
                "--trace",
                str(trace),
            ],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=tmp_path,  # not the checkout: the package as installed
        )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    imported = json.loads(modules_file.read_text())
    assert "bywire.host.agent" in imported and "bywire.host.roadnet.network" in imported
    assert not [m for m in imported if m.startswith("bywire.hil")], imported
    doc = json.loads(summary.read_text())
    urban = doc["urban"]
    assert urban["states"], urban  # the behaviour planned: it left its initial state on the route
    localisation.sock.close()
    assert EcuState.ENGAGED in localisation.states, localisation.states
    requests = read_trace(trace, HOST_COLUMNS)
    # Times count from the run's start, fixed after the modules were built (they read it when they run).
    t = requests["t_s"]
    assert t.min() >= 0.0 and t.max() <= 6.5, (t[:3], t[-3:])
    engaged = requests["ecu_state"] == int(EcuState.ENGAGED)
    assert (requests["accel_request_mps2"][engaged] > 0.1).any(), requests["accel_request_mps2"].max()
    assert max(cmd.throttle_pct for _, cmd in car.commands) > 0.0  # and the ECU acted on them


def _args(*argv: str) -> argparse.Namespace:
    from bywire.host.main import add_arguments

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args(argv)


def test_a_lane_map_is_the_platoon_mission_and_its_origin_the_local_frame(tmp_path: Path) -> None:
    import numpy as np

    from bywire.host.geo import LocalFrame
    from bywire.host.main import car_inputs
    from bywire.host.world.lanemap import record_lane

    frame = LocalFrame(51.47, 5.62)
    lane = record_lane(np.column_stack((np.linspace(0, 500, 100), np.zeros(100))), frame)
    path = tmp_path / "a270.json"
    lane.save(path)
    inputs = car_inputs(_args("gcdc", "--lane-map", str(path), "--cruise", "22"))
    assert inputs.frame().origin_lat_deg == 51.47 and inputs.frame().origin_lon_deg == 5.62
    assert inputs.commands.at(0.0).engage and inputs.commands.at(5.0).v_des_mps == 22.0
    assert inputs.rndf is None and inputs.lane_map is not None


def test_without_a_mission_the_host_asks_for_nothing_and_a_route_is_a_wish_to_drive() -> None:
    from bywire.host.main import car_inputs

    idle = car_inputs(_args("default")).commands.at(100.0)
    assert not idle.engage and idle.v_des_mps == 0.0
    if RNDF.is_file():
        route = car_inputs(_args("urban", "--rndf", str(RNDF), "--mdf", str(MDF))).commands.at(0.0)
        assert route.engage


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (("--rndf", "x.rndf"), "--rndf and --mdf go together"),
        (("--lane-map", "/nonexistent/map.json"), "--lane-map: no such file /nonexistent/map.json"),
        (("--cruise", "99"), "cruise speed must be within 0..60 m/s"),
    ],
)
def test_a_car_command_line_that_cannot_be_driven_is_refused(argv: tuple[str, ...], message: str) -> None:
    from bywire.host.main import car_inputs

    with pytest.raises((SystemExit, ValueError), match=message):
        car_inputs(_args("default", *argv))


def test_a_command_script_is_read_strictly_and_drives_its_profile(tmp_path: Path) -> None:
    from bywire.host.command_script import CommandScriptError, load_command_script

    good = tmp_path / "cruise.yaml"
    good.write_text(
        "mode: drive\nengage_at_s: 1.0\nspeed_mps: [[0, 0], [10, 8]]\nstop_line_m: 120\n"
        "rearm_at_s: [30]\nstop: [{at_s: 40, duration_s: 5}]\n"
    )
    script = load_command_script(good)
    assert not script.at(0.5).engage and script.at(1.0).engage
    assert script.at(5.0).v_des_mps == pytest.approx(4.0) and script.at(20.0).stop_line_m == 120
    assert script.at(30.05).rearm and not script.at(30.2).rearm
    assert script.at(42.0).stop and not script.at(45.0).stop
    bad = tmp_path / "bad.yaml"
    bad.write_text("mode: drive\nstop: [{at_s: soon}]\n")
    with pytest.raises(CommandScriptError, match=r"bad.yaml: stop\[0\].at_s: expected a number"):
        load_command_script(bad)
    bad.write_text("mode: race\n")
    with pytest.raises(CommandScriptError, match=r"bad\.yaml: mode: expected one of drive, script"):
        load_command_script(bad)
    bad.write_text("speed: 3\n")
    with pytest.raises(CommandScriptError, match=r"bad\.yaml: speed: unknown key"):
        load_command_script(bad)
