"""The README's test command, ``pytest -q -n 2``, cold (an empty numba cache, as in CI on a fresh
machine) and then warm (the same cache again, as on a developer's machine), each a fresh process.
Beside the wall time, the CPU seconds of pytest and every process it waited for: the work itself,
which a busy or slow machine stretches less than the wall time.

Usage: python bench/bench_suite.py [WARM_REPEATS]   (default 2; run from the repository root)
"""

import os
import re
import resource
import subprocess
import sys
import tempfile
import time

from _table import report


def _children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run(cache):
    """Wall seconds of ``pytest -q``, the seconds pytest reports for its session, its CPU
    seconds (user + system, with its workers and their processes) and its summary."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    t0, cpu0 = time.perf_counter(), _children_cpu()
    proc = subprocess.run(["pytest", "-q", "-n", "2"], env=env, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    last = proc.stdout.strip().splitlines()[-1]
    if proc.returncode:
        sys.exit(f"the suite failed: {last}")
    session = float(re.search(r" in ([0-9.]+)s", last).group(1))
    return wall, session, cpu, last.split(" in ")[0]


def main(repeats):
    with tempfile.TemporaryDirectory() as tmp:
        rows = [("cold (empty numba cache)", *run(tmp))]
        rows += [(f"warm {i + 1}", *run(tmp)) for i in range(repeats)]
    report(
        "suite",
        f"The test suite, pytest -q -n 2, on {os.cpu_count()} cores: {rows[0][4]}",
        ["run", "wall_s", "session_s", "cpu_s"],
        [dict(run=n, wall_s=w, session_s=s, cpu_s=c) for n, w, s, c, _ in rows],
    )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2)
