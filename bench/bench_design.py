"""`boresight design`: the cost of the objective, and the worked example of the README.

1. A 1,008-CES schedule (the deep example's 24 CESs of 25 minutes at 20 Hz on 42 days, 30 million
   samples) at Nside 512: the time to build the per-CES spin moments and the objective once,
   then the time of one full objective evaluation and of one coordinate-descent trial of a unit.
2. The worked example: examples/budget_deep_sat.toml on examples/schedule_deep_sat.toml, every
   strategy's predicted delta_r and delta_r / sigma(r), and the TOD check of the prediction.

Usage: python bench/bench_design.py [NSIDE]
"""

import sys
import tempfile
import time
from dataclasses import replace

import numpy as np

from boresight import cosmology, design
from boresight.commands import design as design_command
from boresight.instrument import Systematics
from boresight.schedule import load_schedule


def big_schedule():
    base = load_schedule("examples/schedule_deep_sat.toml")
    ces = tuple(
        replace(c, start_unix=c.start_unix + 86400 * day) for day in range(42) for c in base.ces
    )
    return replace(base, ces=ces, repeat_boresight_deg=(0.0,))


def objective_costs(nside):
    schedule = big_schedule()
    budget = Systematics(dg=(0.01, -0.01), rho_arcmin=0.5, chi_deg=30.0)
    t0 = time.perf_counter()
    moments = design.unit_moments(schedule, nside, "ces")
    t1 = time.perf_counter()
    obj = design.objective(moments, budget, cosmology.load_spectra(), 30.0)
    t2 = time.perf_counter()
    angles = np.random.default_rng(0).choice([-90.0, -45.0, 0.0, 45.0, 90.0], moments.n_units)
    obj.delta_r(angles)
    reps = 5
    t3 = time.perf_counter()
    for _ in range(reps):
        obj.delta_r(angles)
    t4 = time.perf_counter()
    design.optimise(obj, (-90.0, -45.0, 0.0, 45.0, 90.0), angles, sweeps=1)
    t5 = time.perf_counter()
    print(
        "| CESs | samples | Nside | observed pixels | entries | moments build | objective build "
        "| one evaluation | one sweep (per unit) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    print(
        f"| {len(schedule.ces)} | {schedule.n_samples:.3g} | {nside} | {moments.pixels.size} "
        f"| {moments.index.size} | {t1 - t0:.1f} s | {t2 - t1:.1f} s | {(t4 - t3) / reps:.3f} s "
        f"| {t5 - t4:.1f} s ({(t5 - t4) / moments.n_units * 1e3:.1f} ms) |"
    )


def worked_example():
    with tempfile.TemporaryDirectory() as tmp:
        result = design_command.run(
            "examples/budget_deep_sat.toml",
            "examples/schedule_deep_sat.toml",
            f"{tmp}/design",
        )
    print(f"\nsigma(r) = {result['sigma_r']:.3g} (30 <= ell <= 300)\n")
    print("| strategy | predicted delta_r | delta_r / sigma(r) | angle changes |")
    print("|---|---|---|---|")
    for r in result["strategies"]:
        print(
            f"| {r['strategy']} | {r['delta_r']:.3g} | {r['delta_r_over_sigma_r']:.3g} "
            f"| {r['changes']} |"
        )
    rows = {r["strategy"]: r["delta_r"] for r in result["strategies"]}
    best = min((v, k) for k, v in rows.items() if k != "optimised")
    print(f"\noptimised / best baseline ({best[1]}): {rows['optimised'] / best[0]:.3g}\n")
    print("| TOD check | predicted delta_r | simulated (leaked power) | ratio |")
    print("|---|---|---|---|")
    for v in result["validation"]:
        print(
            f"| {v['strategy']} | {v['predicted_delta_r']:.3g} | {v['simulated_delta_r']:.3g} "
            f"| {v['ratio']:.3f} |"
        )


if __name__ == "__main__":
    objective_costs(int(sys.argv[1]) if len(sys.argv) > 1 else 512)
    worked_example()
