"""``boresight design``: the boresight angle of each unit of a schedule (a CES, a day, a pass)
chosen against a systematics budget, with the baseline strategies and a TOD check.

It writes the optimised schedule in the input's format (``schedule_designed.*``), a table of
every strategy (``strategies.csv``: predicted delta_r, delta_r / sigma(r), changes of angle and
``<|h_n|^2>``), the optimiser's history (``history.csv``), the angle of each unit
(``units.csv``), the residual spectra of each strategy with the noise and r references
(``design.png``/``.pdf``), ``|h_n|^2`` maps before and after (``hn_before_after.png``), and with
the TOD check a simulation of the budget on the designed and the unrotated schedule
(``validation.csv``). With the budget's ``[operations]``, ``strategies.csv`` adds each
strategy's lost observing time, sigma(r) with it and the total, ``operations.csv`` lists the
operations before each CES of the design and the minutes it loses, and the designed schedule's
CESs start later by what the operations eat. With ``[constraints]`` the search keeps them, each
strategy's row counts what it breaks (``violations``) and ``constraints.csv`` says what each
constraint costs. Scoring the schedule as given (no search) adds its row ("as given") beside the
baselines and writes no schedule. With ``[deprojection]`` the pipeline regresses those templates
of T from each pair difference per block: the objective leaves out the leaks of T they fit, the
TOD check deprojects, and the manifest says so. With ``[filter]`` the pipeline filters each pair
difference before binning: the objective is the filtered leak's, each unit simulated on the
table's ``skies`` (:mod:`boresight.design.filtered`), read against N_ell / F_ell^BB; the TOD check
filters, and its pulls count the objective's own error.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
from datetime import datetime, timezone
from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from .._util import io, precompile, provenance
from ..config import check_systematics
from ..cosmology import load_spectra
from ..design.budget import load_budget, search_instrument
from ..design.filtered import objective_alm, objective_runs
from ..design.job import design
from ..design.operations import shortened, timeline_rows
from ..design.tod_check import validation_report
from ..instrument.hwp import check_sampling
from ..jobs import resources
from ..moments.units import units_of
from ..outputs import plots
from ..schedule import load_schedule, schedule_format, write_schedule
from ..validation import ConfigError
from . import _common

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane
    from ..schedule import ScanMotion

log = logging.getLogger(__name__)

NAME = "design"
N_STRATEGIES = 8  #: the baselines, the schedule as given and the optimised one
HELP = "choose the boresight angles of a schedule against a systematics budget"
#: the designed schedule's file name ending, by the input's format
SUFFIX = {"toml": ".toml", "csv": ".csv", "toast": ".txt", "so-master": ".txt"}


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
    search: bool = True,
) -> dict:
    """Choose a boresight angle per unit of a schedule against a budget (the science is
    :func:`boresight.design.job.design`) and write the files the module lists. Ctrl-C or SIGTERM
    in the search keeps the best schedule found so far (without the figures), in the validation
    the finished design without it; the manifest and the
    :class:`boresight._util.interrupts.Interrupted` raised after the outputs say which.

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
    search : bool
        Search for the best angles (False: score the schedule as given).

    Returns
    -------
    dict
        sigma_r, the strategies' rows, the designed angles per unit and the validation's rows.
    """
    budget = _budget(budget_path, focalplane)
    schedule = load_schedule(schedule_path, motion, frame=frame, turnarounds=turnarounds)
    check_sampling(budget.hwp, schedule.sample_rate_hz)
    _check_given(budget, schedule, schedule_path, scored=not search)
    inputs = [budget_path, schedule_path, *getattr(budget.focalplane, "files", [])]
    io.check_output_dir(out_dir, force, inputs)
    timer = provenance.Timer(log)
    estimate = _prepare(budget, schedule, validate=validate, checks=checks, timer=timer)
    result = design(
        budget, schedule, timer=timer, validate=validate, progress=progress, search_angles=search
    )
    with io.staged_dir(out_dir, force, inputs) as stage:
        _write(result, budget, schedule, schedule_path, stage)
        io.write_json(
            stage / "manifest.json",
            _manifest(result, budget, schedule, (budget_path, schedule_path), timer, estimate),
        )
    if result.stopped is not None:
        result.stopped.kept = (
            f"the best schedule found so far is in {out_dir}"
            if result.found.interrupted is not None
            else f"the finished design is in {out_dir}, without its TOD validation"
        )
        raise result.stopped
    return dict(
        sigma_r=result.sigma_r,
        strategies=result.rows,
        angles_deg=result.found.angles_deg,
        steps_deg=result.found.steps_deg,
        validation=result.validation,
        chosen=result.chosen,
        constraint_costs=result.constraint_costs,
    )


def _prepare(budget, schedule, *, validate, checks, timer):
    """The design's estimate, held to ``checks``, and its kernels compiled; the estimate."""
    opts, focal = budget.design, budget.focalplane
    estimate = resources.schedule_estimate(
        "design",
        schedule,
        opts.nside,
        n_pairs=budget.instrument.n_pairs if focal is None else focal.n_pairs,
        # every strategy on every sky, each with and without the systematics; a filtering
        # pipeline's objective runs every unit on its own skies too
        tod_runs=(2 * N_STRATEGIES * opts.validation_skies if validate else 0)
        + objective_runs(budget),
        systematics=budget.systematics,
        instrument=budget.instrument,
        fwhm_arcmin=budget.noise.fwhm_arcmin,
        design_units=len(units_of(schedule.expanded(), opts.group)),
        **objective_alm(budget),
    )
    resources.require(estimate, checks)
    kernels = precompile.kernels_for("design")
    if validate:
        kernels += precompile.kernels_for("validation", pointing=budget.systematics.has_pointing)
    precompile.precompile(kernels, timer=timer)
    return estimate


def _manifest(result, budget, schedule, paths, timer, estimate):
    """The design's manifest: its inputs, options, sigma(r), what was interrupted, the stages."""
    focal = budget.focalplane
    return provenance.manifest(
        {
            "budget": paths[0],
            "schedule": paths[1],
            "frame": schedule.frame,
            "turnarounds": schedule.turnarounds,
            "design": dataclasses.asdict(budget.design),
            "focalplane": None if focal is None else focal.source,
            "hwp": None if budget.hwp is None else dataclasses.asdict(budget.hwp),
            "sigma_r": result.sigma_r,
            "search_interrupted": result.found.interrupted is not None,
            "searched": result.chosen == "optimised",
            "operations": None
            if budget.operations is None
            else dataclasses.asdict(budget.operations),
            "deprojection": None
            if budget.deprojection is None
            else dataclasses.asdict(budget.deprojection),
            "filter": None
            if budget.filtering is None
            else {"pipeline": str(budget.filtering), "skies": budget.filter_skies},
            "validation": result.checked,
        },
        {"design": budget.design.seed},
        timer.stages,
        estimate.as_dict(),
    )


def _check_given(budget, schedule, path, *, scored):
    """The schedule's own angles against the budget's angle rules: where it is scored as given,
    a CES that breaks one is an error naming the file, the CES and its angle; before a search,
    which gives every CES an allowed angle, a warning."""
    if budget.constraints is None:
        return
    broken = []
    for i, c in enumerate(schedule.expanded()):
        for rule in budget.constraints.angles:
            if rule.applies(c) and c.boresight_deg not in rule.angles_deg:
                when = datetime.fromtimestamp(c.start_unix, timezone.utc).strftime(
                    "%Y-%m-%d %H:%M:%S"
                )
                uid = dict(c.labels).get("uid")  # a master schedule's row
                named = f", uid {uid}" if uid else ""
                broken.append(
                    f"schedule {path}, CES {i + 1} (start {when} UTC, elevation "
                    f"{c.elevation_deg:g} deg{named}), rotation {c.boresight_deg:g} deg: outside "
                    f"the budget's {rule}"
                )
    if broken and scored:
        raise ConfigError(broken[0] + (f" (and {len(broken) - 1} more)" if len(broken) > 1 else ""))
    for line in broken[:3]:
        log.warning("%s; the design gives it an allowed angle", line)


def _budget(budget_path, focalplane):
    """The budget, its focal plane replaced by ``focalplane`` where given and checked alike."""
    budget = load_budget(budget_path)
    if focalplane is None:
        return budget
    if budget.operations is not None or budget.constraints is not None:
        raise ConfigError(
            f"--focalplane with budget {budget_path}'s [operations] or [constraints]: they bind a "
            "design of pairs on the axis, not of a focal plane yet; leave out one of them"
        )
    if budget.hwp is not None:  # the budget's own check, for the flag
        raise ConfigError(
            f"--focalplane with budget {budget_path}'s [hwp]: a design behind a plate is of "
            "pairs on the axis, not of a focal plane yet; leave out one of them"
        )
    budget = dataclasses.replace(
        budget, focalplane=focalplane, instrument=search_instrument(focalplane)
    )
    try:  # the checks the budget's own [instrument] focalplane gets
        check_systematics(budget.systematics, budget.instrument, (0.0,), budget.noise.fwhm_arcmin)
    except ValueError as err:
        raise ConfigError(
            f"--focalplane {focalplane.source} with budget {budget_path}'s [systematics]: {err}"
        ) from None
    return budget


def _write(result, budget, schedule, schedule_path, stage):
    """The design's files, but its manifest, into ``stage``."""
    moments, found = result.moments, result.found
    fmt = schedule_format(schedule_path)
    designed = moments.schedule(schedule, found.angles_deg)
    if result.time_price is not None:
        line = result.time_price.timeline(found.angles_deg)
        ops = timeline_rows(result.time_price, moments.rows, found.angles_deg)
        io.write_csv(stage / "operations.csv", ops, list(ops[0]))
        kept = shortened(designed.ces, line.lost_s)
        if len(kept) < len(designed.ces):
            log.info(
                "%d CESs lost whole to the operations before them", len(designed.ces) - len(kept)
            )
        designed = dataclasses.replace(designed, ces=kept)
    if result.chosen == "optimised":
        write_schedule(designed, stage / f"schedule_designed{SUFFIX[fmt]}", fmt)
    io.write_csv(stage / "strategies.csv", result.rows, list(result.rows[0]))
    fields = ["start", "sweep", "objective", "moves"]
    fields += ["round"] if budget.focalplane is not None else []
    io.write_csv(stage / "history.csv", found.history, fields)
    units = [
        dict(unit=u, first_ces=idx[0], n_ces=len(idx), angle_deg=a)
        for u, (idx, a) in enumerate(zip(moments.units, found.angles_deg))
    ]
    if found.steps_deg is not None:  # the plate's step of each unit (not in the schedule)
        for row, b in zip(units, found.steps_deg):
            row["hwp_step_deg"] = b
    io.write_csv(stage / "units.csv", units, list(units[0]))
    if result.validation:
        io.write_csv(stage / "validation.csv", result.validation, list(result.validation[0]))
    if result.constraint_costs:
        costs = result.constraint_costs
        io.write_csv(stage / "constraints.csv", costs, list(costs[0]))
    curves = {name: e.residual for name, e in result.expected.items()}
    if curves:
        _figures(curves, result, budget, moments, stage)


def _figures(curves, result, budget, moments, stage):
    """design.png (every strategy's expected residual) and hn_before_after.png."""
    white, h_maps, chosen = result.white, result.h_maps, result.chosen
    plots.design_figure(
        curves, white, budget.noise, result.sigma_r, theory=load_spectra(),
        path_stem=stage / "design", kept_bb=result.kept_bb,
    )  # fmt: skip
    # the moment of the largest angle-dependent term (h_2 where every term is h_0 or white)
    dominant = max(white.terms, key=lambda n: white.alpha[n] + white.beta[n], default=2)
    maps = [
        np.where(moments.mask > 0, np.abs(moments.full_sky(h_maps[k][dominant])) ** 2, hp.UNSEEN)
        for k in ("none", chosen)
    ]
    names = [f"|h_{dominant}|^2, no rotation", f"|h_{dominant}|^2, {chosen}"]
    plots.map_figure(maps, names, stage / "hn_before_after.png", unit="")


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
    parser.add_argument(
        "--no-search",
        action="store_true",
        help="score the schedule's own angles beside the baselines, without a search",
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
        search=not args.no_search,
        **_common.pointing(args),
    )
    for row in result["strategies"]:
        line = (
            f"{row['strategy']:<14} delta_r = {row['delta_r']:.3g}  "
            f"({row['delta_r_over_sigma_r']:.3g} sigma(r))"
        )
        if "delta_r_total" in row:
            line += (
                f"; loses {row['lost_min']:.0f} min ({100 * row['lost_fraction']:.1f} %), "
                f"sigma(r) {row['sigma_r_with_lost_time']:.3g}, total {row['delta_r_total']:.3g}"
            )
        log.info("%s", line)
    for row in result["constraint_costs"]:
        log.info(
            "constraint: %s costs %.3g (objective %.4g, without it %.4g)",
            row["constraint"],
            row["cost"],
            row["objective"],
            row["objective_without"],
        )
    if result["validation"]:
        lines, warnings = validation_report(result["validation"])
        for line in lines:
            log.info("%s", line)
        for warning in warnings:
            log.warning("%s", warning)
    return 0
