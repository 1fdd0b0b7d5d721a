"""The noise price of map-domain deprojection: the closed form against the map-maker's own 3x3
solve (linear algebra) and against noise-only Monte Carlo through the engine on a real schedule;
the map-maker's free spin-0 field against a common gain leak."""

from dataclasses import replace

import healpy as hp
import numpy as np
import pytest
from helpers import T0

from boresight import engine, pointing
from boresight.instrument.pairs import Instrument, Systematics
from boresight.predict.deprojection import information, noise_factor, noise_inflation, qu_variance
from boresight.schedule import CES, Schedule, Site
from boresight.sky import Sky


def _normal(angles):
    """The map-maker's 3x3 sums (solve_iqu's layout) of pair-samples at these angles."""
    c, s = np.cos(2 * angles), np.sin(2 * angles)
    w = np.stack([np.ones_like(c), c, s])
    upper = np.triu_indices(3)
    return (w[:, None] * w[None, :]).sum(axis=-1)[upper]


def test_the_closed_form_is_the_schur_complement_of_the_spin0_field():
    """Random sets of angles, some nearly collapsed: the eigenvalues equal those of the 3x3 normal
    matrix's (Q, U) block, less the spin-0 field, to 1e-10, and the variance inflation its inverse
    (to 1e-10 of its square, the rounding of a near-singular solve)."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        n = int(rng.integers(4, 60))
        spread = 10 ** rng.uniform(-1.5, 0.5)
        angles = rng.uniform(0, spread, n) + rng.uniform(0, np.pi)
        e2, e4 = np.exp(2j * angles), np.exp(4j * angles)
        h2, h4 = e2.mean(), e4.mean()
        full = np.zeros((3, 3))
        full[np.triu_indices(3)] = _normal(angles)
        full = full + np.triu(full, 1).T
        schur = full[1:, 1:] - np.outer(full[0, 1:], full[0, 1:]) / full[0, 0]
        low, high = information(h2, h4, deproject=True)
        np.testing.assert_allclose(np.linalg.eigvalsh(schur) / n, [low, high], atol=1e-10)
        np.testing.assert_allclose(
            np.linalg.eigvalsh(full[1:, 1:]) / n,
            information(h2, h4, deproject=False),
            atol=1e-10,
        )
        inflation = np.trace(np.linalg.inv(full)[1:, 1:]) / np.trace(np.linalg.inv(full[1:, 1:]))
        # rounding grows with the condition: as the inflation squared
        assert abs(noise_inflation(h2, h4) - inflation) < 1e-10 * inflation**2


def test_the_price_is_zero_where_h2_vanishes_and_the_paper_pairs_have_a_closed_form():
    h4 = np.array([0.3 + 0.1j, 0.0, -0.5j])
    assert np.allclose(noise_inflation(np.zeros(3), h4), 1.0)
    h2 = np.array([0.2, 0.5j, 0.7 - 0.3j])  # the boresight's; pairs at 0 and 45 deg
    pair_h2 = h2 * (1 + np.exp(2j * np.pi / 4)) / 2
    pair_h4 = h4 * (1 + np.exp(4j * np.pi / 4)) / 2
    want = (1 - np.abs(h2) ** 2 / 2) / (1 - np.abs(h2) ** 2)
    np.testing.assert_allclose(noise_inflation(pair_h2, pair_h4), want, rtol=1e-12)
    # two angles 45 deg apart: the pairs' map-maker solves Q and U, not beside a spin-0 field
    two = np.radians([0.0, 45.0])
    h2, h4 = np.exp(2j * two).mean(), np.exp(4j * two).mean()
    assert np.isinf(noise_inflation(h2, h4)) and information(h2, h4, deproject=False)[0] > 0.4


def _schedule(n_ces=2):
    """5-minute CESs at 10 Hz over 20 deg throws, rising and setting by turns, an hour apart:
    few angles per pixel, h_2 far from 0."""
    ces = tuple(
        CES(T0 + 3600.0 * i, 300.0, 50.0, 150.0 if i % 2 == 0 else 210.0, 20.0, turnaround_s=2.0)
        for i in range(n_ces)
    )
    return Schedule(ces, Site(), 10.0)


@pytest.fixture(scope="module")
def uniform_sky():
    """T = 100 muK everywhere, no polarisation: a gain jitter on detector B is then white noise
    of rms 50 x jitter in every pair difference."""
    nside = 32
    maps = np.zeros((3, 12 * nside**2))
    maps[0] = 100.0
    return Sky.from_maps(maps, lmax=2 * nside)


@pytest.mark.slow
def test_a_noise_only_monte_carlo_through_the_engine_has_the_closed_form_variance(uniform_sky):
    """400 realisations of white noise (a gain jitter on a uniform T) through the engine's pairs
    and pairs-spin0 map-makers on a real schedule: per map-maker, the mean over pixels of the
    measured var(Q) + var(U) over the closed form (h_2, h_4 from the samples' angles with
    bincount) is 1 within 3 %, and the measured inflation is the closed form's within 3 %."""
    schedule, nside = _schedule(6), uniform_sky.nside
    instrument = Instrument()  # the paper's pairs at 0 and 45 deg
    theta, phi, psi = (np.concatenate(x) for x in zip(*pointing.pointing(schedule)))
    pix = hp.ang2pix(nside, theta, phi)
    npix = 12 * nside**2
    hits, h2, h4 = np.zeros(npix), np.zeros(npix, complex), np.zeros(npix, complex)
    for a in instrument.pair_angles_rad:
        hits += np.bincount(pix, minlength=npix)
        for h, n in ((h2, 2), (h4, 4)):
            e = np.exp(1j * n * (psi + a))
            h += np.bincount(pix, e.real, npix) + 1j * np.bincount(pix, e.imag, npix)
    seen = hits >= 20
    h2, h4 = h2[seen] / hits[seen], h4[seen] / hits[seen]
    sigma = 0.5 * 0.01 * 100.0
    measured, spectra = {}, {}
    for mapmaker in ("pairs", "pairs-spin0"):
        maps = [
            engine.simulate_schedule(
                uniform_sky,
                schedule,
                instrument,
                Systematics(dg_jitter=0.01, seed=k),
                evaluation="pixel",
                mapmaker=mapmaker,
            )
            for k in range(400)
        ]
        q = np.array([m.q[seen] for m in maps])
        u = np.array([m.u[seen] for m in maps])
        measured[mapmaker] = (q.var(axis=0) + u.var(axis=0)) / sigma**2
        want = qu_variance(h2, h4, hits[seen], deproject=mapmaker == "pairs-spin0")
        assert seen.sum() > 30 and np.all(np.isfinite(want))
        assert abs(np.mean(measured[mapmaker] / want) - 1) < 0.03, mapmaker
        # the same noise's pseudo-spectrum EE + BB on the footprint, every multipole averaged
        mask = seen.astype(float)
        power = 0.0
        for m in maps:
            qu = np.zeros((3, npix))
            qu[1], qu[2] = m.q * mask, m.u * mask
            cl = hp.anafast(qu, lmax=2 * nside, pol=True)
            power += np.mean(cl[1, 2:] + cl[2, 2:]) / len(maps)
        spectra[mapmaker] = power
    inflation = measured["pairs-spin0"] / measured["pairs"]
    assert np.median(noise_inflation(h2, h4)) > 1.2  # a real price on this scan
    assert abs(np.mean(inflation / noise_inflation(h2, h4)) - 1) < 0.03
    # N_ell's factor. The pseudo-spectra's ratio (a harmonic route) is the ratio of the measured
    # pixel variances' sums on the same draws; that is the closed form's within 3 standard errors
    # of 400 draws' variances, a sum that a few ill-conditioned pixels dominate
    factor = noise_factor(h2, h4, hits[seen])
    summed = measured["pairs-spin0"].sum() / measured["pairs"].sum()
    assert spectra["pairs-spin0"] / spectra["pairs"] == pytest.approx(summed, rel=0.03)
    low, high = information(h2, h4, deproject=True)  # the (Q, U) covariance's eigenvalues
    lam = np.array([1 / low, 1 / high]) / hits[seen]
    error = np.sqrt(2 / 399 * np.sum(lam**2)) / np.sum(lam)  # of a sum of 400 draws' variances
    assert factor > 100 and 0.01 < error < 0.08, (factor, error)
    assert abs(summed / factor - 1) < 3 * error, (summed / factor, error)
    with pytest.raises(ValueError, match="without the field"):
        noise_factor(np.zeros(2), np.ones(2), np.ones(2))  # h_4 = 1: one angle, no Q and U


def test_the_spin0_field_takes_a_common_gain_leak_and_keeps_the_sky(plain_sky):
    """A gain mismatch dg common to the pairs leaks dg T / 2, a spin-0 field, and scales P by
    1 - dg / 2: the pairs-spin0 map-maker gives the sky's Q, U (read in the samples' pixels) so
    scaled to 1e-10 with the leak as its field, where the pairs' map-maker keeps the leak."""
    schedule = replace(_schedule(), repeat_boresight_deg=(0.0, 30.0))
    run = dict(evaluation="pixel")
    leaky = Systematics(dg=0.02)
    spin0 = engine.simulate_schedule(
        plain_sky, schedule, Instrument(), leaky, mapmaker="pairs-spin0", **run
    )
    pairs = engine.simulate_schedule(plain_sky, schedule, Instrument(), leaky, **run)
    ok = spin0.rcond_obs > 1e-3
    px = spin0.pixels[ok]
    i_map, q_map, u_map = plain_sky.maps
    scale = np.max(np.abs(q_map[px]))
    assert ok.sum() >= 10  # every pixel the 2 CESs cross at Nside 16
    assert np.max(np.abs(spin0.q_obs[ok] - 0.99 * q_map[px])) < 1e-10 * scale
    assert np.max(np.abs(spin0.u_obs[ok] - 0.99 * u_map[px])) < 1e-10 * scale
    np.testing.assert_allclose(spin0.i_obs[ok], 0.5 * 0.02 * i_map[px], rtol=1e-8, atol=1e-12)
    kept = np.max(np.abs(pairs.q[px] - 0.99 * q_map[px]))
    assert kept > 1e-3 * scale  # the pairs' map-maker keeps the leak


def test_the_noise_factor_is_the_weighted_sum_of_the_pixels_variances():
    """N_ell's factor: sum w^2 v' / sum w^2 v with v, v' the closed-form variances without and with
    the field; a pixel of weight 0 counts for nothing, even a singular one."""
    rng = np.random.default_rng(2)
    angles = [rng.uniform(0, 0.3 + k / 10, 40) for k in range(12)]
    h2 = np.array([np.exp(2j * a).mean() for a in angles])
    h4 = np.array([np.exp(4j * a).mean() for a in angles])
    hits, weights = rng.integers(10, 100, 12), rng.uniform(0, 1, 12)
    v = qu_variance(h2, h4, hits, deproject=False)
    free = qu_variance(h2, h4, hits, deproject=True)
    want = np.sum(weights**2 * free) / np.sum(weights**2 * v)
    assert noise_factor(h2, h4, hits, weights) == pytest.approx(want, rel=1e-14)
    assert noise_factor(np.zeros(3), 0.2 * np.ones(3), np.ones(3)) == pytest.approx(1.0)
    two = np.radians([0.0, 45.0])  # a pixel the field makes singular, weighted 0
    h2x = np.append(h2, np.exp(2j * two).mean())
    h4x = np.append(h4, np.exp(4j * two).mean())
    hx, wx = np.append(hits, 10), np.append(weights, 0.0)
    assert noise_factor(h2x, h4x, hx, wx) == pytest.approx(want, rel=1e-14)
    assert np.isinf(noise_factor(h2x, h4x, hx))
