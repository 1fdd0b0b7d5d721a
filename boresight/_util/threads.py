"""How many CPU threads the numba kernels use, set per call and checked at the boundary."""

from __future__ import annotations

import contextlib
import os
from typing import TYPE_CHECKING

import numba

if TYPE_CHECKING:
    from collections.abc import Iterator


def max_threads() -> int:
    """The most threads numba may use here.

    Returns
    -------
    int
        numba's NUMBA_NUM_THREADS.
    """
    return numba.config.NUMBA_NUM_THREADS


def default_threads() -> int:
    """The threads that ``nthreads = 0`` ("all cores") stands for.

    They are the cores this process may run on, which ``taskset``, a batch system or a container
    may limit to fewer than the machine has (the count that numba and ducc0 start from too), and
    at most :func:`max_threads`.

    Returns
    -------
    int
    """
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # no CPU affinity on macOS and Windows
        cores = os.cpu_count() or 1
    return max(1, min(cores, max_threads()))


def check_threads(name: str, nthreads: int) -> None:
    """ValueError unless ``nthreads`` is an integer from 0 (all cores) to :func:`max_threads`.

    Parameters
    ----------
    name : str
        The option's name in messages (``run.nthreads``, ``--threads``).
    nthreads : int
        Requested thread count.
    """
    if isinstance(nthreads, bool) or not isinstance(nthreads, int):
        raise TypeError(f"{name} = {nthreads!r} must be an integer")
    if not 0 <= nthreads <= max_threads():
        raise ValueError(f"{name} = {nthreads}; allowed: 0 (all cores) to {max_threads()}")


@contextlib.contextmanager
def numba_threads(nthreads: int) -> Iterator[None]:
    """Run numba kernels on a number of threads inside the block.

    Parameters
    ----------
    nthreads : int
        0 for all cores (:func:`default_threads`).
    """
    old = numba.get_num_threads()
    numba.set_num_threads(nthreads if nthreads > 0 else default_threads())
    try:
        yield
    finally:
        numba.set_num_threads(old)
