"""The simulation engine against analytic identities (paper eq. 6; see docs/conventions.md)."""

import numpy as np
import pytest
from helpers import CENTRED, rel_max

from boresight import engine, masks, predict
from boresight.constants import DEG
from boresight.instrument.pairs import Instrument, Systematics
from boresight.scan import SyntheticScan


@pytest.mark.parametrize("pairs", [(0.0, 45.0), (10.0, 55.0, 100.0), (0.0, 30.0)])
def test_no_systematic_returns_input(small_sky, pairs):
    m = engine.simulate(small_sky, SyntheticScan(**CENTRED), Instrument(pairs))
    assert rel_max(m.q, small_sky.maps[1]) < 1e-12  # rounding of a 2x2 solve
    assert rel_max(m.u, small_sky.maps[2]) < 1e-12


def test_single_pair_single_angle_is_flagged(small_sky):
    m = engine.simulate(small_sky, SyntheticScan(n_phi=1, range_rad=0.5), Instrument((0.0,)))
    assert not m.valid.any() and np.all(m.rcond < 1e-6)


def test_unobserved_pixels_flagged(small_sky):
    pix = np.arange(100, 300)
    m = engine.simulate(small_sky, SyntheticScan(**CENTRED), pixels=pix)
    assert m.valid.sum() == 200 and m.valid[pix].all() and (m.hits[pix] == 4).all()


def test_gain_equals_analytic_map(small_sky, small_sky_unpolarised):
    """dP = 1/2 h2 (dg1 + i dg2) T - (dg1+dg2)/4 P - (dg1-dg2)/4 h4 P*, exact at pixel centres."""
    scan = SyntheticScan(**CENTRED)
    sysm = Systematics(dg=(0.01, -0.02))
    h, _ = engine.scan_moments(scan, small_sky.nside)
    for sky in (small_sky_unpolarised, small_sky):
        ref = engine.simulate(sky, scan)
        m = engine.simulate(sky, scan, systematics=sysm)
        dp = (m.q - ref.q) + 1j * (m.u - ref.u)
        pred = predict.delta_p(sky, h, sysm)
        assert rel_max(dp, pred) < 1e-11  # rounding only


def test_prediction_and_maps_at_observed_pixels(small_sky):
    """delta_p at some pixels and Maps.qu_at are the full-sky ones restricted to them: the
    residual jobs hold only observed-pixel values. delta_p's pointing term reads the gradient
    synthesised on those pixels' rings alone, the full-sky one to rounding (6e-13 relative)."""
    scan = SyntheticScan(**CENTRED)
    sysm = Systematics(dg=(0.01, -0.02), rho_arcmin=(0.5, 0.3))
    h, _ = engine.scan_moments(scan, small_sky.nside)
    pixels = np.flatnonzero(masks.survey_mask("deep", small_sky.nside))
    full = predict.delta_p(small_sky, h, sysm)
    got = predict.delta_p(small_sky, h, sysm, pixels=pixels)
    np.testing.assert_allclose(got, full[pixels], rtol=0, atol=1e-13 * np.abs(full).max())
    pix = np.arange(0, 12 * 64**2, 7)
    m = engine.simulate(small_sky, scan, pixels=pix[::2])  # the others: unobserved, invalid
    assert (~m.valid).any() and m.valid.any()
    np.testing.assert_array_equal(m.qu_at(pix), m.qu[:, pix])


def test_take_qu_hands_on_the_engines_own_maps(small_sky):
    """Maps.take_qu is qu_at on the observed pixels, as the engine's own (2, n) Q, U array (no
    copy), for the sky's maps and for the Q = U = 0 maps made beside them; elsewhere a copy."""
    scan = SyntheticScan(**CENTRED)
    pix = np.arange(0, 12 * 64**2, 7)[::2]
    sim, sim0 = engine.simulate_with_zero_qu(small_sky, scan, pixels=pix)
    assert (~sim.valid).any()  # some pixels unobserved: their UNSEEN become 0
    for maps in (sim, sim0):
        want = maps.qu_at(maps.pixels)
        other = maps.take_qu(maps.pixels[::3])
        assert not np.shares_memory(other, maps.q_obs)
        np.testing.assert_array_equal(other, want[:, ::3])
        got = maps.take_qu(maps.pixels)
        assert np.shares_memory(got, maps.q_obs) and np.shares_memory(got, maps.u_obs)
        np.testing.assert_array_equal(got, want)
    copy = engine.simulate(small_sky, scan, pixels=pix)  # Maps whose rows are not one array
    copy = type(copy)(
        copy.nside, copy.pixels, copy.q_obs.copy(), copy.u_obs.copy(), copy.hits_obs, copy.rcond_obs
    )
    got = copy.take_qu(copy.pixels)
    assert not np.shares_memory(got, copy.q_obs)
    np.testing.assert_array_equal(got, sim.qu_at(sim.pixels))


def test_gain_cancels_with_90_degree_rotation(small_sky_unpolarised):
    scan = SyntheticScan(**CENTRED, rotations_deg=(0, 90))
    m = engine.simulate(small_sky_unpolarised, scan, systematics=Systematics(dg=(0.01, 0.01)))
    t_rms = np.std(small_sky_unpolarised.maps[0])
    assert np.max(np.abs(m.q + 1j * m.u)) < 1e-14 * t_rms  # cancels to rounding


def test_leak_is_a_gain_with_its_own_template(small_sky_unpolarised):
    scan = SyntheticScan(**CENTRED)
    template = np.cos(np.arange(small_sky_unpolarised.maps.shape[1]) / 50.0)
    sysm = Systematics(leak=(0.02, 0.01))
    m = engine.simulate(small_sky_unpolarised, scan, systematics=sysm, leak_template=template)
    h, _ = engine.scan_moments(scan, small_sky_unpolarised.nside)
    pred = predict.delta_p(small_sky_unpolarised, h, sysm, template=template)
    assert rel_max(m.q + 1j * m.u, pred) < 1e-11  # rounding only


def _pointing_error(sky, rho_arcmin):
    scan = SyntheticScan(**CENTRED)
    sysm = Systematics(rho_arcmin=(rho_arcmin, 0.6 * rho_arcmin), chi_deg=(20.0, -35.0))
    m = engine.simulate(sky, scan, systematics=sysm, evaluation="exact")
    h, _ = engine.scan_moments(scan, sky.nside)
    pred = predict.delta_p(sky, h, sysm)
    return np.max(np.abs(m.q + 1j * m.u - pred)), np.max(np.abs(pred))


def test_pointing_matches_first_order_with_quadratic_error(small_sky_unpolarised):
    """Halving rho halves the leak and quarters the error: the formula is right to O(rho^2)."""
    e1, a1 = _pointing_error(small_sky_unpolarised, 1.0)
    e2, a2 = _pointing_error(small_sky_unpolarised, 0.5)
    assert e1 / a1 < 0.03  # second order: ~ rho / (beam scale) ~ 1 arcmin / 25 arcmin
    assert 3.6 < e1 / e2 < 4.4  # ratio 4 for an O(rho^2) remainder
    assert abs(a1 / a2 - 2) < 1e-12


def test_pointing_first_order_cancels_with_180_rotation(small_sky_unpolarised):
    sysm = Systematics(rho_arcmin=0.5)
    leak = engine.simulate(
        small_sky_unpolarised, SyntheticScan(**CENTRED), systematics=sysm, evaluation="exact"
    )
    pbr = engine.simulate(
        small_sky_unpolarised,
        SyntheticScan(**CENTRED, rotations_deg=(0, 180)),
        systematics=sysm,
        evaluation="exact",
    )
    # The O(rho) part cancels; the O(rho^2) rest is ~ rho / beam scale ~ 0.5 / 25 of the leak.
    assert np.max(np.abs(pbr.q + 1j * pbr.u)) < 0.02 * np.max(np.abs(leak.q + 1j * leak.u))


@pytest.mark.parametrize("evaluation", ["interp", "exact"])
def test_zero_qu_maps_are_those_of_the_unpolarised_sky_to_the_bit(small_sky, evaluation):
    """The Q = U = 0 maps from the same pass equal a scan of sky.without_polarisation(): gain,
    pointing, leak (its template the sky's I), angle errors and gain jitter alike."""
    unpolarised = small_sky.without_polarisation()
    scan = SyntheticScan(n_phi=3, range_rad=0.5, rotations_deg=(0, 90), seed=5)
    cases = [Systematics(dg=0.02, rho_arcmin=1.0, leak=(0.01, 0.0))]  # exact evaluation: 1 s each
    if evaluation == "interp":
        cases += [
            Systematics(rho_arcmin=3.0, chi_deg=(10.0, -20.0)),
            Systematics(pol_angle_deg=0.5, dg_jitter=0.01),
        ]
    for sysm in cases:
        kw = dict(systematics=sysm, evaluation=evaluation, chunk_pixels=5000)
        maps, zero = engine.simulate_with_zero_qu(small_sky, scan, **kw)
        alone = engine.simulate(small_sky, scan, **kw)
        separate = engine.simulate(unpolarised, scan, **kw)
        for got, want in ((maps, alone), (zero, separate)):
            for name in ("q", "u", "hits", "rcond"):
                np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
        assert not np.array_equal(zero.q, maps.q)  # the sky's Q, U are in the first only


def test_zero_qu_refuses_detector_beams(small_sky):
    with pytest.raises(ValueError, match="without_polarisation"):
        engine.simulate_with_zero_qu(
            small_sky, SyntheticScan(), systematics=Systematics(dfwhm_a_arcmin=0.5)
        )


def test_chunking_and_threads_do_not_change_results(small_sky):
    scan = SyntheticScan(n_phi=3, range_rad=0.7, rotations_deg=(0, 90), seed=11)
    sysm = Systematics(dg=(0.01, -0.01), rho_arcmin=0.5)
    a = engine.simulate(small_sky, scan, systematics=sysm, chunk_pixels=1 << 16, nthreads=2)
    b = engine.simulate(small_sky, scan, systematics=sysm, chunk_pixels=777, nthreads=1)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.u, b.u)
    c = engine.simulate(
        small_sky,
        SyntheticScan(n_phi=3, range_rad=0.7, rotations_deg=(0, 90), seed=12),
        systematics=sysm,
    )
    assert not np.array_equal(a.q, c.q)


def test_pixel_subset_equals_full_sky_restricted(small_sky):
    scan = SyntheticScan(n_phi=2, range_rad=0.3, seed=5)
    sysm = Systematics(dg=(0.01, -0.01))
    full = engine.simulate(small_sky, scan, systematics=sysm)
    pix = np.arange(5000, 9000)
    part = engine.simulate(small_sky, scan, systematics=sysm, pixels=pix)
    assert np.array_equal(full.q[pix], part.q[pix])


def test_moments_rotation_closed_form():
    scan = SyntheticScan(n_phi=3, range_rad=1.0, seed=2)
    h0, _ = engine.scan_moments(scan, 16)
    for alpha in (70.0, 89.0, 160.0):
        rot = SyntheticScan(n_phi=3, range_rad=1.0, seed=2, rotations_deg=(0, alpha))
        h1, _ = engine.scan_moments(rot, 16)
        for n in range(1, 5):
            want = np.abs(h0[n]) ** 2 * np.cos(n * alpha * DEG / 2) ** 2
            assert np.allclose(np.abs(h1[n]) ** 2, want, rtol=1e-12, atol=1e-15)
            assert np.isclose(
                predict.rotation_suppression(n, (0, alpha)),
                np.cos(n * alpha * DEG / 2) ** 2,
                rtol=1e-12,
            )


@pytest.mark.parametrize("n_max", [-1, 1.5, True])
def test_scan_moments_refuses_an_n_max_that_is_no_count(n_max):
    with pytest.raises((TypeError, ValueError), match="n_max"):
        engine.scan_moments(SyntheticScan(n_phi=2), 8, n_max=n_max)
