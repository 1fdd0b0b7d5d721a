"""Independent tasks, run in this process or on Dask: a local cluster of worker processes, or an
existing scheduler's (a SLURM allocation, say).

Results reach ``finish`` as tasks complete, in any order; a caller that adds them up keeps them by
index and adds in task order, so that nothing depends on which worker finished first.
"""

from __future__ import annotations

import multiprocessing
import os
import re
import sys
from typing import TYPE_CHECKING

from ..validation import ConfigError
from . import interrupts

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

CONNECT_TIMEOUT = "10s"  #: how long to try an existing Dask scheduler before giving up
#: the environment distributed sets in a worker before it starts that a local cluster's workers do
#: without: a fixed MALLOC_TRIM_THRESHOLD_ turns off glibc's sliding mmap threshold, so every large
#: array a chunk allocates is mapped afresh and its pages faulted in again (measured: 1.4-1.7x the
#: CPU of the same task in this process, bench/bench_focalplane_dask.py)
UNSET_IN_WORKERS = ("MALLOC_TRIM_THRESHOLD_",)
#: why a local cluster's workers fail to start from a script without a main guard
GUARD = (
    "a local Dask cluster's workers start by importing the script that made it: put the "
    'script\'s work under `if __name__ == "__main__":` (or use --scheduler serial)'
)


def _in_a_workers_start() -> bool:
    """Whether this is a worker process importing the main script of the process that spawned it
    (multiprocessing's ``__mp_main__``)."""
    main = sys.modules.get("__main__")
    return multiprocessing.parent_process() is not None and getattr(main, "__name__", "") == (
        "__mp_main__"
    )


def dask(what: str = "this"):
    """dask.distributed, or a ConfigError saying how to install it.

    Parameters
    ----------
    what : str
        What needs it, for the message.
    """
    try:
        from dask import distributed
    except ImportError:
        raise ConfigError(
            f"{what} on Dask needs: pip install 'boresight[dask]' (or use --scheduler serial)"
        ) from None
    return distributed


def check_workers(workers: object) -> int:
    """The number of local worker processes, checked: an integer >= 1."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"--workers = {workers!r}; allowed: an integer >= 1")
    return workers


def check_scheduler(scheduler: object) -> str | None:
    """``scheduler`` checked before any work: "serial", None (a local cluster) or a Dask
    scheduler's address, ``host:port`` or ``protocol://host:port``."""
    if scheduler is None or scheduler == "serial":
        return scheduler
    address = r"(?:[a-z][a-z0-9+.-]*://)?(?:\[[0-9a-fA-F:]+\]|[^\s/:\[\]]+):\d{1,5}"
    if not isinstance(scheduler, str) or re.fullmatch(address, scheduler) is None:
        raise ConfigError(
            f"--scheduler {scheduler!r}: 'serial', 'local' or a Dask scheduler's address "
            "(host:port or tcp://host:port)"
        )
    return scheduler


def run(
    function: Callable,
    arguments: Sequence[tuple],
    finish: Callable,
    *,
    scheduler: str | None = "serial",
    workers: int = 2,
    window: int | None = None,
    threads: int | None = None,
) -> None:
    """Call ``finish(i, function(*arguments[i]))`` for every task i.

    Parameters
    ----------
    function : callable
        Importable by the workers (a module-level function).
    arguments : sequence of tuple
    finish : callable
        Called in this process with each task's index and result, as each completes.
    scheduler : str, optional
        "serial" for this process, None for a local Dask cluster of ``workers`` processes, or the
        address of an existing scheduler.
    workers : int
        Local worker processes; each runs numba on its share of this machine's cores
        (``NUMBA_NUM_THREADS``), not on all of them.
    threads : int, optional
        Numba threads in each local worker instead of its share of the cores (a benchmark of
        how the workers scale holds each worker's threads fixed).
    window : int, optional
        On Dask, at most this many tasks submitted and not yet finished (default: all at once):
        a caller that keeps results until the earlier ones arrive then holds at most this many.
    """
    check_scheduler(scheduler)
    if scheduler == "serial":
        for i, args in enumerate(arguments):
            interrupts.check()
            finish(i, function(*args))
        return
    distributed = dask()
    cluster = None
    if scheduler is None:
        if _in_a_workers_start():
            raise ConfigError(GUARD)
        share = max(1, (os.cpu_count() or 1) // check_workers(workers))
        if threads is not None:
            share = check_workers(threads)
        from dask import config

        # in this process's environment while the workers spawn (numba reads its threads on
        # import, which a worker's re-import of the main script does before distributed's
        # ``env`` applies; an existing variable outranks distributed's pre-spawn ones), then put
        # back as it was
        environ = dict(config.get("distributed.nanny.pre-spawn-environ", {}))
        for name in UNSET_IN_WORKERS:
            environ.pop(name, None)
        saved = dict(os.environ)
        os.environ["NUMBA_NUM_THREADS"] = str(share)
        try:
            with config.set({"distributed.nanny.pre-spawn-environ": environ}):
                cluster = distributed.LocalCluster(
                    n_workers=workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                )
        except RuntimeError as err:  # distributed's "Nanny failed to start."
            raise ConfigError(f"{err} {GUARD}") from None
        finally:
            os.environ.clear()
            os.environ.update(saved)
    try:
        client = distributed.Client(
            cluster if cluster is not None else scheduler, timeout=CONNECT_TIMEOUT
        )
    except (OSError, TimeoutError) as err:
        raise ConfigError(f"cannot reach the Dask scheduler at {scheduler}: {err}") from None
    try:
        futures, queued = {}, iter(enumerate(arguments))
        limit = len(arguments) if window is None else max(1, window)

        def submit():
            for i, args in queued:
                futures[client.submit(function, *args, pure=False)] = i
                if len(futures) >= limit:
                    return

        submit()
        running = set(futures)
        while running:
            interrupts.check()
            try:
                done, running = distributed.wait(
                    running, timeout=interrupts.POLL_SECONDS, return_when="FIRST_COMPLETED"
                )
            except TimeoutError:  # distributed's own, a TimeoutError
                continue
            for fut in done:
                finish(futures.pop(fut), fut.result())
                fut.release()
            submit()
            running = set(futures)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
