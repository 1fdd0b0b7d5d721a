"""A queue of spherical-harmonic jobs, inline or on one background thread.

The transforms of a residual job, most of its time at high lmax, go through a :class:`Transforms`
queue: inline by default, or on one background thread so that they overlap the simulation of the
next job (ducc0 releases the GIL and uses every core). Either way the numbers are the same bits.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor

from .._util import interrupts


class Transforms:
    """A queue of spherical-harmonic jobs: inline, or in order on one background thread.

    Parameters
    ----------
    background : bool
        Run jobs on a background thread (ducc0 releases the GIL and uses every core), so they
        overlap the main thread's simulations; else run each at once.
    depth : int
        At most this many background jobs wait at a time (each holds full-sky maps).

    Notes
    -----
    Jobs must not call numba's parallel kernels, which run on the main thread (numba's threading
    layer is not re-entrant). Use as a context manager; :meth:`wait` re-raises a job's error.
    """

    def __init__(self, background=False, depth=2):
        self._pool = (
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="boresight-transforms")
            if background
            else None
        )
        self._queued = deque()
        self._all = []
        self.depth = depth

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=exc[0] is not None)

    def submit(self, fn, *args):
        """Run or queue ``fn(*args)``.

        Returns
        -------
        concurrent.futures.Future
            Of ``fn``'s result (already done when inline).
        """
        if self._pool is None:
            future = Future()
            future.set_result(fn(*args))
            return future
        while len(self._queued) >= self.depth:
            interrupts.result(self._queued.popleft())
        future = self._pool.submit(fn, *args)
        self._queued.append(future)
        self._all.append(future)
        return future

    def wait(self):
        """Wait for every job; re-raises the first job's exception."""
        for future in self._all:
            interrupts.result(future)
