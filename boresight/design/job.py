"""The design job, as a library function: a budget and a schedule in, every strategy's predicted
delta_r, the optimised angles and the TOD check out (:func:`design`, a :class:`DesignResult`);
``boresight design`` writes its files."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from .._util import interrupts
from ..cosmology import load_spectra
from ..moments.offsets import centroid_moments
from ..noise import sigma_r
from ..predict import R_RANGE, expected_residual
from ..validation import require_finite
from .exact import exact_objective, search
from .focalplane import exact_delta_r, search_strategies, strategy_columns, target_of
from .hwp import Plate
from .tod_check import tod_check
from .white import baselines, objective, unit_moments

if TYPE_CHECKING:
    from .._util.provenance import Timer
    from ..schedule import Schedule
    from .budget import Budget

log = logging.getLogger(__name__)


@dataclass
class DesignResult:
    """What :func:`design` found.

    Parameters
    ----------
    sigma_r : float
        The survey's sigma(r) from its noise.
    strategies : dict of str to numpy.ndarray
        Each strategy's angle per unit [deg]: the baselines and ``"optimised"``.
    steps : dict of str to numpy.ndarray or None
        Each strategy's stepped plate's step per unit [deg] (None without one).
    rows : list of dict
        strategies.csv's rows: predicted delta_r, delta_r / sigma(r), changes, ``<|h_n|^2>``.
    found : boresight.design.white.Design
        The search's result: the optimised angles and steps, its history, whether interrupted.
    moments : boresight.design.white.UnitMoments
    plate : boresight.design.hwp.Plate
    white : boresight.design.white.Objective
        The paper's white-h_n approximation, reported beside.
    h_maps : dict of str to numpy.ndarray
        Each strategy's h_n on the observed pixels.
    expected : dict of str to boresight.predict.ExpectedResidual
        Each strategy's expected residual (empty when the search was interrupted).
    validation : list of dict
        The TOD check's rows (:func:`boresight.design.tod_check.tod_check`), empty when not run.
    checked : str
        The TOD check: "done", "skipped" or "interrupted".
    stopped : boresight._util.interrupts.Interrupted or None
        The interrupt that stopped the search or the TOD check.
    """

    sigma_r: float
    strategies: dict
    steps: dict
    rows: list
    found: object
    moments: object
    plate: Plate
    white: object
    h_maps: dict
    expected: dict
    validation: list
    checked: str
    stopped: object = None


def design(
    budget: Budget,
    schedule: Schedule,
    *,
    timer: Timer,
    validate: bool = True,
    progress: bool = False,
) -> DesignResult:
    """Choose a boresight angle per unit of ``schedule`` against ``budget``.

    The per-unit moments, the exact objective (:func:`boresight.design.exact.exact_objective`)
    and the paper's white-h_n approximation beside it, the baselines, the search (on a focal
    plane :func:`boresight.design.focalplane.search_strategies`), every strategy's expected
    residual and, with ``validate``, the TOD check. Ctrl-C or SIGTERM during the search keeps
    the best assignment found so far (``found.interrupted``), during the TOD check the finished
    design (``stopped``); nothing is written.

    Parameters
    ----------
    budget : boresight.design.budget.Budget
    schedule : boresight.schedule.Schedule
    timer : boresight._util.provenance.Timer
        Times each stage.
    validate : bool
        Run the TOD check.
    progress : bool
        Progress bars.

    Returns
    -------
    DesignResult
    """
    focal, opts = budget.focalplane, budget.design
    theory = load_spectra()
    with timer("per-unit spin moments"):
        exact = opts.evaluation == "exact"
        moments = unit_moments(schedule, opts.nside, opts.group, centroids=exact)
        plate = Plate.of(budget, schedule, moments)
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
        found, expected = search_strategies(
            budget, moments, obj, schedule, strategies, startable=startable, theory=theory, timer=timer, tick=tick,
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
            target = target_of(budget, theory, moments, obj)
            expected["optimised"] = exact_delta_r(
                moments, schedule, focal, found.angles_deg, target=target
            )[1]
        for row, name in zip(rows, strategies):
            row.update(strategy_columns(expected[name], obj.template, sigma, row))
        if stopped is not None:
            expected = {}
    require_finite("the strategies' delta_r", [r["delta_r"] for r in rows])
    validation, checked = [], "skipped"
    if validate and stopped is None:
        try:
            with timer("TOD simulation of every strategy"):
                validation = tod_check(
                    budget, moments, obj, schedule, (strategies, steps, plate), expected=expected,
                    progress=progress,
                )  # fmt: skip
            checked = "done"
        except interrupts.Interrupted as err:  # the search is done: keep it, without validation
            stopped, checked = err, "interrupted"
    return DesignResult(
        sigma_r=sigma,
        strategies=strategies,
        steps=steps,
        rows=rows,
        found=found,
        moments=moments,
        plate=plate,
        white=white,
        h_maps=h_maps,
        expected=expected,
        validation=validation,
        checked=checked,
        stopped=stopped,
    )


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
