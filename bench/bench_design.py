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
from _table import report

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
    row = dict(
        ces=len(schedule.ces),
        samples=schedule.n_samples,
        nside=nside,
        observed_pixels=int(moments.pixels.size),
        entries=int(moments.index.size),
        moments_build_s=t1 - t0,
        objective_build_s=t2 - t1,
        one_evaluation_s=(t4 - t3) / reps,
        one_sweep_s=t5 - t4,
        per_unit_ms=(t5 - t4) / moments.n_units * 1e3,
    )
    report(
        "design_costs",
        "design: the cost of the objective on a 1,008-CES schedule",
        list(row),
        [row],
    )


def worked_example():
    with tempfile.TemporaryDirectory() as tmp:
        result = design_command.run(
            "examples/budget_deep_sat.toml",
            "examples/schedule_deep_sat.toml",
            f"{tmp}/design",
        )
    rows = {r["strategy"]: r["delta_r"] for r in result["strategies"]}
    best = min((v, k) for k, v in rows.items() if k != "optimised")
    report(
        "design_example",
        "design on the deep example: every strategy's predicted delta_r",
        ["strategy", "delta_r", "delta_r_over_sigma_r", "changes"],
        result["strategies"],
        f"sigma(r) = {result['sigma_r']:.3g} (30 <= ell <= 300); optimised / best baseline "
        f"({best[1]}): {rows['optimised'] / best[0]:.3g}",
    )
    report(
        "design_validation",
        "design on the deep example: the TOD check of the prediction",
        ["strategy", "predicted_delta_r", "simulated_delta_r", "ratio"],
        result["validation"],
    )


if __name__ == "__main__":
    objective_costs(int(sys.argv[1]) if len(sys.argv) > 1 else 512)
    worked_example()
