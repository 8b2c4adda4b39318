"""The pages of the documentation site that are generated from the code at every build.

`make docs` (MkDocs, `mkdocs.yml`) shows the hand-written guides in docs/ beside pages that must not
drift from what they describe, so they are written here from their source each time and never kept
as copies: the protocol table (`bywire.protocol.table`, from the DBC and the EDS), the scenario and
host-configuration schemas (read from their parsers by `schema_reference`), the calibration's limits
(`bywire.ecu.calibration`, with the Passat's values and their reasons from
`ecu/calibrations/make_passat.py`), the API reference of the public modules of protocol, ecu, the host
runtime and hil, and the start page (the README's). `hooks.py` hands them to MkDocs;
`tests/test_docs.py` checks what they hold.
"""

from __future__ import annotations

import ast
import functools
import importlib
import inspect
import re
from collections.abc import Callable
from pathlib import Path

from schema_reference import SchemaExtractor, SchemaField, iter_sections

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"

# The packages with an API reference: the contract, the firmware, the host's framework, the simulator.
API_PACKAGES = ("bywire.protocol", "bywire.ecu", "bywire.host.runtime", "bywire.hil")

PROTOCOL_PAGE = "protocol.md"
PROTOCOL_PQ_PAGE = "protocol_pq.md"  # the vehicle profile pq's table
SCENARIO_PAGE = "reference/scenario_schema.md"
HOST_CONFIG_PAGE = "reference/host_config_schema.md"
CALIBRATION_PAGE = "reference/calibration_limits.md"

SCENARIO_PARSERS = ("bywire.hil.scenario", "bywire.hil.world.spec", "bywire.hil.world.urban_spec")
HOST_CONFIG_PARSERS = ("bywire.host.config",)


# --- the API reference -------------------------------------------------------------------------------


def public_modules(package: str) -> list[str]:
    """`package` and its modules and subpackages whose names do not start with `_`, sorted."""
    folder = ROOT.joinpath(*package.split("."))
    found = [package]
    for path in sorted(folder.rglob("*.py")):
        parts = path.relative_to(folder).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
            if not parts:
                continue
        if any(p.startswith("_") for p in parts):
            continue
        if not all((folder.joinpath(*parts[:i]) / "__init__.py").is_file() for i in range(1, len(parts))):
            continue  # a folder of scripts or data, not a package
        found.append(".".join((package, *parts)))
    return sorted(found)


def api_path(module: str) -> str:
    return f"api/{module}.md"


def api_page(module: str) -> str:
    return f"::: {module}\n"


# --- the protocol table ------------------------------------------------------------------------------


def protocol_page(profile: str = "bywire") -> str:
    from bywire.protocol.table import render_protocol_table

    return render_protocol_table(profile=profile)


# --- the schemas ---------------------------------------------------------------------------------------


def _cell(text: str) -> str:
    # Choices come with their bars escaped already; everything else may hold a bare one.
    return (text if "\\|" in text else text.replace("|", "\\|")).replace("\n", " ")


def _range(f: SchemaField) -> str:
    if f.lo and f.hi:
        return f"{f.lo} .. {f.hi}"
    if f.lo:
        return f">= {f.lo}"
    if f.hi:
        return f"<= {f.hi}"
    return ""


def _default(f: SchemaField) -> str:
    if f.required:
        return "**required**"
    if f.method == "profile":
        return "none"
    return f.default


def _when(f: SchemaField) -> str:
    return " and ".join(f"`{c}`" for c in f.conditions)


SCHEMA_COLUMNS: tuple[tuple[str, Callable[[SchemaField], str]], ...] = (
    ("field", lambda f: f"`{f.path.rpartition('.')[2]}`"),
    ("type", lambda f: f.kind),
    ("default", _default),
    ("range", _range),
    ("one of", lambda f: f.choices),
    ("read when", _when),
    ("also refused", lambda f: "; ".join(f"“{m}”" for m in f.refusals)),
)


def schema_tables(fields: list[SchemaField]) -> list[str]:
    """One table per mapping of the file (top level first), a row per field, in the parser's order;
    a column only where a row of the table has something in it."""
    lines: list[str] = []
    for section, rows in iter_sections(fields):
        cells = [[render(f) for _, render in SCHEMA_COLUMNS] for f in rows]
        used = [
            i for i, (name, _) in enumerate(SCHEMA_COLUMNS) if name == "field" or any(c[i] for c in cells)
        ]
        lines += ["", f"## `{section}`" if section else "## Top level", ""]
        lines.append("| " + " | ".join(SCHEMA_COLUMNS[i][0] for i in used) + " |")
        lines.append("|" + "---|" * len(used))
        for row in cells:
            lines.append("| " + " | ".join(_cell(row[i]) for i in used) + " |")
    return lines


def _module_doc(module: str) -> str:
    doc = inspect.getdoc(importlib.import_module(module)) or ""
    return doc.strip()


def _schema_page(title: str, parsers: tuple[str, ...], entry: str, guide: str, intro: str) -> str:
    fields = SchemaExtractor(parsers).extract(parsers[0], entry)
    lines = [
        f"# {title}",
        "",
        f"Generated at every build from the parser, `{parsers[0]}.{entry}` "
        f"(and {', '.join(f'`{p}`' for p in parsers[1:]) or 'the helpers it calls'}): "
        "each row is a field the parser reads, with its default and the limits it enforces. "
        # The schema pages live in reference/, the guides beside it.
        f"What the fields mean, with examples: [{guide}](../{guide}).",
        "",
        f"`[]` in a path stands for every item of a list. {intro}",
        "",
        "## From the parser's documentation",
        "",
        _demote(_module_doc(parsers[0])),
    ]
    lines += schema_tables(fields)
    return "\n".join(lines) + "\n"


def _demote(markdown: str) -> str:
    """A docstring shown inside a page: prose as it is, without headings of its own."""
    return re.sub(r"^#+ ", "", markdown, flags=re.MULTILINE)


def scenario_schema_page() -> str:
    return _schema_page(
        "Scenario file schema",
        SCENARIO_PARSERS,
        "parse_scenario",
        "scenarios.md",
        "A scenario is YAML or TOML; paths in it are relative to its own folder. A field that is not in "
        "these tables is refused, with the file, the line (YAML) and the field's path.",
    )


def host_config_schema_page() -> str:
    return _schema_page(
        "Host configuration schema",
        HOST_CONFIG_PARSERS,
        "parse_host_config",
        "host_config.md",
        "A configuration is YAML or TOML. `extends: NAME_OR_FILE` (read before the fields below) starts "
        "from another configuration and overrides its modules by name, field by field. A field that is "
        "not in these tables is refused, with the file and the field's path.",
    )


# --- the calibration's limits --------------------------------------------------------------------------


def _field_comments(cls: type) -> dict[str, str]:
    """The comment after each field of a dataclass (`accel_min_mps2: float  # request clamp ...`)."""
    lines, _ = inspect.getsourcelines(cls)
    out = {}
    for line in lines:
        m = re.match(r"\s+(\w+): [^#=]+(?:=[^#]*)?#\s*(.+)$", line)
        if m:
            out[m.group(1)] = m.group(2).strip()
    return out


def _make_passat_reasons() -> dict[str, str]:
    """Why the Passat has each value: the comments on or above its key in make_passat.make_document."""
    path = ROOT / "bywire" / "ecu" / "calibrations" / "make_passat.py"
    source = path.read_text(encoding="utf-8")
    lines = source.splitlines()
    tree = ast.parse(source)
    reasons: dict[str, str] = {}
    for node in ast.walk(tree):
        if not isinstance(node, ast.Dict):
            continue
        for key in node.keys:
            if not (isinstance(key, ast.Constant) and isinstance(key.value, str)):
                continue
            parts = []
            above = key.lineno - 2
            block: list[str] = []
            while above >= 0 and lines[above].strip().startswith("#"):
                block.insert(0, lines[above].strip().lstrip("#").strip())
                above -= 1
            parts += block
            same = lines[key.lineno - 1]
            if "#" in same:
                parts.append(same.split("#", 1)[1].strip())
            if parts:
                reasons[key.value] = " ".join(parts)
    return reasons


def _map_ranges() -> list[tuple[str, str, str, str]]:
    """The value ranges of the maps' grids: each `_vector(...)` call of the calibration's reader."""
    from bywire.ecu import calibration

    namespace = vars(calibration)
    tree = ast.parse(inspect.getsource(calibration))
    rows = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "_vector":
            path, lo, hi, unit = (node.args[i] for i in (1, 3, 4, 5))
            values = [
                eval(compile(ast.Expression(a), "<calibration>", "eval"), {"__builtins__": {}, **namespace})
                for a in (path, lo, hi, unit)
            ]
            rows.append((str(values[0]), f"{values[1]:g}", f"{values[2]:g}", str(values[3])))
    return rows


def _unit(name: str) -> str:
    suffixes = {
        "_mps2": "m/s²",
        "_mps3": "m/s³",
        "_mps": "m/s",
        "_radps": "rad/s",
        "_rad": "rad",
        "_bar": "bar",
        "_s": "s",
        "_nm": "N m",
        "_pct": "%",
        "_per_s": "1/s",
    }
    for suffix in sorted(suffixes, key=len, reverse=True):
        if name.endswith(suffix):
            return suffixes[suffix]
    return ""


def calibration_limits_page() -> str:
    from bywire.ecu import calibration
    from bywire.ecu.calibration import Calibration, default_calibration

    ranges = calibration._RANGES  # the table the reader enforces, by design not public API
    meaning = _field_comments(Calibration)
    reasons = _make_passat_reasons()
    passat = default_calibration()
    lines = [
        "# Calibration limits",
        "",
        "Generated at every build from `bywire.ecu.calibration`: the range the ECU accepts for every "
        "scalar of a calibration (`calibration_from_dict` refuses anything outside, naming the field), "
        "what the firmware does with it, and the value of the packaged Passat calibration with its reason "
        "from `ecu/calibrations/make_passat.py`. Bounds are inclusive.",
        "",
        f"Format `{calibration.FORMAT}`; on disk and over SDO canonical JSON with a CRC-32 (see "
        "[the module](../api/bywire.ecu.calibration.md)).",
        "",
        "## Scalars",
        "",
        "| field | unit | min | max | accepted | meaning | Passat | why the Passat's value |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, (lo, hi, what) in ranges.items():
        value = getattr(passat, name)
        cells = (
            f"`{name}`",
            _unit(name),
            f"{lo:g}",
            f"{hi:g}",
            what,
            meaning.get(name, ""),
            f"{value:g}",
            reasons.get(name, ""),
        )
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    lines += [
        "",
        "Across fields, the reader also demands: each stop deceleration (`pause_decel_mps2`, "
        "`disable_decel_mps2`, `safe_stop_decel_mps2`) at most `-accel_min_mps2`, so that the request "
        "clamp never weakens a stop; and a brake map that reaches `-accel_min_mps2`.",
        "",
        "## Maps",
        "",
        f"Each grid has 2 .. {calibration._MAX_GRID} points; axes strictly increasing, throttle rows and "
        "brake pressures non-decreasing, the coast map non-increasing, the brake map starting at 0 "
        "(coasting).",
        "",
        "| grid | min | max | unit |",
        "|---|---|---|---|",
    ]
    for path, lo, hi, unit in _map_ranges():
        lines.append(f"| `{path}` | {lo} | {hi} | {unit} |")
    lines.append(f"| `throttle_map.pct` | 0 | {calibration.THROTTLE_PCT_MAX:g} | % |")
    return "\n".join(lines) + "\n"


# --- the start page ------------------------------------------------------------------------------------


def guides() -> list[tuple[str, str]]:
    """The hand-written pages of docs/ (file, title from its first heading), the protocol tables aside."""
    out = []
    for path in sorted(DOCS.glob("*.md")):
        if path.name in (PROTOCOL_PAGE, PROTOCOL_PQ_PAGE):
            continue
        first = next((ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.startswith("# ")), "")
        out.append((path.name, first[2:].strip() or path.stem))
    return out


def reference_pages() -> list[tuple[str, str]]:
    return [
        (PROTOCOL_PAGE, "Protocol table"),
        (PROTOCOL_PQ_PAGE, "Protocol table, vehicle profile pq"),
        (SCENARIO_PAGE, "Scenario file schema"),
        (HOST_CONFIG_PAGE, "Host configuration schema"),
        (CALIBRATION_PAGE, "Calibration limits"),
    ]


def index_page() -> str:
    """The README, with a map of this site after its opening (the text before its first section)."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    opening, sep, rest = readme.partition("\n## ")
    site = [
        "",
        "## This documentation",
        "",
        "Built by `make docs` into `build/docs/` (and checked by `make test`); the reference pages and the "
        "API are generated from the code at every build.",
        "",
        "- Guides: " + ", ".join(f"[{title}]({name})" for name, title in guides()),
        "- Reference: " + ", ".join(f"[{title}]({name})" for name, title in reference_pages()),
        "- API: " + ", ".join(f"[`{p}`]({api_path(p)})" for p in API_PACKAGES),
        "",
    ]
    return opening.rstrip() + "\n" + "\n".join(site) + sep + rest


# --- the site ---------------------------------------------------------------------------------------------


@functools.cache
def generated_pages() -> dict[str, str]:
    """Every generated page: its path in the site's sources -> its Markdown."""
    pages = {
        "index.md": index_page(),
        PROTOCOL_PAGE: protocol_page(),
        PROTOCOL_PQ_PAGE: protocol_page("pq"),
        SCENARIO_PAGE: scenario_schema_page(),
        HOST_CONFIG_PAGE: host_config_schema_page(),
        CALIBRATION_PAGE: calibration_limits_page(),
    }
    for package in API_PACKAGES:
        for module in public_modules(package):
            pages[api_path(module)] = api_page(module)
    return pages


def navigation() -> list[dict[str, object]]:
    """The site's navigation: home, guides, reference, then the API by package and module."""
    api = [
        {f"{package}": [{module: api_path(module)} for module in public_modules(package)]}
        for package in API_PACKAGES
    ]
    return [
        {"Home": "index.md"},
        {"Guides": [{title: name} for name, title in guides()]},
        {"Reference": [{title: name} for name, title in reference_pages()]},
        {"API": api},
    ]
