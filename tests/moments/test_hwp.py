"""The moments h_{n,m} behind a half-wave plate: the terms they take."""

import dataclasses

import healpy as hp
import numpy as np
import pytest
from helpers import T0
from plates import minute_schedule, wide_schedule

from boresight import moments, pointing
from boresight import moments as scanstats
from boresight.instrument import focalplane
from boresight.instrument.hwp import HWP
from boresight.schedule import CES, Schedule, Site


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
    from boresight.instrument.hwp import HWP

    ces = CES(T0, 60.0, 50.0, 130.0, 20.0)
    with pytest.raises(error, match=message):
        moments.hwp_moments(Schedule((ces,), Site(), 2.0), HWP("continuous"), 8, terms=terms)


def test_hwp_moments_are_the_h_n_times_the_hwp_average_of_a_stepped_plate():
    """With the CES set repeated at one boresight angle and the HWP stepped per repeat, every
    pixel sees the same psi in each repeat, so h_{n,m} = h_n mean_k exp(i m chi_k) exactly; h_{n,0}
    is the fused kernel's h_n (scanstats.characterise_schedule)."""
    schedule = minute_schedule([0.0, 600.0], repeats=(0.0, 0.0))
    plate = HWP("stepped", angles_deg=(0.0, 30.0), step="repeat")
    hits, h = scanstats.hwp_moments(schedule, plate, 16)
    stats = scanstats.characterise_schedule(schedule, 16)
    np.testing.assert_array_equal(hits, stats.hits)
    seen = hits > 0
    for (n, m), moment in h.items():
        average = np.mean(np.exp(1j * m * np.radians([0.0, 30.0])))
        np.testing.assert_allclose(moment[seen], stats.h[n, seen] * average, atol=1e-12)
        assert np.all(moment[~seen] == 0)
    assert (
        np.abs(h[(2, 4)][seen]).max() > 0.1 and abs(np.mean(np.exp(4j * np.radians([0, 30])))) > 0.4
    )
    # four steps of 22.5 deg cancel m = 4 and 8 wherever the repeats see the sky alike
    four = dataclasses.replace(schedule, repeat_boresight_deg=(0.0,) * 4)
    _, h4 = scanstats.hwp_moments(four, HWP("stepped", step="repeat"), 16, terms=((2, -4), (1, 8)))
    assert max(np.abs(v).max() for v in h4.values()) < 1e-14


def test_hwp_moments_of_a_continuous_plate_bin_as_numpy_does():
    schedule = minute_schedule([0.0, 600.0])
    plate = HWP("continuous", frequency_hz=0.7, phase_deg=10.0)
    terms = ((2, -4), (0, 4), (3, 8))
    hits, h = scanstats.hwp_moments(schedule, plate, 16, terms, chunk_samples=33)
    theta, phi, psi, chi = (np.concatenate(x) for x in zip(*pointing.pointing(schedule, hwp=plate)))
    pix = hp.ang2pix(16, theta, phi)
    np.testing.assert_array_equal(hits, np.bincount(pix, minlength=hits.size))
    for n, m in terms:
        w = np.exp(1j * (n * psi + m * chi))
        sums = np.bincount(pix, w.real, hits.size) + 1j * np.bincount(pix, w.imag, hits.size)
        np.testing.assert_allclose(
            h[(n, m)], np.where(hits > 0, sums / np.maximum(hits, 1), 0), atol=1e-12
        )
    with pytest.raises(ValueError, match="repeated"):
        scanstats.hwp_moments(schedule, plate, 16, ((2, -4), (2, -4)))
    with pytest.raises(ValueError, match="continuous or a stepped"):
        scanstats.hwp_moments(schedule, HWP(), 16)
    pairs = focalplane.hexagon(7, 10.0)
    for bad, words in (
        (dict(pair_weights=np.ones((7, 3))), "give focalplane"),
        (dict(focalplane=pairs, pair_weights=np.ones((7, 2))), r"pair_weights: shape \(7, 2\)"),
        (dict(focalplane=pairs, relative=True, pair_weights=np.ones((7, 3))), "not with pair"),
    ):
        with pytest.raises(ValueError, match=words):
            scanstats.hwp_moments(schedule, plate, 16, terms, **bad)


def test_the_pointing_moments_behind_a_plate_are_its_hwp_moments():
    """scanstats.pointing_behind against scanstats.hwp_moments (the plate's angle chi, not
    chi - gamma) of each pair of a 7-pixel hexagon behind a spinning plate: exp(-i m gamma)
    h_{n,m} to 1e-12; and its offset-weighted moments against the samples' offsets binned by hand
    with numpy."""
    schedule = wide_schedule(2)
    plate = HWP("continuous", frequency_hz=0.37)
    hexagon = focalplane.hexagon(7, 10.0)
    got = scanstats.pointing_behind(schedule, hexagon, plate, 16)
    plain = [(n, m) for n, m, offset in scanstats.POINTING_BEHIND_TERMS if offset is None]
    pairs = {}
    scanstats.hwp_moments(
        schedule, plate, 16, plain, focalplane=hexagon,
        each=lambda i, hits, h: pairs.update({i: (hits, h)}),
    )  # fmt: skip
    chunks = list(pointing.detector_pointing(schedule, hexagon, hwp=plate))
    for i, gamma in enumerate(np.radians(hexagon.gamma_deg)):
        hits, h = pairs[i]
        for k, (n, m, offset) in enumerate(scanstats.POINTING_BEHIND_TERMS):
            if offset is None:
                want = np.exp(-1j * m * gamma) * h[n, m]
                np.testing.assert_allclose(got[i, k], want, rtol=0, atol=1e-12)
        theta, phi, psi = (np.concatenate([c[j][i] for c in chunks]) for j in range(3))
        chi = np.concatenate([c[3] for c in chunks])
        pix = hp.ang2pix(16, theta, phi)
        c_theta, c_phi = hp.pix2ang(16, pix)
        delta = (theta - c_theta) + 1j * np.sin(c_theta) * (
            (phi - c_phi + np.pi) % (2 * np.pi) - np.pi
        )
        seen = hits > 0
        w = np.exp(1j * (psi + 4 * (chi - gamma))) * delta  # "g1 delta"
        want = np.bincount(pix, w.real, hits.size) + 1j * np.bincount(pix, w.imag, hits.size)
        k = scanstats.POINTING_BEHIND_TERMS.index((1, 4, "delta"))
        np.testing.assert_allclose(
            got[i, k, seen], want[seen] / hits[seen], atol=hp.nside2resol(16) ** 2
        )
        assert np.abs(got[i, k]).max() > 0.01 * hp.nside2resol(16)


def test_the_beam_moments_behind_a_plate_are_its_hwp_moments():
    """scanstats.beams_behind's unweighted moments against scanstats.hwp_moments of each pair of
    a 7-pixel hexagon behind a spinning plate, exp(-i m gamma) h_{n,m}, to 1e-12; its offset
    weights are pointing_behind's (the same binning, tested above)."""
    schedule = wide_schedule(2)
    plate = HWP("continuous", frequency_hz=0.37)
    hexagon = focalplane.hexagon(7, 10.0)
    got = scanstats.beams_behind(schedule, hexagon, plate, 16)
    plain = [
        (k, (n, m)) for k, (n, m, offset) in enumerate(scanstats.BEAM_BEHIND_TERMS) if not offset
    ]
    pairs = {}
    scanstats.hwp_moments(
        schedule, plate, 16, [nm for _, nm in plain], focalplane=hexagon,
        each=lambda i, hits, h: pairs.update({i: h}),
    )  # fmt: skip
    for i, gamma in enumerate(np.radians(hexagon.gamma_deg)):
        for k, (n, m) in plain:
            want = np.exp(-1j * m * gamma) * pairs[i][n, m]
            np.testing.assert_allclose(got[i, k], want, rtol=0, atol=1e-12)
    assert got.shape == (7, 44, 12 * 16**2) and np.abs(got[:, -1]).max() > 0


def test_the_focal_planes_moments_behind_a_plate_are_each_computed_once():
    """characterise_focalplane with the pointing's and the beams' moments keeps each (n, m,
    offset) once (the pointing's second order shares the beams' T part: 53 maps per pair, not
    75), and FocalPlaneStats.behind reads them as pointing_behind and beams_behind give them."""
    schedule = wide_schedule(1)
    plate = HWP("continuous", frequency_hz=0.37)
    pairs = focalplane.hexagon(7, 10.0).subset([0, 3])
    stats = scanstats.characterise_focalplane(
        schedule, pairs, 16, per_pair=True, hwp=plate, pointing=True, beams=True
    )
    assert len(stats.behind_terms) == stats.pair_behind_h.shape[1] == 53
    for terms, alone in (
        (scanstats.POINTING_BEHIND_TERMS, scanstats.pointing_behind(schedule, pairs, plate, 16)),
        (scanstats.BEAM_BEHIND_TERMS, scanstats.beams_behind(schedule, pairs, plate, 16)),
    ):
        assert stats.has_behind(terms)
        for k, term in enumerate(terms):
            np.testing.assert_array_equal(stats.behind(*term), alone[:, k])


def test_the_reflected_angle_moments_are_the_hwp_moments():
    """A pair at gamma behind the HWP has moments <exp(i n (psi + 2 chi - 2 gamma))> =
    exp(-2 i n gamma) h_{n,2n}: the focal plane's fused kernel with the HWP against
    scanstats.hwp_moments, to rounding, for a continuous and a stepped plate."""
    schedule = minute_schedule([0.0, 600.0], repeats=(0.0, 90.0))
    pairs = focalplane.on_axis((0.0, 22.5, 45.0))
    for plate in (HWP("continuous", frequency_hz=0.61), HWP("stepped", step="ces")):
        stats = scanstats.characterise_focalplane(schedule, pairs, 16, per_pair=True, hwp=plate)
        hits, h = scanstats.hwp_moments(schedule, plate, 16, [(n, 2 * n) for n in range(1, 5)])
        for i, gamma in enumerate(np.radians(pairs.gamma_deg)):
            np.testing.assert_array_equal(stats.pair_hits[i], hits)
            for n in range(1, 5):
                turned = np.exp(-2j * n * gamma) * h[(n, 2 * n)]
                np.testing.assert_allclose(stats.pair_h[i, n], turned, atol=1e-12)


def test_the_hwp_moments_progress_ends_at_the_schedules_samples(capsys):
    """With the turnarounds excluded their samples are never yielded; the bar still ends full."""
    schedule = dataclasses.replace(minute_schedule([0.0, 600.0]), turnarounds="exclude")
    scanstats.hwp_moments(schedule, HWP("stepped"), 8, progress=True)
    err = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert f"{schedule.n_samples}/{schedule.n_samples} " in err, err


def test_a_focal_planes_hwp_moments_are_its_pairs_own():
    """Off the axis each pair has its own samples: scanstats.hwp_moments with a focal plane (one
    pair at a time through detector_pointing) against the focal plane's fused kernel with the
    HWP (characterise_focalplane's reflected-angle moments, exp(-2 i n gamma) h_{n,2n} of each
    pair) to rounding, for every pair of a 7-pixel hexagon 10 deg wide; the combination is the
    hit-weighted mean of the pairs' own."""
    schedule = minute_schedule([0.0, 600.0], repeats=(0.0, 90.0))
    pairs = focalplane.hexagon(7, 10.0)
    plate = HWP("continuous", frequency_hz=0.61)
    stats = scanstats.characterise_focalplane(schedule, pairs, 16, per_pair=True, hwp=plate)
    terms = [(n, 2 * n) for n in range(1, 5)]
    own = {}
    hits, h = scanstats.hwp_moments(
        schedule, plate, 16, terms, focalplane=pairs, each=lambda i, n, m: own.update({i: (n, m)})
    )
    assert sorted(own) == list(range(7)) and len({int(o[0].sum()) for o in own.values()}) == 1
    np.testing.assert_array_equal(hits, stats.combined.hits)
    for i, gamma in enumerate(np.radians(pairs.gamma_deg)):
        np.testing.assert_array_equal(own[i][0], stats.pair_hits[i])
        for n in range(1, 5):
            turned = np.exp(-2j * n * gamma) * own[i][1][(n, 2 * n)]
            np.testing.assert_allclose(stats.pair_h[i, n], turned, atol=1e-12)
    weighted = sum(o[0] * o[1][(2, 4)] for o in own.values()) / np.maximum(hits, 1)
    np.testing.assert_allclose(h[(2, 4)], weighted, atol=1e-12)
    assert np.count_nonzero(own[0][0] != own[1][0]) > 5  # off the axis: their own pixels


def test_the_plates_own_moments_combine_each_pairs_with_its_weights():
    """plate_moments: on the axis the boresight's h_{n,m} of PLATE_TERMS serve every plate case
    and the predictions average over the pairs' angles; off the axis the synchronous signal's
    moments are the hit-weighted mean of each pair's own weighted by 1, exp(-4 i gamma),
    exp(-4 i gamma) (summed here from the pairs' own moments, the map-maker's combination), and
    the rest are the pairs' moments of chi - gamma / 2."""
    schedule = minute_schedule([0.0, 600.0], repeats=(0.0, 90.0))
    plate = HWP("continuous", frequency_hz=0.61)
    assert set(moments.PLATE_TERMS) == set(
        moments.IP_TERMS + moments.SYNCHRONOUS_TERMS + moments.JITTER_TERMS
    )
    axis = focalplane.on_axis((0.0, 45.0))
    on = moments.plate_moments(schedule, plate, 16, axis)
    hits, h = moments.hwp_moments(schedule, plate, 16, moments.PLATE_TERMS)
    np.testing.assert_array_equal(on.hits, hits)
    assert on.synchronous is on.h and on.pair_angles_deg == (0.0, 45.0)
    for term in moments.PLATE_TERMS:
        np.testing.assert_array_equal(on.h[term], h[term])
    pairs = focalplane.hexagon(7, 10.0)
    off = moments.plate_moments(schedule, plate, 16, pairs)
    assert off.pair_angles_deg is None
    own = {}
    total, _ = moments.hwp_moments(
        schedule, plate, 16, moments.SYNCHRONOUS_TERMS, focalplane=pairs,
        each=lambda i, n, m: own.update({i: (n, m)}),
    )  # fmt: skip
    np.testing.assert_array_equal(off.hits, total)
    weights = moments.synchronous_weights(pairs)
    np.testing.assert_allclose(weights[:, 1], np.exp(-4j * np.radians(pairs.gamma_deg)))
    for k, term in enumerate(moments.SYNCHRONOUS_TERMS):
        mean = sum(weights[i, k] * n * h_i[term] for i, (n, h_i) in own.items())
        np.testing.assert_allclose(off.synchronous[term], mean / np.maximum(total, 1), atol=1e-12)
    _, relative = moments.hwp_moments(
        schedule, plate, 16, moments.PLATE_TERMS, focalplane=pairs, relative=True
    )
    for term in moments.PLATE_TERMS:
        np.testing.assert_array_equal(off.h[term], relative[term])
