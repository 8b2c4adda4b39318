"""The host configuration file: which modules run, with which rates, deadlines, policies and parameters.

One YAML (or TOML) file per host setup (schema in docs/host_config.md), started with
`bywire host run CONFIG`. Parsing is as strict as for scenarios: an unknown key, a wrong type or an
impossible value is refused with the file and the path of the field (`default.yaml:
modules[4].policy.action: expected one of restart, degrade, stop, got 'reboot'`).

A configuration may `extends:` another (a shipped name or a file) and override its modules by name,
field by field, so a variant (perception in its own process, say) states only what differs.
"""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from bywire.host.modules import KINDS
from bywire.host.runtime.module import ACTIONS, FailurePolicy, ModuleSpec
from bywire.schema import Reader, SchemaError

SUFFIXES = (".yaml", ".yml", ".toml")


class HostConfigError(SchemaError):
    """A host configuration that cannot be run, with the file and the path of the bad field."""


class _Reader(Reader):
    error_type = HostConfigError


@dataclass(frozen=True)
class ModuleConfig:
    spec: ModuleSpec
    kind: str
    params: dict[str, Any]


@dataclass(frozen=True)
class HostConfig:
    source: str
    ecu_link: str
    sensor_bus: str | None
    tick_s: float
    health_period_s: float
    live_view_port: int | None
    modules: tuple[ModuleConfig, ...]
    data: dict[str, Any] = field(default_factory=dict)  # as parsed (after `extends`): for recordings
    v2x: str | None = None  # cooperative driving: the V2X link (v2x://... or mem://...)
    gps_serial: str | None = None  # cooperative driving: the GPS/INS serial port

    def uses(self, *kinds: str) -> bool:
        return any(m.kind in kinds for m in self.modules)

    def module(self, name: str) -> ModuleConfig:
        for m in self.modules:
            if m.spec.name == name:
                return m
        raise KeyError(name)


def shipped_configs() -> dict[str, Path]:
    folder = resources.files("bywire.host") / "configs"
    return {Path(str(e)).stem: Path(str(e)) for e in folder.iterdir() if Path(str(e)).suffix in SUFFIXES}


def _resolve(name_or_file: str, relative_to: str | None = None) -> Path:
    path = Path(name_or_file)
    if path.suffix in SUFFIXES:
        if not path.is_absolute() and relative_to is not None and Path(relative_to).is_file():
            path = Path(relative_to).parent / path
        if not path.is_file():
            raise HostConfigError(name_or_file, "", "no such host configuration file")
        return path
    known = shipped_configs()
    if name_or_file not in known:
        raise HostConfigError(
            name_or_file, "", f"unknown host configuration; shipped ones: {', '.join(sorted(known))}"
        )
    return known[name_or_file]


def _read(path: Path) -> Any:
    text = path.read_text(encoding="utf-8")
    try:
        data = tomllib.loads(text) if path.suffix == ".toml" else yaml.safe_load(text)
    except (yaml.YAMLError, tomllib.TOMLDecodeError) as exc:
        raise HostConfigError(str(path), "", f"not valid {path.suffix[1:].upper()}: {exc}") from exc
    if not isinstance(data, dict):
        raise HostConfigError(str(path), "", f"expected a mapping at the top, got {type(data).__name__}")
    return data


def _merge(base: dict[str, Any], over: dict[str, Any], source: str) -> dict[str, Any]:
    """`over` on top of `base`; modules are merged by name, field by field (policy and params too)."""
    merged = {k: v for k, v in base.items()}
    for key, value in over.items():
        if key == "modules":
            if not isinstance(value, list):
                raise HostConfigError(source, "modules", "expected a list of modules")
            mods = [dict(m) for m in base.get("modules", []) if isinstance(m, dict)]
            names = [m.get("name") for m in mods]
            for i, item in enumerate(value):
                if not isinstance(item, dict) or "name" not in item:
                    raise HostConfigError(source, f"modules[{i}]", "expected a mapping with a name")
                if item["name"] in names:
                    target = mods[names.index(item["name"])]
                    for k, v in item.items():
                        if (
                            k in ("policy", "params")
                            and isinstance(v, dict)
                            and isinstance(target.get(k), dict)
                        ):
                            target[k] = {**target[k], **v}
                        else:
                            target[k] = v
                else:
                    mods.append(dict(item))
                    names.append(item["name"])
            merged["modules"] = mods
        elif isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = {**merged[key], **value}
        else:
            merged[key] = value
    return merged


def _load_data(path: Path, depth: int = 0) -> dict[str, Any]:
    data = _read(path)
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if depth > 8 or not isinstance(parent, str):
        raise HostConfigError(str(path), "extends", "expected the name or file of another host configuration")
    return _merge(_load_data(_resolve(parent, str(path)), depth + 1), data, str(path))


def _policy(r: _Reader) -> FailurePolicy:
    kw: dict[str, Any] = {
        "action": r.string("action", default="restart", choices=ACTIONS),
        "escalate_to": r.string("escalate_to", default="stop", choices=("degrade", "stop")),
        "max_restarts": int(r.number("max_restarts", default=3.0, lo=0.0, hi=1000.0)),
        "restart_window_s": r.number("restart_window_ms", default=30_000.0, lo=0.0) / 1e3,
        "backoff_s": r.number("backoff_ms", default=0.0, lo=0.0, hi=600_000.0) / 1e3,
        "backoff_max_s": r.number("backoff_max_ms", default=2000.0, lo=0.0) / 1e3,
        "slow_misses": int(r.number("slow_misses", default=3.0, lo=1.0, hi=1000.0)),
        "slow_window": int(r.number("slow_window", default=10.0, lo=1.0, hi=1000.0)),
        "degrade_speed_mps": r.number("degrade_speed_mps", default=5.0, lo=0.0, hi=70.0),
        "restart_as_dependant": r.boolean("restart_as_dependant", True),
        "silent_releases": int(r.number("silent_releases", default=3.0, lo=1.0, hi=1000.0)),
    }
    if r.has("on_slow"):
        kw["on_slow"] = r.string("on_slow", choices=ACTIONS)
    hang = r.opt_number("hang_after_ms", lo=0.1)
    kw["hang_after_s"] = None if hang is None else hang / 1e3
    if kw["slow_window"] < kw["slow_misses"]:
        raise r.error("slow_window", f"must be >= slow_misses ({kw['slow_misses']})")
    r.finish()
    return FailurePolicy(**kw)


def _module(r: _Reader) -> ModuleConfig:
    name = r.string("name")
    kind_name = r.string("kind", choices=tuple(KINDS))
    kind = KINDS[kind_name]
    period_ms = r.number("period_ms", default=kind.period_s * 1e3, lo=0.1, hi=3_600_000.0)
    deadline_ms = r.number("deadline_ms", default=kind.deadline_s * 1e3, lo=0.01, hi=3_600_000.0)
    isolation = r.string("isolation", default="thread", choices=("thread", "process"))
    always_release = r.boolean("always_release", kind.always_release)
    if isolation == "process" and kind.needs_resources:
        raise r.error(
            "isolation", f"a {kind_name} module uses the host's buses and cannot run in a process of its own"
        )
    policy = _policy(r.sub("policy"))
    params = r.raw("params", {}) or {}
    if not isinstance(params, dict):
        raise r.error("params", f"expected a mapping, got {params!r}")
    try:
        kind.check_params(params)
    except ValueError as exc:
        raise r.error("params", str(exc)) from exc
    r.finish()
    try:
        spec = ModuleSpec(
            name=name,
            inputs=kind.inputs,
            sampled=kind.sampled,
            outputs=kind.outputs,
            period_s=period_ms / 1e3,
            deadline_s=deadline_ms / 1e3,
            policy=policy,
            isolation=isolation,  # type: ignore[arg-type]
            always_release=always_release,
        )
    except ValueError as exc:
        raise r.error("name", str(exc)) from exc
    return ModuleConfig(spec, kind_name, dict(params))


def parse_host_config(data: Any, source: str) -> HostConfig:
    r = _Reader(data, source, "")
    ecu_link = r.string("ecu_link", default="udp://127.0.0.1:47001?peer=127.0.0.1:47000")
    sensor_bus = r.raw("sensor_bus")
    if sensor_bus is not None and not isinstance(sensor_bus, str):
        raise r.error("sensor_bus", f"expected a bus URL or null, got {sensor_bus!r}")
    # `scenario:` named the simulator's script a host drove before a car's mission could be given on the
    # command line; files that still carry it load, and it means nothing.
    r.string("scenario", default="")
    v2x = r.raw("v2x")
    if v2x is not None and not (isinstance(v2x, str) and v2x.startswith(("v2x://", "mem://"))):
        raise r.error("v2x", f"expected a v2x://HOST:PORT or mem://NAME link, or null, got {v2x!r}")
    gps_serial = r.raw("gps_serial")
    if gps_serial is not None and not (isinstance(gps_serial, str) and gps_serial):
        raise r.error(
            "gps_serial", f"expected a serial port (a path or pyserial URL) or null, got {gps_serial!r}"
        )
    rt = r.sub("runtime")
    tick_s = rt.number("tick_ms", default=1.0, lo=0.1, hi=100.0) / 1e3
    health_s = rt.number("health_period_ms", default=100.0, lo=1.0, hi=60_000.0) / 1e3
    rt.finish()
    lv = r.sub("live_view")
    live = lv.boolean("enabled", False)
    port = int(lv.number("port", default=8765.0, lo=1.0, hi=65535.0))
    lv.finish()
    raw_modules = r.raw("modules")
    if not isinstance(raw_modules, list) or not raw_modules:
        raise r.error("modules", "expected a non-empty list of modules")
    modules = tuple(_module(_Reader(item, source, f"modules[{i}]")) for i, item in enumerate(raw_modules))
    names = [m.spec.name for m in modules]
    for i, n in enumerate(names):
        if n in names[:i]:
            raise HostConfigError(source, f"modules[{i}].name", f"two modules named {n!r}")
    producers: dict[str, str] = {}
    for i, m in enumerate(modules):
        for topic in m.spec.outputs:
            if topic in producers:
                raise HostConfigError(
                    source, f"modules[{i}]", f"{topic} is already produced by module {producers[topic]!r}"
                )
            producers[topic] = m.spec.name
    r.finish()
    return HostConfig(
        source,
        ecu_link,
        sensor_bus,
        tick_s,
        health_s,
        port if live else None,
        modules,
        copy.deepcopy(data),
        v2x,
        gps_serial,
    )


def load_host_config(
    name_or_file: str,
    module_params: Mapping[str, Mapping[str, Any]] | None = None,
    params_at: tuple[str, str] = ("", "params"),
) -> HostConfig:
    """A shipped configuration by bare name (`default`), or any configuration file; `module_params`
    (module name -> parameters) set some of its modules' parameters over the file's, as an `extends`
    file would (a scenario's `host.params`: an error names them by `params_at`, (file, field path))."""
    path = _resolve(name_or_file)
    data = _load_data(path)
    if module_params:
        names = {m.get("name") for m in data.get("modules", []) if isinstance(m, dict)}
        for name, params in module_params.items():
            source, field_path = params_at[0] or str(path), f"{params_at[1]}.{name}"
            if name not in names:
                known = ", ".join(sorted(str(n) for n in names))
                message = f"no module {name!r} in {path.name} (its modules: {known})"
                raise HostConfigError(source, field_path, message)
            if not isinstance(params, Mapping):
                raise HostConfigError(source, field_path, f"expected a mapping of parameters, got {params!r}")
        over = {"modules": [{"name": n, "params": dict(p)} for n, p in module_params.items()]}
        data = _merge(data, over, params_at[0] or str(path))
    return parse_host_config(data, str(path))
