"""The transform queue: inline and background jobs give the same results in submission order, at
most ``depth`` background jobs wait at a time, and a job's error reaches the caller."""

import threading
import time

import numpy as np
import pytest

from boresight import harmonics
from boresight.jobs.transforms import Transforms


def test_background_jobs_give_the_inline_results_in_order():
    rng = np.random.default_rng(1)
    maps = [rng.normal(size=12 * 16**2) for _ in range(5)]
    results = {}
    for background in (False, True):
        with Transforms(background=background) as queue:
            futures = [queue.submit(harmonics.map2alm, m, 32) for m in maps]
            queue.wait()
        results[background] = [f.result() for f in futures]
    for inline, threaded in zip(results[False], results[True]):
        np.testing.assert_array_equal(inline, threaded)  # the same bits


def test_at_most_depth_background_jobs_wait():
    release, running = threading.Event(), []

    def job(i):
        running.append(i)
        release.wait(5)
        return i

    with Transforms(background=True, depth=2) as queue:
        first = [queue.submit(job, i) for i in range(2)]
        waiter = threading.Thread(target=queue.submit, args=(job, 2))
        waiter.start()
        time.sleep(0.2)
        assert waiter.is_alive()  # the third waits for the first to finish
        release.set()
        waiter.join(5)
        queue.wait()
    assert [f.result() for f in first] == [0, 1] and running == [0, 1, 2]


@pytest.mark.parametrize("background", [False, True])
def test_a_jobs_error_reaches_the_caller(background):
    def broken():
        raise RuntimeError("transform failed")

    with pytest.raises(RuntimeError, match="transform failed"):
        with Transforms(background=background) as queue:
            queue.submit(broken)
            queue.wait()
