"""The cost of filtering before binning: ``engine.simulate_schedule`` on the deep example with
each filter against the raw pair differences, in CPU seconds per pair-sample, and its peak memory
for the CES set once against twice (0/90: twice the samples on the same pixels).

A filter acts CES by CES inside the streaming loop (boresight.mitigation.Filtering): its cost
should stay within 1.5x of the raw engine's per pair-sample, and its peak memory should not grow
with the schedule's length (one CES's samples at a time, beside the full-sky sums). Runs
alternate raw and filtered, and each ratio is of the median of its repeats.

Usage: python bench/bench_filtering.py [NSIDE] [REPEATS]

Writes bench/results/filtering.json.
"""

import dataclasses
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

from _table import report

from boresight import engine
from boresight.instrument.pairs import PAPER_GAIN, Instrument
from boresight.mitigation import Filtering
from boresight.schedule import load_schedule
from boresight.sky import SkyConfig, make_sky

ROOT = Path(__file__).resolve().parent.parent
FILTERS = ("p1", "p3", "ground", "p3+ground", "p1+ground3-split", "groundbin1")


def _cpu(sky, schedule, filtering):
    t0 = time.process_time()
    engine.simulate_schedule(sky, schedule, Instrument(), PAPER_GAIN, filtering=filtering)
    return time.process_time() - t0


def _peak_mib(sky, schedule, filtering):
    tracemalloc.start()
    engine.simulate_schedule(sky, schedule, Instrument(), PAPER_GAIN, filtering=filtering)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2**20


def main(nside, repeats):
    schedule = load_schedule(str(ROOT / "examples" / "schedule_deep_sat.toml")).single()
    twice = schedule.repeated((0.0, 90.0))
    quarter = dataclasses.replace(schedule, ces=schedule.ces[: len(schedule.ces) // 4])
    sky = make_sky(SkyConfig(nside=nside, lmax=2 * nside, fwhm_arcmin=60.0, seed=1))
    pair_samples = schedule.n_samples * Instrument().n_pairs
    raw = Filtering()
    _cpu(sky, quarter, Filtering.parse("p3+ground"))  # compile every kernel first
    rows = []
    for text in FILTERS:
        filtering = Filtering.parse(text)
        times = {"raw": [], "filtered": []}
        for _ in range(repeats):  # alternate A and B
            times["raw"].append(_cpu(sky, schedule, raw))
            times["filtered"].append(_cpu(sky, schedule, filtering))
        a, b = (statistics.median(times[k]) for k in ("raw", "filtered"))
        rows.append(
            {
                "filter": str(filtering),
                "raw_ns_per_pair_sample": 1e9 * a / pair_samples,
                "filtered_ns_per_pair_sample": 1e9 * b / pair_samples,
                "filtered_over_raw": b / a,
                "peak_mib_once": _peak_mib(sky, schedule, filtering),
                "peak_mib_twice": _peak_mib(sky, twice, filtering),
            }
        )
    report(
        "filtering",
        f"The cost of filtering before binning, the deep example once, Nside {nside}",
        list(rows[0]),
        rows,
        notes=(
            f"examples/schedule_deep_sat.toml once ({len(schedule.ces)} CESs, "
            f"{schedule.n_samples} samples at {schedule.sample_rate_hz:g} Hz), the paper's Q and "
            "U pairs with dg = +-0.01, a sky read by interpolation; CPU seconds (process time) "
            f"per pair-sample, the median of {repeats} runs alternating raw and filtered; peak: "
            "tracemalloc's peak of the Python and numpy allocations of one simulation, of the CES "
            "set once and twice (0/90: twice the samples, the same pixels)."
        ),
    )


if __name__ == "__main__":
    main(
        int(sys.argv[1]) if len(sys.argv) > 1 else 128,
        int(sys.argv[2]) if len(sys.argv) > 2 else 3,
    )
