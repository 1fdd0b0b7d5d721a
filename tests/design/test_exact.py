"""The exact design objective and its search: equal to the expectation of the written-out
schedule, the enumerated optimum against direct evaluation, the descent against the
enumeration, and the prediction against the mean of TOD skies."""

import dataclasses

import numpy as np
import pytest
from helpers import EXAMPLES

from boresight import design, engine, predict, spectra
from boresight import moments as scanstats
from boresight.config import RunOptions
from boresight.constants import N_MAX
from boresight.design.exact import exact_objective, exhaustive, search
from boresight.harmonics import alm2cl
from boresight.instrument.focalplane import on_axis
from boresight.instrument.hwp import HWP, mirrored, reflected_systematics
from boresight.instrument.pairs import Instrument, Spread, Systematics
from boresight.jobs.residual import residual
from boresight.moments import unit_moments
from boresight.schedule import CES, Schedule, load_schedule
from boresight.sky import SkyConfig, make_sky

NSIDE, FWHM = 32, 60.0
ANGLES = (0.0, 45.0, 90.0)
BUDGET = Systematics(dg=(0.01, -0.01), rho_arcmin=3.0, chi_deg=30.0, ellipticity_b=0.05)


@pytest.fixture(scope="module")
def schedule():
    """Eight 5-minute CESs of the deep example at 2 Hz: 8 units, 3^8 assignments."""
    base = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    ces = tuple(CES(**{**c.__dict__, "duration_s": 300.0}) for c in base.ces[::3])
    return Schedule(ces, base.site, 2.0)


@pytest.fixture(scope="module")
def moments(schedule):
    return unit_moments(schedule, NSIDE, "ces")


@pytest.fixture(scope="module")
def obj(moments, theory):
    return exact_objective(moments, BUDGET, theory, FWHM)


@pytest.mark.parametrize(
    "budget, instrument, evaluation, deprojected",
    [
        (BUDGET, None, "interp", ()),
        pytest.param(BUDGET, None, "exact", (), marks=pytest.mark.slow),
        (
            Systematics(dg=Spread(0.002, 0.01), rho_arcmin=1.0),
            Instrument("uniform", 4),
            "interp",
            (),
        ),
        (BUDGET, None, "interp", ("gain",)),
    ],
    ids=["numbers", "numbers, read exactly", "rms over 4 pairs", "gain deprojected"],
)
def test_the_objective_is_the_expectation_of_the_assignments_h_n(
    moments, theory, budget, instrument, evaluation, deprojected
):
    """The quadratic form in the units' alm equals predict.expected_residual's delta_r of the
    assignment's own h_n maps (a transform of every weight, no unit decomposition) to rounding,
    for either reading of the sky at the samples, and for a pipeline that deprojects."""
    obj = exact_objective(
        moments,
        budget,
        theory,
        FWHM,
        instrument=instrument,
        evaluation=evaluation,
        deprojected=deprojected,
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
            deprojected=deprojected,
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


@pytest.mark.slow
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


@pytest.mark.slow
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
@pytest.mark.slow
def test_the_prediction_is_the_mean_of_tod_skies(schedule, centred, theory, evaluation):
    """The TOD engine on the schedule's own samples, 8 skies per strategy, the sky read as the
    objective reads it: the mean total residual's delta_r equals the objective within 5 % or
    2.5 standard errors. Read exactly, the objective carries the samples' offsets from their
    pixel centres (the units' centroid sums): at 2 Hz a pixel of Nside 32 holds a few scan
    lines, and without them the pointing's leak is predicted 0.68-0.71 of the TOD's."""
    obj = exact_objective(centred, BUDGET, theory, FWHM, evaluation=evaluation)
    bare = dataclasses.replace(centred, centroids=None)
    without = exact_objective(bare, BUDGET, theory, FWHM, evaluation=evaluation)
    run = RunOptions(evaluation=evaluation)
    for angles in (np.zeros(centred.n_units), np.where(np.arange(centred.n_units) % 2, 90.0, 0.0)):
        scan = centred.schedule(schedule, angles)
        values = []
        for seed in range(8):
            sky = make_sky(
                SkyConfig(nside=NSIDE, lmax=2 * NSIDE, fwhm_arcmin=FWHM, seed=seed), theory
            )
            job = residual(sky, scan, BUDGET, centred.mask, 2 * NSIDE, run=run)
            values.append(predict.delta_r(job.total, obj.template))
        mean, se = np.mean(values), np.std(values, ddof=1) / np.sqrt(len(values))
        predicted = obj.delta_r(angles)
        if evaluation == "exact":
            assert predicted > 1.2 * without.delta_r(angles)  # the offsets matter here
        else:  # read by interpolation, the offsets are not taken
            assert predicted == without.delta_r(angles)
        assert abs(mean - predicted) < max(0.05 * abs(predicted), 2.5 * se), (mean, se, predicted)


#: what pairs carry through a HWP: a gain mismatch and a polarisation-angle error
THROUGH = Systematics(dg=(0.01, -0.01), pol_angle_deg=0.5)
STEPS = (0.0, 22.5, 45.0, 67.5)
#: a continuous plate that the 2 Hz samples do not alias (4 f / rate = 0.6)
SPINNING = HWP("continuous", frequency_hz=0.3)


@pytest.fixture(scope="module")
def spinning_moments(schedule):
    return unit_moments(schedule, NSIDE, "ces", hwp=SPINNING)


def test_behind_a_plate_the_objective_is_the_expectation_of_the_reflected_h_n(
    moments, spinning_moments, theory
):
    """Behind a stepped plate the pairs' gain and angle errors reach the maps as bare pairs' at
    their reflected angles do, and the plate's IP through the crossing angles' own h_2: the
    objective at boresight angles a and steps b equals predict.expected_residual of the h_n at
    a + 2 b and of the IP's h_2 at a (a transform of every weight, no unit decomposition), to
    rounding; behind a continuous plate, of the h_n of psi + 2 chi at a. The steps matter (a
    change of one unit's step changes the objective)."""
    rng = np.random.default_rng(4)
    angles, steps = rng.choice(ANGLES, moments.n_units), rng.choice(STEPS, moments.n_units)
    stepped = HWP("stepped", ip=1e-3, ip_phase_deg=30.0, angle_offset_deg=0.2)
    cases = [
        (stepped, None, moments.h(angles + 2 * steps)),
        (dataclasses.replace(SPINNING, ip=1e-3), spinning_moments, spinning_moments.h(angles)),
    ]
    for plate, own, h in cases:
        obj = exact_objective(moments, THROUGH, theory, FWHM, hwp=plate, plate_moments=own)
        expected = predict.expected_residual(
            moments.full_sky(h), moments.mask, THROUGH, theory, FWHM, lmax=obj.lmax,
            hits=moments.full_sky(moments.hits), hwp=plate,
            plate_h=moments.full_sky(moments.h(angles)),
        )  # fmt: skip
        want = predict.delta_r(expected.residual, obj.template)
        given = steps if plate.mode == "stepped" else None
        assert obj.delta_r(angles, given) == pytest.approx(want, rel=1e-10)
    # the pairs' terms as bare pairs at their reflected angles carry them
    bare = predict.expected_residual(
        moments.full_sky(moments.h(angles + 2 * steps)), moments.mask,
        reflected_systematics(stepped, THROUGH), theory, FWHM, lmax=obj.lmax,
        instrument=mirrored(Instrument()), hits=moments.full_sky(moments.hits),
    )  # fmt: skip
    obj = exact_objective(moments, THROUGH, theory, FWHM, hwp=dataclasses.replace(stepped, ip=0))
    want = predict.delta_r(bare.residual, obj.template)
    assert obj.delta_r(angles, steps) == pytest.approx(want, rel=1e-10)
    moved = steps.copy()
    moved[0] = (moved[0] + 22.5) % 90.0
    assert abs(obj.delta_r(angles, moved) / obj.delta_r(angles, steps) - 1) > 1e-3
    with pytest.raises(ValueError, match="plate_moments"):
        exact_objective(moments, THROUGH, theory, FWHM, hwp=SPINNING)
    with pytest.raises(ValueError, match="jitter"):
        exact_objective(moments, THROUGH, theory, FWHM, hwp=HWP("stepped", angle_jitter_deg=0.1))


@pytest.mark.slow
def test_a_plates_ip_is_designed_by_the_boresight_and_the_pairs_by_the_steps(moments, theory):
    """With the plate's IP alone the steps do not matter and the search's optimum is the
    boresight's alone; with the pairs' gain alone the objective depends on a + 2 b only. With
    both, the enumerated optimum over (angle, step) is below either's best of the other
    variable held fixed, and no one of 300 random assignments is below it."""
    ip = HWP("stepped", ip=1e-3, ip_phase_deg=30.0)
    only_ip = exact_objective(moments, Systematics(), theory, FWHM, hwp=ip)
    rng = np.random.default_rng(6)
    angles, steps = rng.choice(ANGLES, moments.n_units), rng.choice(STEPS, moments.n_units)
    assert only_ip.delta_r(angles, steps) == pytest.approx(
        only_ip.delta_r(angles, np.zeros(moments.n_units)), rel=1e-12
    )
    gain = exact_objective(moments, Systematics(dg=(0.01, -0.01)), theory, FWHM, hwp=HWP("stepped"))
    shifted = angles + 2 * steps
    assert gain.delta_r(angles, steps) == pytest.approx(
        gain.delta_r(shifted, np.zeros(moments.n_units)), rel=1e-10
    )
    both = exact_objective(moments, Systematics(dg=(0.01, -0.01)), theory, FWHM, hwp=ip)
    allowed, allowed_steps = (0.0, 90.0), (0.0, 22.5)  # 4^8 options
    best = exhaustive(both, allowed, steps_deg=allowed_steps)
    assert best.value == pytest.approx(both(best.angles_deg, best.steps_deg), rel=1e-12)
    fixed_steps = exhaustive(both, allowed).value  # steps all 0
    assert best.value < fixed_steps
    trials = [
        (rng.choice(allowed, moments.n_units), rng.choice(allowed_steps, moments.n_units))
        for _ in range(300)
    ]
    assert min(both(a, b) for a, b in trials) >= best.value - 1e-12 * abs(best.value)
    found = search(
        both, allowed, np.zeros(moments.n_units), steps_deg=allowed_steps, exhaustive_limit=0
    )
    assert found.value <= best.value + 0.005 * abs(best.value)
    assert found.value == pytest.approx(both(found.angles_deg, found.steps_deg), rel=1e-12)


def _total_bb(ref, tod, footprint, lmax):
    """pseudo-C_BB(P + dP) - pseudo-C_BB(P) of two focal-plane maps."""
    b = [
        footprint.alm(np.array([m.q[footprint.pixels], m.u[footprint.pixels]]), lmax, 2)[1]
        for m in (ref, tod)
    ]
    return alm2cl(b[1]) - alm2cl(b[0])


@pytest.mark.parametrize("mode", ["stepped", "continuous"])
def test_behind_a_plate_the_prediction_is_the_mean_of_tod_skies(
    schedule, moments, spinning_moments, theory, mode
):
    """The focal-plane engine behind the plate, with its IP (5e-3 at a 30 deg phase) and the
    pairs' gain mismatch, 16 skies per strategy: the mean total residual's delta_r equals the
    objective within 5 % or 2.5 standard errors, for no rotation and for 0/90 on alternate
    units (with the steps in turn behind a stepped plate); without its IP term the objective
    would be more than 2.5 standard errors off (the IP is half or more of the residual)."""
    gain = Systematics(dg=(0.005, -0.005))
    plate = dataclasses.replace(SPINNING if mode == "continuous" else HWP("stepped"), ip=5e-3,
                                ip_phase_deg=30.0)  # fmt: skip
    own = spinning_moments if mode == "continuous" else None
    obj = exact_objective(moments, gain, theory, FWHM, hwp=plate, plate_moments=own)
    ideal = dataclasses.replace(plate, ip=0.0)
    without = exact_objective(moments, gain, theory, FWHM, hwp=ideal, plate_moments=own)
    units = np.arange(moments.n_units)
    footprint = spectra.as_footprint(moments.mask)
    pairs = on_axis()
    for angles in (np.zeros(moments.n_units), np.where(units % 2, 90.0, 0.0)):
        steps = np.asarray(STEPS)[units % len(STEPS)] if mode == "stepped" else None
        scan = moments.schedule(schedule, angles)
        seen = plate if steps is None else moments.stepped_plate(plate, steps)
        values = []
        for seed in range(16):
            sky = make_sky(
                SkyConfig(nside=NSIDE, lmax=2 * NSIDE, fwhm_arcmin=FWHM, seed=seed), theory
            )
            ref = engine.simulate_focalplane(sky, scan, pairs, hwp=dataclasses.replace(seen, ip=0))
            tod = engine.simulate_focalplane(sky, scan, pairs, gain, hwp=seen)
            values.append(predict.delta_r(_total_bb(ref, tod, footprint, obj.lmax), obj.template))
        mean, se = np.mean(values), np.std(values, ddof=1) / np.sqrt(len(values))
        predicted = obj.delta_r(angles, steps)
        assert abs(mean - predicted) < max(0.05 * abs(predicted), 2.5 * se), (mean, se, predicted)
        assert abs(mean - without.delta_r(angles, steps)) > 2.5 * se


@pytest.fixture(scope="module")
def centred(schedule):
    return unit_moments(schedule, NSIDE, "ces", centroids=True)


@pytest.mark.slow
def test_read_exactly_the_objective_carries_the_samples_offsets(schedule, centred, theory):
    """With the units' sums of the samples' offsets from their pixel centres, the objective read
    exactly equals predict.expected_residual with the assignment's own centroid moments
    (scanstats.centroid_moments of the written-out schedule) to rounding, for a budget with a
    gain, a pointing offset, a beam ellipticity (whose terms reach h_-n) and an angle error;
    the units' sums add up to the schedule's moments times the hits."""
    budget = Systematics(
        dg=(0.01, -0.01), rho_arcmin=3.0, chi_deg=30.0, ellipticity_b=0.05, pol_angle_deg=0.3
    )
    obj = exact_objective(centred, budget, theory, FWHM, evaluation="exact")
    bare = exact_objective(
        dataclasses.replace(centred, centroids=None), budget, theory, FWHM, evaluation="exact"
    )
    rng = np.random.default_rng(8)
    for angles in (np.zeros(centred.n_units), rng.choice(ANGLES, centred.n_units)):
        scan = centred.schedule(schedule, angles)
        offsets = scanstats.centroid_moments(scan, NSIDE)
        expected = predict.expected_residual(
            centred.full_sky(centred.h(angles)), centred.mask, budget, theory, FWHM,
            lmax=obj.lmax, hits=centred.full_sky(centred.hits), evaluation="exact",
            offsets=offsets,
        )  # fmt: skip
        want = predict.delta_r(expected.residual, obj.template)
        assert obj.delta_r(angles) == pytest.approx(want, rel=1e-9)
        assert abs(bare.delta_r(angles) / want - 1) > 0.05  # the offsets matter here
    total = np.zeros((2, N_MAX + 1, centred.pixels.size), dtype=np.complex128)
    np.add.at(total, (slice(None), slice(None), centred.index), centred.centroids)
    offsets = scanstats.centroid_moments(
        centred.schedule(schedule, np.zeros(centred.n_units)), NSIDE
    )
    np.testing.assert_allclose(total / centred.hits, offsets[:, :, centred.pixels], atol=1e-15)
