"""docs/protocol.md is generated from vehicle.dbc and ecu.eds and must not drift from them."""

from __future__ import annotations

from pathlib import Path

import pytest

from bywire.protocol.table import REGENERATE, render_protocol_table, write_protocol_table

DOC = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"


@pytest.fixture(scope="module")
def rendered() -> str:
    return render_protocol_table()


def test_docs_protocol_md_is_up_to_date(rendered: str) -> None:
    assert DOC.is_file(), f"{DOC} is missing: run `{REGENERATE}`"
    current = DOC.read_text(encoding="utf-8")
    assert current == rendered, (
        f"{DOC} differs from protocol/vehicle.dbc + protocol/ecu.eds: regenerate it with `{REGENERATE}`"
    )


def test_render_is_deterministic(rendered: str) -> None:
    assert render_protocol_table() == rendered


@pytest.mark.parametrize(
    "row",
    [
        # vehicle CAN frames, with sender and cycle time
        "| 0x0F0 (240) | ESTOP_Radio | ESTOP | 8 | 50 ms |",
        "| 0x100 (256) | DBW_Command | ECU | 8 | 10 ms |",
        # a signal with bit position, length, scale, unit, range and value table
        "| EcuState | 54 | 3 | unsigned | 1 | 0 |  | 0 .. ",
        "| SteerAngle | 38 | 16 | signed | 0.0001 | 0 | rad | -0.6 .. 0.6 |",
        # CANopen COB-IDs
        "| 0x090 | EMCY | ECU -> host |",
        "| 0x190 | TPDO1 | ECU -> host | status, every 20 ms |",
        "| 0x210 | RPDO1 | host -> ECU | request, stale after 100 ms |",
        "| 0x701 | heartbeat (host) | host -> ECU | NMT state u8; consumed by the ECU, timeout 100 ms",
        "| 0x710 | heartbeat (ECU) | ECU -> host | NMT state u8, every 20 ms (0x1017) |",
        # PDO mapping with scaling and unit
        "| 0-1 | 0x2000sub1 | Accel request | INTEGER16 | 0.001 | m/s^2 | -32.768 .. 32.767 |",
        "| 3-4 | 0x2100sub3 | Speed | INTEGER16 | 0.01 | m/s | -327.68 .. 327.67 |",
        # manufacturer objects and EMCY codes
        "| 0x2200sub3 | Calibration.Calibration blob | DOMAIN | rw |",
        "| 0x2300sub1 | Commands.Disable unlatch | UNSIGNED8 | wo |",
        "| 0x0001 | HOST_HEARTBEAT | 0x8130 | 0x11 |",
    ],
)
def test_table_holds_the_contract(rendered: str, row: str) -> None:
    assert any(line.startswith(row) for line in rendered.splitlines()), row


def test_value_tables_are_rendered(rendered: str) -> None:
    (line,) = [row for row in rendered.splitlines() if row.startswith("| EcuState | 54 |")]
    assert "0=OFF, 1=READY, 2=ENGAGED, 3=PAUSED, 4=SAFE_STOP, 5=DISABLED, 6=MANUAL" in line


def test_write_protocol_table(tmp_path: Path, rendered: str) -> None:
    out = tmp_path / "protocol.md"
    write_protocol_table(out)
    assert out.read_text(encoding="utf-8") == rendered


def test_render_reflects_the_eds(tmp_path: Path) -> None:
    """The table is generated, not copied: change the EDS and the table changes with it."""
    eds = (Path(__file__).resolve().parents[2] / "protocol" / "ecu.eds").read_text()
    changed = tmp_path / "ecu.eds"
    changed.write_text(
        eds.replace(
            "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\nDataType=0x0006\n"
            "AccessType=rw\nDefaultValue=20",
            "[1017]\nParameterName=Producer heartbeat time\n"
            "ObjectType=0x7\nDataType=0x0006\nAccessType=rw\nDefaultValue=50",
        )
    )
    assert changed.read_text() != eds
    text = render_protocol_table(eds_path=changed)
    assert "NMT state u8, every 50 ms (0x1017)" in text


# -- vehicle profile pq ------------------------------------------------------------------------------

DOC_PQ = DOC.parent / "protocol_pq.md"


def test_docs_protocol_pq_md_is_up_to_date() -> None:
    from bywire.protocol.table import REGENERATE_PQ

    assert DOC_PQ.is_file(), f"{DOC_PQ} is missing: run `{REGENERATE_PQ}`"
    assert DOC_PQ.read_text(encoding="utf-8") == render_protocol_table(profile="pq"), (
        f"{DOC_PQ} differs from protocol/vehicle_pq.dbc + vw_pq.dbc: regenerate it with `{REGENERATE_PQ}`"
    )


@pytest.mark.parametrize(
    "row",
    [
        # ours, moved off the PQ engine message MSG_1 (0x100)
        "| 0x0F1 (241) | DBW_Command | ECU | 8 | 10 ms |",
        "| 0x0F8 (248) | GW_Inertial | GATEWAY | 8 | 10 ms |",
        # the car's, with its protection and the typed frame it becomes
        "| 0x0D0 (208) | Lenkhilfe_3 | 6 | 10 ms | XOR, byte 0 | bits 12..15 | `SteerReport` |",
        "| 0x4A8 (1192) | Bremse_5 | 8 | 20 ms | XOR, byte 7 | bits 52..55 | `BrakePressure` |",
        "| 0x4A0 (1184) | Bremse_3 | 8 | 10 ms | - | - | `WheelSpeeds` |",
        "| GE1_Wahl_Pos | 12 | 4 | 1 |  | 0 .. 15 | `GearReport.gear_engaged` "
        "| 5=DRIVE, 7=REVERSE, else refused |",
        "| MO3_Pedalwert | 16 | 8 | 0.4 | % | 0 .. 101.6 | `GasPedal.throttle_pedal_pct` | raw * 0.4 % |",
    ],
)
def test_pq_table_documents_the_profile(row: str) -> None:
    assert row in render_protocol_table(profile="pq")


def test_cli_prints_the_pq_table(capsys: pytest.CaptureFixture[str]) -> None:
    from bywire.cli import main

    assert main(["protocol", "table", "--profile", "pq"]) == 0
    out = capsys.readouterr().out
    assert out == render_protocol_table(profile="pq")
    assert "bywire protocol table, vehicle profile pq" in out and "0x100 (256) | DBW_Command" not in out


def test_an_unknown_profile_is_refused() -> None:
    with pytest.raises(ValueError, match="vehicle profile 'mqb': expected one of bywire, pq"):
        render_protocol_table(profile="mqb")
