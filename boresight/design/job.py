"""The design job, as a library function: a budget and a schedule in, every strategy's predicted
delta_r, the optimised angles and the TOD check out (:func:`design`, a :class:`DesignResult`);
``boresight design`` writes its files."""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from .._util import interrupts
from ..cosmology import load_spectra
from ..moments.offsets import centroid_moments
from ..moments.units import unit_moments
from ..noise import sigma_r
from ..predict import R_RANGE, expected_residual
from ..predict.terms import TERMS, deprojected_by
from ..validation import ConfigError, require_finite
from .constraints import Feasibility
from .exact import exact_objective, search
from .filtered import filtered_objective, filtered_sigma_r
from .focalplane import exact_delta_r, search_strategies, strategy_columns, target_of
from .hwp import Plate
from .operations import TimePrice, observed, table_columns
from .tod_check import tod_check
from .white import Design, baselines, objective

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
        Each strategy's angle per unit [deg]: the baselines, the schedule's own angles ("as
        given") and, unless the search was skipped, ``"optimised"``.
    steps : dict of str to numpy.ndarray or None
        Each strategy's stepped plate's step per unit [deg] (None without one).
    rows : list of dict
        strategies.csv's rows: predicted delta_r, delta_r / sigma(r), changes, ``<|h_n|^2>``.
    found : boresight.design.white.Design
        The search's result: the optimised angles and steps, its history, whether interrupted.
    moments : boresight.moments.UnitMoments
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
    time_price : boresight.design.operations.TimePrice or None
        The budget's [operations] priced: each strategy's lost observing time.
    constraint_costs : list of dict
        constraints.csv's rows: each of the budget's constraints, the objective the search
        reaches without it and what it costs (empty without constraints or a search).
    kept_bb : numpy.ndarray, optional
        A filtering pipeline's F_ell^BB (lmax + 1,), by which its spectra are corrected.
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
    time_price: TimePrice | None = None
    constraint_costs: list = dataclasses.field(default_factory=list)
    kept_bb: np.ndarray | None = None

    @property
    def chosen(self) -> str:
        """The strategy the design gives: "optimised", or "as given" without a search."""
        return "optimised" if "optimised" in self.strategies else AS_GIVEN


#: the strategy of the schedule's own angles
AS_GIVEN = "as given"


def given_angles(moments) -> np.ndarray | None:
    """The schedule's own angle of each unit [deg] (its CESs' boresight angles, repeats in);
    None where a unit's CESs have different angles (a day holding a repeat at another angle)."""
    out = np.empty(moments.n_units)
    for u, idx in enumerate(moments.units):
        angles = {moments.rows[i].boresight_deg for i in idx}
        if len(angles) > 1:
            return None
        out[u] = angles.pop()
    return out


def design(
    budget: Budget,
    schedule: Schedule,
    *,
    timer: Timer,
    validate: bool = True,
    progress: bool = False,
    search_angles: bool = True,
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
    search_angles : bool
        Search for the best angles; False scores the schedule as given beside the baselines.

    Returns
    -------
    DesignResult
    """
    focal, opts = budget.focalplane, budget.design
    if focal is not None and not search_angles:
        raise ConfigError("--no-search scores pairs on the axis, not a focal plane yet")
    theory = load_spectra()
    with timer("per-unit spin moments"):
        exact = opts.evaluation == "exact"
        moments = unit_moments(schedule, opts.nside, opts.group, centroids=exact)
        plate = Plate.of(budget, schedule, moments)
    edges = np.array([R_RANGE[0], R_RANGE[1] + 1])  # sigma(r)'s band
    sigma = sigma_r(budget.noise, theory, edges)
    price = None
    if budget.operations is not None:
        price = TimePrice(
            moments.rows, moments.units, budget.operations, budget.noise, theory, edges
        )
    with timer("objective"):
        if budget.filtering is not None:  # each unit's filtered leak, simulated per sky
            obj = filtered_objective(
                moments, schedule, budget, theory, change_cost=opts.change_cost,
                feasibility=_feasibility(budget, moments), progress=progress,
            )  # fmt: skip
            sigma = filtered_sigma_r(budget, theory, obj)
        else:
            obj = exact_objective(
                moments, budget.systematics, theory, budget.noise.fwhm_arcmin,
                change_cost=opts.change_cost, instrument=budget.instrument,
                evaluation=opts.evaluation, hwp=plate.hwp, plate_moments=plate.moments,
                time_price=price, feasibility=_feasibility(budget, moments),
                deprojected=budget.deprojected,
            )  # fmt: skip
        white = objective(  # the paper's white-h_n approximation, reported beside
            moments, budget.systematics, theory, budget.noise.fwhm_arcmin,
            instrument=budget.instrument, deprojected=budget.deprojected,
        )  # fmt: skip
    strategies = baselines(moments.n_units, opts.angles_deg, opts.seed)
    given = given_angles(moments)
    if given is not None:
        strategies[AS_GIVEN] = given
    elif not search_angles:
        raise ConfigError(
            f"the schedule as given has no one angle per design unit (group = {opts.group!r}: a "
            "unit holds CESs at different angles); score it with group = 'ces'"
        )
    else:
        log.info("the schedule as given has no one angle per %s: no 'as given' row", opts.group)
    allowed = set(opts.angles_deg)
    feasibility = obj.feasibility
    startable = {
        k: v
        for k, v in strategies.items()
        if set(v) <= allowed and (feasibility is None or feasibility.ok(v))
    }
    if startable:
        start = min(startable.values(), key=lambda a: obj(a, plate.baseline))
    elif feasibility is not None:
        start = feasibility.greedy(opts.angles_deg)
        if not feasibility.ok(start):
            raise ConfigError(
                "the budget's [constraints] cannot all be kept: the fewest changes their angle "
                f"rules force break max_changes_per_day = "
                f"{budget.constraints.max_changes_per_day}"
            )
    else:
        start = np.full(moments.n_units, opts.angles_deg[0])
    log.info(
        "%d units, %d pixels; sigma(r) = %.3g",
        moments.n_units,
        moments.pixels.size,
        sigma,
    )
    if budget.filtering is not None:
        log.info(
            "the pipeline runs %s: the objective simulates each unit through it on %d skies",
            budget.pipeline,
            budget.filter_skies,
        )
    elif budget.deprojection:
        gone = [t for t in TERMS if t.name in deprojected_by(budget.deprojected)]
        log.info(
            "the pipeline deprojects %s: the objective leaves out %s",
            budget.deprojection,
            ", ".join(f"h_{t.n} {t.symbol}" for t in gone),
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
    if not search_angles:
        value = dataclasses.replace(obj, feasibility=None)(strategies[AS_GIVEN], plate.baseline)
        found = Design(
            strategies[AS_GIVEN], value, [dict(start=0, sweep=0, objective=value, moves=0)],
            steps_deg=None if plate.allowed is None else plate.baseline,
        )  # fmt: skip
        bar.update(total)
    elif focal is None:
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
    seen = None
    if price is not None:  # each strategy's delta_r on its CESs as observed
        seen = _Observed(budget, schedule, moments, obj, theory)
        if search_angles and focal is None and found.interrupted is None:
            with timer("the search again on the CESs as observed"):
                found = _search_observed(budget, seen, found, startable, plate, progress)
    steps = {name: plate.baseline for name in strategies}
    if search_angles:
        strategies["optimised"] = found.angles_deg
        steps["optimised"] = found.steps_deg
    rows, h_maps = [], {}
    each = tqdm(strategies.items(), total=len(strategies), desc="each strategy as observed",
                unit="strategy", disable=not (progress and price is not None))  # fmt: skip
    for name, angles in each:
        h = moments.h(angles)
        h_maps[name] = h
        dr = obj.delta_r(angles, steps[name])
        rows.append(
            dict(
                strategy=name,
                delta_r=dr,
                delta_r_over_sigma_r=dr / sigma,
                # the paper's approximation knows no plate and no filter
                delta_r_white_approximation=(
                    np.nan if plate.hwp or budget.filtering else white.delta_r_of(h)
                ),
                changes=obj.changes(angles, steps[name]),
                **{f"mean_abs_h{n}_sq": float(np.mean(np.abs(h[n]) ** 2)) for n in range(1, 5)},
            )
        )
        if price is not None:
            whole, dr = dr, seen.delta_r(angles, steps[name])
            rows[-1].update(
                delta_r=dr,
                delta_r_over_sigma_r=dr / sigma,
                delta_r_ces_whole=whole,
                **table_columns(price, angles, dr),
            )
        if feasibility is not None:
            rows[-1]["violations"] = feasibility.violations(angles)
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
    costs = []
    if feasibility is not None and search_angles and stopped is None and focal is None:
        with timer("the cost of each constraint"):
            costs = _constraint_costs(budget, moments, obj, found, start, plate, progress)
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
        time_price=price,
        constraint_costs=costs,
        kept_bb=getattr(obj, "kept_bb", None),
    )


#: the most searches again on the CESs as the previous one's design observes them
OBSERVED_ROUNDS = 3


class _Observed:
    """Each assignment's systematic delta_r on its CESs as observed, the operations before
    each cut from its start (:func:`boresight.design.operations.observed`): the units' moments
    of those CESs and their exact objective, made once per pattern of lost time."""

    def __init__(self, budget, schedule, moments, obj, theory):
        self.budget, self.schedule, self.moments, self.obj = budget, schedule, moments, obj
        self.theory, self._objectives = theory, {}

    def objective(self, angles_deg):
        """The exact objective of the CESs as ``angles_deg`` leaves them."""
        lost = self.obj.time_price.timeline(angles_deg).lost_s
        if not lost.any():
            return self.obj
        key = tuple(np.round(lost, 3))
        if key not in self._objectives:
            opts, moments = self.budget.design, self.moments
            rows = observed(moments.rows, lost, self.schedule.sample_rate_hz)
            scan = dataclasses.replace(self.schedule, ces=rows, repeat_boresight_deg=(0.0,))
            seen = unit_moments(scan, opts.nside, opts.group, centroids=opts.evaluation == "exact",
                                units=moments.units)  # fmt: skip
            self._objectives[key] = exact_objective(
                seen, self.budget.systematics, self.theory, self.budget.noise.fwhm_arcmin,
                change_cost=opts.change_cost, instrument=self.budget.instrument,
                evaluation=opts.evaluation, time_price=self.obj.time_price,
                feasibility=self.obj.feasibility, deprojected=self.budget.deprojected,
            )  # fmt: skip
        return self._objectives[key]

    def delta_r(self, angles_deg, steps_deg=None) -> float:
        return self.objective(angles_deg).delta_r(angles_deg, steps_deg)

    def total(self, angles_deg, steps_deg=None) -> float:
        """The search's objective on the CESs as observed."""
        return self.objective(angles_deg)(angles_deg, steps_deg)


def _search_observed(budget, seen, found, startable, plate, progress=False):
    """The search again, each time on the moments of the CESs as the previous design observes
    them (the objective credits each CES whole, a rotation's lost samples included), until the
    lost time repeats or :data:`OBSERVED_ROUNDS`; the design kept is the one whose objective on
    its own observed CESs is lowest, among these and the startable baselines."""
    opts = budget.design
    pool = [(found.angles_deg, found.steps_deg)]
    pool += [(a, plate.baseline) for a in startable.values()]
    pool.append((_stretch_search(seen.obj, opts, startable, found), found.steps_deg))
    last = found
    bar = tqdm(total=OBSERVED_ROUNDS, desc="search on the CESs as observed", unit="round",
               disable=not progress)  # fmt: skip
    for _ in range(OBSERVED_ROUNDS):
        bar.update()
        obj = seen.objective(last.angles_deg)
        if obj is seen.obj:  # nothing lost: the objective was exact
            break
        again = search(
            obj, opts.angles_deg, last.angles_deg, steps_deg=plate.allowed,
            start_steps_deg=last.steps_deg, sweeps=opts.sweeps, restarts=opts.restarts,
            seed=opts.seed,
        )  # fmt: skip
        pool.append((again.angles_deg, again.steps_deg))
        if seen.objective(again.angles_deg) is obj:  # the same lost time: a fixed point
            break
        last = again
    bar.close()
    totals = [seen.total(a, b) for a, b in tqdm(pool, desc="each candidate as observed",
                                                unit="design", disable=not progress)]  # fmt: skip
    k = int(np.argmin(totals))
    log.info(
        "on the CESs as observed: the search's first design %.4g, the kept one %.4g",
        totals[0],
        totals[k],
    )
    return Design(pool[k][0], totals[k], found.history, steps_deg=found.steps_deg
                  if pool[k][1] is None else pool[k][1])  # fmt: skip


def _stretch_search(obj, opts, startable, found):
    """The best assignment of one angle per stretch that rotations cannot cut
    (:meth:`boresight.design.operations.TimePrice.segments`), by coordinate descent over the
    stretches from the best startable baseline: designs that lose no time to rotations, which
    the search's one- and two-unit moves cannot reach from a design that does."""
    stretches = obj.time_price.segments()
    start = min(startable.values(), key=obj) if startable else found.angles_deg
    angles = np.array(start, dtype=float)
    for stretch in stretches:  # one angle per stretch: its first unit's
        angles[stretch] = angles[stretch[0]]
    value = obj(angles, found.steps_deg)
    for _ in range(opts.sweeps):
        moved = False
        for stretch in stretches:
            for a in opts.angles_deg:
                trial = angles.copy()
                trial[stretch] = a
                v = obj(trial, found.steps_deg)
                if v < value - 1e-12 * abs(value):
                    angles, value, moved = trial, v, True
        if not moved:
            break
    return angles


def _feasibility(budget, moments):
    """The budget's constraints bound to the units, or None; ConfigError where a unit can take
    none of the design's angles."""
    if budget.constraints is None:
        return None
    tolerance = 1.0 if budget.operations is None else budget.operations.angle_tolerance_deg
    try:
        out = Feasibility(budget.constraints, moments.rows, moments.units, tolerance)
        out.check_allowed(budget.design.angles_deg)
    except ValueError as err:
        raise ConfigError(f"[constraints]: {err}") from None
    return out


def _constraint_costs(budget, moments, obj, found, start, plate, progress=False):
    """What each constraint costs: the search rerun without it (from the same start and
    seed), its objective's rise from that one's."""
    opts, constraints = budget.design, budget.constraints
    rows = []
    names = tqdm(constraints.names, desc="each constraint's cost", unit="search",
                 disable=not progress)  # fmt: skip
    for k, name in enumerate(names):
        loose = _feasibility(
            dataclasses.replace(budget, constraints=constraints.without(k)), moments
        )
        freer = dataclasses.replace(obj, feasibility=loose)
        other = search(
            freer, opts.angles_deg, start, steps_deg=plate.allowed,
            start_steps_deg=plate.baseline, sweeps=opts.sweeps, restarts=opts.restarts,
            seed=opts.seed,
        )  # fmt: skip
        best = min(other.value, found.value)  # a search without it can do no worse
        rows.append(
            dict(
                constraint=name,
                objective=found.value,
                objective_without=best,
                cost=found.value - best,
                delta_r=obj.delta_r(found.angles_deg, found.steps_deg),
                delta_r_without=obj.delta_r(other.angles_deg, other.steps_deg)
                if other.value < found.value
                else obj.delta_r(found.angles_deg, found.steps_deg),
            )
        )
        log.info("constraint %s costs %.3g in the objective", name, found.value - best)
    return rows


def _expected(budget, moments, obj, schedule, theory, plate, angles, steps):
    """The exact expected residual of an assignment's observed-pixel h_n (:func:`boresight.
    predict.expected_residual`) at the objective's band limits, the hits spread as the
    schedule's and read as the design's ``evaluation``; read exactly, with the samples' offsets
    from their pixel centres (:func:`boresight.moments.centroid_moments`). Behind the budget's
    HWP, of the pairs' reflected h_n and the crossing angles' own (``plate``)."""
    if budget.filtering is not None:  # the skies' filtered leaks, turned
        return obj.expected(angles, steps)
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
        deprojected=budget.deprojected,
    )
