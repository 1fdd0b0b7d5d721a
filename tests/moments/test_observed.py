"""Observed pixels: the slot table, the footprint estimate made before a scan is streamed, and a
focal plane's per-pair sums held on the pixels it observes, equal to the sky's to the bit."""

import dataclasses

import healpy as hp
import numpy as np
import pytest
from helpers import EXAMPLES, toast_schedule

from boresight import moments
from boresight.instrument import focalplane
from boresight.moments import observed
from boresight.schedule import load_schedule


def test_slots_number_pixels_in_the_order_they_are_first_hit():
    slots = observed.Slots(48)
    first = slots.index(np.array([[7, 3, -1], [7, 40, 3]]))
    np.testing.assert_array_equal(first, [[0, 1, -1], [0, 2, 1]])
    second = slots.index(np.array([40, 5, 5, -1, 7]))
    np.testing.assert_array_equal(second, [2, 3, 3, -1, 0])
    np.testing.assert_array_equal(slots.pixels, [7, 3, 40, 5])
    assert slots.n == 4 and slots.slot[[7, 3, 40, 5]].tolist() == [0, 1, 2, 3]
    assert np.count_nonzero(slots.slot >= 0) == 4


def test_growing_keeps_the_rows_and_adds_zeros():
    a = np.arange(12.0).reshape(2, 3, 2)
    assert observed.grow_rows(a, 3, axis=1) is a
    grown = observed.grow_rows(a, 4, axis=1)
    assert grown.shape == (2, 4, 2)  # half again as many as it had, at least as many as asked
    np.testing.assert_array_equal(grown[:, :3], a)
    assert not grown[:, 3:].any()
    assert observed.grow_rows(a, 9, axis=1).shape == (2, 9, 2)


def test_the_footprint_widens_the_edge_by_the_radius():
    """A disc of boresight pixels widened by r is the disc of radius R + r, within a pixel's
    diagonal either side (healpy's query_disc as the independent route)."""
    nside, centre = 32, hp.ang2vec(60.0, -40.0, lonlat=True)
    disc = hp.query_disc(nside, centre, np.radians(10.0))
    wide = observed.footprint_pixels(disc, nside, 5.0)
    inner = hp.query_disc(nside, centre, np.radians(15.0))
    outer = hp.query_disc(nside, centre, np.radians(15.0) + 4 * hp.max_pixrad(nside))
    assert set(inner) <= set(wide) <= set(outer)
    assert set(observed.footprint_pixels(disc, nside, 0.0)) >= set(disc)


@pytest.mark.parametrize(
    "spec, nside, centre",
    [("hexagon:37:35", 64, (0.0, 0.0)), ("hexagon:7:10", 128, (1.5, -1.0)), ("axis", 128, (0, 0))],
)
def test_the_estimate_covers_what_the_pairs_observe(spec, nside, centre):
    """Before any streaming, the estimate of a focal plane's observed pixels on the deep example
    is at least what its pairs then observe and at most 1.35 times it (the memory estimate rests
    on it; measured 1.09-1.30, and 1.02-1.26 on the wide example)."""
    schedule = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    fp = dataclasses.replace(focalplane.load_focalplane(spec), rotation_centre_deg=centre)
    estimate = moments.observed_pixels(schedule, fp, nside)
    planes = moments.characterise_focalplane(schedule, fp, nside)
    seen = np.count_nonzero(planes.combined.hits)
    assert seen <= estimate <= 1.35 * seen, (seen, estimate)


def test_per_pair_maps_on_the_observed_pixels_are_the_skys(monkeypatch):
    """Each pair's hits and h_n are held on the observed pixels in RING order and put on the sky
    where asked; an estimate far too small (the rows growing chunk by chunk) and chunks of a few
    samples give every array to the bit."""
    schedule = toast_schedule()
    fp = focalplane.hexagon(7, 30.0)
    planes = moments.characterise_focalplane(schedule, fp, 32, per_pair=True)
    seen = np.flatnonzero(planes.combined.hits)
    np.testing.assert_array_equal(planes.observed, seen)
    assert planes.observed_pair_h.shape == (7, moments.N_MAX + 1, seen.size)
    np.testing.assert_array_equal(planes.pair_hits[:, seen], planes.observed_pair_hits)
    np.testing.assert_array_equal(planes.pair_h[:, :, seen], planes.observed_pair_h)
    unseen = np.setdiff1d(np.arange(planes.combined.hits.size), seen)
    assert not planes.pair_hits[:, unseen].any() and not planes.pair_h[:, :, unseen].any()
    np.testing.assert_array_equal(planes.observed_pair_hits.sum(axis=0), planes.combined.hits[seen])
    monkeypatch.setattr("boresight.moments.focalplane.observed_pixels", lambda *a: 1)
    small = moments.characterise_focalplane(schedule, fp, 32, chunk_samples=700, per_pair=True)
    for name in ("observed", "observed_pair_hits", "observed_pair_h", "sum_sq", "pair_weights"):
        np.testing.assert_array_equal(getattr(small, name), getattr(planes, name), err_msg=name)
    np.testing.assert_array_equal(small.combined.hits, planes.combined.hits)


def test_a_union_of_parts_holds_the_dense_sums_and_joined_bitmaps():
    """Parts over random pixel sets (some inside the union so far, some growing it; arrays with
    rows to spare, pixel axes 0 and 1) added to a Union equal the same parts added into the
    sky's arrays with numpy's own scatter-add and scatter-or."""
    rng = np.random.default_rng(3)
    npix, m = 300, 2
    union = observed.Union(axes=(0, 1, 0), joins=(False, False, True))
    sums, per, bits = np.zeros((npix, 3)), np.zeros((m, npix)), np.zeros(npix, dtype=np.uint64)
    first = np.sort(rng.choice(npix, 120, replace=False))
    for k in range(6):
        pixels = first[rng.random(first.size) < 0.5] if k % 2 else np.sort(
            rng.choice(npix, 80, replace=False)
        )  # fmt: skip
        spare = 5  # rows past the pixels', which must be ignored
        a = rng.normal(size=(pixels.size + spare, 3))
        b = rng.normal(size=(m, pixels.size + spare))
        c = rng.integers(0, 2**63, pixels.size + spare, dtype=np.uint64)
        union.add(pixels, a, b, c)
        np.add.at(sums, pixels, a[: pixels.size])
        np.add.at(per, (slice(None), pixels), b[:, : pixels.size])
        np.bitwise_or.at(bits, pixels, c[: pixels.size])
    held = union.pixels
    assert np.all(np.diff(held) > 0)
    n = held.size
    np.testing.assert_allclose(union.arrays[0][:n], sums[held], rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(union.arrays[1][:, :n], per[:, held], rtol=1e-15, atol=1e-15)
    np.testing.assert_array_equal(union.arrays[2][:n], bits[held])
    seen = np.zeros(npix, dtype=bool)
    seen[held] = True
    assert not np.any(sums[~seen]) and not np.any(per[:, ~seen])
