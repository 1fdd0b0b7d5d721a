"""``boresight design``: the boresight angle of each unit of a schedule (a CES, a day, a pass)
chosen against a systematics budget, with the baseline strategies and a TOD check."""

from __future__ import annotations

import argparse
import dataclasses
import logging
from typing import TYPE_CHECKING, NamedTuple

import healpy as hp
import numpy as np
import scipy.stats
from tqdm import tqdm

from .. import engine, spectra
from .._util import interrupts, io, precompile, provenance
from ..config import RunOptions, check_systematics
from ..cosmology import load_spectra
from ..design.budget import load_budget, search_instrument
from ..design.exact import exact_objective, search
from ..design.focalplane import Target, exact_delta_r, unit_sums
from ..design.focalplane import search as focalplane_search
from ..design.white import baselines, objective, unit_moments, units_of
from ..instrument.focalplane import on_axis
from ..instrument.hwp import check_sampling
from ..instrument.pairs import Systematics
from ..jobs import resources
from ..jobs.residual import residual
from ..moments.offsets import centroid_moments
from ..noise import sigma_r
from ..outputs import plots
from ..predict import R_RANGE, delta_r, expected_residual
from ..predict import focalplane as predict_fp
from ..schedule import load_schedule, schedule_format, write_schedule
from ..sky import SkyConfig, make_sky
from ..validation import ConfigError, require_finite
from . import _common

if TYPE_CHECKING:
    from ..design.white import UnitMoments
    from ..instrument.focalplane import FocalPlane
    from ..instrument.hwp import HWP
    from ..schedule import ScanMotion

log = logging.getLogger(__name__)

NAME = "design"
N_STRATEGIES = 7  #: the baselines and the optimised one
HELP = "choose the boresight angles of a schedule against a systematics budget"
#: the designed schedule's file name ending, by the input's format
SUFFIX = {"toml": ".toml", "csv": ".csv", "toast": ".txt"}


def run(
    budget_path: str,
    schedule_path: str,
    out_dir: str,
    *,
    force: bool = False,
    motion: ScanMotion | None = None,
    validate: bool = True,
    progress: bool = False,
    frame: str | None = None,
    turnarounds: str | None = None,
    focalplane: FocalPlane | None = None,
    checks: resources.Checks = resources.Checks(),
) -> dict:
    """Choose a boresight angle per unit of a schedule against a budget.

    Writes the optimised schedule in the input's format (``schedule_designed.*``), a table of
    every strategy (``strategies.csv``: predicted delta_r, delta_r / sigma(r), changes of angle
    and ``<|h_n|^2>``), the optimiser's history (``history.csv``), the angle of each unit
    (``units.csv``), the residual spectra of each strategy with the noise and r references
    (``design.png``/``.pdf``), ``|h_n|^2`` maps before and after (``hn_before_after.png``), and
    with ``validate`` a TOD simulation of the budget on the designed and the unrotated schedule
    (``validation.csv``). Ctrl-C or SIGTERM during the search keeps the best schedule found so
    far (without the figures), during the validation the finished design without it; the manifest says which, and the
    :class:`boresight._util.interrupts.Interrupted` raised after the outputs are written says what was
    kept.

    Parameters
    ----------
    budget_path, schedule_path, out_dir : str
    force : bool
    motion : boresight.schedule.ScanMotion, optional
        For a TOAST schedule.
    validate : bool
        Run the TOD simulation.
    progress : bool
    frame, turnarounds : str, optional
        Replace the schedule file's (:class:`boresight.schedule.Schedule`).
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        Replaces the budget's ``[instrument] focalplane``. The search then runs on the focal
        plane's own moments (:func:`boresight.design.focalplane.search`), and every strategy is
        evaluated on it, each pair on its own samples, with the coherent and scattered parts
        (``strategies.csv``' ``delta_r`` and ``fp_*`` columns), and validated there.
    checks : boresight.jobs.resources.Checks
        The memory and time checks to make.

    Returns
    -------
    dict
        sigma_r, the strategies' rows, the designed angles per unit and the validation's rows.
    """
    budget = load_budget(budget_path)
    if focalplane is not None and budget.hwp is not None:  # the budget's own check, for the flag
        raise ConfigError(
            f"--focalplane with budget {budget_path}'s [hwp]: a design behind a plate is of "
            "pairs on the axis, not of a focal plane yet; leave out one of them"
        )
    if focalplane is not None:
        budget = dataclasses.replace(
            budget, focalplane=focalplane, instrument=search_instrument(focalplane)
        )
        try:  # the checks the budget's own [instrument] focalplane gets
            check_systematics(
                budget.systematics, budget.instrument, (0.0,), budget.noise.fwhm_arcmin
            )
        except ValueError as err:
            raise ConfigError(
                f"--focalplane {focalplane.source} with budget {budget_path}'s [systematics]: {err}"
            ) from None
    focal = budget.focalplane
    opts = budget.design
    schedule = load_schedule(schedule_path, motion, frame=frame, turnarounds=turnarounds)
    check_sampling(budget.hwp, schedule.sample_rate_hz)
    inputs = [budget_path, schedule_path, *(focal.files if focal is not None else [])]
    io.check_output_dir(out_dir, force, inputs)
    estimate = resources.schedule_estimate(
        "design",
        schedule,
        opts.nside,
        n_pairs=budget.instrument.n_pairs if focal is None else focal.n_pairs,
        # every strategy on every sky, each with and without the systematics
        tod_runs=2 * N_STRATEGIES * opts.validation_skies if validate else 0,
        systematics=budget.systematics,
        instrument=budget.instrument,
        fwhm_arcmin=budget.noise.fwhm_arcmin,
        design_units=len(units_of(schedule.expanded(), opts.group)),
    )
    resources.require(estimate, checks)
    timer = provenance.Timer(log)
    kernels = precompile.kernels_for("design")
    if validate:
        kernels += precompile.kernels_for("validation", pointing=budget.systematics.has_pointing)
    precompile.precompile(kernels, timer=timer)
    theory = load_spectra()
    with timer("per-unit spin moments"):
        exact = opts.evaluation == "exact"
        moments = unit_moments(schedule, opts.nside, opts.group, centroids=exact)
        plate = _Plate.of(budget, schedule, moments)
    with timer("objective"):
        obj = exact_objective(
            moments,
            budget.systematics,
            theory,
            budget.noise.fwhm_arcmin,
            change_cost=opts.change_cost,
            instrument=budget.instrument,
            evaluation=opts.evaluation,
            hwp=plate.hwp,
            plate_moments=plate.moments,
        )
        white = objective(  # the paper's white-h_n approximation, reported beside
            moments, budget.systematics, theory, budget.noise.fwhm_arcmin,
            instrument=budget.instrument,
        )  # fmt: skip
    sigma = sigma_r(budget.noise, theory, np.array([R_RANGE[0], R_RANGE[1] + 1]))
    strategies = baselines(moments.n_units, opts.angles_deg, opts.seed)
    allowed = set(opts.angles_deg)
    startable = {k: v for k, v in strategies.items() if set(v) <= allowed}
    start = (
        min(startable.values(), key=lambda a: obj(a, plate.baseline))
        if startable
        else np.full(moments.n_units, opts.angles_deg[0])
    )
    log.info(
        "%d units, %d pixels; sigma(r) = %.3g",
        moments.n_units,
        moments.pixels.size,
        sigma,
    )
    if not white.terms:
        log.info(
            "the budget's systematics do not depend on the boresight angles (h_0 and white "
            "terms only): every schedule has the same predicted delta_r"
        )
    total = (opts.restarts + 1) * opts.sweeps * moments.n_units
    if focal is not None:
        total = moments.n_units * len(opts.angles_deg) + total
    bar = tqdm(total=total, desc="design search", unit="unit", disable=not progress)
    tick = bar.update if progress else None
    if focal is None:
        with timer("search"):
            found = search(
                obj, opts.angles_deg, start, steps_deg=plate.allowed,
                start_steps_deg=plate.baseline, sweeps=opts.sweeps, restarts=opts.restarts,
                seed=opts.seed, progress=tick,
            )  # fmt: skip
    else:
        found, expected = _search_focalplane(
            budget, moments, obj, schedule, strategies, startable, theory, timer, tick,
            progress=progress,
        )  # fmt: skip
    if bar.n < total:  # the search converged before its last sweep: say so, at 100 %
        bar.total = bar.n
        bar.set_postfix_str("converged", refresh=False)
    bar.close()
    strategies["optimised"] = found.angles_deg
    steps = {name: plate.baseline for name in strategies}
    steps["optimised"] = found.steps_deg
    rows, h_maps = [], {}
    for name, angles in strategies.items():
        h = moments.h(angles)
        h_maps[name] = h
        dr = obj.delta_r(angles, steps[name])
        rows.append(
            dict(
                strategy=name,
                delta_r=dr,
                delta_r_over_sigma_r=dr / sigma,
                # the paper's approximation knows no plate
                delta_r_white_approximation=np.nan if plate.hwp else white.delta_r_of(h),
                changes=obj.changes(angles, steps[name]),
                **{f"mean_abs_h{n}_sq": float(np.mean(np.abs(h[n]) ** 2)) for n in range(1, 5)},
            )
        )
    stopped = found.interrupted
    if focal is None:
        expected = {}  # an interrupted search writes its best schedule at once, without figures
        if stopped is None:
            with timer("expected residual of every strategy"):
                expected = {
                    n: _expected(budget, moments, obj, schedule, theory, plate, strategies[n],
                                 steps[n])
                    for n in tqdm(h_maps, desc="expected residual", unit="strategy",
                                  disable=not progress)
                }  # fmt: skip
    else:
        with timer("the optimised schedule on the focal plane"):
            target = _target(budget, theory, moments, obj)
            expected["optimised"] = exact_delta_r(
                moments, schedule, focal, found.angles_deg, target=target
            )[1]
        for row, name in zip(rows, strategies):
            row.update(_focalplane_columns(expected[name], obj.template, sigma, row))
        if stopped is not None:
            expected = {}
    require_finite("the strategies' delta_r", [r["delta_r"] for r in rows])
    validation, checked = [], "skipped"
    if validate and stopped is None:
        try:
            with timer("TOD simulation of every strategy"):
                validation = _validate(
                    budget, moments, obj, schedule, (strategies, steps, plate), expected,
                    progress=progress,
                )  # fmt: skip
            checked = "done"
        except interrupts.Interrupted as err:  # the search is done: keep it, without validation
            stopped, checked = err, "interrupted"
    curves = {name: e.residual for name, e in expected.items()}
    designed = moments.schedule(schedule, found.angles_deg)
    fmt = schedule_format(schedule_path)
    with io.staged_dir(out_dir, force, inputs) as stage:
        write_schedule(designed, stage / f"schedule_designed{SUFFIX[fmt]}", fmt)
        io.write_csv(stage / "strategies.csv", rows, list(rows[0]))
        fields = ["start", "sweep", "objective", "moves"] + (["round"] if focal is not None else [])
        io.write_csv(stage / "history.csv", found.history, fields)
        units = [
            dict(unit=u, first_ces=idx[0], n_ces=len(idx), angle_deg=a)
            for u, (idx, a) in enumerate(zip(moments.units, found.angles_deg))
        ]
        if found.steps_deg is not None:  # the plate's step of each unit (not in the schedule)
            for row, b in zip(units, found.steps_deg):
                row["hwp_step_deg"] = b
        io.write_csv(stage / "units.csv", units, list(units[0]))
        if validation:
            io.write_csv(stage / "validation.csv", validation, list(validation[0]))
        if curves:
            _figures(curves, white, budget, sigma, theory, moments, h_maps, stage)
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                {
                    "budget": budget_path,
                    "schedule": schedule_path,
                    "frame": schedule.frame,
                    "turnarounds": schedule.turnarounds,
                    "design": dataclasses.asdict(budget.design),
                    "focalplane": None if focal is None else focal.source,
                    "hwp": None if plate.hwp is None else dataclasses.asdict(plate.hwp),
                    "sigma_r": sigma,
                    "search_interrupted": found.interrupted is not None,
                    "validation": checked,
                },
                {"design": opts.seed},
                timer.stages,
                estimate.as_dict(),
            ),
        )
    if stopped is not None:
        stopped.kept = (
            f"the best schedule found so far is in {out_dir}"
            if found.interrupted is not None
            else f"the finished design is in {out_dir}, without its TOD validation"
        )
        raise stopped
    return dict(
        sigma_r=sigma,
        strategies=rows,
        angles_deg=found.angles_deg,
        steps_deg=found.steps_deg,
        validation=validation,
    )


def _figures(curves, white, budget, sigma, theory, moments, h_maps, stage):
    """design.png (every strategy's expected residual) and hn_before_after.png."""
    plots.design_figure(
        curves, white, budget.noise, sigma, theory=theory, path_stem=stage / "design"
    )
    # the moment of the largest angle-dependent term (h_2 where every term is h_0 or white)
    dominant = max(white.terms, key=lambda n: white.alpha[n] + white.beta[n], default=2)
    maps = [
        np.where(moments.mask > 0, np.abs(moments.full_sky(h_maps[k][dominant])) ** 2, hp.UNSEEN)
        for k in ("none", "optimised")
    ]
    names = [f"|h_{dominant}|^2, no rotation", f"|h_{dominant}|^2, optimised"]
    plots.map_figure(maps, names, stage / "hn_before_after.png", unit="")


class _Plate(NamedTuple):
    """The budget's HWP, as the design sees it: a continuous plate's unit moments of psi + 2 chi
    (where the pairs carry systematics), a stepped plate's allowed steps, and the steps of the
    baselines (the allowed steps in turn, unit by unit)."""

    hwp: HWP | None = None
    moments: UnitMoments | None = None
    allowed: tuple | None = None
    baseline: np.ndarray | None = None

    @classmethod
    def of(cls, budget, schedule, moments):
        hwp = budget.hwp
        if hwp is None:
            return cls()
        if hwp.stepped:
            turn = np.asarray(hwp.angles_deg)[np.arange(moments.n_units) % len(hwp.angles_deg)]
            return cls(hwp, allowed=hwp.angles_deg, baseline=turn)
        opts = budget.design
        spun = None
        if budget.systematics.has_amplitude:
            spun = unit_moments(schedule, opts.nside, opts.group, hwp=hwp)
        return cls(hwp, spun)

    def pairs_h(self, moments, angles, steps):
        """The h_n of the pairs' reflected angle (their own without a plate)."""
        if self.hwp is None:
            return moments.h(angles)
        if self.hwp.stepped:
            return moments.h(np.asarray(angles) + 2 * np.asarray(steps))
        return (self.moments or moments).h(angles)  # no pair terms where there are none

    def seen(self, moments, steps):
        """The HWP the TOD sees on an assignment (a stepped plate at its units' steps)."""
        if self.hwp is None or self.hwp.spinning:
            return self.hwp
        return moments.stepped_plate(self.hwp, steps)


def _expected(budget, moments, obj, schedule, theory, plate, angles, steps):
    """The exact expected residual of an assignment's observed-pixel h_n (:func:`boresight.
    predict.expected_residual`) at the objective's band limits, the hits spread as the
    schedule's and read as the design's ``evaluation``; read exactly, with the samples' offsets
    from their pixel centres (:func:`boresight.moments.centroid_moments`). Behind the budget's
    HWP, of the pairs' reflected h_n and the crossing angles' own (``plate``)."""
    exact = budget.design.evaluation == "exact"
    offsets = centroid_moments(moments.schedule(schedule, angles), moments.nside) if exact else None
    return expected_residual(
        moments.full_sky(plate.pairs_h(moments, angles, steps)),
        moments.mask,
        budget.systematics,
        theory,
        budget.noise.fwhm_arcmin,
        lmax=obj.lmax,
        band=obj.band,
        instrument=budget.instrument,
        hits=moments.full_sky(moments.hits),
        evaluation=budget.design.evaluation,
        offsets=offsets,
        hwp=plate.hwp,
        plate_h=moments.full_sky(moments.h(angles)),
    )


def _search_focalplane(
    budget, moments, obj, schedule, strategies, startable, theory, timer, tick, *, progress
):
    """The search on the focal plane (:func:`boresight.design.focalplane.search`) from the best
    baseline there; every baseline's exact expectation on the mask they share."""
    opts, focal = budget.design, budget.focalplane
    with timer("every baseline on the focal plane"):
        expected = _on_focalplane(budget, moments, obj, schedule, strategies, theory, progress)
    exact = {n: delta_r(e.residual, obj.template) for n, e in expected.items()}
    start = (
        strategies[min(startable, key=lambda n: exact[n] + opts.change_cost * obj.changes(
            strategies[n]))]
        if startable
        else np.full(moments.n_units, opts.angles_deg[0])
    )  # fmt: skip
    with timer("per-unit, per-angle moments of every pair"):
        sums = unit_sums(moments, schedule, focal, opts.angles_deg, progress=tick)
    with timer("search"):
        found = focalplane_search(
            sums, moments, schedule, _target(budget, theory, moments, obj), start,
            change_cost=opts.change_cost, sweeps=opts.sweeps, restarts=opts.restarts,
            seed=opts.seed, progress=tick,
        )  # fmt: skip
    return found, expected


def _target(budget, theory, moments, obj):
    """The focal-plane search's :class:`boresight.design.focalplane.Target`."""
    return Target(
        budget.systematics, theory, budget.noise.fwhm_arcmin, moments.mask, obj.template,
        obj.lmax, budget.design.evaluation,
    )  # fmt: skip


def _on_focalplane(budget, moments, obj, schedule, strategies, theory, progress):
    """Each strategy's exact expected residual on the focal plane, every pair on its own samples
    (:func:`boresight.design.focalplane.exact_delta_r`), on the boresight's footprint."""
    target = _target(budget, theory, moments, obj)
    expected = {}
    for name, angles in tqdm(
        strategies.items(), desc="baselines on the focal plane", unit="strategy",
        disable=not progress,
    ):  # fmt: skip
        interrupts.check()
        _, expected[name] = exact_delta_r(
            moments, schedule, budget.focalplane, angles, target=target
        )
    return expected


def _focalplane_columns(expected, template, sigma, row):
    """strategies.csv's focal-plane columns: delta_r becomes the focal plane's, the on-axis
    objective's is kept as delta_r_on_axis."""
    total = delta_r(expected.residual, template)
    return dict(
        delta_r=total,
        delta_r_over_sigma_r=total / sigma,
        delta_r_on_axis=row["delta_r"],
        fp_delta_r_coherent=delta_r(expected.coherent.residual, template),
        fp_delta_r_scattered=delta_r(expected.scattered, template),
    )


def _validate(budget, moments, obj, schedule, assignments, expected, *, progress=False):
    """Every strategy's predicted delta_r against the mean of TOD simulations of it.

    The simulation runs the budget's systematics through the TOD engine on the schedule's own
    samples, read as the design's ``evaluation``, at the design's Nside with lmax = 2 Nside, on
    ``validation_skies`` sky realisations
    (and, for {mean, rms} parameters, as many draws of the focal plane, seeded alike); with a
    focal plane, every pair on its own samples (:func:`boresight.engine.simulate_focalplane`).
    Like is compared with like: the total residual C_BB(sys) - C_BB(no sys) with the predicted
    total, the leaked power <dB, dB> with the predicted leaked power (``expected``, per
    strategy); each mean with its standard error. ``assignments``: the strategies' angles and
    steps, and the budget's :class:`_Plate`, behind which the pairs on the axis are simulated
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
            cross, auto = _tod_parts(sky, scan, systematics, budget, moments.mask, lmax, seen)
            total.append(delta_r(cross + auto, obj.template))
            leaked.append(delta_r(auto, obj.template))
            bar.update()
        per_sky[name] = np.array(total)
        row = dict(strategy=name, skies=skies)
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
    best = next(row for row in out if row["strategy"] == "optimised")
    for row in out:
        mean, se = _mean_se(per_sky[row["strategy"]] - per_sky[best["strategy"]])
        row["predicted_minus_optimised"] = row["predicted_delta_r"] - best["predicted_delta_r"]
        row["simulated_minus_optimised"] = mean
        row["simulated_minus_optimised_se"] = se
        row["difference_resolved"] = bool(abs(mean) > 2 * se) if se > 0 else False
    return out


def _mean_se(values):
    """The mean of a few skies' values and its standard error (NaN from one sky)."""
    values = np.asarray(values, dtype=float)
    se = float(np.std(values, ddof=1) / np.sqrt(values.size)) if values.size > 1 else float("nan")
    return float(np.mean(values)), se


def validation_report(rows: list[dict]) -> tuple[list[str], list[str]]:
    """The TOD check as lines to print, and its warnings.

    Per strategy: the predicted and simulated total delta_r, the simulation's standard error and
    how many of them it lies from the prediction; whether the skies resolve its difference from
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
    lines = [
        f"TOD check ({rows[0]['skies']} skies per strategy; total delta_r):",
        f"  {'strategy':<14} {'predicted':>10} {'simulated':>10} {'+-':>9} {'off by':>8}  "
        "vs optimised",
    ]
    warnings, unresolved = [], []
    for row in rows:
        predicted, mean = row["predicted_delta_r"], row["simulated_delta_r"]
        se = row["simulated_delta_r_se"]
        pull = (mean - predicted) / se if se > 0 else float("nan")
        if row["strategy"] == "optimised":
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
            f"the TOD check's {rows[0]['skies']} skies do not resolve the optimised strategy's "
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


def _tod_parts(sky, scan, systematics, budget, mask, lmax, hwp=None):
    """The TOD's residual pseudo-C_BB parts (cross with the sky, auto) of one sky, behind
    ``hwp`` (the reference behind it without its IP)."""
    evaluation = budget.design.evaluation
    focal = budget.focalplane
    if hwp is not None:
        focal = on_axis(budget.instrument.pair_angles_deg)
    elif focal is None:
        job = residual(
            sky, scan, systematics, mask, lmax, instrument=budget.instrument,
            run=RunOptions(evaluation=evaluation),
        )  # fmt: skip
        return job.total - job.auto, job.auto
    plates = (None, None) if hwp is None else (dataclasses.replace(hwp, ip=0.0), hwp)
    maps = [
        engine.simulate_focalplane(
            sky,
            scan,
            focal,
            s,
            evaluation=evaluation,
            rcond_min=predict_fp.RCOND_EXPECTATION,
            hwp=p,
        )  # fmt: skip
        for s, p in zip((Systematics(), systematics), plates)
    ]
    ref, sys = (np.array([np.where(m.valid, m.q, 0.0), np.where(m.valid, m.u, 0.0)]) for m in maps)
    return spectra.residual_bb_parts(sys, ref, mask, lmax)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("budget", help="TOML with [systematics], [noise] and [design] tables")
    parser.add_argument("schedule", help="schedule file (TOML, CSV or TOAST)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--force", action="store_true", help="replace an earlier output")
    parser.add_argument(
        "--no-validate",
        action="store_true",
        help="skip the TOD simulation of the design",
    )
    _common.focalplane_flag(parser, "; replaces the budget's [instrument] focalplane")
    _common.motion_flags(parser)
    _common.pointing_flags(parser)


def main(args: argparse.Namespace) -> int:
    result = run(
        args.budget,
        args.schedule,
        args.out,
        force=args.force,
        motion=_common.motion(args),
        validate=not args.no_validate,
        progress=_common.progress(args),
        focalplane=_common.focalplane(args),
        checks=_common.checks(args),
        **_common.pointing(args),
    )
    for row in result["strategies"]:
        log.info(
            "%-14s delta_r = %.3g  (%.3g sigma(r))",
            row["strategy"],
            row["delta_r"],
            row["delta_r_over_sigma_r"],
        )
    if result["validation"]:
        lines, warnings = validation_report(result["validation"])
        for line in lines:
            log.info("%s", line)
        for warning in warnings:
            log.warning("%s", warning)
    return 0
