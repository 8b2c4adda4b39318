"""Campaign files: which scenarios, which of their fields varied over which values, how many runs.

A campaign is a YAML file (docs/campaigns.md). Each of its `sweeps` takes one scenario (a shipped name
or a file), fixes some of its fields (`set`), varies others over every combination of a `grid` and over
random draws (`sample`), and may judge every run with `checks` of its own, beside the scenario's (a
bound derived for the whole range, where the scenario's own limit holds for its one speed). Fields are
named as the scenario's readers name them (`vehicle.v0_mps`, `faults[0].at_s`), plus two parameters
that are not fields: `leader_profile` (an OpenACC or CARMA CSV: a path, or `shared:GLOB` for every
match in the shared data) and `perception` (`perfect` | `lidar`).

Parsing is as strict as a scenario's, with the file's line in every error (`smoke.yaml:12:
sweeps[1].grid.vehicle.v0_mps: expected a non-empty list of values`), and every run it expands to is
parsed as a scenario before the first one starts, so that a typo stops the campaign at once, not an
hour into it.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from bywire.hil.scenario import ScenarioError, builtin_scenarios, parse_check, resolve_shipped, shipped_files
from bywire.hil.scenario_overrides import OverrideError, check_path
from bywire.hil.world.urban_spec import SHARED_PREFIX, shared_data_root
from bywire.schema import Reader, SchemaError

CAMPAIGN_SUFFIXES = (".yaml", ".yml")
# Parameters that are not fields of the scenario file: they select inputs of the run (`hil run` options).
RUN_OPTIONS = ("leader_profile", "perception")
DISTRIBUTIONS = ("uniform", "normal", "integer", "choice")
MAX_RUNS = 10_000_000  # a grid that expands beyond this is a typo, not a campaign


class CampaignError(SchemaError):
    """A campaign file that cannot be run, with the file and the path of the bad field."""


class _Reader(Reader):
    error_type = CampaignError


@dataclass(frozen=True)
class Distribution:
    kind: str  # one of DISTRIBUTIONS
    args: tuple[Any, ...]

    def draw(self, rng: Any) -> Any:
        """One value (numpy Generator `rng`), as a plain Python number or the chosen value."""
        if self.kind == "uniform":
            return float(rng.uniform(self.args[0], self.args[1]))
        if self.kind == "normal":
            return float(rng.normal(self.args[0], self.args[1]))
        if self.kind == "integer":
            return int(rng.integers(self.args[0], self.args[1], endpoint=True))
        return self.args[int(rng.integers(0, len(self.args)))]


@dataclass(frozen=True)
class Sweep:
    name: str
    scenario: str  # a shipped name or an absolute path
    fixed: dict[str, Any]
    grid: tuple[tuple[str, tuple[Any, ...]], ...]
    samples: int  # random draws per grid point (1 without `sample`)
    distributions: tuple[tuple[str, Distribution], ...]
    checks: tuple[dict[str, Any], ...]  # raw, parsed again by the worker (hil.scenario.parse_check)
    invariants: tuple[str, ...]  # metrics that must be equal across the sweep's runs


@dataclass(frozen=True)
class Run:
    """One run of a campaign: what a worker needs, as plain data (it travels to other processes and
    machines), and its place in the campaign."""

    index: int
    sweep: str
    scenario: str
    overrides: dict[str, Any]  # scenario fields (fixed and varied)
    params: dict[str, Any]  # the varied ones (the grid's and the draws'), the row's `p.` columns
    options: dict[str, Any] = field(default_factory=dict)  # leader_profile, perception
    checks: tuple[dict[str, Any], ...] = ()
    source: str = ""  # the campaign file, for the checks' errors
    invariants: tuple[str, ...] = ()  # the sweep's: judged across its runs by the report

    @property
    def run_id(self) -> str:
        """A stable name for the run: the same sweep, scenario, fields and options give the same id on
        every machine, so a resumed campaign knows what it has done."""
        key = json.dumps(
            [self.sweep, self.scenario, self.overrides, self.options, list(self.checks)],
            sort_keys=True,
            default=str,
        )
        return hashlib.sha256(key.encode()).hexdigest()[:16]

    def to_dict(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "run_id": self.run_id,
            "sweep": self.sweep,
            "scenario": self.scenario,
            "overrides": self.overrides,
            "params": self.params,
            "options": self.options,
            "checks": list(self.checks),
            "source": self.source,
            "invariants": list(self.invariants),
        }


@dataclass(frozen=True)
class Campaign:
    name: str
    description: str
    source: str
    seed: int
    sweeps: tuple[Sweep, ...]


def _distribution(r: _Reader, key: str) -> Distribution:
    raw = r.raw(key)
    if not isinstance(raw, dict) or len(raw) != 1 or next(iter(raw)) not in DISTRIBUTIONS:
        raise r.error(key, f"expected one of {{{': [..]}, {'.join(DISTRIBUTIONS)}: [..]}}, got {raw!r}")
    kind, args = next(iter(raw.items()))
    if not isinstance(args, list) or not args:
        raise r.error(f"{key}.{kind}", f"expected a list, got {args!r}")
    if kind == "choice":
        return Distribution(kind, tuple(args))
    if len(args) != 2 or not all(isinstance(a, int | float) and not isinstance(a, bool) for a in args):
        raise r.error(f"{key}.{kind}", f"expected [two numbers], got {args!r}")
    if kind == "integer" and not all(isinstance(a, int) for a in args):
        raise r.error(f"{key}.{kind}", f"expected [two integers], got {args!r}")
    if kind == "normal" and args[1] < 0:
        raise r.error(f"{key}.{kind}", f"a standard deviation >= 0, got {args[1]}")
    if kind != "normal" and args[0] > args[1]:
        raise r.error(f"{key}.{kind}", f"expected [low, high] with low <= high, got {args!r}")
    return Distribution(kind, tuple(args))


def _param_name(r: _Reader, key: str) -> None:
    if key in RUN_OPTIONS:
        return
    try:
        check_path(key)
    except OverrideError as exc:
        raise r.error(key, str(exc)) from None


def _leader_profiles(r: _Reader, key: str, values: list[Any], spec_dir: Path) -> list[str]:
    """Each leader profile as the worker reads it: `shared:REL` (a glob expanded to every match, sorted)
    or an absolute path (a relative one is the campaign file's folder's)."""
    out: list[str] = []
    for i, v in enumerate(values):
        if not isinstance(v, str):
            raise r.error(f"{key}[{i}]", f"expected a CSV path or shared:GLOB, got {v!r}")
        if v.startswith(SHARED_PREFIX):
            pattern = v[len(SHARED_PREFIX) :]
            root = shared_data_root()
            found = sorted(p.relative_to(root).as_posix() for p in root.glob(pattern) if p.is_file())
            if not found:
                raise r.error(f"{key}[{i}]", f"no file matches {pattern!r} under {root}")
            out.extend(f"{SHARED_PREFIX}{p}" for p in found)
        else:
            path = Path(v).expanduser()
            path = path if path.is_absolute() else spec_dir / path
            if not path.is_file():
                raise r.error(f"{key}[{i}]", f"no such file: {path}")
            out.append(str(path))
    return out


def _sweep(r: _Reader, spec_dir: Path, index: int) -> Sweep:
    scenario = r.string("scenario")
    path = Path(scenario)
    if path.suffix in (".yaml", ".yml", ".toml"):
        path = path if path.is_absolute() else spec_dir / path
        if not path.is_file():
            raise r.error("scenario", f"no such scenario file: {path}")
        scenario = str(path)
    elif scenario not in builtin_scenarios():
        raise r.error("scenario", f"unknown scenario {scenario!r} (see `bywire hil list`, or give a file)")
    name = r.string("name", default=Path(scenario).stem)
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}", name):
        raise r.error("name", f"expected 1-64 letters, digits, '_', '-' or '.', got {name!r}")
    fixed_raw = r.raw("set", {}) or {}
    if not isinstance(fixed_raw, dict):
        raise r.error("set", f"expected a mapping of field: value, got {fixed_raw!r}")
    fixed = dict(fixed_raw)
    fr = r.sub("set")
    for key in fixed:
        _param_name(fr, str(key))
        fr.raw(key)
    grid: list[tuple[str, tuple[Any, ...]]] = []
    gr = r.sub("grid")
    for key in list(gr.data):
        _param_name(gr, str(key))
        values = gr.raw(key)
        if not isinstance(values, list) or not values:
            raise gr.error(str(key), f"expected a non-empty list of values, got {values!r}")
        if key == "leader_profile":
            values = _leader_profiles(gr, str(key), values, spec_dir)
        grid.append((str(key), tuple(values)))
    samples = 1
    dists: list[tuple[str, Distribution]] = []
    if r.has("sample"):
        sr = r.sub("sample")
        samples = int(sr.number("runs", lo=1.0, hi=float(MAX_RUNS)))
        pr = sr.sub("params")
        for key in list(pr.data):
            _param_name(pr, str(key))
            if key == "leader_profile":
                raise pr.error(str(key), "leader profiles are listed in the grid, not drawn")
            dists.append((str(key), _distribution(pr, str(key))))
        pr.finish()
        sr.finish()
    if "leader_profile" in fixed:
        fixed["leader_profile"] = _leader_profiles(fr, "leader_profile", [fixed["leader_profile"]], spec_dir)[
            0
        ]
    names = [k for k, _ in grid] + [k for k, _ in dists]
    both = sorted(set(names) & set(fixed)) or sorted({k for k in names if names.count(k) > 1})
    if both:
        raise r.error(
            "grid", f"{both[0]} is given more than once (set, grid and sample each name a field once)"
        )
    raw_checks = r.raw("checks", []) or []
    if not isinstance(raw_checks, list):
        raise r.error("checks", "expected a list of checks")
    checks = tuple(raw_checks)
    for i, item in enumerate(checks):
        try:
            parse_check(item, r.source, r._p(f"checks[{i}]"))
        except ScenarioError as exc:
            raise CampaignError(exc.source, exc.path, exc.message) from None
    invariants = r.raw("invariant", []) or []
    if not isinstance(invariants, list) or not all(isinstance(m, str) for m in invariants):
        raise r.error("invariant", f"expected a list of metric names, got {invariants!r}")
    r.finish()
    return Sweep(name, scenario, fixed, tuple(grid), samples, tuple(dists), checks, tuple(invariants))


def parse_campaign(data: Any, source: str) -> Campaign:
    """A `Campaign` from parsed YAML; `source` names the file in errors (and relative paths start there)."""
    r = _Reader(data, source, "")
    name = r.string("name")
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}", name):
        raise r.error("name", f"expected 1-64 letters, digits, '_', '-' or '.', got {name!r}")
    description = r.string("description", default="")
    seed = int(r.number("seed", default=0.0, lo=0.0, hi=2.0**63))
    raw = r.raw("sweeps")
    if not isinstance(raw, list) or not raw:
        raise r.error("sweeps", "expected a non-empty list of sweeps")
    for key in r.data:
        if isinstance(key, str) and key.startswith("x-"):
            r.raw(key)  # a place for YAML anchors the sweeps share (`x-grid: &grid`), as compose files do
    spec_dir = Path(source).parent
    sweeps = tuple(_sweep(_Reader(item, source, f"sweeps[{i}]"), spec_dir, i) for i, item in enumerate(raw))
    seen: set[str] = set()
    for i, s in enumerate(sweeps):
        if s.name in seen:
            raise CampaignError(
                source, f"sweeps[{i}].name", f"two sweeps are named {s.name!r}: name them apart"
            )
        seen.add(s.name)
    r.finish()
    return Campaign(name, description, source, seed, sweeps)


def expand(campaign: Campaign) -> list[Run]:
    """Every run of the campaign, in a fixed order: sweeps as listed, the grid's combinations with its
    last field varying fastest, then the draws. The draws of a grid point come from a generator seeded by
    (campaign seed, sweep, point, draw), so that a run's values never depend on where it runs."""
    import numpy as np

    runs: list[Run] = []
    for si, sweep in enumerate(campaign.sweeps):
        keys = [k for k, _ in sweep.grid]
        points = list(itertools.product(*(values for _, values in sweep.grid)))
        if len(runs) + len(points) * sweep.samples > MAX_RUNS:
            raise CampaignError(campaign.source, f"sweeps[{si}]", f"expands beyond {MAX_RUNS} runs")
        for pi, point in enumerate(points):
            for di in range(sweep.samples):
                params: dict[str, Any] = dict(zip(keys, point, strict=True))
                if sweep.distributions:
                    rng = np.random.default_rng([campaign.seed, si, pi, di])
                    params.update((k, d.draw(rng)) for k, d in sweep.distributions)
                every = {**sweep.fixed, **params}
                options = {k: every.pop(k) for k in RUN_OPTIONS if k in every}
                runs.append(
                    Run(
                        index=len(runs),
                        sweep=sweep.name,
                        scenario=sweep.scenario,
                        overrides=every,
                        params=params,
                        options=options,
                        checks=sweep.checks,
                        source=campaign.source,
                        invariants=sweep.invariants,
                    )
                )
    return runs


def check_runs(campaign: Campaign, runs: list[Run]) -> None:
    """Parse every run's scenario: a field that does not exist or a value out of range is refused
    before anything runs, naming the sweep, the run and the field."""
    from bywire.hil.scenario import parse_scenario, resolve_scenario_path, with_perception
    from bywire.hil.scenario_overrides import apply_overrides

    files: dict[str, tuple[str, Any]] = {}
    for run in runs:
        if run.scenario not in files:
            path = resolve_scenario_path(run.scenario)
            files[run.scenario] = (str(path), yaml.safe_load(path.read_text(encoding="utf-8")))
        source, data = files[run.scenario]
        si = next(i for i, s in enumerate(campaign.sweeps) if s.name == run.sweep)
        try:
            scenario = parse_scenario(apply_overrides(data, run.overrides), source)
            if "perception" in run.options:
                with_perception(scenario, str(run.options["perception"]))
        except (SchemaError, ValueError) as exc:
            what = f"{exc.path}: {exc.message}" if isinstance(exc, SchemaError) and exc.path else str(exc)
            if isinstance(exc, SchemaError) and not exc.path:
                what = exc.message
            raise CampaignError(
                campaign.source, f"sweeps[{si}]", f"run {run.index} ({_params_text(run)}): {what}"
            ) from None


def _params_text(run: Run) -> str:
    return ", ".join(f"{k}={v}" for k, v in {**run.params, **run.options}.items()) or "as the scenario is"


def builtin_campaigns() -> dict[str, Path]:
    """Campaigns shipped in hil/campaigns/, by bare name."""
    return shipped_files("campaigns", CAMPAIGN_SUFFIXES)


def resolve_campaign_path(name_or_file: str) -> Path:
    return resolve_shipped(name_or_file, CAMPAIGN_SUFFIXES, builtin_campaigns, CampaignError, "campaign")


def campaign_line(text: str, path: str) -> int | None:
    """The line of `path` in the campaign's YAML `text`, as `schema.yaml_line` finds it, where a key may
    itself hold dots and brackets (a scenario field named in a grid: `grid.faults[0].at_s`)."""
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return None
    line = None
    rest = path
    while rest and node is not None:
        if isinstance(node, yaml.MappingNode):
            keys = {getattr(k, "value", None): (k, v) for k, v in node.value}
            # the longest key the path begins with, so `vehicle.v0_mps` is one key, not two
            found = max(
                (
                    k
                    for k in keys
                    if isinstance(k, str) and (rest == k or rest.startswith((f"{k}.", f"{k}[")))
                ),
                key=len,
                default=None,
            )
            if found is None:
                break
            key_node, node = keys[found]
            line = key_node.start_mark.line + 1
            rest = rest[len(found) :].lstrip(".")
        elif isinstance(node, yaml.SequenceNode):
            m = re.match(r"\[(\d+)\]\.?", rest)
            if m is None or int(m.group(1)) >= len(node.value):
                break
            node = node.value[int(m.group(1))]
            line = node.start_mark.line + 1
            rest = rest[m.end() :]
        else:
            break
    return line


def load_campaign(name_or_file: str) -> tuple[Campaign, list[Run], str]:
    """A shipped campaign by bare name or any campaign file, its runs (each checked), and its text
    (kept beside the results)."""
    path = resolve_campaign_path(name_or_file)
    text = path.read_text(encoding="utf-8")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        raise CampaignError(where, "", f"not valid YAML: {getattr(exc, 'problem', exc)}") from None
    try:
        campaign = parse_campaign(data, str(path))
        runs = expand(campaign)
        check_runs(campaign, runs)
    except SchemaError as exc:
        if exc.source != str(path):
            raise
        raise exc.at_line(campaign_line(text, exc.path)) from None
    return campaign, runs, text


__all__ = [
    "Campaign",
    "CampaignError",
    "Run",
    "Sweep",
    "builtin_campaigns",
    "check_runs",
    "expand",
    "load_campaign",
    "parse_campaign",
]
