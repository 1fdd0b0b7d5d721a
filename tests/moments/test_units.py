"""A design's units: their spin sums turned by one angle per unit are the h_n a scan of the
designed schedule measures, on the axis, behind a spinning plate and pair by pair off it."""

import dataclasses
import time

import numpy as np
import pytest
from helpers import EXAMPLES

from boresight import moments
from boresight.instrument import focalplane
from boresight.instrument.hwp import HWP
from boresight.schedule import CES, Schedule, load_schedule

NSIDE = 16
ALLOWED = (-45.0, 0.0, 30.0, 90.0)


@pytest.fixture(scope="module")
def schedule():
    """Four 3-minute CESs of the deep example at 2 Hz, observed again at +90 deg."""
    base = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    ces = tuple(CES(**{**c.__dict__, "duration_s": 180.0}) for c in base.ces[::6])
    return Schedule(ces, base.site, 2.0, repeat_boresight_deg=(0.0, 90.0))


@pytest.fixture(scope="module")
def units(schedule):
    return moments.unit_moments(schedule, NSIDE, "ces", centroids=True)


def test_units_follow_the_schedule(schedule, units):
    """Each CES and each repeat is a unit; a day's units share a UTC date; the hits are every
    sample; the designed schedule has one CES per unit at its angle."""
    assert units.n_units == 2 * len(schedule.ces)
    rows = schedule.expanded()
    for unit in moments.units_of(rows, "day"):
        assert len({time.gmtime(rows[i].start_unix)[:3] for i in unit}) == 1
    np.testing.assert_allclose(units.hits.sum(), schedule.n_samples)
    angles = np.arange(units.n_units, dtype=float)
    designed = units.schedule(schedule, angles)
    assert designed.repeat_boresight_deg == (0.0,) and len(designed.ces) == units.n_units
    for u, unit in enumerate(units.units):
        assert {designed.ces[i].boresight_deg for i in unit} == {angles[u]}
    with pytest.raises(ValueError, match="group must be one of"):
        moments.units_of(rows, "week")


def test_turned_sums_are_the_designed_schedules_h_n(schedule, units):
    """h_n of random angles per unit, from the sums at angle 0, equals h_n a new scan of the
    designed schedule measures (a different route: pointing at each angle); so do the
    centroid moments of the samples' offsets."""
    rng = np.random.default_rng(5)
    for _ in range(2):
        angles = rng.choice(ALLOWED, units.n_units)
        stats = moments.characterise_schedule(units.schedule(schedule, angles), NSIDE)
        np.testing.assert_array_equal(np.flatnonzero(stats.hits), units.pixels)
        np.testing.assert_array_equal(stats.hits[units.pixels], units.hits)
        h = units.h(angles)
        assert np.all(h[0] == 1.0)
        np.testing.assert_allclose(units.full_sky(h)[1:], stats.h[1:], atol=1e-13)
    phases = np.exp(1j * np.arange(units.centroids.shape[1])[:, None] * np.radians(angles))
    turned = np.zeros(units.centroids.shape[:2] + (units.pixels.size,), complex)
    for u in range(units.n_units):
        rows = slice(units.offsets[u], units.offsets[u + 1])
        np.add.at(turned, (slice(None), slice(None), units.index[rows]),
                  units.centroids[:, :, rows] * phases[None, :, u, None])  # fmt: skip
    direct = moments.centroid_moments(units.schedule(schedule, angles), NSIDE)
    for k in range(2):
        np.testing.assert_allclose(turned[k] / units.hits, direct[k][:, units.pixels], atol=1e-12)


def test_behind_a_spinning_plate_the_sums_are_of_the_reflected_angle(schedule):
    """With a continuous plate the sums are of psi + 2 chi: turned, they are h_{n,2n} of the
    designed schedule behind the plate (:func:`boresight.moments.hwp_moments`)."""
    plate = HWP(mode="continuous", frequency_hz=0.13)
    units = moments.unit_moments(schedule, NSIDE, "ces", hwp=plate)
    angles = np.random.default_rng(2).choice(ALLOWED, units.n_units)
    terms = tuple((n, 2 * n) for n in (1, 2, 4))
    hits, h = moments.hwp_moments(units.schedule(schedule, angles), plate, NSIDE, terms)
    turned = units.full_sky(units.h(angles))
    for n, m in terms:
        np.testing.assert_allclose(turned[n], h[(n, m)], atol=1e-12)
    with pytest.raises(ValueError, match="continuous"):
        moments.unit_moments(schedule, NSIDE, "ces", hwp=HWP(mode="stepped"))


def test_a_focal_planes_unit_sums_are_each_pairs_h_n_at_each_allowed_angle(schedule, units):
    """Off the axis the sums of unit u at allowed angle k are each pair's own hits and h_n of
    that unit's CESs scanned at that angle; an angle outside the allowed ones is refused."""
    plane = focalplane.hexagon(7, 10.0)
    allowed = (0.0, 90.0)
    sums = moments.unit_sums(units, schedule, plane, allowed)
    assert sums.unit_count == units.n_units
    u, k = 3, 1
    rows = tuple(
        dataclasses.replace(units.rows[i], boresight_deg=allowed[k]) for i in units.units[u]
    )
    one = Schedule(rows, schedule.site, schedule.sample_rate_hz)
    stats = moments.characterise_focalplane(one, plane, NSIDE, per_pair=True)
    np.testing.assert_array_equal(sums.pixels[u][k], stats.observed)
    hits = stats.observed_pair_hits
    np.testing.assert_array_equal(sums.sums[u][k][:, 0].real, hits)
    np.testing.assert_allclose(
        sums.sums[u][k][:, 1:], stats.observed_pair_h[:, 1:] * hits[:, None, :], atol=1e-9
    )
    np.testing.assert_array_equal(sums.choices(np.array([90.0, 0.0])), [1, 0])
    with pytest.raises(ValueError, match="allowed angles"):
        sums.choices(np.array([45.0]))
