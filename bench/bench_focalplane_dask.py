"""A focal plane's h_n on a local Dask cluster of 1, 2 and 4 workers against this process alone.

The deep example's CES set observed at ANGLES boresight angles (default 12: 0, 30, ..., 330
deg, 8.6 million samples at 20 Hz, 120 hours; 24 doubles it), cut into groups of CESs of at least
``moments.focalplane.GROUP_SAMPLES`` samples, one task each) seen by TOAST's 37-pixel 35-deg
hexagon at NSIDE. Each worker runs numba on its share of the cores (NUMBA_NUM_THREADS), or on
one thread (how workers scale when each brings its own core, as a cluster's nodes do); at most
two tasks a worker are in flight, and this process adds the results in task order as they
arrive. Wall and CPU seconds (this process's and its workers') and this process's own peak
resident memory (the client's: what it holds of the tasks' results), best of REPEATS runs;
every Dask result equal to the serial one to the bit.

Usage: python bench/bench_focalplane_dask.py [NSIDE] [REPEATS] [ANGLES]

Writes bench/results/focalplane_dask.json.
"""

import hashlib
import json
import os
import resource
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
#: name -> (scheduler, local workers, numba threads in each: None for its share of the cores)
RUNS = {
    "serial": ("serial", 1, None),
    "1 worker, its share": (None, 1, None),
    "2 workers, their share": (None, 2, None),
    "4 workers, their share": (None, 4, None),
    "1 worker, 1 thread": (None, 1, 1),
    "2 workers, 1 thread each": (None, 2, 1),
}


def season(angles=12):
    schedule = load_schedule(str(ROOT / "examples" / "schedule_deep_sat.toml"))
    return replace(schedule, repeat_boresight_deg=tuple(360.0 / angles * k for k in range(angles)))


def one(name, nside, angles):
    """One run in this (fresh) process: its wall seconds, peak resident GiB and a digest of its
    maps, printed as JSON."""
    scheduler, workers, threads = RUNS[name]
    schedule, focal = season(angles), hexagon(37, 35.0)
    characterise_focalplane(replace(schedule, ces=schedule.ces[:1]), focal, nside)  # compiled
    before = cpu_seconds()
    t0 = time.perf_counter()
    stats = characterise_focalplane(
        schedule, focal, nside, scheduler=scheduler, workers=workers, worker_threads=threads
    )
    seconds = time.perf_counter() - t0
    cpu = cpu_seconds() - before
    digest = hashlib.sha256()
    for array in (stats.sum_sq, stats.pair_weights, stats.combined.h, stats.combined.hits):
        digest.update(array.tobytes())
    with open("/proc/self/status") as f:
        peak = next(int(line.split()[1]) for line in f if line.startswith("VmHWM")) / 2**20
    print(json.dumps({"seconds": seconds, "cpu": cpu, "peak": peak, "digest": digest.hexdigest()}))


def cpu_seconds():
    """CPU seconds of this process and of its children that have ended (the local cluster's
    workers, once it has closed)."""
    return sum(
        u.ru_utime + u.ru_stime
        for u in (
            resource.getrusage(resource.RUSAGE_SELF),
            resource.getrusage(resource.RUSAGE_CHILDREN),
        )
    )


def _alike(name):
    """The one-worker run with the same threads a worker as ``name``."""
    if RUNS[name][0] == "serial":
        return None
    return "1 worker, 1 thread" if RUNS[name][2] == 1 else "1 worker, its share"


def main(nside, repeats, angles):
    best, cpus, peaks, digests = {}, {}, {}, set()
    for _ in range(repeats):
        for name in RUNS:  # alternated, each in a fresh process
            out = (
                subprocess.run(
                    [sys.executable, __file__, "--one", name, str(nside), str(angles)],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                .stdout.strip()
                .splitlines()[-1]
            )
            run = json.loads(out)
            digests.add(run["digest"])
            if run["seconds"] < best.get(name, float("inf")):
                best[name], cpus[name] = run["seconds"], run["cpu"]
            peaks[name] = max(peaks.get(name, 0.0), run["peak"])
    assert len(digests) == 1, "a Dask run differs from the serial one"
    rows = [
        {
            "run": name,
            "wall [s]": f"{seconds:.1f}",
            "CPU [s]": f"{cpus[name]:.1f}",
            "speed-up over 1 worker alike": (
                f"{best[first] / seconds:.2f}" if (first := _alike(name)) else ""
            ),
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
            f"examples/schedule_deep_sat.toml's CES set at {angles} boresight angles, "
            f"{season(angles).n_samples:,} samples at 20 Hz in "
            f"{len(time_groups(season(angles)))} groups of "
            "CESs, TOAST's 37-pixel 35-deg hexagon (37 pairs, one block); wall seconds, best of "
            f"{repeats}, each run in a fresh process, the runs alternated, cluster start-up "
            "included; CPU seconds of the process and its workers. A worker's share of the "
            f"{os.cpu_count()} cores is cores / workers threads; with 1 thread each, the workers "
            "scale as a cluster's nodes would. The peak is the process's own (for Dask, the "
            "client's: the workers are processes of their own); every result equal to the serial "
            "run's to the bit."
        ),
    )


if __name__ == "__main__":
    if sys.argv[1:2] == ["--one"]:
        one(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
    else:
        main(
            int(sys.argv[1]) if len(sys.argv) > 1 else 256,
            int(sys.argv[2]) if len(sys.argv) > 2 else 1,
            int(sys.argv[3]) if len(sys.argv) > 3 else 12,
        )
