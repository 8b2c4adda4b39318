"""A run's progress on a terminal: simulated time, speed against real time, and time left.

Drawn by rich on stderr, and only when stderr is a terminal: a run whose output goes to a file, a
pipe or CI prints no progress at all (tqdm and pip do the same), so logs hold only results. The
runner reports the fraction of the scenario's duration done; the speed is simulated seconds per
wall-clock second (x20 is a SIL run twenty times faster than real time, x1.0 a HIL run).
"""

from __future__ import annotations

from types import TracebackType
from typing import TYPE_CHECKING, Self, TextIO

if TYPE_CHECKING:
    from rich.progress import Progress, Task, TaskID
    from rich.text import Text


def wants_progress(stream: TextIO) -> bool:
    """Whether progress belongs on `stream`: only a terminal."""
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


class TerminalProgress:
    """A rich progress display used as a context manager: drawn from entry, finished at the exit
    (also on an interrupt). Subclasses build `_progress` and say what one call advances."""

    _progress: Progress

    def __enter__(self) -> Self:
        self._progress.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._progress.stop()


class RunProgress(TerminalProgress):
    """A progress line for one run; call it with the fraction done (0..1), use it as a context
    manager so that the line is finished (or cleared, on an interrupt) when the run ends."""

    def __init__(self, label: str, duration_s: float, stream: TextIO) -> None:
        # rich loads (~50 ms) only for a run that draws progress
        from rich.console import Console
        from rich.progress import BarColumn, Progress, ProgressColumn, TextColumn, TimeRemainingColumn
        from rich.text import Text

        class SimulatedTime(ProgressColumn):
            def render(self, task: Task) -> Text:
                return Text(f"{task.completed:6.1f}/{task.total or 0:.1f} s simulated")

        class Speed(ProgressColumn):
            def render(self, task: Task) -> Text:
                return Text(f"x{task.speed:.1f} real time" if task.speed else "x? real time")

        self._progress: Progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            SimulatedTime(),
            Speed(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=Console(file=stream),
            refresh_per_second=4,  # its drawing thread shares the GIL with a SIL run
            transient=False,
        )
        self._duration_s = duration_s
        self._task: TaskID = self._progress.add_task(label, total=duration_s)

    def __call__(self, fraction: float) -> None:
        self._progress.update(self._task, completed=min(max(fraction, 0.0), 1.0) * self._duration_s)
