"""A focal plane's h_n on a local Dask cluster of 1, 2 and 4 workers against this process alone.

The deep example's CES set observed at 12 boresight angles (0, 30, ..., 330 deg: 8.6 million
samples at 20 Hz, 120 hours, cut into groups of CESs of at least
``moments.focalplane.GROUP_SAMPLES`` samples, one task each) seen by TOAST's 37-pixel 35-deg
hexagon at NSIDE. Each worker runs numba on its share of the cores (NUMBA_NUM_THREADS), at most
two tasks a worker are in flight, and this process adds the results in task order as they
arrive. Wall seconds and this process's own peak resident memory (the client's: what it holds
of the tasks' results), best of REPEATS runs; every Dask result equal to the serial one to the
bit.

Usage: python bench/bench_focalplane_dask.py [NSIDE] [REPEATS]

Writes bench/results/focalplane_dask.json.
"""

import hashlib
import json
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

from _table import report

from boresight.instrument.focalplane import hexagon
from boresight.moments.focalplane import characterise_focalplane, time_groups
from boresight.schedule import load_schedule

ROOT = Path(__file__).resolve().parent.parent
RUNS = {
    "serial": ("serial", 1),
    "1 worker": (None, 1),
    "2 workers": (None, 2),
    "4 workers": (None, 4),
}


def season():
    schedule = load_schedule(str(ROOT / "examples" / "schedule_deep_sat.toml"))
    return replace(schedule, repeat_boresight_deg=tuple(30.0 * k for k in range(12)))


def one(name, nside):
    """One run in this (fresh) process: its wall seconds, peak resident GiB and a digest of its
    maps, printed as JSON."""
    scheduler, workers = RUNS[name]
    schedule, focal = season(), hexagon(37, 35.0)
    characterise_focalplane(replace(schedule, ces=schedule.ces[:1]), focal, nside)  # compiled
    t0 = time.perf_counter()
    stats = characterise_focalplane(schedule, focal, nside, scheduler=scheduler, workers=workers)
    seconds = time.perf_counter() - t0
    digest = hashlib.sha256()
    for array in (stats.sum_sq, stats.pair_weights, stats.combined.h, stats.combined.hits):
        digest.update(array.tobytes())
    with open("/proc/self/status") as f:
        peak = next(int(line.split()[1]) for line in f if line.startswith("VmHWM")) / 2**20
    print(json.dumps({"seconds": seconds, "peak": peak, "digest": digest.hexdigest()}))


def main(nside, repeats):
    best, peaks, digests = {}, {}, set()
    for _ in range(repeats):
        for name in RUNS:  # alternated, each in a fresh process
            out = (
                subprocess.run(
                    [sys.executable, __file__, "--one", name, str(nside)],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                .stdout.strip()
                .splitlines()[-1]
            )
            run = json.loads(out)
            digests.add(run["digest"])
            best[name] = min(best.get(name, float("inf")), run["seconds"])
            peaks[name] = max(peaks.get(name, 0.0), run["peak"])
    assert len(digests) == 1, "a Dask run differs from the serial one"
    first = best["1 worker"]
    rows = [
        {
            "run": name,
            "wall [s]": f"{seconds:.1f}",
            "speed-up over 1 worker": f"{first / seconds:.2f}",
            "this process's peak [GiB]": f"{peaks[name]:.2f}",
        }
        for name, seconds in best.items()
    ]
    report(
        "focalplane_dask",
        f"A focal plane's h_n on local Dask workers, Nside {nside}",
        list(rows[0]),
        rows,
        notes=(
            f"examples/schedule_deep_sat.toml's CES set at 12 boresight angles, "
            f"{season().n_samples:,} samples at 20 Hz in {len(time_groups(season()))} groups of "
            "CESs, TOAST's 37-pixel 35-deg hexagon (37 pairs, one block); wall seconds, best of "
            f"{repeats}, each run in a fresh process, the runs alternated; the peak is that "
            "process's (for Dask, the client's: the workers are processes of their own); every "
            "result equal to the serial run's to the bit."
        ),
    )


if __name__ == "__main__":
    if sys.argv[1:2] == ["--one"]:
        one(sys.argv[2], int(sys.argv[3]))
    else:
        main(
            int(sys.argv[1]) if len(sys.argv) > 1 else 256,
            int(sys.argv[2]) if len(sys.argv) > 2 else 1,
        )
