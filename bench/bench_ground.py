"""Real-scan throughput on a 24-CES schedule (Nside 512 by default).

* pointing: pointing.pointing alone (theta, phi, psi per sample);
* pointing + hit binning: moments.characterise_schedule (hits, h_n and crossing-angle bitmaps
  per pixel, pointing fused in). Timed at 100 and 400 Hz; the difference gives the steady-state
  rate per sample, the rest is a fixed per-map cost (allocation and per-pixel finalisation);
* pointing + TOD and maps: engine.simulate_samples (sky interpolation, pair differences, binning).

Usage: python bench/bench_ground.py [NSIDE]
"""

import sys
import time

from _table import report

from boresight import engine, moments, pointing
from boresight.schedule import CES, Schedule
from boresight.sky import SkyConfig, make_sky

CES = tuple(
    CES(
        start_unix=1.79e9 + i * 3600,
        duration_s=3300,
        elevation_deg=50,
        az_centre_deg=134 if i % 2 else 226,
        az_throw_deg=60,
    )
    for i in range(24)
)


def timed(fn, *args):
    t0 = time.perf_counter()
    fn(*args)
    return time.perf_counter() - t0


def main(nside):
    s = make_sky(SkyConfig(nside=nside, lmax=2 * nside, fwhm_arcmin=30.0, seed=1))
    warm = Schedule(CES[:1], sample_rate_hz=1.0)
    moments.characterise_schedule(warm, nside)
    engine.simulate_samples(s, pointing.pointing(warm))
    short, long = (Schedule(CES, sample_rate_hz=r) for r in (100.0, 400.0))
    t_point = timed(lambda: [None for _ in pointing.pointing(short)])
    t_short = timed(moments.characterise_schedule, short, nside)
    t_long = timed(moments.characterise_schedule, long, nside)
    t_tod = timed(lambda: engine.simulate_samples(s, pointing.pointing(short)))
    n_s, n_l = short.n_samples, long.n_samples
    steady = (n_l - n_s) / (t_long - t_short)
    report(
        "ground",
        f"Real-scan throughput, 24 CESs at Nside {nside}: samples per second",
        ["stage", "samples", "samples_per_s"],
        [
            dict(stage="pointing", samples=n_s, samples_per_s=n_s / t_point),
            dict(stage="pointing + hit binning", samples=n_s, samples_per_s=n_s / t_short),
            dict(stage="pointing + hit binning", samples=n_l, samples_per_s=n_l / t_long),
            dict(stage="pointing + hit binning, steady state", samples=None, samples_per_s=steady),
            dict(stage="pointing + TOD and maps", samples=n_s, samples_per_s=n_s / t_tod),
        ],
        f"the hit binning's fixed cost per map: {t_short - n_s / steady:.2f} s",
    )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 512)
