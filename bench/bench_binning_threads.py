"""The binning's threads on a southern field: 1 against 2 threads, the pixel ranges uniform in RING
index (as before) and balanced by the samples (``moments.axis.pixel_ranges``).

The deep example's CES set (declination -45 deg, 24 CESs) at NSIDE: (1) ``moments.axis._bin``
alone on its samples' pixels and angles, computed once and repeated COPIES times (the same field
observed that many times as long: a call of a few milliseconds times its threads' start more
than their work); (2) the whole focal-plane path, ``scan-stats``' ``characterise_focalplane`` of TOAST's
37-pixel 10-deg hexagon (pointing of every pair and binning). Wall seconds, best of REPEATS runs,
the thread counts alternated; each result equal to the one-thread run's to the bit.

Usage: python bench/bench_binning_threads.py [NSIDE] [REPEATS] [COPIES]

Writes bench/results/binning_threads.json.
"""

import sys
import time
from dataclasses import replace
from pathlib import Path

import numba
import numpy as np
from _table import report

from boresight import pointing
from boresight.instrument.focalplane import hexagon
from boresight.moments.axis import Accumulator, _bin, ces_hits, pixel_ranges
from boresight.moments.focalplane import characterise_focalplane
from boresight.schedule import load_schedule

ROOT = Path(__file__).resolve().parent.parent


def samples(schedule, nside):
    parts = [ces_hits(*args, nside, 360, False) for *_, args in pointing.ces_chunks(schedule)]
    return [np.concatenate(x) for x in zip(*parts)]


def bin_once(pix, c, s, b, nside, bounds):
    acc = Accumulator(nside, 1.0)
    t0 = time.perf_counter()
    _bin(pix, c, s, b, acc.sums, acc.hits, acc.occupancy, bounds)
    return time.perf_counter() - t0, acc


def main(nside, repeats, copies):
    schedule = load_schedule(str(ROOT / "examples" / "schedule_deep_sat.toml"))
    once = replace(schedule, repeat_boresight_deg=(0.0,))
    pix, c, s, b = (np.tile(x, copies) for x in samples(once, nside))
    npix = 12 * nside**2
    ranges = {
        "uniform": lambda n: np.array([p * npix // n for p in range(n + 1)], dtype=np.int64),
        "balanced": lambda n: pixel_ranges(pix, npix, n),
    }
    best, ref = {}, None
    bin_once(pix, c, s, b, nside, ranges["uniform"](2))  # compiled
    for _ in range(repeats):
        for name, make in ranges.items():
            for threads in (1, 2):
                numba.set_num_threads(threads)
                seconds, acc = bin_once(pix, c, s, b, nside, make(threads))
                ref = acc if ref is None else ref
                assert np.array_equal(acc.sums, ref.sums) and np.array_equal(acc.hits, ref.hits)
                key = ("binning", name, threads)
                best[key] = min(best.get(key, np.inf), seconds)
    focal = hexagon(37, 10.0)
    short = replace(once, ces=once.ces[:6])
    maps = None
    for _ in range(repeats):
        for threads in (1, 2):
            numba.set_num_threads(threads)
            t0 = time.perf_counter()
            stats = characterise_focalplane(short, focal, nside)
            seconds = time.perf_counter() - t0
            h = stats.combined.h
            maps = h if maps is None else maps
            assert np.array_equal(h, maps)
            key = ("focal-plane path", "balanced", threads)
            best[key] = min(best.get(key, np.inf), seconds)
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    halves = [np.sum((pix >= lo) & (pix < hi)) for lo, hi in ((0, npix // 2), (npix // 2, npix))]
    rows = []
    for (stage, name, threads), seconds in best.items():
        if threads == 2:
            one = best[(stage, name, 1)]
            rows.append(
                {
                    "stage": stage,
                    "pixel ranges": name,
                    "1 thread [s]": f"{one:.3f}",
                    "2 threads [s]": f"{seconds:.3f}",
                    "speed-up": f"{one / seconds:.2f}",
                }
            )
    report(
        "binning_threads",
        f"The binning's threads on a southern field, Nside {nside}",
        list(rows[0]),
        rows,
        notes=(
            f"examples/schedule_deep_sat.toml's CES set, its samples {copies} times: "
            f"{pix.size:,} samples; RING's uniform "
            f"halves hold {halves[0]:,} and {halves[1]:,} of them. Binning: moments.axis._bin "
            "alone; focal-plane path: characterise_focalplane of TOAST's 37-pixel 10-deg hexagon "
            f"over the first 6 CESs. Wall seconds, best of {repeats}, alternated; every result "
            "equal to the one-thread run's to the bit."
        ),
    )


if __name__ == "__main__":
    main(
        int(sys.argv[1]) if len(sys.argv) > 1 else 512,
        int(sys.argv[2]) if len(sys.argv) > 2 else 3,
        int(sys.argv[3]) if len(sys.argv) > 3 else 8,
    )
