"""``nthreads = 0`` means the cores this process may run on, as numba and ducc0 count them."""

import os
import subprocess
import sys

import numba
import pytest

from boresight._util import threads

PINNED = """
import ducc0, numba
from boresight._util import threads
print(threads.default_threads(), ducc0.misc.thread_pool_size(), threads.max_threads())
"""


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity here")
def test_a_process_pinned_to_one_core_defaults_to_one_thread_like_ducc0():
    env = dict(os.environ, NUMBA_NUM_THREADS="2")  # explicit counts may still go up to 2
    one_core = min(os.sched_getaffinity(0))
    proc = subprocess.run(
        [sys.executable, "-c", PINNED],
        env=env,
        preexec_fn=lambda: os.sched_setaffinity(0, {one_core}),
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["1", "1", "2"]


def test_the_default_is_the_allowed_cores_capped_at_numbas_pool(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3}, raising=False)
    assert threads.default_threads() == 1
    many = set(range(threads.max_threads() + 5))
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: many, raising=False)
    assert threads.default_threads() == threads.max_threads()


def test_numba_threads_zero_runs_on_the_default_and_restores():
    before = numba.get_num_threads()
    with threads.numba_threads(0):
        assert numba.get_num_threads() == threads.default_threads()
    with threads.numba_threads(threads.max_threads()):
        assert numba.get_num_threads() == threads.max_threads()
    assert numba.get_num_threads() == before
