"""Independent tasks in this process or on a local Dask cluster: every task once, its result
with its index, and bad worker counts refused."""

import operator

import pytest

from boresight._util import tasks
from boresight.validation import ConfigError


def _collect(scheduler):
    got = {}
    tasks.run(operator.mul, [(i, i + 1) for i in range(5)], got.__setitem__, scheduler=scheduler)
    return got


def test_serial_tasks_run_once_each_in_order():
    order = []
    tasks.run(operator.add, [(1, 2), (3, 4)], lambda i, r: order.append((i, r)))
    assert order == [(0, 3), (1, 7)]


def test_a_local_cluster_gives_every_task_its_result():
    pytest.importorskip("dask.distributed")
    assert _collect(None) == _collect("serial") == {i: i * (i + 1) for i in range(5)}


@pytest.mark.parametrize("workers", [0, -1, 1.5, True, "2"])
def test_bad_worker_counts_are_refused(workers):
    with pytest.raises(ConfigError, match="--workers"):
        tasks.check_workers(workers)
