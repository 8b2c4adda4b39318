"""A campaign from its file to its folder: expand, skip what is done, run the rest, keep every row.

The loop is the same whichever executor computes the runs (`executors`): each record that comes back
is written at once (`store.save_record`, atomic), the progress advances, and when the campaign ends,
or is stopped (Ctrl-C, SIGTERM), the results table is rebuilt from every finished run. A killed
campaign (SIGKILL, a power cut) loses only the runs being computed; `resume` runs those and the ones
never started, none twice.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bywire.hil.campaign import store
from bywire.hil.campaign.executors import open_executor
from bywire.hil.campaign.spec import Campaign, Run
from bywire.hil.campaign.worker import code_version, run_one


@dataclass
class Outcome:
    total: int  # runs of the campaign
    skipped: int  # done before this invocation (resume)
    ran: int  # done by this one
    passed: int  # of those done by this one
    failed: int
    errors: int
    interrupted_by: int | None = None  # the signal that stopped it

    @property
    def done(self) -> int:
        return self.skipped + self.ran


def prepare(
    folder: Path,
    campaign: Campaign,
    runs: list[Run],
    spec_text: str,
    resume: bool,
    notice: Callable[[str], None] | None = None,
) -> list[Run]:
    """The campaign's folder made or checked; the runs still to do. On resume a run file that cannot be
    read is set aside (`store.set_aside_unreadable`, said through `notice`) and its run done again."""
    ids = [r.run_id for r in runs]
    if len(set(ids)) != len(ids):
        dup = next(r for r in runs if ids.count(r.run_id) > 1)
        raise store.StoreError(
            f"{campaign.source}: run {dup.index} of sweep {dup.sweep} appears twice in the campaign "
            "(the same scenario, fields and options): give each run once"
        )
    if resume:
        store.check_resume(folder, campaign.name, ids)
        for path in store.set_aside_unreadable(folder):
            if notice is not None:
                notice(f"{path}: not a run's record as a worker writes it; set aside, its run runs again")
        done = store.done_ids(folder)
        return [r for r in runs if r.run_id not in done]
    store.create(folder, campaign.name, spec_text, ids, code_version())
    return list(runs)


def execute(
    folder: Path,
    todo: list[Run],
    total: int,
    address: str | None,
    workers: int | None,
    on_record: Callable[[dict[str, Any]], None] | None = None,
    run_fn: Callable[[dict[str, Any]], dict[str, Any]] = run_one,
) -> Outcome:
    """Run `todo` on the executor `address` names; every record saved as it comes. A KeyboardInterrupt
    (Ctrl-C, or SIGTERM through `process_util.signals_interrupt`) stops the executor and is raised
    again after the results table is written."""
    outcome = Outcome(total=total, skipped=total - len(todo), ran=0, passed=0, failed=0, errors=0)
    executor = open_executor(address, workers) if todo else None
    cancel = True
    by_id = {r.run_id: r for r in todo}
    try:
        if executor is not None:
            for record in executor.map_unordered(run_fn, [r.to_dict() for r in todo]):
                record["run"] = by_id[record["row"]["run_id"]].to_dict()
                store.save_record(folder, record)
                verdict = record["row"]["verdict"]
                outcome.ran += 1
                outcome.passed += verdict == "pass"
                outcome.failed += verdict == "fail"
                outcome.errors += verdict == "error"
                if on_record is not None:
                    on_record(record)
        cancel = False
    finally:
        if executor is not None:
            executor.close(cancel=cancel)
        store.write_results(folder)
    return outcome


__all__ = ["Outcome", "execute", "prepare"]
