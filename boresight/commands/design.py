"""``boresight design``: the boresight angle of each unit of a schedule (a CES, a day, a pass)
chosen against a systematics budget, with the baseline strategies and a TOD check."""

from __future__ import annotations

import argparse
import dataclasses
import logging
from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from .. import interrupts, io, plots, precompile, provenance, resources
from ..cosmology import load_spectra
from ..design import baselines, drawn, load_budget, objective, optimise, unit_moments
from ..noise import sigma_r
from ..predict import R_RANGE, Prediction, delta_r, residual_pseudo_bb
from ..residual import residual
from ..schedule import load_schedule, schedule_format, write_schedule
from ..sky import SkyConfig, make_sky
from ..validation import require_finite
from . import _common

if TYPE_CHECKING:
    from ..schedule import ScanMotion

log = logging.getLogger(__name__)

NAME = "design"
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
    far, during the validation the finished design without it; the manifest says which, and the
    :class:`boresight.interrupts.Interrupted` raised after the outputs are written says what was
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
    checks : boresight.resources.Checks
        The memory and time checks to make.

    Returns
    -------
    dict
        sigma_r, the strategies' rows, the designed angles per unit and the validation's rows.
    """
    budget = load_budget(budget_path)
    opts = budget.design
    schedule = load_schedule(schedule_path, motion, frame=frame, turnarounds=turnarounds)
    inputs = [budget_path, schedule_path]
    io.check_output_dir(out_dir, force, inputs)
    estimate = resources.schedule_estimate(
        "design",
        schedule,
        opts.nside,
        n_pairs=budget.instrument.n_pairs,
        tod_runs=4 if validate else 0,  # the designed and the unrotated schedule, each twice
        systematics=budget.systematics,
        instrument=budget.instrument,
        fwhm_arcmin=budget.noise.fwhm_arcmin,
    )
    resources.require(estimate, checks)
    timer = provenance.Timer(log)
    kernels = precompile.kernels_for("design")
    if validate:
        kernels += precompile.kernels_for("validation", pointing=budget.systematics.has_pointing)
    precompile.precompile(kernels, timer=timer)
    theory = load_spectra()
    with timer("per-unit spin moments"):
        moments = unit_moments(schedule, opts.nside, opts.group)
    with timer("objective"):
        obj = objective(
            moments,
            budget.systematics,
            theory,
            budget.noise.fwhm_arcmin,
            change_cost=opts.change_cost,
            instrument=budget.instrument,
        )
    sigma = sigma_r(budget.noise, theory, np.array([R_RANGE[0], R_RANGE[1] + 1]))
    strategies = baselines(moments.n_units, opts.angles_deg, opts.seed)
    allowed = set(opts.angles_deg)
    startable = {k: v for k, v in strategies.items() if set(v) <= allowed}
    start = (
        min(startable.values(), key=obj)
        if startable
        else np.full(moments.n_units, opts.angles_deg[0])
    )
    log.info(
        "%d units, %d pixels; sigma(r) = %.3g",
        moments.n_units,
        moments.pixels.size,
        sigma,
    )
    if not obj.terms:
        log.info(
            "the budget's systematics do not depend on the boresight angles (h_0 and white "
            "terms only): every schedule has the same predicted delta_r"
        )
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=opts.sweeps * moments.n_units, desc="design", unit="unit")
    with timer("coordinate descent"):
        found = optimise(
            obj,
            opts.angles_deg,
            start,
            sweeps=opts.sweeps,
            seed=opts.seed,
            progress=bar.update if bar else None,
        )
    if bar:
        bar.close()
    strategies["optimised"] = found.angles_deg
    rows, h_maps = [], {}
    for name, angles in strategies.items():
        h = moments.h(angles)
        h_maps[name] = h
        dr = obj.delta_r_of(h)
        rows.append(
            dict(
                strategy=name,
                delta_r=dr,
                delta_r_over_sigma_r=dr / sigma,
                changes=obj.changes(angles),
                **{f"mean_abs_h{n}_sq": float(np.mean(np.abs(h[n]) ** 2)) for n in range(1, 5)},
            )
        )
    require_finite("the strategies' delta_r", [r["delta_r"] for r in rows])
    validation, stopped, checked = [], found.interrupted, "skipped"
    if validate and stopped is None:
        try:
            with timer("TOD simulation of the designed and unrotated schedules"):
                predicted = {row["strategy"]: row["delta_r"] for row in rows}
                validation = _validate(budget, moments, obj, schedule, strategies, predicted)
            checked = "done"
        except interrupts.Interrupted as err:  # the search is done: keep it, without validation
            stopped, checked = err, "interrupted"
    mask = moments.mask
    prediction = Prediction(theory, obj.coupling, budget.noise.fwhm_arcmin)
    curves = {
        name: residual_pseudo_bb(
            moments.full_sky(h),
            mask,
            prediction,
            budget.systematics,
            instrument=budget.instrument,
            crossings=moments.full_sky(moments.hits),
            expected=drawn(budget.systematics),
        )
        for name, h in h_maps.items()
    }
    designed = moments.schedule(schedule, found.angles_deg)
    fmt = schedule_format(schedule_path)
    with io.staged_dir(out_dir, force, inputs) as stage:
        write_schedule(designed, stage / f"schedule_designed{SUFFIX[fmt]}", fmt)
        io.write_csv(stage / "strategies.csv", rows, list(rows[0]))
        io.write_csv(stage / "history.csv", found.history, ["sweep", "objective", "moves"])
        io.write_csv(
            stage / "units.csv",
            [
                dict(unit=u, first_ces=idx[0], n_ces=len(idx), angle_deg=a)
                for u, (idx, a) in enumerate(zip(moments.units, found.angles_deg))
            ],
            ["unit", "first_ces", "n_ces", "angle_deg"],
        )
        if validation:
            io.write_csv(stage / "validation.csv", validation, list(validation[0]))
        plots.design_figure(
            curves, obj, budget.noise, sigma, theory=theory, path_stem=stage / "design"
        )
        # the moment of the largest angle-dependent term (h_2 where every term is h_0 or white)
        dominant = max(obj.terms, key=lambda n: obj.alpha[n] + obj.beta[n], default=2)
        plots.map_figure(
            [
                np.where(
                    mask > 0,
                    np.abs(moments.full_sky(h_maps[k][dominant])) ** 2,
                    hp.UNSEEN,
                )
                for k in ("none", "optimised")
            ],
            [f"|h_{dominant}|^2, no rotation", f"|h_{dominant}|^2, optimised"],
            stage / "hn_before_after.png",
            unit="",
        )
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                {
                    "budget": budget_path,
                    "schedule": schedule_path,
                    "frame": schedule.frame,
                    "turnarounds": schedule.turnarounds,
                    "design": dataclasses.asdict(budget.design),
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
        validation=validation,
    )


def _validate(budget, moments, obj, schedule, strategies, predicted):
    """Simulated against predicted delta_r of the designed and the unrotated schedule.

    The simulation runs the budget's systematics through the TOD engine on the schedule's own
    samples, at the design's Nside with lmax = 2 Nside; its delta_r is that of the leaked power
    (the prediction's quantity) and, for reference, of the whole residual with its cross term.
    A budget with {mean, rms} parameters simulates one draw of its focal plane (``seed``), which
    scatters about the predicted expectation.
    """
    nside, lmax = moments.nside, 2 * moments.nside
    sky = make_sky(SkyConfig(nside=nside, lmax=lmax, fwhm_arcmin=budget.noise.fwhm_arcmin))
    out = []
    for name in ("optimised", "none"):
        scan = moments.schedule(schedule, strategies[name])
        job = residual(
            sky,
            scan,
            budget.systematics,
            moments.mask,
            lmax,
            instrument=budget.instrument,
        )
        simulated = delta_r(job.auto, obj.template) + obj.const
        out.append(
            dict(
                strategy=name,
                predicted_delta_r=predicted[name],
                simulated_delta_r=simulated,
                simulated_delta_r_with_cross_term=delta_r(job.total, obj.template),
                ratio=simulated / predicted[name] if predicted[name] else float("nan"),
            )
        )
    return out


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
    return 0
