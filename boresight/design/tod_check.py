"""The design's TOD check: every strategy's predicted delta_r against the mean of TOD
simulations of it, on the same skies, and the report that says where they differ."""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.stats
from tqdm import tqdm

from ..config import RunOptions
from ..instrument.focalplane import on_axis
from ..jobs.residual import residual, simulate_reference
from ..predict import delta_r
from ..predict import focalplane as predict_fp
from ..sky import SkyConfig, make_sky


def tod_check(budget, moments, obj, schedule, assignments, *, expected, progress=False):
    """Every strategy's predicted delta_r against the mean of TOD simulations of it.

    The simulation runs the budget's systematics through the TOD engine on the schedule's own
    samples, read as the design's ``evaluation``, at the design's Nside with lmax = 2 Nside, on
    ``validation_skies`` sky realisations
    (and, for {mean, rms} parameters, as many draws of the focal plane, seeded alike); with a
    focal plane, every pair on its own samples (:func:`boresight.engine.simulate_focalplane`).
    Like is compared with like: the total residual C_BB(sys) - C_BB(no sys) with the predicted
    total, the leaked power <dB, dB> with the predicted leaked power (``expected``, per
    strategy); each mean with its standard error. ``assignments``: the strategies' angles and
    steps, and the budget's :class:`boresight.design.hwp.Plate`, behind which the pairs on the axis are simulated
    as a focal plane.

    Every strategy runs on the same skies, so its difference from the optimised one is measured
    sky by sky (``minus_optimised_*``, paired): ``difference_resolved`` says whether that mean
    difference is more than 2 of its standard errors from zero, that is whether the skies
    resolve the difference the prediction reports.
    """
    nside, lmax = moments.nside, 2 * moments.nside
    skies = budget.design.validation_skies
    strategies, steps, plate = assignments
    out, per_sky = [], {}
    bar = tqdm(total=len(strategies) * skies, desc="TOD check", unit="sky", disable=not progress)
    for name, angles in strategies.items():
        scan = moments.schedule(schedule, angles)
        seen = plate.seen(moments, steps[name])
        total, leaked = [], []
        for seed in range(skies):
            sky = make_sky(
                SkyConfig(nside=nside, lmax=lmax, fwhm_arcmin=budget.noise.fwhm_arcmin, seed=seed)
            )
            systematics = dataclasses.replace(budget.systematics, seed=seed)
            cross, auto = tod_parts(
                sky, scan, systematics, budget, moments.mask, lmax=lmax, hwp=seen
            )
            if budget.filtering is not None:  # a filtered leak's bias, as the objective reads it
                cross, auto = cross / obj.kept_bb, auto / obj.kept_bb
            total.append(delta_r(cross + auto, obj.template))
            leaked.append(delta_r(auto, obj.template))
            bar.update()
        per_sky[name] = np.array(total)
        row = dict(strategy=name, skies=skies)
        if budget.filtering is not None:  # a filtered objective's own skies: its error too
            row["predicted_delta_r_se"] = obj.delta_r_se(angles, steps[name])
        for key, values, cl in (
            ("", total, expected[name].residual),
            ("leaked_", leaked, expected[name].leaked),
        ):
            predicted = delta_r(cl, obj.template)
            mean, se = _mean_se(values)
            row.update(
                {
                    f"predicted_{key}delta_r": predicted,
                    f"simulated_{key}delta_r": mean,
                    f"simulated_{key}delta_r_se": se,
                    f"{key}ratio": mean / predicted if predicted else float("nan"),
                }
            )
        out.append(row)
    bar.close()
    best = next(row for row in out if row["strategy"] == reference(out))
    for row in out:
        mean, se = _mean_se(per_sky[row["strategy"]] - per_sky[best["strategy"]])
        row["predicted_minus_optimised"] = row["predicted_delta_r"] - best["predicted_delta_r"]
        row["simulated_minus_optimised"] = mean
        row["simulated_minus_optimised_se"] = se
        row["difference_resolved"] = bool(abs(mean) > 2 * se) if se > 0 else False
    return out


def reference(rows: list[dict]) -> str:
    """The strategy the others are measured against: "optimised", or "as given" where the
    design scored the schedule without a search (the ``*_minus_optimised`` columns then hold
    the differences from it)."""
    names = {row["strategy"] for row in rows}
    return "optimised" if "optimised" in names else "as given"


def _mean_se(values):
    """The mean of a few skies' values and its standard error (NaN from one sky)."""
    values = np.asarray(values, dtype=float)
    se = float(np.std(values, ddof=1) / np.sqrt(values.size)) if values.size > 1 else float("nan")
    return float(np.mean(values)), se


def validation_report(rows: list[dict]) -> tuple[list[str], list[str]]:
    """The TOD check as lines to print, and its warnings.

    Per strategy: the predicted and simulated total delta_r, the simulation's standard error
    (with a filtered objective's own, from its skies, in quadrature) and how many of them it lies
    from the prediction; whether the skies resolve its difference from
    the optimised strategy. A warning for every strategy whose simulation is more than 2 standard
    errors from its prediction, and one naming the differences the skies do not resolve.

    Parameters
    ----------
    rows : list of dict
        ``validation.csv``'s rows.

    Returns
    -------
    (list of str, list of str)
    """
    chosen = reference(rows)
    lines = [
        f"TOD check ({rows[0]['skies']} skies per strategy; total delta_r):",
        f"  {'strategy':<14} {'predicted':>10} {'simulated':>10} {'+-':>9} {'off by':>8}  "
        f"vs {chosen}",
    ]
    warnings, unresolved = [], []
    for row in rows:
        predicted, mean = row["predicted_delta_r"], row["simulated_delta_r"]
        se = float(np.hypot(row["simulated_delta_r_se"], row.get("predicted_delta_r_se", 0.0)))
        pull = (mean - predicted) / se if se > 0 else float("nan")
        if row["strategy"] == chosen:
            versus = "-"
        elif row["difference_resolved"]:
            versus = "resolved"
        else:
            versus = "not resolved"
            unresolved.append(row["strategy"])
        lines.append(
            f"  {row['strategy']:<14} {predicted:>10.3g} {mean:>10.3g} {se:>9.2g} "
            f"{pull:>7.1f}s  {versus}"
        )
        if abs(pull) > 2:
            warnings.append(
                f"the TOD check: {row['strategy']}'s simulated delta_r {mean:.3g} +- {se:.2g} is "
                f"{abs(pull):.1f} standard errors from its prediction {predicted:.3g}"
                + _few_skies(row["skies"])
            )
    if unresolved:
        warnings.append(
            f"the TOD check's {rows[0]['skies']} skies do not resolve the {chosen} strategy's "
            f"difference from {', '.join(unresolved)} (within 2 standard errors of zero); "
            "raise [design] validation_skies to test it"
        )
    return lines, warnings


def _few_skies(skies):
    """What a warning adds where the skies are few: a standard error from n skies is itself
    uncertain, so 2 of them are not a 95 % bound (Student's t with n - 1 degrees of freedom; on
    the deep example, "stepped" was 6.2 errors off with 4 skies and 0.8 with 16)."""
    if skies >= 10:
        return ""
    bound = float(scipy.stats.t.ppf(0.975, skies - 1)) if skies > 1 else float("inf")
    return (
        f" (from {skies} skies the error is itself uncertain: 95 % of draws lie within "
        f"{bound:.1f} of them; raise [design] validation_skies to check)"
    )


def tod_parts(sky, scan, systematics, budget, mask, *, lmax, hwp=None):
    """The TOD's residual pseudo-C_BB parts (cross with the sky, auto) of one sky, from the one
    residual job (:func:`boresight.jobs.residual.residual`). A focal plane (or the budget's
    pairs on the axis behind ``hwp``) is binned with the focal-plane prediction's cut
    (:data:`boresight.predict.focalplane.RCOND_EXPECTATION`), the reference behind the plate
    without its IP. A budget that filters or deprojects filters or deprojects the TOD
    (:attr:`boresight.design.budget.Budget.pipeline`), its reference's as its own."""
    focal = budget.focalplane if hwp is None else on_axis(budget.instrument.pair_angles_deg)
    run = RunOptions(evaluation=budget.design.evaluation)
    reference = None
    if focal is not None:
        run = dataclasses.replace(run, rcond_min=predict_fp.RCOND_EXPECTATION)
    if hwp is not None:
        reference, _ = simulate_reference(
            sky, scan, mask, lmax, run=run, focalplane=focal, hwp=dataclasses.replace(hwp, ip=0.0)
        )
    job = residual(
        sky, scan, systematics, mask, lmax, instrument=budget.instrument, run=run,
        reference=reference, focalplane=focal, hwp=hwp, filtering=budget.pipeline,
    )  # fmt: skip
    return job.cross, job.auto
