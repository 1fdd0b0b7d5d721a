"""`boresight design`: the exact objective's cost, and its prediction against the TOD.

1. Cost: the deep example's 24 CESs repeated on 42 days (1,008 CESs, 30 million samples), one
   angle per UTC day (42 units), at Nside 256: the time to build the units' moments and the
   objective (its kernels and every unit's h_n alm), one full evaluation, the whole search
   (every start and sweep), and the peak memory.
2. The TOD check, like with like: for the gain, pointing and gain + pointing + ellipticity
   budgets, on the deep example schedule (48 units, Nside 128) and on a short one (8 of its
   CESs at its 2 repeats: 16 units, 3 allowed angles, Nside 64), every strategy's predicted
   total-residual delta_r against the mean of SKIES TOD skies, with its standard error, and
   the paper's white-h_n approximation beside it.

3. The same check with the sky read exactly at every sample (``evaluation = "exact"``), the
   prediction carrying the samples' offsets from their pixel centres: every budget on both
   schedules.

RATE_HZ resamples both schedules (default their own 20 Hz): the exact TOD costs 4x the
interpolated one per sample.

Usage: python bench/bench_design.py [SKIES] [interp|exact] [RATE_HZ]
"""

import resource
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from _table import report

from boresight import cosmology
from boresight.commands import design as design_command
from boresight.design.exact import exact_objective, search
from boresight.instrument.pairs import Systematics
from boresight.moments import unit_moments
from boresight.schedule import load_schedule, write_schedule

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
BUDGETS = {
    "gain": "dg = [0.01, -0.01]",
    "pointing": "rho_arcmin = 0.5\nchi_deg = 30.0",
    "gain + pointing + ellipticity": (
        "dg = [0.01, -0.01]\nrho_arcmin = 0.5\nchi_deg = 30.0\nellipticity_b = 0.01"
    ),
}
NOISE = "depth_uk_arcmin = 3.0\nfsky = 0.1\nfwhm_arcmin = 30.0"


def big_schedule():
    base = load_schedule(str(EXAMPLES / "schedule_deep_sat.toml"))
    ces = tuple(
        replace(c, start_unix=c.start_unix + 86400 * day) for day in range(42) for c in base.ces
    )
    return replace(base, ces=ces, repeat_boresight_deg=(0.0,))


def objective_costs(nside=256):
    schedule = big_schedule()
    budget = Systematics(dg=(0.01, -0.01), rho_arcmin=0.5, chi_deg=30.0)
    allowed = (-90.0, -45.0, 0.0, 45.0, 90.0)
    t0 = time.perf_counter()
    moments = unit_moments(schedule, nside, "day")
    t1 = time.perf_counter()
    obj = exact_objective(moments, budget, cosmology.load_spectra(), 30.0)
    t2 = time.perf_counter()
    angles = np.random.default_rng(0).choice(allowed, moments.n_units)
    reps = 3
    for _ in range(reps):
        obj.delta_r(angles)
    t3 = time.perf_counter()
    found = search(obj, allowed, np.zeros(moments.n_units))
    t4 = time.perf_counter()
    row = dict(
        ces=len(schedule.ces),
        units=moments.n_units,
        samples=schedule.n_samples,
        nside=nside,
        lmax=obj.lmax,
        moments_build_s=t1 - t0,
        objective_build_s=t2 - t1,
        one_evaluation_s=(t3 - t2) / reps,
        search_s=t4 - t3,
        passes=len(found.history),
        peak_rss_gib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
    )
    report(
        "design_costs",
        "design: the exact objective on a 1,008-CES schedule, one angle per day",
        list(row),
        [row],
    )


def _schedules(tmp, rate_hz):
    """The deep example and its short cut (every third CES), at ``rate_hz`` (None: its own)."""
    base = load_schedule(str(EXAMPLES / "schedule_deep_sat.toml"))
    rate = base.sample_rate_hz if rate_hz is None else rate_hz
    paths = []
    for name, ces in (("deep", base.ces), ("short", base.ces[::3])):
        paths.append(f"{tmp}/{name}.toml")
        write_schedule(replace(base, ces=ces, sample_rate_hz=rate), paths[-1], "toml")
    return paths, rate


def _ratio(simulated, predicted):
    """simulated / predicted, or "-" where the prediction is zero or far below the TOD's noise
    (a residual that the strategy cancels)."""
    if abs(predicted) < 1e-12:
        return "-"
    return f"{simulated / predicted:.3f}"


def validation(skies, evaluation="interp", rate_hz=None):
    rows = []
    exact = evaluation == "exact"
    with tempfile.TemporaryDirectory() as tmp:
        (deep, short), rate = _schedules(tmp, rate_hz)
        schedules = {
            "deep (48 units, Nside 128)": (
                deep,
                "angles_deg = [-90.0, -45.0, 0.0, 45.0, 90.0]\nnside = 128",
            ),
            "short (16 units, Nside 64)": (
                short,
                "angles_deg = [0.0, 45.0, 90.0]\nnside = 64",
            ),
        }
        for schedule_name, (schedule, design_table) in schedules.items():
            for budget_name, systematics in BUDGETS.items():
                path = Path(tmp) / "budget.toml"
                path.write_text(
                    f"[systematics]\n{systematics}\n[noise]\n{NOISE}\n"
                    f"[design]\n{design_table}\nvalidation_skies = {skies}\n"
                    f'evaluation = "{evaluation}"\n'
                )
                result = design_command.run(str(path), schedule, f"{tmp}/out", force=True)
                white = {
                    r["strategy"]: r["delta_r_white_approximation"] for r in result["strategies"]
                }
                searched = {r["strategy"]: r["delta_r"] for r in result["strategies"]}
                for v in result["validation"]:
                    sim, se, pred = (
                        v["simulated_delta_r"],
                        v["simulated_delta_r_se"],
                        v["predicted_delta_r"],
                    )
                    rows.append(
                        dict(
                            schedule=schedule_name,
                            budget=budget_name,
                            strategy=v["strategy"],
                            simulated=f"{sim:.4g} +- {se:.2g}",
                            predicted=f"{pred:.4g}",
                            ratio=_ratio(sim, pred),
                            within=f"{abs(sim - pred) / max(se, 1e-300):.1f} se",
                            objective=f"{searched[v['strategy']]:.4g}",
                            white_approximation=f"{white[v['strategy']]:.4g}",
                            white_ratio=_ratio(sim, white[v["strategy"]]),
                        )
                    )
    report(
        "design_validation_exact" if exact else "design_validation",
        f"design: predicted total delta_r against the mean of {skies} TOD skies"
        + (", the sky read exactly at every sample" if exact else "")
        + f", the schedules at {rate:g} Hz",
        list(rows[0]),
        rows,
        "simulated: mean +- standard error over the skies; within: |simulated - predicted| in "
        "standard errors; objective: the search's exact objective (read exactly, with the "
        "samples' offsets from their pixel centres); white_approximation: the paper's "
        "slowly-varying-h_n objective",
    )


if __name__ == "__main__":
    evaluation = sys.argv[2] if len(sys.argv) > 2 else "interp"
    validation(
        int(sys.argv[1]) if len(sys.argv) > 1 else 16,
        evaluation,
        float(sys.argv[3]) if len(sys.argv) > 3 else None,
    )
    if evaluation == "interp":
        objective_costs()
