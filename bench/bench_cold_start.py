"""Commands as a new user meets them: cold (an empty numba cache, so every kernel the command runs
compiles first) and warm (the same cache again), each a fresh process with a cache of its own:
the quick reproduction, and ``design`` and ``scan-stats`` on the deep example schedule.

Usage: python bench/bench_cold_start.py [NSIDE]   (default 512, the --quick run; run from the
repository root)
"""

import os
import subprocess
import sys
import tempfile
import time

from _table import report

DEEP = ["examples/budget_deep_sat.toml", "examples/schedule_deep_sat.toml"]


def commands(nside):
    quick = ["reproduce", "--quick"] + (["--nside", str(nside)] if nside != 512 else [])
    return {
        f"reproduce --quick (Nside {nside})": quick,
        "design (deep example, with its TOD check)": ["design", *DEEP],
        "scan-stats (deep example)": ["scan-stats", DEEP[1]],
    }


def run(cmd, cache, out):
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    t0 = time.perf_counter()
    subprocess.run(["boresight", "-q", *cmd, "--force", "--out", out], env=env, check=True)
    return time.perf_counter() - t0


def main(nside):
    rows = []
    for name, cmd in commands(nside).items():
        with tempfile.TemporaryDirectory() as tmp:
            cache, out = os.path.join(tmp, "numba-cache"), os.path.join(tmp, "out")
            rows.append((name, run(cmd, cache, out), run(cmd, cache, out)))
    report(
        "cold_start",
        "Commands in a fresh process: cold (empty numba cache) and warm",
        ["command", "cold_s", "warm_s", "compilation_s"],
        [dict(command=n, cold_s=c, warm_s=w, compilation_s=c - w) for n, c, w in rows],
    )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 512)
