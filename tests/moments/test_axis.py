"""Crossing statistics of real scans: h_n under rotation repeats, the synthetic twin, N_phi and R,
and the fused characterisation of a schedule against the streamed one."""

import numpy as np
import pytest
from helpers import night_schedule

from boresight import engine, masks, moments, pointing
from boresight.moments import compute_moments
from boresight.scan import SyntheticScan


def test_repeat_at_180_cancels_h1_h3():
    stats = moments.characterise(pointing.pointing(night_schedule(rate=4).repeated([0, 180])), 64)
    obs = stats.observed
    assert obs.sum() > 300
    assert np.abs(stats.h[1, obs]).max() < 1e-13 and np.abs(stats.h[3, obs]).max() < 1e-13
    # h_2 survives a 180 deg repeat (except where rising and setting scans cross near 90 deg).
    assert np.median(np.abs(stats.h[2, obs])) > 0.5


def test_twin_reproduces_hn_power():
    stats = moments.characterise(pointing.pointing(night_schedule()), 64)
    twin = stats.synthetic_twin(seed=1)
    h, _ = engine.scan_moments(twin, 64, pixels=stats.observed)
    means = stats.survey_means()
    for n in range(1, 5):
        twin_mean = np.mean(np.abs(h[n, stats.observed]) ** 2)
        assert abs(twin_mean / means[f"mean_abs_h{n}_sq"] - 1) < 0.10, n


def test_distinct_angles_and_range():
    """Known angles in one pixel: 3 separated values, two of them closer than the tolerance."""
    nside = 8
    theta = np.full(5, 1.0)
    phi = np.full(5, 1.0)
    psi = np.radians([10.0, 10.5, 50.0, 120.0, 10.2])
    stats = moments.characterise([(theta, phi, psi)], nside, tolerance_deg=1.0)
    p = np.flatnonzero(stats.observed)[0]
    assert stats.n_distinct[p] == 3
    assert abs(np.degrees(stats.range_rad[p]) - 110.0) <= 1.0  # 10 .. 120 deg, to a bin
    assert abs(np.degrees(stats.centre_rad[p]) - 65.0) <= 1.0


def test_fused_schedule_characterisation_equals_streamed():
    sched = night_schedule(rate=4).repeated([0, 90])
    a = moments.characterise(pointing.pointing(sched), 128)
    b = moments.characterise_schedule(sched, 128)
    assert np.array_equal(a.hits, b.hits)
    assert np.max(np.abs(a.h - b.h)) < 1e-12
    # Angle bins agree except where rounding moves an angle across a bin edge (1e-16 of 1 deg).
    assert np.mean(a.n_distinct != b.n_distinct) < 1e-3


def test_binning_threads_own_balanced_pixel_ranges():
    """A southern field lies in one corner of RING's pixel indices: the uniform halves put every
    hit in one thread's range, the balanced ranges about half in each; whatever the ranges or the
    threads, every pixel's sums are the same to the bit (each pixel's samples add in order)."""
    import numba

    from boresight.moments.axis import Accumulator, _bin, pixel_ranges

    sched = night_schedule(rate=4)
    pix, c, s, b = [], [], [], []
    for args in pointing.ces_chunks(sched):
        p, cc, ss, bb = moments.axis.ces_hits(*args[2], 64, 360, False)
        pix.append(p), c.append(cc), s.append(ss), b.append(bb)
    pix, c, s, b = (np.concatenate(x) for x in (pix, c, s, b))
    npix = 12 * 64**2
    uniform = np.array([0, npix // 2, npix])
    halves = [np.sum((pix >= lo) & (pix < hi)) for lo, hi in zip(uniform[:-1], uniform[1:])]
    assert min(halves) == 0  # the field is in one half
    bounds = pixel_ranges(pix, npix, 2)
    shares = [np.sum((pix >= lo) & (pix < hi)) for lo, hi in zip(bounds[:-1], bounds[1:])]
    assert abs(shares[0] - shares[1]) < 0.05 * pix.size
    assert np.array_equal(pixel_ranges(pix, npix, 1), [0, npix])
    results = []
    for ranges in (uniform, bounds, pixel_ranges(pix, npix, 7)):
        acc = Accumulator(64, 1.0)
        _bin(pix, c, s, b, acc.sums, acc.hits, acc.occupancy, ranges)
        results.append(acc)
    for other in results[1:]:
        assert np.array_equal(other.sums, results[0].sums)
        assert np.array_equal(other.hits, results[0].hits)
        assert np.array_equal(other.occupancy, results[0].occupancy)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        single = moments.characterise_schedule(sched, 64)
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(single.h, moments.characterise_schedule(sched, 64).h)


def test_a_jobs_crossings_are_int32_on_the_observed_pixels_only():
    """compute_moments keeps the crossings in int32, equal to the engine's on the pixels asked
    for and zero elsewhere."""
    nside = 16
    mask = masks.survey_mask("deep", nside) > 0
    scan = SyntheticScan(n_phi=3, range_rad=1.0, seed=2, rotations_deg=(0.0, 70.0))
    mom = compute_moments(scan, nside, mask)
    _, whole = engine.scan_moments(scan.one_repeat(), nside, 4)
    assert mom.crossings.dtype == np.int32
    np.testing.assert_array_equal(mom.crossings, np.where(mask, whole, 0))
    assert whole[~mask].any()  # the scan crosses pixels outside the mask, which are left out


def test_rotated_power_is_that_of_the_rotated_scan():
    """Moments.rotated_power (one repeat's <|h_n|^2> times |<e^{i n alpha}>|^2) against the h_n
    of the whole rotated scan, moments made of all its repeats (in complex128; the job keeps them
    in complex64, 6e-8 per value, so 1e-7)."""
    nside = 16
    pixels = np.flatnonzero(masks.survey_mask("wide", nside))
    for angles in ((0.0, 70.0), (0.0, 45.0, 160.0)):
        scan = SyntheticScan(n_phi=3, range_rad=1.0, seed=2, rotations_deg=angles)
        mom = compute_moments(scan, nside, pixels, n_max=4)
        whole, _ = engine.scan_moments(scan, nside, 4, pixels=pixels)
        assert mom.h.dtype == np.complex64
        for n in range(1, 5):
            want = np.mean(np.abs(whole[n, pixels]) ** 2)
            assert mom.rotated_power(n) == pytest.approx(want, rel=1e-7), (angles, n)
