"""Real-scan throughput: pointing alone, and pointing + pair-difference binning of a CES schedule.

Usage: python bench/bench_ground.py [NSIDE] (a 24-CES schedule at 100 Hz: 7.9 M samples).
"""
import sys
import time

from boresight import engine, ground, sky


def main(nside):
    ces = tuple(ground.CES(start_unix=1.79e9 + i * 3600, duration_s=3300, elevation_deg=50,
                           az_centre_deg=134 if i % 2 else 226, az_throw_deg=60)
                for i in range(24))
    sched = ground.Schedule(ces, sample_rate_hz=100.0)
    s = sky.make_sky(sky.SkyConfig(nside=nside, lmax=2 * nside, fwhm_arcmin=30.0, seed=1))
    engine.simulate_samples(s, [next(ground.pointing(ground.Schedule(ces[:1], sample_rate_hz=1)))])
    t0 = time.perf_counter()
    for _ in ground.pointing(sched):
        pass
    t_point = time.perf_counter() - t0
    t0 = time.perf_counter()
    engine.simulate_samples(s, ground.pointing(sched))
    t_all = time.perf_counter() - t0
    n = sched.n_samples
    print(f"{'Nside':>6} {'samples':>9} {'pointing /s':>12} {'pointing+binning /s':>20}")
    print(f"{nside:>6} {n:>9.2e} {n / t_point:>12.3e} {n / t_all:>20.3e}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 512)
