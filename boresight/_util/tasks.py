"""Independent tasks, run in this process or on Dask: a local cluster of worker processes, or an
existing scheduler's (a SLURM allocation, say).

Results reach ``finish`` as tasks complete, in any order; a caller that adds them up keeps them by
index and adds in task order, so that nothing depends on which worker finished first.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from ..validation import ConfigError
from . import interrupts

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

CONNECT_TIMEOUT = "10s"  #: how long to try an existing Dask scheduler before giving up


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
        cluster = distributed.LocalCluster(
            n_workers=check_workers(workers),
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
        )
    try:
        client = distributed.Client(
            cluster if cluster is not None else scheduler, timeout=CONNECT_TIMEOUT
        )
    except (OSError, TimeoutError) as err:
        raise ConfigError(f"cannot reach the Dask scheduler at {scheduler}: {err}") from None
    try:
        futures = {
            client.submit(function, *args, pure=False): i for i, args in enumerate(arguments)
        }
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
                finish(futures[fut], fut.result())
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
