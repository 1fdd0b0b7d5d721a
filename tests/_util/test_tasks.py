"""Independent tasks in this process or on a local Dask cluster: every task once, its result
with its index, and bad worker counts refused."""

import json
import operator
import os
import subprocess
import sys

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


def test_a_window_bounds_the_tasks_in_flight_and_workers_share_the_cores():
    """With a window of 2 every task still arrives once; each of 2 workers runs numba on half
    the cores, not on all of them."""
    pytest.importorskip("dask.distributed")
    import numba

    got = {}
    tasks.run(numba.get_num_threads, [()] * 7, got.__setitem__, scheduler=None, workers=2, window=2)
    assert sorted(got) == list(range(7))
    assert set(got.values()) == {max(1, (os.cpu_count() or 1) // 2)}


@pytest.mark.slow
def test_a_script_without_a_main_guard_gets_one_clear_error(tmp_path):
    """A script that starts a local cluster at its top level: its workers import it again, and
    the error names the guard instead of distributed's "Nanny failed to start" traceback alone."""
    pytest.importorskip("dask.distributed")
    script = tmp_path / "unguarded.py"
    script.write_text(
        "import operator\n"
        "from boresight._util import tasks\n"
        "tasks.run(operator.add, [(1, 2)], print, scheduler=None, workers=1)\n"
    )
    proc = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=120, cwd=tmp_path
    )
    assert proc.returncode != 0
    assert 'put the script\'s work under `if __name__ == "__main__":`' in proc.stderr


def test_local_workers_keep_glibcs_sliding_mmap_threshold_and_take_the_threads_asked(tmp_path):
    """From a script that imports numba first (its workers re-import it before distributed's
    ``env`` applies): each worker runs numba on the threads asked, without the
    MALLOC_TRIM_THRESHOLD_ that distributed fixes (it maps every large array afresh: 1.4-1.7x
    the CPU of a focal-plane task), and the script's own environment is left as it was."""
    pytest.importorskip("dask.distributed")
    script = tmp_path / "threads.py"
    script.write_text(
        "import json, os\n"
        "import numba\n"
        "from boresight._util import tasks\n"
        "def main():\n"
        "    before, got = dict(os.environ), {}\n"
        "    calls = [(numba.get_num_threads, ())] * 2 + [(os.getenv, ('MALLOC_TRIM_THRESHOLD_',))]\n"
        "    tasks.run(lambda f, a: f(*a), calls, got.__setitem__, scheduler=None, workers=1, threads=1)\n"
        "    print(json.dumps({'got': got, 'same': dict(os.environ) == before}))\n"
        'if __name__ == "__main__":\n'
        "    main()\n"
    )
    proc = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=180, cwd=tmp_path,
        env={**os.environ, "NUMBA_NUM_THREADS": "2"},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out == {"got": {"0": 1, "1": 1, "2": None}, "same": True}
