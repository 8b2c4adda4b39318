"""`bywire log info|plot|export FILE`: inspecting an MCAP recording from the command line.

`info` lists the topics with their schema, message count, first/last time, mean rate and gaps, and
says whether the file was closed cleanly or is a crash-truncated recording. `plot` draws chosen
numeric fields over time into a PNG. `export` writes its CAN frames into a python-can log file
(ASC, BLF, TRC, candump .log, ...) for the field's tools, each bus on its own channel
(`runtime.can_log`). They read with `mcap_reader`'s tolerant reader, so a recording
cut short by a crash is inspected up to its last complete chunk, and a damaged one is refused with
a LogError naming the file and the problem.

Gaps: a topic's period is the median interval between its distinct log times (so bursts of frames
sharing one time stamp, as on a CAN bus topic, do not make it zero); an interval longer than 3x that
period counts as a gap.

Wiring: `add_arguments(log_subparsers)` adds the commands to an argparse subparsers object created
with `dest="log_command"`, and `main(args)` dispatches on `args.log_command` through `COMMANDS`
(add `replay` there).
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bywire.host.runtime.can_frame import CAN_TOPIC_PREFIX
from bywire.host.runtime.log_schema import LogError
from bywire.host.runtime.mcap_reader import McapLogReader, read_objects

GAP_FACTOR = 3.0  # an interval longer than this many periods is a gap


def add_arguments(log_subparsers: Any) -> None:
    """Add `info`, `plot`, `export`, `scene` and `replay` to the subparsers of `bywire log` (created with
    dest="log_command")."""
    info = log_subparsers.add_parser(
        "info", help="topics of a recording: message counts, rates, gaps; whether it was closed cleanly"
    )
    info.add_argument("file", type=Path, help="an MCAP recording")
    info.add_argument("--json", type=Path, metavar="OUT", help="also write the result as JSON ('-': stdout)")
    plot = log_subparsers.add_parser("plot", help="time plots of chosen numeric fields of a recording")
    plot.add_argument("file", type=Path, help="an MCAP recording")
    plot.add_argument(
        "--signal",
        action="append",
        required=True,
        metavar="TOPIC.FIELD",
        help="a numeric field, nested fields and indexes with dots (/ego/pose.v_mps, /can/vehicle.dlc, "
        "/track.points.0.x_m); repeat for more plots",
    )
    plot.add_argument("--output", type=Path, metavar="PNG", help="the image to write (default: FILE.png)")
    export = log_subparsers.add_parser(
        "export",
        help="the CAN frames of a recording as ASC, BLF, TRC, MF4, candump .log or CSV (by OUT's suffix); "
        "the vehicle bus on channel 1, the host link on channel 2",
    )
    export.add_argument("file", type=Path, help="an MCAP recording")
    export.add_argument(
        "-o", "--output", type=Path, required=True, metavar="OUT", help="the log file to write"
    )
    scene = log_subparsers.add_parser(
        "scene",
        help="the urban host's world of a recording as a Foxglove 3D scene: obstacle cells, tracks, our "
        "car, its path, the LIDAR's points (needs bywire[live])",
    )
    scene.add_argument("file", type=Path, help="an MCAP recording of an urban run")
    scene.add_argument(
        "-o", "--output", type=Path, required=True, metavar="OUT", help="the MCAP file to write"
    )
    rep = log_subparsers.add_parser(
        "replay", help="feed a recording back through the host's computing modules on simulated time"
    )
    rep.add_argument(
        "file", type=Path, help="an MCAP recording of a bywire host (bywire hil run NAME --record)"
    )
    rep.add_argument(
        "--check",
        action="store_true",
        help="exit 1 unless every replayed output matches the recording within the tolerances",
    )
    rep.add_argument("--module", action="append", metavar="NAME", help="replay only these modules (repeat)")
    rep.add_argument(
        "--json", type=Path, metavar="OUT", help="also write the comparison as JSON ('-': stdout)"
    )


def main(args: argparse.Namespace, inputs_for: Any = None) -> int:
    """Run one `bywire log` command; 0 on success, 2 on a recording or argument error (printed).
    `inputs_for`: how `replay` rebuilds a recording's mission (default: a car's, `host.replay`)."""
    if args.log_command == "replay":
        return _cmd_replay(args, inputs_for)
    command = COMMANDS.get(args.log_command)
    if command is None:
        known = ", ".join(COMMANDS)
        print(f"error: log: unknown command {args.log_command!r} (known: {known})", file=sys.stderr)
        return 2
    try:
        return command(args)
    except LogError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


# -- info ---------------------------------------------------------------------------------------------------


def log_info(path: str | Path) -> dict[str, Any]:
    """The summary `bywire log info` prints, as a JSON-ready dict (times in seconds of log time)."""
    reader = McapLogReader(path)
    schemas: dict[str, str] = {}
    times_ns: dict[str, list[int]] = {}
    for msg in reader.messages():
        topic = msg.topic
        if topic not in times_ns:
            times_ns[topic] = []
            schemas[topic] = msg.channel.schema.name if msg.channel.schema is not None else ""
        times_ns[topic].append(msg.log_time_ns)
    for info in reader.channels.values():  # topics that were declared but carry no message
        if info.topic not in times_ns:
            times_ns[info.topic] = []
            schemas[info.topic] = info.schema.name if info.schema is not None else ""
    topics = {topic: _topic_stats(schemas[topic], times_ns[topic]) for topic in sorted(times_ns)}
    firsts = [t["first_s"] for t in topics.values() if t["first_s"] is not None]
    lasts = [t["last_s"] for t in topics.values() if t["last_s"] is not None]
    return {
        "file": str(path),
        "complete": reader.complete,
        "ending": reader.end_note,
        "damage": reader.damage,
        "messages": sum(t["count"] for t in topics.values()),
        "start_s": min(firsts) if firsts else None,
        "end_s": max(lasts) if lasts else None,
        "duration_s": max(lasts) - min(firsts) if firsts else 0.0,
        "topics": topics,
    }


def _topic_stats(schema: str, times_ns: list[int]) -> dict[str, Any]:
    count = len(times_ns)
    stats: dict[str, Any] = {
        "schema": schema,
        "count": count,
        "first_s": None,
        "last_s": None,
        "rate_hz": None,
        "period_s": None,
        "max_gap_s": None,
        "gaps": 0,
    }
    if count == 0:
        return stats
    # Sorted: a file's order is chunk order, and times may step back across topics' chunks.
    t_ns = np.sort(np.asarray(times_ns, dtype=np.uint64)).astype(np.int64)
    stats["first_s"] = float(t_ns[0]) * 1e-9
    stats["last_s"] = float(t_ns[-1]) * 1e-9
    if count < 2:
        return stats
    intervals_s = np.diff(t_ns) * 1e-9
    span_s = float(t_ns[-1] - t_ns[0]) * 1e-9
    stats["max_gap_s"] = float(intervals_s.max())
    if span_s > 0:
        stats["rate_hz"] = (count - 1) / span_s
        period_s = float(np.median(intervals_s[intervals_s > 0]))
        stats["period_s"] = period_s
        stats["gaps"] = int(np.count_nonzero(intervals_s > GAP_FACTOR * period_s))
    return stats


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def format_info(info: dict[str, Any]) -> str:
    state = "complete" if info["complete"] else "NOT CLOSED (crash-truncated or still being written)"
    lines = [
        f"{info['file']}: {state}; {info['ending']}",
        f"{info['messages']} messages on {len(info['topics'])} topics, "
        f"{_fmt(info['start_s'], '.3f')} .. {_fmt(info['end_s'], '.3f')} s "
        f"(duration {info['duration_s']:.3f} s)",
        "",
    ]
    rows = [("topic", "schema", "count", "rate_hz", "first_s", "last_s", "max_gap_s", "gaps")]
    for topic, t in info["topics"].items():
        rows.append(
            (
                topic,
                t["schema"] or "-",
                str(t["count"]),
                _fmt(t["rate_hz"], ".2f"),
                _fmt(t["first_s"], ".3f"),
                _fmt(t["last_s"], ".3f"),
                _fmt(t["max_gap_s"], ".4f"),
                str(t["gaps"]),
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    for row in rows:
        cells = [
            cell.ljust(width) if i < 2 else cell.rjust(width)
            for i, (cell, width) in enumerate(zip(row, widths, strict=True))
        ]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines) + "\n"


def _cmd_info(args: argparse.Namespace) -> int:
    info = log_info(args.file)
    sys.stdout.write(format_info(info))
    if args.json is not None:
        text = json.dumps(info, indent=2) + "\n"
        if str(args.json) == "-":
            sys.stdout.write(text)
        else:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(text, encoding="utf-8")
    return 0


# -- plot ---------------------------------------------------------------------------------------------------


def _split_signal(signal: str, topics: list[str], path: str | Path) -> tuple[str, list[str]]:
    """TOPIC.FIELD -> (topic, field path); the longest matching topic wins (topics may contain dots)."""
    for topic in sorted(topics, key=len, reverse=True):
        if signal.startswith(topic + ".") and len(signal) > len(topic) + 1:
            return topic, signal[len(topic) + 1 :].split(".")
    if signal in topics:
        raise LogError(path, f"signal {signal!r} names a topic but no field: say TOPIC.FIELD")
    raise LogError(path, f"signal {signal!r}: no such topic; the recording has {', '.join(topics) or 'none'}")


def _fields_of(value: Any) -> list[str]:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return [f.name for f in dataclasses.fields(value)]
    if isinstance(value, dict):
        return [str(k) for k in value]
    if isinstance(value, list | tuple):
        return [str(i) for i in range(len(value))]
    return []


def field_value(obj: Any, field_path: list[str]) -> Any:
    """The value at a dotted field path in a decoded object (dataclass, dict, tuple/list by index).

    None (an absent Optional) anywhere on the path gives None: a gap in the plot, not an error.
    Raises KeyError with the fields that exist where the path went wrong.
    """
    value = obj
    for depth, name in enumerate(field_path):
        if value is None:
            return None
        if dataclasses.is_dataclass(value) and not isinstance(value, type) and name in _fields_of(value):
            value = getattr(value, name)
        elif isinstance(value, dict) and name in value:
            value = value[name]
        elif isinstance(value, list | tuple) and name.isdigit() and int(name) < len(value):
            value = value[int(name)]
        else:
            where = ".".join(field_path[:depth]) or "the message"
            known = _fields_of(value)
            raise KeyError(
                f"no field {name!r} in {where}"
                + (f" (fields: {', '.join(known)})" if known else f" (a {type(value).__name__} value)")
            )
    return value


def _as_number(value: Any) -> float | None:
    """A plottable number for a field value; None for what is not a number at all."""
    if value is None:
        return math.nan
    if isinstance(value, enum.Enum):
        value = value.value
    if isinstance(value, bool | int | float | np.integer | np.floating | np.bool_):
        return float(value)
    return None


def plot_signals(path: str | Path, signals: list[str], output: str | Path) -> Path:
    """Plot each signal (TOPIC.FIELD) over log time into `output` (PNG); LogError for unknown names."""
    reader = McapLogReader(path)
    topics = sorted({msg.topic for msg in reader.messages()})
    wanted = [(signal, *_split_signal(signal, topics, path)) for signal in signals]
    series: dict[str, tuple[list[float], list[float]]] = {signal: ([], []) for signal in signals}
    checked: set[str] = set()
    for entry in read_objects(path, topics={topic for _, topic, _ in wanted}):
        for signal, topic, field_path in wanted:
            if entry.topic != topic:
                continue
            try:
                value = field_value(entry.obj, field_path)
            except KeyError as exc:
                raise LogError(path, f"signal {signal!r}: {exc.args[0]}") from None
            number = _as_number(value)
            if number is None:
                if signal not in checked:
                    fields = _fields_of(value)
                    hint = f"; its fields: {', '.join(fields)}" if fields else ""
                    raise LogError(path, f"signal {signal!r} is a {type(value).__name__}, not a number{hint}")
                number = math.nan
            checked.add(signal)
            series[signal][0].append(entry.t_s)
            series[signal][1].append(number)
    empty = [signal for signal, (t, _) in series.items() if not t]
    if empty:
        raise LogError(path, f"no messages for {', '.join(empty)}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    height_in = 2.2 * len(signals) + 0.8
    fig, axes = plt.subplots(len(signals), 1, sharex=True, figsize=(10, height_in), squeeze=False)
    for ax, signal in zip(axes[:, 0], signals, strict=True):
        t, y = series[signal]
        order = np.argsort(t, kind="stable")
        if signal.startswith(CAN_TOPIC_PREFIX):  # frames are events, not a signal held between them
            ax.plot(np.asarray(t)[order], np.asarray(y)[order], ".", markersize=3)
        else:
            ax.plot(np.asarray(t)[order], np.asarray(y)[order], drawstyle="steps-post", linewidth=1.0)
        ax.set_ylabel(signal, fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("log time [s]")
    fig.suptitle(str(path), fontsize=9)
    fig.tight_layout()
    out = Path(output)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def _cmd_plot(args: argparse.Namespace) -> int:
    output = args.output if args.output is not None else args.file.with_suffix(".png")
    out = plot_signals(args.file, args.signal, output)
    print(f"plot: {', '.join(args.signal)} -> {out}")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from bywire.host.runtime.can_log import export_frames

    try:
        counts = export_frames(args.file, args.output)
    except ValueError as exc:  # python-can's answer to a suffix it has no writer for
        raise LogError(args.output, str(exc)) from None
    per_bus = ", ".join(f"{bus} {n}" for bus, n in counts.items()) or "none"
    print(f"export: {sum(counts.values())} frames ({per_bus}) -> {args.output}")
    return 0


def _cmd_scene(args: argparse.Namespace) -> int:
    try:
        import foxglove

        from bywire.host.modules.scene_view import SOURCE_TOPICS, SceneConverter
        from bywire.host.runtime.live_view import foxglove_channel
    except ImportError as exc:
        print(f"error: log scene needs foxglove-sdk: pip install 'bywire[live]' ({exc})", file=sys.stderr)
        return 2
    if args.output.resolve() == args.file.resolve():
        raise LogError(args.output, "the scene would overwrite the recording it is made from")
    converter = SceneConverter()
    context = foxglove.Context()
    channels: dict[str, Any] = {}
    counts: dict[str, int] = {}
    try:
        writer = foxglove.open_mcap(args.output, allow_overwrite=True, context=context)
    except Exception as exc:  # the SDK's own error types: a folder that is not there, no permission
        raise LogError(args.output, f"cannot write: {exc}") from None
    with writer:
        for entry in read_objects(args.file, topics=SOURCE_TOPICS):
            for topic, msg in converter.convert(entry.topic, entry.obj):
                channel = channels.get(topic)
                if channel is None:
                    channel = channels[topic] = foxglove_channel(topic, msg, context)
                channel.log(msg, log_time=entry.log_time_ns)
                counts[topic] = counts.get(topic, 0) + 1
    if not counts:
        print(
            f"scene: {args.file} holds none of {', '.join(SOURCE_TOPICS)} (not an urban run)", file=sys.stderr
        )
        return 1
    per_topic = ", ".join(f"{t} {n}" for t, n in sorted(counts.items()))
    print(f"scene: {per_topic} -> {args.output} (open it in Foxglove beside the recording, 3D panel)")
    return 0


def _cmd_replay(args: argparse.Namespace, inputs_for: Any = None) -> int:
    from bywire.host.replay import ReplayError, car_run_inputs, replay

    try:
        result = replay(args.file, args.module, inputs_for or car_run_inputs)
    except ReplayError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    doc = result.to_json()
    print(
        f"replay {args.file}: modules {', '.join(result.modules)}; {result.releases} releases, "
        f"{result.restarts} supervisor restarts re-enacted"
    )
    for topic, c in doc["topics"].items():
        worst = max(c["max_abs_diff"].values(), default=0.0)
        verdict = "ok" if c["mismatched"] == 0 and c["recorded"] == c["replayed"] else "DIFFERS"
        print(
            f"  {topic:<22} recorded {c['recorded']:>6}  replayed {c['replayed']:>6}  "
            f"mismatched {c['mismatched']:>5}  max |diff| {worst:.3g}  {verdict}"
        )
        for line in c["first_mismatches"][:5]:
            print(f"      {line}")
    if args.json is not None:
        text = json.dumps(doc, indent=1)
        if str(args.json) == "-":
            print(text)
        else:
            args.json.write_text(text + "\n", encoding="utf-8")
    print("replay matches the recording" if result.matches else "replay DIFFERS from the recording")
    return 0 if result.matches or not args.check else 1


COMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {
    "info": _cmd_info,
    "plot": _cmd_plot,
    "export": _cmd_export,
    "scene": _cmd_scene,
    "replay": _cmd_replay,
}


def build_parser() -> argparse.ArgumentParser:
    """A stand-alone parser (`python -m bywire.host.log_cli info FILE`), as `bywire log` wires it."""
    parser = argparse.ArgumentParser(prog="bywire log", description="inspect an MCAP recording")
    add_arguments(parser.add_subparsers(dest="log_command", required=True, metavar="COMMAND"))
    return parser


if __name__ == "__main__":
    raise SystemExit(main(build_parser().parse_args()))
