"""The design objective on a focal plane: the dense quadratic of delta_r in the units' per-angle,
per-pair moments against the exact expectation, and its search against enumeration."""

import numpy as np
import pytest
from helpers import EXAMPLES

from boresight import coupling, predict
from boresight.cosmology import load_spectra
from boresight.design.exact import exact_objective
from boresight.design.focalplane import (
    DenseForm,
    Target,
    descend,
    exact_delta_r,
    linearised,
    search,
    unit_sums,
)
from boresight.instrument import focalplane
from boresight.instrument.pairs import Instrument, Spread, Systematics
from boresight.moments import unit_moments
from boresight.moments.focalplane import characterise_focalplane
from boresight.predict import focalplane as predict_fp
from boresight.schedule import CES, Schedule, load_schedule

NSIDE, LMAX = 16, 32
ALLOWED = (0.0, 45.0, 90.0)
BUDGET = Systematics(dg=Spread(0.002, 0.01), rho_arcmin=0.5, chi_deg=20.0, seed=3)
#: a gain given as a number: with a drawn one the on-axis beams take the draw's gain
BEAMS = Systematics(
    dg=0.005, ellipticity_a=0.05, ellipticity_angle_a_deg=30.0, dfwhm_b_arcmin=3.0, seed=3
)


@pytest.fixture(scope="module")
def problem():
    """Eight 5-minute CESs of the deep example at 2 Hz (8 units), the theory, and the hexagon's
    mask: the boresight's footprint, well conditioned at 0 and 90 deg."""
    base = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    ces = tuple(CES(**{**c.__dict__, "duration_s": 300.0}) for c in base.ces[::3])
    schedule = Schedule(ces, base.site, 2.0)
    moments = unit_moments(schedule, NSIDE, "ces")
    return schedule, moments, load_spectra()


def _setup(problem, focal, budget=BUDGET):
    schedule, moments, theory = problem
    mask = moments.mask.copy()
    for a in (0.0, 90.0):
        stats = characterise_focalplane(
            moments.schedule(schedule, np.full(moments.n_units, a)), focal, NSIDE, per_pair=True
        )
        mask *= predict_fp.rcond(stats) >= predict_fp.RCOND_EXPECTATION
    template = predict.tensor_template(coupling.mask_coupling(mask, LMAX), theory, 30.0, NSIDE)
    sums = unit_sums(moments, schedule, focal, ALLOWED)
    return Target(budget, theory, 30.0, mask, template, LMAX), sums


def _exact(problem, focal, angles, target):
    schedule, moments, _ = problem
    return exact_delta_r(moments, schedule, focal, angles, target=target)[0]


@pytest.mark.parametrize("budget", [BUDGET, BEAMS], ids=["gain and pointing", "beams"])
def test_on_the_axis_the_form_is_exact_everywhere(problem, budget):
    """Pairs on the axis: hits and H_4 do not move with the angles, so the form linearised at
    0 deg equals the exact focal-plane expectation and the on-axis objective at any assignment,
    to rounding; its anchor is only the h_0 terms' in-pixel scatter (tiny; with the beams their
    G_0's, 0.4 %). The beams' terms h_n G_n each pair's own, n = -2..4."""
    schedule, moments, theory = problem
    focal = focalplane.on_axis()
    target, sums = _setup(problem, focal, budget)
    zero = np.zeros(moments.n_units)
    anchor = _exact(problem, focal, zero, target)
    form = linearised(sums, sums.choices(zero), target, exact=anchor)
    assert abs(form.const) < (1e-4 if budget is BUDGET else 1e-2) * anchor
    on_axis = exact_objective(moments, budget, theory, 30.0, instrument=Instrument(), lmax=LMAX)
    rng = np.random.default_rng(0)
    for _ in range(3):
        angles = rng.choice(ALLOWED, moments.n_units)
        exact = _exact(problem, focal, angles, target)
        assert abs(form(angles) - exact) < 1e-9 * exact
        assert abs(on_axis.delta_r(angles) - exact) < 1e-9 * exact


@pytest.mark.slow
def test_off_the_axis_the_form_is_exact_at_its_reference(problem):
    """TOAST's 7-pixel, 20 deg hexagon: the form is the exact expectation at its reference with
    an anchor that is only the in-pixel scatter. Away from it the hits and H_4 it holds fixed
    move (here a unit is all the data of the pixels it covers: one unit moved to 90 deg is off
    by 2-144 %), which is why the search judges each round by the exact value."""
    schedule, moments, theory = problem
    focal = focalplane.hexagon(7, 20.0)
    target, sums = _setup(problem, focal)
    zero = np.zeros(moments.n_units)
    anchor = _exact(problem, focal, zero, target)
    form = linearised(sums, sums.choices(zero), target, exact=anchor)
    assert form(zero) == pytest.approx(anchor, rel=1e-12)
    assert abs(form.const) < 1e-3 * anchor


def _random_form(seed, n_units=8, n_allowed=3):
    rng = np.random.default_rng(seed)
    m = n_units * n_allowed
    a = rng.normal(size=(m, 2 * m))
    gram = (a @ a.T / m).reshape(n_units, n_allowed, n_units, n_allowed)
    linear = rng.normal(size=(n_units, n_allowed)) * 3
    return DenseForm(gram, linear, 50.0, np.array(ALLOWED))


def test_descent_finds_the_enumerated_optimum():
    """8 units x 3 angles: coordinate descent with one- and two-unit moves and 4 restarts
    against every one of the 6561 assignments, on 6 random positive forms: the optimum in at
    least 5 of 6, within 0.5 % in all."""
    hits = 0
    for seed in range(6):
        form = _random_form(seed)
        best = descend(form, np.zeros(8, dtype=int), exhaustive_limit=0, seed=seed)
        optimum = descend(form, np.zeros(8, dtype=int))  # enumerates
        assert best.value >= optimum.value - 1e-9
        assert best.value <= optimum.value + 0.005 * abs(optimum.value)
        hits += np.isclose(best.value, optimum.value, rtol=1e-12)
        assert best.value == pytest.approx(form(best.angles_deg))
    assert hits >= 5


@pytest.mark.slow
def test_the_search_keeps_the_best_exact_value(problem):
    """The rounds of re-linearisation end at an assignment whose exact value is the one reported
    and no worse than the start's."""
    schedule, moments, theory = problem
    focal = focalplane.hexagon(7, 20.0)
    target, sums = _setup(problem, focal)
    zero = np.zeros(moments.n_units)
    found = search(sums, moments, schedule, target, zero, sweeps=3, restarts=1)
    exact = _exact(problem, focal, found.angles_deg, target)
    assert found.value == pytest.approx(exact, rel=1e-12)
    assert found.value <= _exact(problem, focal, zero, target)
    assert {"round"} <= set(found.history[0])
