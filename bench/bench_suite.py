"""The README's test command, ``pytest -q``, cold (an empty numba cache, as in CI on a fresh
machine) and then warm (the same cache again, as on a developer's machine), each a fresh process.

Usage: python bench/bench_suite.py [WARM_REPEATS]   (default 2; run from the repository root)
"""

import os
import re
import subprocess
import sys
import tempfile
import time


def run(cache):
    """Wall seconds of ``pytest -q`` and the seconds pytest reports for its session."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    t0 = time.perf_counter()
    proc = subprocess.run(["pytest", "-q"], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    last = proc.stdout.strip().splitlines()[-1]
    if proc.returncode:
        sys.exit(f"the suite failed: {last}")
    return wall, float(re.search(r" in ([0-9.]+)s", last).group(1)), last.split(" in ")[0]


def main(repeats):
    with tempfile.TemporaryDirectory() as tmp:
        rows = [("cold (empty numba cache)", *run(tmp))]
        rows += [(f"warm {i + 1}", *run(tmp)) for i in range(repeats)]
    print(f"pytest -q, {os.cpu_count()} cores, {rows[0][3]}")
    print("| run | wall [s] | pytest's session [s] |")
    print("|---|---|---|")
    for name, wall, session, _ in rows:
        print(f"| {name} | {wall:.1f} | {session:.1f} |")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2)
