"""Every tool subcommand is reachable through the one `bywire` entry point (`bywire.cli.main`), as a
user types it: the parser knows it and dispatches to the subsystem's main."""

from __future__ import annotations

from pathlib import Path

import pytest

from bywire.cli import build_parser, main


def test_behaviour_diagram_prints_the_generated_statechart(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["behaviour", "diagram"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("stateDiagram-v2")
    for state in ("Drive", "Intersection", "Zone", "Replan", "GlobalRecovery", "PrioStop", "DriveKTurn"):
        assert state in text, state


def test_behaviour_diagram_png_needs_an_output_and_writes_one(tmp_path: Path) -> None:
    assert main(["behaviour", "diagram", "--format", "png"]) == 2
    out = tmp_path / "hsm.png"
    assert main(["behaviour", "diagram", "--format", "png", "--output", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "argv",
    [
        ["rndf", "check", "x.rndf"],
        ["mission", "plan", "a.rndf", "b.mdf"],
        ["platoon", "record-map", "log.nmea", "-o", "map.json"],
        ["platoon", "string-stability", "run.csv"],
        ["v2x", "meter", "send"],
        ["bench", "urban"],
        ["behaviour", "diagram"],
    ],
)
def test_the_parser_knows_every_tool(argv: list[str]) -> None:
    args = build_parser().parse_args(argv)
    assert args.command == argv[0]


def test_a_tool_group_without_its_command_is_a_usage_error() -> None:
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["behaviour"])
    assert exc.value.code == 2
