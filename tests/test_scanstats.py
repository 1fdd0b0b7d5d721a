"""Crossing statistics of real scans: h_n under rotation repeats, the synthetic twin, N_phi and R,
and the fused characterisation of a schedule against the streamed one."""

import numpy as np
import pytest
from helpers import T0

from boresight import engine, focalplane, pointing, scanstats
from boresight.schedule import CES, Schedule, Site


def _night(site=Site(), rate=10.0, n=6, el=50.0):
    ces = tuple(
        CES(
            start_unix=T0 + i * 3600,
            duration_s=1800,
            elevation_deg=el,
            az_centre_deg=140 if i < n // 2 else 220,
            az_throw_deg=30,
        )
        for i in range(n)
    )
    return Schedule(ces, site, sample_rate_hz=rate)


def test_repeat_at_180_cancels_h1_h3():
    stats = scanstats.characterise(pointing.pointing(_night(rate=4).repeated([0, 180])), 64)
    obs = stats.observed
    assert obs.sum() > 300
    assert np.abs(stats.h[1, obs]).max() < 1e-13 and np.abs(stats.h[3, obs]).max() < 1e-13
    # h_2 survives a 180 deg repeat (except where rising and setting scans cross near 90 deg).
    assert np.median(np.abs(stats.h[2, obs])) > 0.5


def test_twin_reproduces_hn_power():
    stats = scanstats.characterise(pointing.pointing(_night()), 64)
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
    stats = scanstats.characterise([(theta, phi, psi)], nside, tolerance_deg=1.0)
    p = np.flatnonzero(stats.observed)[0]
    assert stats.n_distinct[p] == 3
    assert abs(np.degrees(stats.range_rad[p]) - 110.0) <= 1.0  # 10 .. 120 deg, to a bin
    assert abs(np.degrees(stats.centre_rad[p]) - 65.0) <= 1.0


def test_fused_schedule_characterisation_equals_streamed():
    sched = _night(rate=4).repeated([0, 90])
    a = scanstats.characterise(pointing.pointing(sched), 128)
    b = scanstats.characterise_schedule(sched, 128)
    assert np.array_equal(a.hits, b.hits)
    assert np.max(np.abs(a.h - b.h)) < 1e-12
    # Angle bins agree except where rounding moves an angle across a bin edge (1e-16 of 1 deg).
    assert np.mean(a.n_distinct != b.n_distinct) < 1e-3


def _hexagon_schedule():
    from helpers import toast_schedule

    return toast_schedule()


def test_a_focal_plane_on_the_axis_is_the_boresight_scan():
    """Pairs on the axis: the combination is the boresight's h_n with n_pairs times its hits, the
    scattered weights are |h_n|^2 / n_pairs, and each pair's means are the boresight's."""
    schedule = _hexagon_schedule()
    alone = scanstats.characterise_schedule(schedule, 32)
    planes = scanstats.characterise_focalplane(schedule, focalplane.on_axis((0, 45, 90)), 32)
    np.testing.assert_array_equal(planes.combined.hits, 3 * alone.hits)
    assert np.max(np.abs(planes.combined.h - alone.h)) < 1e-13
    np.testing.assert_array_equal(planes.combined.n_distinct, alone.n_distinct)
    expected = np.abs(alone.h) ** 2 / 3
    assert np.max(np.abs(planes.scattered() - expected)) < 1e-13
    w = alone.hits.astype(float)
    for row in planes.pair_means():
        assert row["hits"] == alone.hits.sum()
        for n in range(1, 5):
            assert np.isclose(row[f"abs_h{n}_sq"], np.sum(w * np.abs(alone.h[n]) ** 2) / w.sum())


def test_focal_plane_stats_equal_binning_each_pairs_own_pointing(monkeypatch):
    """The fused kernels against the streamed route (detector_pointing, then characterise), pair
    by pair and combined; one pair per block (the memory bound) changes nothing."""
    schedule = _hexagon_schedule()
    fp = focalplane.hexagon(7, 30.0)
    planes = scanstats.characterise_focalplane(schedule, fp, 32, per_pair=True)
    chunks = [np.concatenate(x, axis=1) for x in zip(*pointing.detector_pointing(schedule, fp))]
    pairs = [scanstats.characterise([tuple(c[i] for c in chunks)], 32) for i in range(7)]
    joined = scanstats.characterise([tuple(c.ravel() for c in chunks)], 32)
    np.testing.assert_array_equal(planes.combined.hits, joined.hits)
    assert np.max(np.abs(planes.combined.h - joined.h)) < 1e-12
    sum_sq = sum(p.hits.astype(float) ** 2 * np.abs(p.h) ** 2 for p in pairs)
    np.testing.assert_allclose(planes.sum_sq, sum_sq, rtol=1e-12, atol=1e-9)
    for i, p in enumerate(pairs):
        np.testing.assert_array_equal(planes.pair_hits[i], p.hits)
        assert np.max(np.abs(planes.pair_h[i] - p.h)) < 1e-12
    monkeypatch.setattr(scanstats, "PAIR_BLOCK_BYTES", 1)
    assert len(scanstats.pair_blocks(7, 32)) == 7
    blocked = scanstats.characterise_focalplane(schedule, fp, 32)
    np.testing.assert_allclose(blocked.sum_sq, planes.sum_sq, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(blocked.pair_weights, planes.pair_weights, rtol=1e-12)


def test_rotation_cancels_h2_only_on_the_axis():
    """A 0/90 repeat of a schedule cancels h_2 exactly for the pair on the boresight; a pair
    17.5 deg off it lands elsewhere at 90 deg and keeps much of its h_2 (the issue's TOAST
    table: 0.48-0.67 of 0.87-0.99)."""
    schedule = _hexagon_schedule()
    fp = focalplane.hexagon(37, 35.0).subset([0, 19])  # on the axis, and at a vertex
    assert fp.radius_deg[1] == pytest.approx(17.5)
    fixed = scanstats.characterise_focalplane(schedule, fp, 64).pair_means()
    turned = scanstats.characterise_focalplane(schedule.repeated([0.0, 90.0]), fp, 64)
    turned = turned.pair_means()
    assert turned[0]["abs_h2_sq"] < 1e-20 < 0.5 < fixed[0]["abs_h2_sq"]
    assert turned[1]["abs_h2_sq"] > 0.3 * fixed[1]["abs_h2_sq"]


@pytest.mark.slow
def test_focal_plane_blocks_on_dask_give_the_serial_result_to_the_bit(monkeypatch):
    """Blocks of pairs as tasks on a local Dask cluster add up in block order: the same result
    as in this process, whichever worker finishes first."""
    pytest.importorskip("dask.distributed")
    schedule = _hexagon_schedule()
    fp = focalplane.hexagon(7, 30.0)
    monkeypatch.setattr(scanstats, "PAIR_BLOCK_BYTES", 3 * 12 * 32**2 * 88)  # 3 pairs a block
    assert len(scanstats.pair_blocks(7, 32)) == 3
    serial = scanstats.characterise_focalplane(schedule, fp, 32)
    dask = scanstats.characterise_focalplane(schedule, fp, 32, scheduler=None, workers=2)
    np.testing.assert_array_equal(dask.combined.hits, serial.combined.hits)
    np.testing.assert_array_equal(dask.combined.h, serial.combined.h)
    np.testing.assert_array_equal(dask.combined.n_distinct, serial.combined.n_distinct)
    np.testing.assert_array_equal(dask.sum_sq, serial.sum_sq)
    np.testing.assert_array_equal(dask.pair_weights, serial.pair_weights)


def test_centroid_moments_are_each_samples_place_in_its_pixel():
    """The offsets of the samples from their pixel centres, weighted by exp(i n psi), against
    the small-angle offsets (theta - theta_c, sin theta_c (phi - phi_c)) binned by hand: equal
    to second order in the pixel size, and no larger than a pixel."""
    import healpy as hp

    nside = 16
    schedule = _night(rate=1.0, n=2)
    got = scanstats.centroid_moments(schedule, nside, n_max=2)
    theta, phi, psi = (np.concatenate(x) for x in zip(*pointing.pointing(schedule)))
    pix = hp.ang2pix(nside, theta, phi)
    c_theta, c_phi = hp.pix2ang(nside, pix)
    wrapped = (phi - c_phi + np.pi) % (2 * np.pi) - np.pi
    delta = (theta - c_theta) + 1j * np.sin(c_theta) * wrapped
    hits = np.bincount(pix, minlength=12 * nside**2)
    seen = hits > 0
    size = hp.nside2resol(nside)
    for n in range(3):
        for k, value in enumerate((delta, np.conj(delta))):
            w = np.exp(1j * n * psi) * value
            want = np.bincount(pix, w.real, hits.size) + 1j * np.bincount(pix, w.imag, hits.size)
            want = want[seen] / hits[seen]
            np.testing.assert_allclose(got[k, n, seen], want, rtol=0, atol=size**2)
    assert np.abs(got[0, 0]).max() < size
    assert np.abs(got[0, 0]).max() > 0.05 * size  # the centroids are off the centres
    assert np.all(got[:, :, ~seen] == 0)


def test_a_focal_planes_centroid_moments_are_each_pairs_own():
    """With a focal plane, pair i's offsets are its own samples' (detector_pointing), binned by
    hand as above, weighted by the crossing angle of its h_n in characterise_focalplane; pairs on
    the axis have the boresight's, to rounding."""
    import healpy as hp

    nside, n_max = 16, 2
    schedule = _night(rate=1.0, n=2)
    hexagon = focalplane.hexagon(7, 10.0)
    got = scanstats.centroid_moments(schedule, nside, n_max=n_max, focalplane=hexagon)
    stats = scanstats.characterise_focalplane(schedule, hexagon, nside, per_pair=True)
    chunks = list(pointing.detector_pointing(schedule, hexagon))
    size = hp.nside2resol(nside)
    for i in (0, 4):  # the centre and a corner 5 deg off the axis
        theta, phi, psi = (np.concatenate([c[k][i] for c in chunks]) for k in range(3))
        pix = hp.ang2pix(nside, theta, phi)
        hits = np.bincount(pix, minlength=12 * nside**2)
        seen = hits > 0
        c_theta, c_phi = hp.pix2ang(nside, pix)
        wrapped = (phi - c_phi + np.pi) % (2 * np.pi) - np.pi
        delta = (theta - c_theta) + 1j * np.sin(c_theta) * wrapped

        def binned(w, pix=pix, hits=hits, seen=seen):
            out = np.bincount(pix, w.real, hits.size) + 1j * np.bincount(pix, w.imag, hits.size)
            return out[seen] / hits[seen]

        for n in range(n_max + 1):
            spin = np.exp(1j * n * psi)
            np.testing.assert_allclose(binned(spin), stats.pair_h[i, n, seen], rtol=0, atol=1e-12)
            for k, value in enumerate((delta, np.conj(delta))):
                np.testing.assert_allclose(got[i, k, n, seen], binned(spin * value), atol=size**2)
        assert np.abs(got[i, 0, 0]).max() > 0.05 * size
    assert not np.allclose(got[0], got[4])  # a pair off the axis crosses its pixels elsewhere
    on_axis = focalplane.on_axis((0.0, 45.0))
    alone = scanstats.centroid_moments(schedule, nside, n_max=n_max)
    for pair in scanstats.centroid_moments(schedule, nside, n_max=n_max, focalplane=on_axis):
        np.testing.assert_allclose(pair, alone, rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    "terms, error, message",
    [
        ([(1.5, 4)], TypeError, "a term's n = 1.5 is not an integer"),  # was taken as (1, 4)
        ([(2, 4.0)], TypeError, "a term's m = 4.0"),
        ([], ValueError, "one or more"),
        ([(2, 4, 8)], ValueError, "pairs of integers"),
        (7, TypeError, "a sequence of"),
    ],
)
def test_hwp_moments_refuse_terms_that_are_not_integer_pairs(terms, error, message):
    from boresight.hwp import HWP

    ces = CES(T0, 60.0, 50.0, 130.0, 20.0)
    with pytest.raises(error, match=message):
        scanstats.hwp_moments(Schedule((ces,), Site(), 2.0), HWP("continuous"), 8, terms=terms)
