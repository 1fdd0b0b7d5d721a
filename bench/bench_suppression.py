"""What each systematic costs to simulate, and the whole `boresight suppression` map.

1. Per systematic of boresight.jobs.suppression.axis.CATALOGUE: the engine's time for the paper's deep
   survey at 0/90 deg rotation (the simulation alone, interpolated sky, all cores), against the
   same scan without a systematic.
2. The whole suppression map (sky, 9 systematics x 4 schedules, predictions, transforms): wall
   time and peak RSS of this process, and the map's table at the last Nside (deterministic: the
   same as `boresight suppression --nside N`).

Usage: python bench/bench_suppression.py [NSIDE ...]   (default 256 512)
"""

import resource
import sys
import time

from _table import report

from boresight import engine, masks
from boresight.instrument.pairs import Systematics
from boresight.jobs import suppression
from boresight.scan import paper_scan
from boresight.sky import SkyConfig, make_sky


def per_systematic(sky):
    obs = masks.survey_mask("deep", sky.nside) > 0
    scan = paper_scan("deep", 90.0)
    rows = []
    for name, sysm in [("none", Systematics())] + [
        (e.name, e.for_repeats(2)) for e in suppression.CATALOGUE
    ]:
        engine.simulate(sky, scan, systematics=sysm, pixels=obs)  # compile, warm caches
        t0 = time.perf_counter()
        engine.simulate(sky, scan, systematics=sysm, pixels=obs)
        rows.append((name, time.perf_counter() - t0))
    return rows, int(obs.sum())


def main(nsides):
    costs, whole = [], []
    for nside in nsides:
        cfg = SkyConfig(nside=nside, lmax=3 * nside - 1, fwhm_arcmin=30.0)
        sky = make_sky(cfg)
        rows, npix = per_systematic(sky)
        base = rows[0][1]
        costs += [
            dict(nside=nside, systematic=name, engine_s=t, times_no_systematic=t / base)
            for name, t in rows
        ]
        t0 = time.perf_counter()
        result = suppression.run(make_sky(cfg))
        whole.append((nside, npix, time.perf_counter() - t0))
        table = suppression.markdown(suppression.table(result, nside))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    report(
        "suppression_costs",
        "What each systematic costs the engine: the deep survey at 0/90 deg rotation",
        list(costs[0]),
        costs,
    )
    report(
        "suppression",
        "The whole suppression map: 9 systematics x 4 schedules, simulated and predicted",
        ["nside", "observed_pixels", "seconds"],
        [dict(nside=n, observed_pixels=p, seconds=t) for n, p, t in whole],
        f"peak RSS of this process {rss:.2f} GiB",
    )
    print(f"\nThe suppression map at Nside {nsides[-1]}:\n")
    print(table)


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [256, 512])
