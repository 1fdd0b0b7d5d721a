"""Wall time of the paper reproduction, stage by stage, its peak RSS against the memory estimate,
and its time in passes of one spin-2 analysis at its Nside and lmax.

A pass is ducc0's full-sky spin-2 ``adjoint_synthesis`` on the same cores, timed three times
before the run and three times after it (a shared machine's speed drifts), in CPU seconds and
wall seconds; the run's passes are its own CPU (wall) time over the median pass's.

Usage: python bench/bench_reproduce.py [NSIDE [LMAX]] [--backend gpu]
(default Nside 512 / lmax 1535, the --quick run; 2048 4000 is the paper's resolution).
"""

import json
import resource
import sys
import tempfile
import time

import ducc0
import numpy as np
from _table import report

from boresight import harmonics
from boresight.commands import reproduce
from boresight.config import RunOptions
from boresight.jobs import paper


def passes(nside, lmax, repeats=3):
    """(CPU s, wall s) of ``repeats`` spin-2 analyses, full sky, on every core."""
    maps = np.random.default_rng(1).standard_normal((2, 12 * nside**2))
    geometry = harmonics.healpix_geometry(nside)
    out = []
    for _ in range(repeats):
        cpu, wall = time.process_time(), time.perf_counter()
        ducc0.sht.adjoint_synthesis(map=maps, lmax=lmax, spin=2, nthreads=0, **geometry)
        out.append((time.process_time() - cpu, time.perf_counter() - wall))
    return out


def main(nside, lmax, backend):
    study = paper.preset(nside=nside, lmax=lmax, run=RunOptions(backend=backend))
    timed = passes(nside, lmax)
    with tempfile.TemporaryDirectory() as tmp:
        cpu, t0 = time.process_time(), time.perf_counter()
        claims = reproduce.run(f"{tmp}/out", study)
        total, cpu = time.perf_counter() - t0, time.process_time() - cpu
        with open(f"{tmp}/out/manifest.json") as f:
            manifest = json.load(f)
    timed += passes(nside, lmax)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    rows = [dict(stage=name, seconds=s) for name, s in manifest["wall_time_s"].items()]
    rows.append(dict(stage="total", seconds=total))
    pass_cpu, pass_wall = (np.array(x) for x in zip(*timed))
    estimate = manifest["estimate"]["memory_gib"]
    report(
        f"reproduce_{nside}_{backend}",
        f"The paper's reproduction at Nside {nside}, lmax {lmax}, backend {backend}, by stage",
        ["stage", "seconds"],
        rows,
        f"peak RSS {rss:.2f} GiB (the estimate {estimate:.2f} GiB is {estimate / rss:.2f}x); "
        f"{sum(c.reproduced for c in claims)} of {len(claims)} claims reproduced; "
        f"{cpu:.0f} CPU-s, {total:.0f} s wall; a spin-2 pass {np.min(pass_cpu):.1f}-"
        f"{np.max(pass_cpu):.1f} CPU-s (median {np.median(pass_cpu):.1f}; "
        f"{np.min(pass_wall):.1f}-{np.max(pass_wall):.1f} s wall), so "
        f"{cpu / np.median(pass_cpu):.0f} passes by CPU ({cpu / np.max(pass_cpu):.0f}-"
        f"{cpu / np.min(pass_cpu):.0f}) and {total / np.median(pass_wall):.0f} by wall time",
    )


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--backend" and a != "gpu"]
    backend = "gpu" if "gpu" in sys.argv[1:] else "cpu"
    nside = int(args[0]) if args else 512
    lmax = int(args[1]) if len(args) > 1 else 3 * nside - 1
    main(nside, lmax, backend)
