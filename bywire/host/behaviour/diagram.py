"""The behaviour's statechart as one diagram, generated from the code (so it cannot drift from it).

`mermaid(machine)` writes Mermaid `stateDiagram-v2` text: every composite state as a `state X { ... }`
block with its initial state (`[*] --> X`), every transition and every no-progress timer as an edge
labelled with its guard's label (a transition whose source and target lie in the same composite is
written inside that composite's block, the others at the top). `png(machine, path)` draws the same with
matplotlib, one panel per level (the main level, then each composite), so that 32 states and their
transitions stay readable: within a panel the states stand in columns by their distance from the
panel's initial state; transitions leaving the panel end at a small box naming the target.

CLI (`bywire behaviour diagram`): `add_arguments(p)` / `main(args)`; `--format mermaid` (default, to
stdout or `--output FILE`) or `--format png --output FILE`.
"""

from __future__ import annotations

import argparse
import sys
from collections import deque
from pathlib import Path
from typing import Any

from .hsm import Machine, NoProgress, State, Transition

__all__ = ["add_arguments", "edges", "main", "mermaid", "png"]

Edge = tuple[str, str, str]  # (source, target, label)
ANY = "(any state)"  # the drawing's source of a family-wide rule
_DX, _DY = 4.4, 1.7  # column and row spacing of the drawing (boxes are 2.7 x 0.66)


def edges(machine: Machine[Any]) -> list[Edge]:
    """Every transition and no-progress timer as (source, target, label), in declaration order."""
    out: list[Edge] = []
    for state, tr in machine.transitions():
        if isinstance(tr, NoProgress):
            out.append((state.name, tr.recovery, tr.label))
        else:
            assert isinstance(tr, Transition)
            out.append((state.name, tr.target, tr.label))
    return out


def _label(text: str) -> str:
    # Mermaid ends a label at a newline and reads ':' / ';' / '#' as syntax
    return text.replace(":", " -").replace(";", ",").replace("#", "no.").replace("\n", " ")


def _scope(machine: Machine[Any], source: str, target: str) -> str:
    """The composite whose block holds the edge: the nearest one containing both ends (root: top)."""
    a = machine.ancestors(source)
    b = machine.ancestors(target)
    common = machine.root.name
    for x, y in zip(a[:-1], b[:-1], strict=False):
        if x is not y:
            break
        common = x.name
    return common


def mermaid(machine: Machine[Any]) -> str:
    """The Mermaid `stateDiagram-v2` text of the whole machine (see the module docstring)."""
    by_scope: dict[str, list[Edge]] = {}
    for src, dst, label in edges(machine):
        by_scope.setdefault(_scope(machine, src, dst), []).append((src, dst, label))
    lines = ["stateDiagram-v2"]

    def block(state: State[Any], indent: str) -> None:
        if state.initial is not None:
            lines.append(f"{indent}[*] --> {state.initial}")
        for child in state.children:
            if child.is_composite:
                lines.append(f"{indent}state {child.name} {{")
                block(child, indent + "    ")
                lines.append(f"{indent}}}")
            else:
                lines.append(f"{indent}{child.name}")
            if child.doc:
                lines.append(f"{indent}note right of {child.name} : {_label(child.doc)}")
        for src, dst, label in by_scope.get(state.name, ()):
            lines.append(f"{indent}{src} --> {dst} : {_label(label)}")

    block(machine.root, "    ")
    return "\n".join(lines) + "\n"


def _columns(state: State[Any], local: list[Edge]) -> dict[str, int]:
    """Column of each child: BFS distance from the initial child over the panel's own edges."""
    names = [c.name for c in state.children]
    col = {name: -1 for name in names}
    start = state.initial or names[0]
    col[start] = 0
    queue = deque([start])
    while queue:
        u = queue.popleft()
        for src, dst, _ in local:
            if src == u and dst in col and col[dst] < 0:
                col[dst] = col[u] + 1
                queue.append(dst)
    top = max(col.values()) + 1
    for name in names:  # reached from outside only (recovery states, targets of jumps)
        if col[name] < 0:
            col[name] = top
    return col


def _layout(machine: Machine[Any], panel: State[Any], local: list[Edge]) -> dict[str, tuple[float, float]]:
    """Positions of a panel's children: a circle for the main level, columns by BFS depth otherwise."""
    import math

    names = [c.name for c in panel.children]
    if panel is machine.root:
        n = len(names)
        return {
            name: (
                4.5 * math.cos(math.pi - 2.0 * math.pi * i / n),
                2.6 * math.sin(math.pi - 2.0 * math.pi * i / n),
            )
            for i, name in enumerate(names)
        }
    col = _columns(panel, local)
    rows: dict[int, int] = {}
    pos: dict[str, tuple[float, float]] = {}
    for name in names:
        c = col[name]
        pos[name] = (c * _DX, -rows.get(c, 0) * _DY)
        rows[c] = rows.get(c, 0) + 1
    return pos


def png(machine: Machine[Any], path: str | Path, dpi: int = 130) -> None:
    """Draw the machine with matplotlib into `path` (PNG), one panel per level."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    panels = [s for s in machine.root.walk() if s.is_composite]
    all_edges = edges(machine)
    layouts = []
    for panel in panels:
        members = {c.name for c in panel.children}
        below = {}
        for child in panel.children:  # an edge from deep inside a child starts at that child
            for st in child.walk():
                below[st.name] = child.name
        local: list[Edge] = []
        outside: list[Edge] = []
        for src, dst, label in all_edges:
            if src == panel.name and dst in below:  # the family's own rule, from any of its states
                local.append((ANY, below[dst], label))
            if src not in below:
                continue
            if dst in members:
                local.append((below[src], dst, label))
            elif dst not in below:
                outside.append((below[src], dst, label))
        pos = _layout(machine, panel, local)
        x_out = max(x for x, _ in pos.values()) + _DX
        for i, name in enumerate(sorted({dst for _, dst, _ in outside})):
            pos[f"->{name}"] = (x_out, -i * 1.2)
        if any(src == ANY for src, _, _ in local):
            pos[ANY] = (min(x for x, _ in pos.values()) - _DX, 0.0)
        layouts.append((panel, local, outside, pos))
    heights = [max(y for _, y in pos.values()) - min(y for _, y in pos.values()) + 2.5 for *_, pos in layouts]
    fig, axes = plt.subplots(
        len(panels), 1, figsize=(15, 0.62 * sum(heights) + 1.0), gridspec_kw={"height_ratios": heights}
    )
    for ax, (panel, local, outside, pos) in zip(axes, layouts, strict=True):
        for name, (x, y) in pos.items():
            external = name.startswith("->") or name == ANY
            composite = not external and machine.states[name].is_composite
            ax.add_patch(
                FancyBboxPatch(
                    (x - 1.35, y - 0.33),
                    2.7,
                    0.66,
                    boxstyle="round,pad=0.04",
                    facecolor="#eeeeee" if external else ("#d8e8ff" if composite else "#ffffff"),
                    edgecolor="#888888" if external else "#222222",
                    linewidth=0.8 if external else 1.2,
                    zorder=2,
                )
            )
            text = ("to " + name[2:]) if name.startswith("->") else name
            weight = "bold" if name == panel.initial else "normal"
            ax.text(x, y, text, ha="center", va="center", fontsize=7.5, weight=weight, zorder=3)
        drawn = local + [(src, f"->{dst}", label) for src, dst, label in outside]
        for k, (src, dst, label) in enumerate(drawn):
            (x0, y0), (x1, y1) = pos[src], pos[dst]
            bend = 0.18 if k % 2 else -0.18
            if src == dst:
                x1, y1, bend = x0 + 1.0, y0 + 0.6, 1.2
            ax.add_patch(
                FancyArrowPatch(
                    (x0, y0),
                    (x1, y1),
                    connectionstyle=f"arc3,rad={bend}",
                    arrowstyle="-|>",
                    mutation_scale=9,
                    linewidth=0.7,
                    color="#444444",
                    shrinkA=16,
                    shrinkB=16,
                    zorder=1,
                )
            )
            # the midpoint of matplotlib's arc3 curve: half its control point's offset
            mx, my = 0.5 * (x0 + x1) + 0.5 * bend * (y1 - y0), 0.5 * (y0 + y1) - 0.5 * bend * (x1 - x0)
            ax.text(
                mx,
                my,
                label,
                fontsize=5.5,
                ha="center",
                va="center",
                color="#1a4d99",
                zorder=4,
                bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 0.4},
            )
        xs = [q[0] for q in pos.values()]
        ys = [q[1] for q in pos.values()]
        ax.set_xlim(min(xs) - 1.6, max(xs) + 1.6)
        ax.set_ylim(min(ys) - 1.0, max(ys) + 1.0)
        ax.set_aspect("equal")
        title = "Behaviour: the main level (seed 000 Fig. 11)" if panel is machine.root else panel.name
        ax.set_title(title, loc="left", fontsize=10)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--format", choices=("mermaid", "png"), default="mermaid", help="output format")
    p.add_argument("--output", type=Path, help="file to write (mermaid: default stdout; png: required)")


def main(args: argparse.Namespace) -> int:
    from .behaviour import build_machine

    machine = build_machine()
    fmt = getattr(args, "format", "mermaid")
    out: Path | None = getattr(args, "output", None)
    if fmt == "png":
        if out is None:
            print("bywire behaviour diagram: --format png needs --output FILE", file=sys.stderr)
            return 2
        out.parent.mkdir(parents=True, exist_ok=True)
        png(machine, out)
        print(f"wrote {out}")
        return 0
    text = mermaid(machine)
    if out is None:
        sys.stdout.write(text)
    else:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text, encoding="utf-8")
    return 0
