"""Where a campaign's runs execute: a pool of local processes, or a Ray cluster through its task API.

Both take the same function (`worker.run_one`) and the same plain-data runs, and give back the same
plain-data records, so that the campaign's loop (`campaign.runner`) is one code path; only where a
run is computed differs. At most `2 x workers` runs are in flight at a time: a stopped campaign loses
at most the runs being computed, and results come back as they finish.

- `LocalPool`: `concurrent.futures.ProcessPoolExecutor` on `workers` processes (default: every core),
  started with `spawn` (no inherited threads or locks of the parent); each worker dies with the
  campaign (Linux `PR_SET_PDEATHSIG`), so a killed campaign leaves no orphan simulating on.
- `RayCluster`: `ray.init(address)`: `local` starts a Ray instance on this machine for the campaign
  (no dashboard), `auto` joins the cluster this machine is part of (`ray start`), `ray://HOST:PORT`
  connects through Ray Client; each run is a task of one CPU. The package must be installed on the
  cluster's nodes at the same version (each row records the version it ran with).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any, Protocol

Record = dict[str, Any]


class ExecutorError(ValueError):
    """A pool or cluster that cannot be had (said with the address): bad input, like a URL that fails."""


class Executor(Protocol):
    workers: int

    def map_unordered(self, fn: Callable[[Any], Record], items: list[Any]) -> Iterator[Record]: ...

    def close(self, cancel: bool) -> None: ...


def _die_with_parent() -> None:
    """A pool worker's first act: ask Linux for SIGKILL when the campaign's process dies."""
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_pdeathsig = 1
        libc.prctl(pr_set_pdeathsig, int(signal.SIGKILL))
    except (OSError, AttributeError):  # not Linux: the worker ends when its queue closes
        pass
    # Ctrl-C on the terminal reaches the whole process group: the campaign stops its workers itself
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class LocalPool:
    def __init__(self, workers: int | None = None) -> None:
        import multiprocessing

        self.workers = workers or os.cpu_count() or 1
        self._pool = ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_die_with_parent,
        )

    def map_unordered(self, fn: Callable[[Any], Record], items: list[Any]) -> Iterator[Record]:
        pending: set[Future[Record]] = set()
        queue = iter(items)
        for item in queue:
            pending.add(self._pool.submit(fn, item))
            if len(pending) >= 2 * self.workers:
                break
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                yield future.result()
                nxt = next(queue, None)
                if nxt is not None:
                    pending.add(self._pool.submit(fn, nxt))

    def close(self, cancel: bool) -> None:
        if cancel:
            # the runs being computed go too: a stopped campaign stops now, and reruns them on resume
            for process in list(getattr(self._pool, "_processes", {}).values()):
                process.kill()
        self._pool.shutdown(wait=True, cancel_futures=cancel)


class RayCluster:
    def __init__(self, address: str, workers: int | None = None) -> None:
        try:
            import ray
        except ImportError:
            raise ExecutorError(
                f"--address {address}: Ray is not installed; pip install 'bywire[cluster]'"
            ) from None
        self._ray = ray
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
        if address == "local":
            import bywire

            # the workers import this very `bywire` (a checkout's, not another installation's)
            root = str(Path(bywire.__file__).resolve().parent.parent)
            path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p)
            kwargs["runtime_env"] = {"env_vars": {"PYTHONPATH": path}}
            if workers:
                kwargs["num_cpus"] = workers
        else:
            kwargs["address"] = address
            if address.startswith("ray://"):
                kwargs.pop("include_dashboard")
        try:
            ray.init(**kwargs)
        except Exception as exc:  # Ray's own errors: ConnectionError, RuntimeError, ValueError ...
            raise ExecutorError(f"--address {address}: Ray did not start or connect: {exc}") from None
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.workers = min(workers, cpus) if workers else cpus

    def map_unordered(self, fn: Callable[[Any], Record], items: list[Any]) -> Iterator[Record]:
        ray = self._ray
        task = ray.remote(num_cpus=1, max_retries=0)(fn)
        pending: list[Any] = []
        queue = iter(items)
        for item in queue:
            pending.append(task.remote(item))
            if len(pending) >= 2 * self.workers:
                break
        self._pending = pending
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            self._pending = pending
            for ref in done:
                yield ray.get(ref)
                nxt = next(queue, None)
                if nxt is not None:
                    pending.append(task.remote(nxt))
                    self._pending = pending

    def close(self, cancel: bool) -> None:
        if cancel:
            for ref in getattr(self, "_pending", []):
                self._ray.cancel(ref, force=True)
        self._ray.shutdown()


def open_executor(address: str | None, workers: int | None) -> Executor:
    """The local pool (address None) or a Ray cluster (`local`, `auto`, `ray://HOST:PORT`)."""
    if address is None:
        return LocalPool(workers)
    if address not in ("local", "auto") and not address.startswith("ray://"):
        raise ExecutorError(f"--address {address}: expected ray://HOST:PORT, auto or local")
    return RayCluster(address, workers)


__all__ = ["Executor", "ExecutorError", "LocalPool", "RayCluster", "open_executor"]
