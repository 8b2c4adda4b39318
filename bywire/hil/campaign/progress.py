"""A campaign's progress on a terminal: runs done of all, passed and failed so far, time left.

Drawn by rich on stderr and only when stderr is a terminal (`run_progress.wants_progress`), as a
single run's progress is: a campaign in CI or a pipe prints its summary only. The time left is rich's
estimate from the rate of recent runs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, TextIO

from bywire.hil.run_progress import TerminalProgress

if TYPE_CHECKING:
    from rich.progress import TaskID


class CampaignProgress(TerminalProgress):
    def __init__(self, label: str, total: int, done: int, stream: TextIO) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self._progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("runs  [green]{task.fields[passed]} pass[/] [red]{task.fields[failed]} fail[/]"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=Console(file=stream),
            refresh_per_second=2,
        )
        self._task: TaskID = self._progress.add_task(label, total=total, completed=done, passed=0, failed=0)
        self._passed = 0
        self._failed = 0

    def __call__(self, record: dict[str, Any]) -> None:
        if record["row"]["verdict"] == "pass":
            self._passed += 1
        else:
            self._failed += 1
        self._progress.update(self._task, advance=1, passed=self._passed, failed=self._failed)
