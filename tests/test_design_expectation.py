"""The exact design objective and its search: equal to the expectation of the written-out
schedule, the enumerated optimum against direct evaluation, the descent against the
enumeration, and the prediction against the mean of TOD skies."""

import numpy as np
import pytest

from boresight import design, predict, scanstats
from boresight.config import RunOptions
from boresight.design_expectation import exact_objective, exhaustive, search
from boresight.instrument import Instrument, Spread, Systematics
from boresight.residual import residual
from boresight.schedule import CES, Schedule, load_schedule
from boresight.sky import SkyConfig, make_sky

NSIDE, FWHM = 32, 60.0
ANGLES = (0.0, 45.0, 90.0)
BUDGET = Systematics(dg=(0.01, -0.01), rho_arcmin=3.0, chi_deg=30.0, ellipticity_b=0.05)


@pytest.fixture(scope="module")
def schedule():
    """Eight 5-minute CESs of the deep example at 2 Hz: 8 units, 3^8 assignments."""
    base = load_schedule("examples/schedule_deep_sat.toml")
    ces = tuple(CES(**{**c.__dict__, "duration_s": 300.0}) for c in base.ces[::3])
    return Schedule(ces, base.site, 2.0)


@pytest.fixture(scope="module")
def moments(schedule):
    return design.unit_moments(schedule, NSIDE, "ces")


@pytest.fixture(scope="module")
def obj(moments, theory):
    return exact_objective(moments, BUDGET, theory, FWHM)


@pytest.mark.parametrize(
    "budget, instrument, evaluation",
    [
        (BUDGET, None, "interp"),
        (BUDGET, None, "exact"),
        (Systematics(dg=Spread(0.002, 0.01), rho_arcmin=1.0), Instrument("uniform", 4), "interp"),
    ],
    ids=["numbers", "numbers, read exactly", "rms over 4 pairs"],
)
def test_the_objective_is_the_expectation_of_the_assignments_h_n(
    moments, theory, budget, instrument, evaluation
):
    """The quadratic form in the units' alm equals predict.expected_residual's delta_r of the
    assignment's own h_n maps (a transform of every weight, no unit decomposition) to rounding,
    for either reading of the sky at the samples."""
    obj = exact_objective(
        moments, budget, theory, FWHM, instrument=instrument, evaluation=evaluation
    )
    rng = np.random.default_rng(2)
    for _ in range(3):
        angles = rng.choice(ANGLES, moments.n_units)
        expected = predict.expected_residual(
            moments.full_sky(moments.h(angles)),
            moments.mask,
            budget,
            theory,
            FWHM,
            lmax=obj.lmax,
            instrument=instrument,
            hits=moments.full_sky(moments.hits),
            evaluation=evaluation,
        )
        want = predict.delta_r(expected.residual, obj.template)
        assert obj.delta_r(angles) == pytest.approx(want, rel=1e-10)


def test_the_readings_differ_where_the_values_are_read(moments, theory):
    """A gain reads T by value: bilinear interpolation smooths it more than the hits' own
    spread, so the exact reading predicts more. A pointing offset reads only the gradient,
    exactly either way: the two differ only in the cross term with the sky's own P, which is
    read by value (1e-4 of delta_r here)."""
    zero = np.zeros(moments.n_units)
    gain = Systematics(dg=(0.01, -0.01))
    interp, exact = (
        exact_objective(moments, gain, theory, FWHM, evaluation=e).delta_r(zero)
        for e in ("interp", "exact")
    )
    assert exact > 1.01 * interp
    pointing = Systematics(rho_arcmin=3.0, chi_deg=30.0)
    interp, exact = (
        exact_objective(moments, pointing, theory, FWHM, evaluation=e).delta_r(zero)
        for e in ("interp", "exact")
    )
    assert exact == pytest.approx(interp, rel=1e-3)
    with pytest.raises(ValueError, match="evaluation"):
        exact_objective(moments, gain, theory, FWHM, evaluation="nearest")


def test_the_enumeration_is_the_minimum_of_direct_evaluations(obj, moments):
    """exhaustive()'s optimum is a real assignment's direct value, and no one of 400 random
    assignments (nor a baseline of the allowed angles) evaluated directly is below it."""
    best = exhaustive(obj, ANGLES)
    assert best.value == pytest.approx(obj(best.angles_deg), rel=1e-12)
    rng = np.random.default_rng(5)
    trials = [rng.choice(ANGLES, moments.n_units) for _ in range(400)]
    trials += [
        a for a in design.baselines(moments.n_units, ANGLES).values() if set(a) <= set(ANGLES)
    ]
    assert min(obj(a) for a in trials) >= best.value - 1e-12 * abs(best.value)


def test_the_descent_finds_the_global_optimum(obj, moments):
    """Coordinate descent with one- and two-unit moves and restarts, enumeration switched off:
    within 0.5 % of the enumerated optimum for every seed, and on it for at least 5 of 6."""
    best = exhaustive(obj, ANGLES).value
    found = [
        search(obj, ANGLES, np.zeros(moments.n_units), seed=s, exhaustive_limit=0).value
        for s in range(6)
    ]
    assert all(v <= best + 0.005 * abs(best) for v in found)
    assert sum(v == pytest.approx(best, rel=1e-9) for v in found) >= 5
    values = search(obj, ANGLES, np.zeros(moments.n_units), exhaustive_limit=0).history
    for start in {h["start"] for h in values}:  # each start's passes only descend
        run = [h["objective"] for h in values if h["start"] == start]
        assert all(b <= a + 1e-12 * abs(a) for a, b in zip(run, run[1:]))


def test_change_cost_and_interrupt(moments, theory):
    """A change cost that outweighs every gain keeps the angles constant; an interrupt returns
    the best assignment so far with its direct value."""
    costly = exact_objective(moments, BUDGET, theory, FWHM, change_cost=1e3)
    found = search(costly, ANGLES, np.zeros(moments.n_units), exhaustive_limit=0)
    assert costly.changes(found.angles_deg) == 0
    assert exhaustive(costly, ANGLES).value == pytest.approx(found.value, rel=1e-12)
    obj = exact_objective(moments, BUDGET, theory, FWHM)
    calls = []

    def stop_after_five(_):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt

    found = search(
        obj, ANGLES, np.zeros(moments.n_units), progress=stop_after_five, exhaustive_limit=0
    )
    assert found.interrupted and found.value == pytest.approx(obj(found.angles_deg))


@pytest.mark.xdist_group("timing")  # not beside the signals test (its latency)
@pytest.mark.parametrize("evaluation", ["interp", "exact"])
def test_the_prediction_is_the_mean_of_tod_skies(schedule, moments, theory, evaluation):
    """The TOD engine on the schedule's own samples, 8 skies per strategy, the sky read as the
    prediction reads it: the mean total residual's delta_r equals the prediction within 5 % or
    2.5 standard errors. Read exactly, the prediction carries the samples' offsets from their
    pixel centres (scanstats.centroid_moments): at 2 Hz a pixel of Nside 32 holds a few scan
    lines, and without them the pointing's leak is predicted 0.68-0.71 of the TOD's."""
    obj = exact_objective(moments, BUDGET, theory, FWHM, evaluation=evaluation)
    run = RunOptions(evaluation=evaluation)
    for angles in (np.zeros(moments.n_units), np.where(np.arange(moments.n_units) % 2, 90.0, 0.0)):
        scan = moments.schedule(schedule, angles)
        values = []
        for seed in range(8):
            sky = make_sky(
                SkyConfig(nside=NSIDE, lmax=2 * NSIDE, fwhm_arcmin=FWHM, seed=seed), theory
            )
            job = residual(sky, scan, BUDGET, moments.mask, 2 * NSIDE, run=run)
            values.append(predict.delta_r(job.total, obj.template))
        mean, se = np.mean(values), np.std(values, ddof=1) / np.sqrt(len(values))
        predicted = obj.delta_r(angles)
        if evaluation == "exact":
            expected = predict.expected_residual(
                moments.full_sky(moments.h(angles)), moments.mask, BUDGET, theory, FWHM,
                lmax=obj.lmax, hits=moments.full_sky(moments.hits), evaluation="exact",
                offsets=scanstats.centroid_moments(scan, NSIDE),
            )  # fmt: skip
            without = predicted
            predicted = predict.delta_r(expected.residual, obj.template)
            assert predicted > 1.2 * without  # the offsets matter here
        assert abs(mean - predicted) < max(0.05 * abs(predicted), 2.5 * se), (mean, se, predicted)
