"""Polarisation-angle errors, gain drift, gain jitter and focal planes: the engine's
sample-by-sample pair differences against the analytic coefficients of boresight.predict."""

from dataclasses import replace

import healpy as hp
import numpy as np
import pytest
from helpers import rel_max

from boresight import config, coupling, engine, masks, predict, sky, spectra
from boresight.instrument.pairs import Instrument, Spread, Systematics
from boresight.scan import SyntheticScan
from boresight.schedule import CES, Schedule

CENTRED = dict(n_phi=4, range_rad=0.9, in_pixel="centre", seed=3)
ANGLES = Systematics(
    pol_angle_deg=(0.7, -0.4, 1.1), nonortho_deg=(0.5, 1.3, -0.8), dg=(0.01, -0.004, 0.007)
)


def _dp(sky_, scan, instrument, systematics, **kw):
    ref = engine.simulate(sky_, scan, instrument, **kw)
    m = engine.simulate(sky_, scan, instrument, systematics, **kw)
    return (m.q - ref.q) + 1j * (m.u - ref.u)


def _pred(sky_, scan, instrument, systematics, h=None):
    """The closed-form spurious map; ``h``: the scan's moments, when already computed."""
    h = engine.scan_moments(scan.one_repeat(), sky_.nside)[0] if h is None else h
    return predict.delta_p(sky_, h, systematics, instrument, rotations_deg=scan.rotations_deg)


@pytest.mark.parametrize(
    "angles, rotations",
    [
        ((0.0, 45.0, 90.0), (0.0,)),
        ((0.0, 30.0, 75.0), (0.0,)),  # m_4 != 0: the map-maker couples h_4
        ((10.0, 55.0, 100.0), (0.0, 90.0)),
        ((0.0, 30.0, 75.0), (0.0, 60.0, 150.0)),
    ],
)
def test_angle_errors_gain_and_drift_equal_the_analytic_map(small_sky, angles, rotations):
    """At pixel centres the gain, angle-error and drift terms are exact: the engine's per-sample
    sums and the closed form (Y - H_4 Y*) / (1 - |H_4|^2) agree to rounding."""
    scan = SyntheticScan(**CENTRED, rotations_deg=rotations)
    drift = tuple(0.003 * (-1) ** k * (k + 1) for k in range(len(rotations)))
    sysm = Systematics(
        pol_angle_deg=ANGLES.pol_angle_deg,
        nonortho_deg=ANGLES.nonortho_deg,
        dg=ANGLES.dg,
        dg_repeat=drift,
    )
    inst = Instrument(angles)
    dp = _dp(small_sky, scan, inst, sysm)
    assert rel_max(dp, _pred(small_sky, scan, inst, sysm)) < 1e-10


@pytest.mark.parametrize("rotations", [(0.0, 90.0), (0.0, 180.0)])
def test_common_angle_error_survives_every_rotation(small_sky, rotations):
    """A common angle error is an h_0 rotation of P: no boresight rotation changes it."""
    sysm = Systematics(pol_angle_deg=1.5)
    still = _dp(small_sky, SyntheticScan(**CENTRED), Instrument(), sysm)
    turned = _dp(small_sky, SyntheticScan(**CENTRED, rotations_deg=rotations), Instrument(), sysm)
    p = small_sky.maps[1] + 1j * small_sky.maps[2]
    assert rel_max(still, (np.exp(-2j * np.radians(1.5)) - 1) * p) < 1e-12
    assert rel_max(turned, still) < 1e-12


def test_non_orthogonality_only_lowers_the_efficiency(small_sky):
    """B at 90 + eps deg from A: the pair difference sees cos(eps) P at the mean angle, so no E-to-B
    and a rotation-immune efficiency loss."""
    eps = 2.0
    dp = _dp(small_sky, SyntheticScan(**CENTRED), Instrument(), Systematics(nonortho_deg=eps))
    p = small_sky.maps[1] + 1j * small_sky.maps[2]
    assert rel_max(dp, (np.cos(np.radians(eps)) - 1) * p) < 1e-10


def test_gain_drift_spoils_the_90_degree_cancellation_by_its_difference(small_sky_unpolarised):
    """dg = 0.01 cancels at (0, 90); a drift (+d, -d) between the repeats leaves h_2 d (1 + i) T / 2
    whatever the common gain."""
    scan = SyntheticScan(**CENTRED, rotations_deg=(0.0, 90.0))
    sysm = Systematics(dg=0.01, dg_repeat=(0.002, -0.002))
    dp = _dp(small_sky_unpolarised, scan, Instrument(), sysm)
    h, _ = engine.scan_moments(scan.one_repeat(), small_sky_unpolarised.nside)
    want = h[2] * 0.002 * (1 + 1j) / 2 * small_sky_unpolarised.maps[0]
    assert rel_max(dp, want) < 1e-10
    flat = _dp(small_sky_unpolarised, scan, Instrument(), Systematics(dg=0.01))
    assert np.max(np.abs(flat)) < 1e-14 * np.max(np.abs(small_sky_unpolarised.maps[0]))


def test_jitter_is_white_with_the_predicted_variance(small_sky_unpolarised):
    """Per-sample gain jitter sigma gives |dP|^2 of mean sigma^2 T^2 / N_samples in every pixel
    (an exponential variable per pixel: the mean over n pixels is good to 1 / sqrt(n))."""
    sigma = 0.02
    scan = SyntheticScan(**{**CENTRED, "n_phi": 6}, rotations_deg=(0.0, 45.0))
    sysm = Systematics(dg_jitter=sigma)
    dp = _dp(small_sky_unpolarised, scan, Instrument(), sysm)
    m = engine.simulate(small_sky_unpolarised, scan, systematics=sysm)
    n_samples = m.hits * 2  # Maps.hits counts hits x repeats; x 2 pairs
    ratio = np.abs(dp) ** 2 * n_samples / (sigma * small_sky_unpolarised.maps[0]) ** 2
    assert abs(np.mean(ratio) - 1) < 4 / np.sqrt(ratio.size)


def test_jitter_does_not_depend_on_chunks_or_threads(small_sky):
    scan = SyntheticScan(n_phi=3, range_rad=1.0, rotations_deg=(0.0, 90.0), seed=9)
    sysm = Systematics(dg_jitter=(0.01, 0.03))
    a = engine.simulate(small_sky, scan, systematics=sysm, chunk_pixels=1000, nthreads=1)
    b = engine.simulate(small_sky, scan, systematics=sysm, chunk_pixels=7919, nthreads=2)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.u, b.u)
    other = engine.simulate(small_sky, replace(scan, seed=10), systematics=sysm)
    ref_other = engine.simulate(small_sky, replace(scan, seed=10))
    ref = engine.simulate(small_sky, scan)
    # another seed draws other jitter (the hits move too, so compare the jitter's own part)
    assert not np.allclose(a.q - ref.q, other.q - ref_other.q)


def test_jitter_on_a_schedule_is_white_with_the_predicted_variance(small_sky_unpolarised):
    """A schedule's samples draw their jitter keyed by (seed, index in the stream): |dP|^2 has
    mean sigma^2 <T^2> / N_samples per pixel as for synthetic hits (T read where each sample
    falls, averaged in its pixel), and the maps do not depend on the chunking."""
    from boresight import pointing

    sigma = 0.02
    sky_ = small_sky_unpolarised
    ces = tuple(
        CES(1.79e9 + 3600 * i, 1800.0, 50.0, az, 40.0, 1.0, 45.0 * i)
        for i, az in enumerate((130.0, 230.0, 135.0, 225.0))
    )
    schedule = Schedule(ces, sample_rate_hz=2.0)
    sysm = Systematics(dg_jitter=sigma, seed=4)

    def maps(chunk, systematics):
        stream = pointing.pointing(schedule, chunk_samples=chunk)
        return engine.simulate_samples(sky_, stream, systematics=systematics)

    m, ref = maps(1 << 20, sysm), maps(1 << 20, Systematics())
    assert np.array_equal(m.q, maps(977, sysm).q) and np.array_equal(m.u, maps(977, sysm).u)
    ok = m.valid & ref.valid & (m.hits > 20)
    dp = (m.q - ref.q)[ok] + 1j * (m.u - ref.u)[ok]
    t2 = np.zeros(sky_.maps.shape[1])  # <T^2> over each pixel's samples
    counts = np.zeros_like(t2)
    for theta, phi, _ in pointing.pointing(schedule):
        pix = hp.ang2pix(sky_.nside, theta, phi)
        t = hp.get_interp_val(sky_.maps[0], theta, phi)
        t2 += np.bincount(pix, t**2, t2.size)
        counts += np.bincount(pix, minlength=t2.size)
    n_samples = (m.hits * 2)[ok]  # samples x 2 pairs
    ratio = np.abs(dp) ** 2 * n_samples / (sigma**2 * (t2 / np.maximum(counts, 1))[ok])
    assert ratio.size > 300 and abs(np.mean(ratio) - 1) < 4 / np.sqrt(ratio.size)


def test_jitter_cl_prediction(theory):
    """The predicted white jitter spectrum against the simulated pseudo-C_BB, wide mask, Nside 128:
    within 5 % in bands of ~10^4 modes (measured 3.5 %). Pixel-centre hits, and the sky's variance
    summed to 3 Nside - 1, so that the hits see the pixel map whose T^2 the prediction uses. The
    spectra stop at lmax 300, well above the last band (256), where LSQR converges in a few steps
    (at 3 Nside - 1 it takes 10 s and the bands agree to 4.6 %)."""
    nside, lmax = 128, 300
    s = sky.make_sky(sky.SkyConfig(nside=nside, lmax=383, fwhm_arcmin=30.0, seed=3), theory)
    mask = masks.survey_mask("wide", nside)
    scan = SyntheticScan(**{**CENTRED, "n_phi": 5}, rotations_deg=(0.0, 45.0))
    sysm = Systematics(dg_jitter=0.03)
    dp = _dp(s, scan, Instrument(), sysm, pixels=mask > 0)
    sim = spectra.pseudo_spectra(np.array([0 * dp.real, dp.real, dp.imag]), mask, lmax)[2]
    h, hits = engine.scan_moments(scan.one_repeat(), nside, pixels=mask > 0)
    couplings = coupling.mask_coupling(mask, lmax, band=383)
    prediction = predict.Prediction(
        theory, couplings, 30.0, field_cl=predict.local_cl(s, mask, lmax)
    )
    pred = predict.residual_pseudo_bb(
        h,
        mask,
        prediction,
        sysm,
        rotations_deg=scan.rotations_deg,
        crossings=hits,
    )
    edges = spectra.linear_bins(40, 256, 54)
    _, want = spectra.bin_spectrum(sim, edges)
    _, got = spectra.bin_spectrum(pred, edges)
    assert np.all(np.abs(got / want - 1) < 0.05), got / want


@pytest.mark.parametrize(
    "instrument",
    [
        Instrument("uniform", 16),
        Instrument("0/45/90/135", 8),
        Instrument((3.0, 17.0, 101.0, 44.0, 60.0)),
    ],
)
def test_focal_planes_keep_the_map_maker_exact(small_sky, instrument):
    m = engine.simulate(small_sky, SyntheticScan(**CENTRED), instrument)
    assert rel_max(m.q, small_sky.maps[1]) < 1e-12
    assert rel_max(m.u, small_sky.maps[2]) < 1e-12


def test_presets():
    assert Instrument("uniform", 2).pair_angles_deg == (0.0, 45.0)
    assert Instrument("uniform", 4).pair_angles_deg == (0.0, 22.5, 45.0, 67.5)
    assert Instrument("0/45/90/135", 6).pair_angles_deg == (0.0, 45.0, 90.0, 135.0, 0.0, 45.0)
    assert Instrument((5.0, 6.0)).n_pairs == 2


def test_per_pair_draws_are_keyed_by_seed_and_pair():
    sysm = Systematics(dg=Spread(0.001, 0.01), pol_angle_deg={"mean": 0.0, "rms": 0.5}, seed=11)
    few, many = sysm.per_pair(4), sysm.per_pair(4096)
    np.testing.assert_array_equal(few.dg, many.dg[:4])  # pair i's draw does not depend on N
    assert abs(np.mean(many.dg) - 0.001) < 4 * 0.01 / 64 and abs(np.std(many.dg) / 0.01 - 1) < 0.05
    assert abs(np.std(np.degrees(many.pol_angle)) / 0.5 - 1) < 0.05
    assert abs(np.corrcoef(many.dg, many.pol_angle)[0, 1]) < 4 / 64  # independent parameters
    other = Systematics(dg=Spread(0.001, 0.01), seed=12).per_pair(4)
    assert not np.array_equal(other.dg, few.dg)


def test_random_focal_plane_residual_falls_as_one_over_n_pairs(small_sky):
    """Zero-mean per-pair gain and angle errors: the residual power over N = 1, 4, 16, 64 pairs
    falls as N^-1. Each N averages 48 focal-plane draws (scatter ~ 1 / sqrt(48) per point); the
    fitted slope is good to ~0.05. The powers are those of the map-level closed form, which the
    first two draws of every N check against the engine to 1e-9 (simulating all 192 focal planes
    would cost the suite ~30 s for the same numbers). The 0/45 deg repeat makes one pair's 2x2
    system as well conditioned as many pairs' (m_4 = 0), so N = 1 is on the same law."""
    scan = SyntheticScan(**CENTRED, rotations_deg=(0.0, 45.0))
    h = engine.scan_moments(scan.one_repeat(), small_sky.nside)[0]  # the same for every draw
    powers = []
    for n in (1, 4, 16, 64):
        inst = Instrument("uniform", n)
        p = []
        for seed in range(48):
            sysm = Systematics(dg=Spread(0.0, 0.01), pol_angle_deg=Spread(0.0, 0.3), seed=seed)
            pred = _pred(small_sky, scan, inst, sysm, h)
            p.append(np.mean(np.abs(pred) ** 2))
            if seed < 2:  # the prediction is the simulation, to rounding
                assert rel_max(_dp(small_sky, scan, inst, sysm), pred) < 1e-9
        powers.append(np.mean(p))
    slope = np.polyfit(np.log([1, 4, 16, 64]), np.log(powers), 1)[0]
    assert abs(slope + 1) < 0.15, (slope, powers)


@pytest.mark.parametrize("n", [2, 3, 8, 64])
def test_uniform_plane_cancels_h4_terms_not_the_gain(n):
    """A "uniform" plane of n pairs at 90 i / n deg: <e^{4 i a}> = 0, so m_4 and a gain spread's
    h_4 term vanish, but the gain's coherent h_2 coefficient is dg <e^{2 i a}> =
    dg (2 / n) / (1 - e^{i pi / n}) (a geometric series) = dg (1 / n + i cot(pi / 2n) / n), which
    tends to 2i dg / pi, not 0."""
    inst = Instrument("uniform", n)
    c = predict.coefficients(Systematics(dg=0.01), inst)
    assert abs(c.m4) < 1e-15 and abs(c.p4) < 1e-15
    assert abs(c.t2 - 0.01 * (2 / n) / (1 - np.exp(1j * np.pi / n))) < 1e-15
    if n == 64:  # 2i / pi, up to the 1 / n of the series' end points
        assert abs(c.t2 / 0.01 - 2j / np.pi) < 1.01 / n


@pytest.mark.parametrize(
    "table, match",
    [
        ({"dg_jitter": -0.01}, "dg_jitter"),
        ({"pol_angle_deg": float("nan")}, "pol_angle_deg"),
        ({"nonortho_deg": 50.0}, "nonortho_deg"),
        ({"dg": {"mean": 0.0, "rms": -1.0}}, "dg.rms"),
        ({"dg": {"mu": 0.0}}, "mean"),
        ({"dg_repeat": [0.9, 0.1]}, "1 rotation repeats"),
        ({"dg": 0.6, "dg_repeat": 0.6}, "detector B's gain"),
    ],
)
def test_bad_parameters_are_config_errors(table, match):
    raw = {"sky": {"nside": 16, "lmax": 47}, "systematics": table}
    with pytest.raises(config.ConfigError, match=f"systematics.*{match}"):
        config.parse_study(raw)


@pytest.mark.parametrize(
    "table, match",
    [
        ({"pair_angles_deg": "hexagonal", "n_pairs": 4}, "preset"),
        ({"pair_angles_deg": "uniform"}, "n_pairs"),
        ({"pair_angles_deg": [0.0, 45.0], "n_pairs": 3}, "n_pairs"),
    ],
)
def test_bad_focal_planes_are_config_errors(table, match):
    with pytest.raises(config.ConfigError, match=f"instrument.*{match}"):
        config.parse_study({"sky": {"nside": 16, "lmax": 47}, "instrument": table})


def test_expected_cl_falls_as_one_over_n_and_equals_a_fixed_plane_without_scatter(small_sky):
    mask = masks.survey_mask("deep", 64)
    h, _ = engine.scan_moments(SyntheticScan(**CENTRED), 64)
    theory = small_sky_theory()
    cl = {}
    for n in (4, 16):
        sysm = Systematics(dg=Spread(0.0, 0.01), pol_angle_deg=Spread(0.0, 0.5))
        inst = Instrument("uniform", n)
        cl[n] = predict.systematic_cl(
            h, mask, sysm, theory, 100, fwhm_arcmin=60.0, instrument=inst, expected=True
        )
    np.testing.assert_allclose(cl[4][:, 2:], 4 * cl[16][:, 2:], rtol=1e-10)
    fixed = Systematics(dg=(0.01, -0.004), pol_angle_deg=0.3)
    spread = Systematics(dg=(0.01, -0.004), pol_angle_deg=Spread(0.3, 0.0))
    np.testing.assert_allclose(
        predict.systematic_cl(h, mask, spread, theory, 100, fwhm_arcmin=60.0, expected=True),
        predict.systematic_cl(h, mask, fixed, theory, 100, fwhm_arcmin=60.0),
        rtol=1e-12,
    )
    with pytest.raises(ValueError, match="dg_repeat"):
        predict.expected_power(Systematics(dg_repeat=Spread(0.0, 0.01)))


def small_sky_theory():
    from boresight.cosmology import load_spectra

    return load_spectra()


@pytest.mark.parametrize(
    "kwargs, field", [(dict(rho_arcmin=-0.1), "rho_arcmin"), (dict(dg=(0.1, np.inf)), "dg")]
)
def test_bad_systematics(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Systematics(**kwargs)


def test_systematics_length_must_match_pairs():
    with pytest.raises(ValueError, match="3 pairs"):
        Systematics(dg=(0.1, 0.2)).per_pair(Instrument((0, 45, 90)).n_pairs)


def test_each_key_fills_its_own_parameter_by_name():
    """Every Systematics key lands in the PairParameters field of its name, in engine units
    (it was filled by position from LIMITS' order)."""
    from boresight.constants import ARCMIN, DEG
    from boresight.instrument.pairs import LIMITS, PARAMETER_OF, PairParameters

    assert sorted(PARAMETER_OF) == sorted(LIMITS)
    assert sorted(PARAMETER_OF.values()) == sorted(PairParameters._fields)
    values = dict(rho_arcmin=2.0, chi_deg=30.0, leak=0.01, pol_angle_deg=0.5, nonortho_deg=1.0)
    values.update(dg=0.02, dfwhm_b_arcmin=0.3, ellipticity_a=0.05, ellipticity_angle_b_deg=20.0)
    params = Systematics(**values).per_pair(3)
    units = {"_arcmin": ARCMIN, "_deg": DEG}
    for key, value in values.items():
        unit = next((u for suffix, u in units.items() if key.endswith(suffix)), 1.0)
        np.testing.assert_allclose(getattr(params, PARAMETER_OF[key]), value * unit, rtol=1e-15)
    np.testing.assert_array_equal(params.dfwhm_a, 0.0)
