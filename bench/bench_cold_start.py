"""The quick reproduction as a new user meets it: cold (an empty numba cache, so every kernel it
runs compiles first) and warm (the same cache again), each a fresh process.

Usage: python bench/bench_cold_start.py [NSIDE]   (default 512, the --quick run)
"""

import os
import subprocess
import sys
import tempfile
import time


def run(cache, out, nside):
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    cmd = ["boresight", "-q", "reproduce", "--quick", "--force", "--out", out]
    if nside != 512:
        cmd += ["--nside", str(nside)]
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True)
    return time.perf_counter() - t0


def main(nside):
    with tempfile.TemporaryDirectory() as tmp:
        cache = os.path.join(tmp, "numba-cache")
        cold = run(cache, os.path.join(tmp, "cold"), nside)
        warm = run(cache, os.path.join(tmp, "warm"), nside)
    print(f"boresight reproduce --quick, Nside {nside}, {os.cpu_count()} cores")
    print("| run | wall [s] |")
    print("|---|---|")
    print(f"| cold (empty numba cache) | {cold:.1f} |")
    print(f"| warm | {warm:.1f} |")
    print(f"| compilation (cold - warm) | {cold - warm:.1f} |")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 512)
