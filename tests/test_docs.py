"""The documentation site's generated pages hold what they must (`make docs` builds the site itself,
failing on any warning; these tests need no MkDocs).

The pages come from the code at every build (tools/docs_site): the protocol table from the DBC and the
EDS, the scenario and host-configuration schemas from their parsers, the calibration's limits from the
ECU's reader, the API reference from the public modules. Each test holds one of them to its source.
"""

from __future__ import annotations

import sys
import textwrap
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cantools
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
TOOLS = ROOT / "tools" / "docs_site"


@pytest.fixture(scope="module")
def pages() -> Any:
    sys.path.insert(0, str(TOOLS))
    try:
        import reference_pages
        import schema_reference
    finally:
        sys.path.remove(str(TOOLS))
    return reference_pages, schema_reference


def _rows(page: str) -> list[list[str]]:
    return [
        [c.strip() for c in line.strip("|").split(" | ")]
        for line in page.splitlines()
        if line.startswith("| ")
    ]


# --- the protocol table ------------------------------------------------------------------------------------


def test_protocol_page_lists_every_can_message_and_signal(pages: Any) -> None:
    reference_pages, _ = pages
    page = reference_pages.generated_pages()[reference_pages.PROTOCOL_PAGE]
    db = cantools.database.load_file(str(ROOT / "bywire" / "protocol" / "vehicle.dbc"))
    assert db.messages
    for message in db.messages:
        assert f"| 0x{message.frame_id:03X} ({message.frame_id}) | {message.name} |" in page, message.name
        assert f"### 0x{message.frame_id:03X} {message.name}" in page
        for signal in message.signals:
            assert f"| {signal.name} | {signal.start} | {signal.length} |" in page, signal.name


# --- the calibration's limits ------------------------------------------------------------------------------


def test_calibration_page_has_every_limit_with_its_bounds_and_the_passat_value(pages: Any) -> None:
    from bywire.ecu import calibration

    reference_pages, _ = pages
    page = reference_pages.generated_pages()[reference_pages.CALIBRATION_PAGE]
    rows = {row[0]: row for row in _rows(page)}
    passat = calibration.default_calibration()
    assert calibration._RANGES
    for name, (lo, hi, _why) in calibration._RANGES.items():
        row = rows[f"`{name}`"]
        assert (float(row[2]), float(row[3])) == (lo, hi), name
        assert float(row[6]) == pytest.approx(getattr(passat, name), rel=1e-6), name
    # The Passat's reasons come from make_passat.py's comments, e.g. the hold pressure's physics.
    assert "holds 1650 kg" in rows["`hold_brake_bar`"][7]
    for grid in ("throttle_map.speed_mps", "brake_map.bar", "coast_map.accel_mps2", "throttle_map.pct"):
        assert f"`{grid}`" in rows, grid
    assert rows["`brake_map.bar`"][1:3] == ["0", f"{calibration.BRAKE_BAR_MAX:g}"]


# --- the schemas -------------------------------------------------------------------------------------------


def _key_paths(data: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """Every key of a parsed file as a schema path (`world.vehicles[].driver.kind`), with its value."""
    if isinstance(data, dict):
        for key, value in data.items():
            path = f"{prefix}.{key}" if prefix else str(key)
            yield path, value
            yield from _key_paths(value, path)
    elif isinstance(data, list):
        for item in data:
            yield from _key_paths(item, f"{prefix}[]")


def _undocumented(files: list[Path], fields: set[str]) -> list[str]:
    """Keys of `files` that the schema does not have (neither as a field nor as the section of one),
    skipping the inside of free-form values (`params`, `extra`): only where the schema names fields
    below a key."""
    documented = set(fields)
    for path in fields:
        parts = path.split(".")
        documented |= {".".join(parts[:i]).removesuffix("[]") for i in range(1, len(parts))}
    missing = []
    for path in files:
        text = path.read_text(encoding="utf-8")
        data = tomllib.loads(text) if path.suffix == ".toml" else yaml.safe_load(text)
        for key, _ in _key_paths(data):
            parent = key.rpartition(".")[0]
            open_below = parent and not any(d.startswith(f"{parent}.") for d in documented)
            if key not in documented and not open_below:
                missing.append(f"{path.name}: {key}")
    return missing


def test_scenario_schema_has_every_field_the_shipped_scenarios_use(pages: Any) -> None:
    from bywire.hil.scenario import builtin_scenarios

    reference_pages, schema_reference = pages
    fields = schema_reference.SchemaExtractor(reference_pages.SCENARIO_PARSERS).extract(
        "bywire.hil.scenario", "parse_scenario"
    )
    documented = {f.path for f in fields}
    scenarios = list(builtin_scenarios().values())
    assert len(scenarios) > 20
    assert _undocumented(scenarios, documented) == []
    # Sections reached through helpers, list items and the world's and urban's own parsers.
    for path in ("faults[].mode", "world.vehicles[].v2v.late[].extra_s", "urban.scenery.buildings[].x_m"):
        assert path in documented, path


def test_host_config_schema_has_every_field_the_shipped_configurations_use(pages: Any) -> None:
    from bywire.host.config import shipped_configs

    reference_pages, schema_reference = pages
    fields = schema_reference.SchemaExtractor(reference_pages.HOST_CONFIG_PARSERS).extract(
        "bywire.host.config", "parse_host_config"
    )
    documented = {f.path for f in fields} | {"extends"}  # read before the parser, told on the page
    configs = list(shipped_configs().values())
    assert configs
    assert _undocumented(configs, documented) == []
    page = reference_pages.generated_pages()[reference_pages.HOST_CONFIG_PAGE]
    assert "`extends: NAME_OR_FILE`" in page


@pytest.mark.parametrize(
    ("page_name", "row"),
    [
        ("SCENARIO_PAGE", "| `v0_mps` | number | 0 | 0 .. 70 |"),
        ("SCENARIO_PAGE", "| `duration_s` | number | **required** | 0.1 .. 86400 |"),
        ("SCENARIO_PAGE", "| `pedal_pct` | number | 30 | 0 .. 100 |  | `kind == 'driver_brake'` |"),
        ("SCENARIO_PAGE", "| `v_set_mps` | number | 27.7778 | 0 .. 70 |  | `kind != 'scripted'` |"),
        ("HOST_CONFIG_PAGE", "| `tick_ms` | number | 1 | 0.1 .. 100 |"),
        ("HOST_CONFIG_PAGE", '| `action` | string | "restart" |  | `restart` \\| `degrade` \\| `stop` |'),
    ],
)
def test_schema_pages_show_defaults_limits_and_guards(pages: Any, page_name: str, row: str) -> None:
    reference_pages, _ = pages
    page = reference_pages.generated_pages()[getattr(reference_pages, page_name)]
    assert any(line.startswith(row) for line in page.splitlines()), row


PARSER = """
from bywire.schema import Reader

UNITS = ("m", "km")
LIMIT = 2.5


def _span(r, key):
    return r.number(key, default=LIMIT * 2, lo=0.0)


def _item(r):
    kind = r.string("kind", choices=UNITS)
    if kind == "km":
        r.boolean("rounded", False)
    r.finish()


def parse(data, source):
    r = Reader(data, source, "")
    r.string("name")
    box = r.sub("box")
    _span(box, "width_m")
    raw = r.raw("items", []) or []
    for i, item in enumerate(raw):
        _item(Reader(item, source, f"items[{i}]"))
    if r.has("extra"):
        r.opt_number("extra", hi=LIMIT)
    if not isinstance(raw, list):
        raise r.error("items", "expected a list of items")
"""


def test_the_schema_is_read_from_the_parser(
    pages: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, schema_reference = pages
    (tmp_path / "toy_parser.py").write_text(textwrap.dedent(PARSER), encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    fields = {
        f.path: f for f in schema_reference.SchemaExtractor(("toy_parser",)).extract("toy_parser", "parse")
    }
    assert list(fields) == ["name", "box.width_m", "items", "items[].kind", "items[].rounded", "extra"]
    assert fields["name"].required
    assert (fields["box.width_m"].default, fields["box.width_m"].lo) == ("5", "0")  # evaluated: LIMIT * 2
    assert fields["items"].kind == "a list of items"
    assert fields["items[].kind"].choices == "`m` \\| `km`"
    assert fields["items[].rounded"].conditions == ["kind == 'km'"]
    assert (fields["extra"].hi, fields["extra"].required, fields["extra"].conditions) == ("2.5", False, [])
    sections = [name for name, _ in schema_reference.iter_sections(list(fields.values()))]
    assert sections == ["", "box", "items[]"]


# --- the API reference and the site ---------------------------------------------------------------------


def test_api_reference_covers_the_public_modules_of_each_package(pages: Any) -> None:
    reference_pages, _ = pages
    generated = reference_pages.generated_pages()
    for package in reference_pages.API_PACKAGES:
        folder = ROOT.joinpath(*package.split("."))
        modules = reference_pages.public_modules(package)
        for path in folder.glob("*.py"):
            module = f"{package}.{path.stem}"
            assert (module in modules) != path.stem.startswith("_"), module
        for module in modules:
            assert not any(part.startswith("_") for part in module.split(".")), module
            assert generated[reference_pages.api_path(module)] == f"::: {module}\n"
    assert "bywire.hil.world.spec" in reference_pages.public_modules("bywire.hil")
    assert "bywire.protocol.canopen_link.nmt" in reference_pages.public_modules("bywire.protocol")


def _nav_paths(nav: Any) -> Iterator[str]:
    if isinstance(nav, str):
        yield nav
    elif isinstance(nav, dict):
        for value in nav.values():
            yield from _nav_paths(value)
    elif isinstance(nav, list):
        for value in nav:
            yield from _nav_paths(value)


def test_every_page_of_the_navigation_exists(pages: Any) -> None:
    reference_pages, _ = pages
    generated = reference_pages.generated_pages()
    paths = list(_nav_paths(reference_pages.navigation()))
    assert len(paths) == len(set(paths))
    for path in paths:
        assert path in generated or (ROOT / "docs" / path).is_file(), path
    # Every guide of docs/ is in it, and the start page opens with the README's.
    for guide in (ROOT / "docs").glob("*.md"):
        assert guide.name in paths, guide.name
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert generated["index.md"].startswith(readme.partition("\n## ")[0])
