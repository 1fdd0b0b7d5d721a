"""The survey's noise: depth from NET, N_ell, and sigma(r) against a closed form and a
simulation."""

import healpy as hp
import numpy as np
import pytest

from boresight import cosmology, noise
from boresight.constants import ARCMIN


def _flat_spectra(lensing, tensor, lmax=400):
    zero = np.zeros(lmax + 1)
    return cosmology.Spectra(
        tt=zero, ee=zero, te=zero, bb_lens=np.full(lmax + 1, lensing), tt_tensor=zero,
        ee_tensor=zero, te_tensor=zero, bb_tensor=np.full(lmax + 1, tensor),
    )  # fmt: skip


def test_depth_from_net_matches_the_pixel_route():
    """depth = sqrt(2) NET / sqrt(time per pixel) x sqrt(pixel area), with the time shared
    evenly over the observed pixels."""
    n = noise.SurveyNoise(
        fsky=0.1, fwhm_arcmin=30.0, net_uk_sqrt_s=350.0, n_detectors=2000, years=3
    )
    nside = 256
    pixel_area = hp.nside2pixarea(nside)
    observed = 0.1 * 12 * nside**2
    seconds_per_pixel = 2000 * 3 * noise.YEAR_S / observed
    sigma_p = np.sqrt(2) * 350.0 / np.sqrt(seconds_per_pixel)
    assert n.depth == pytest.approx(sigma_p * np.sqrt(pixel_area) / ARCMIN, rel=1e-12)
    n_ell = n.n_ell(300)
    beam = hp.gauss_beam(30 * ARCMIN, lmax=300)
    np.testing.assert_allclose(n_ell * beam**2, (n.depth * ARCMIN) ** 2, rtol=1e-12)


def test_sigma_r_closed_form_full_sky_white_noise():
    """Full sky, white noise, no beam, flat spectra: one band of nu modes gives
    sigma(r) = sqrt(2 / nu) (A_lens C_lens + N) / C_tensor."""
    lens, tensor, depth = 2e-6, 5e-5, 3.0
    spectra = _flat_spectra(lens, tensor)
    n = noise.SurveyNoise(fsky=1.0, fwhm_arcmin=0.0, depth_uk_arcmin=depth)
    big_n = (depth * ARCMIN) ** 2
    for lo, hi in ((80, 81), (20, 200)):
        nu = np.sum(2 * np.arange(lo, hi) + 1)
        expected = np.sqrt(2 / nu) * (0.5 * lens + big_n) / tensor
        got = noise.sigma_r(n, spectra, np.array([lo, hi]), a_lens=0.5)
        assert got == pytest.approx(expected, rel=1e-12)
    # splitting a band of flat spectra into two keeps the information
    one = noise.sigma_r(n, spectra, np.array([20, 200]))
    two = noise.sigma_r(n, spectra, np.array([20, 90, 200]))
    assert two == pytest.approx(one, rel=1e-12)


def test_a_filters_transfer_scales_the_noise_and_adds_the_leaked_e():
    """A filtering pipeline's corrected spectrum: one band of flat spectra gives the closed form
    with N / F + T C^EE / F, and a filter that keeps F of a white noise of depth d is a survey of
    depth d / sqrt(F) (per band, each band its own F)."""
    lens, tensor, depth, ee = 2e-6, 5e-5, 3.0, 4e-4
    spectra = _flat_spectra(lens, tensor)
    spectra = cosmology.Spectra(**{**spectra.__dict__, "ee": np.full(401, ee)})
    n = noise.SurveyNoise(fsky=1.0, fwhm_arcmin=0.0, depth_uk_arcmin=depth)
    big_n = (depth * ARCMIN) ** 2
    nu = np.sum(2 * np.arange(20, 200) + 1)
    for f, t in ((0.6, 0.0), (0.6, 0.01), (1.0, 0.02)):
        expected = np.sqrt(2 / nu) * (0.5 * lens + (big_n + t * ee) / f) / tensor
        got = noise.sigma_r(
            n, spectra, np.array([20, 200]), a_lens=0.5, transfer_bb=[f], e_to_b=[t]
        )
        assert got == pytest.approx(expected, rel=1e-12)
    theory = cosmology.load_spectra()
    edges = np.array([30, 128, 192, 257])
    f_bb = np.array([0.59, 0.89, 0.88])
    per_band = [
        noise.band_fisher(
            noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, depth_uk_arcmin=depth / np.sqrt(f)),
            theory,
            edges,
        )[b]
        for b, f in enumerate(f_bb)
    ]
    model = noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, depth_uk_arcmin=depth)
    filtered = noise.band_fisher(model, theory, edges, transfer_bb=f_bb)
    np.testing.assert_allclose(filtered, per_band, rtol=1e-12)
    # a negative estimate of the E-to-B leak counts as none; no filter is the raw survey
    assert noise.sigma_r(model, theory, edges, transfer_bb=f_bb, e_to_b=[-0.01, 0, 0]) == (
        noise.sigma_r(model, theory, edges, transfer_bb=f_bb)
    )
    assert noise.sigma_r(model, theory, edges, transfer_bb=[1, 1, 1]) == pytest.approx(
        noise.sigma_r(model, theory, edges), rel=1e-14
    )
    # the noise filtered too: K of it kept is a survey of depth d sqrt(K / F); K = F is the raw
    # survey, K = 1 the bound N / F
    kept = np.array([0.9, 0.97, 1.01])
    per_band = [
        noise.band_fisher(
            noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, depth_uk_arcmin=depth * np.sqrt(k / f)),
            theory,
            edges,
        )[b]
        for b, (f, k) in enumerate(zip(f_bb, kept))
    ]
    got = noise.band_fisher(model, theory, edges, transfer_bb=f_bb, noise_kept=kept)
    np.testing.assert_allclose(got, per_band, rtol=1e-12)
    assert noise.sigma_r(model, theory, edges, transfer_bb=f_bb, noise_kept=f_bb) == (
        pytest.approx(noise.sigma_r(model, theory, edges), rel=1e-12)
    )
    assert noise.sigma_r(model, theory, edges, transfer_bb=f_bb, noise_kept=[1, 1, 1]) == (
        noise.sigma_r(model, theory, edges, transfer_bb=f_bb)
    )


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(transfer_bb=[0.5, 0.5]), "one value per band"),
        (dict(transfer_bb=[0.0, 0.5, 0.5]), r"\(0, 1\]"),
        (dict(transfer_bb=[1.5, 0.5, 0.5]), r"\(0, 1\]"),
        (dict(e_to_b=[np.nan, 0, 0]), "finite"),
        (dict(noise_kept=[0.0, 1, 1]), "noise_kept must be positive"),
        (dict(noise_kept=[1, 1]), "one value per band"),
    ],
)
def test_a_bad_transfer_is_one_clear_error(kwargs, message, theory):
    model = noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, depth_uk_arcmin=3.0)
    with pytest.raises(ValueError, match=message):
        noise.sigma_r(model, theory, np.array([30, 128, 192, 257]), **kwargs)
    given = noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, sigma_r=0.003)
    with pytest.raises(ValueError, match="no N_ell for a filter"):
        noise.sigma_r(given, theory, np.array([30, 301]), transfer_bb=[0.5])
    with pytest.raises(ValueError, match="no N_ell for a filter"):
        noise.sigma_r(given, theory, np.array([30, 301]), noise_kept=[0.5])


def test_sigma_r_matches_the_scatter_of_simulated_estimates():
    """An independent route: full-sky Gaussian B realisations (lensing + noise, r = 0), r estimated
    from each multipole's C_ell and combined with inverse-variance weights 2 C_ell^2 / (2 ell + 1);
    its scatter over 400 skies is sigma(r) within 3x the Monte Carlo error (1 / sqrt(798))."""
    spectra = cosmology.load_spectra()
    n = noise.SurveyNoise(fsky=1.0, fwhm_arcmin=30.0, depth_uk_arcmin=10.0)
    edges = np.array([2, 10, 30, 60, 100, 150])
    lmax = edges[-1] - 1
    total = spectra.bb(a_lens=1.0)[: lmax + 1] + n.n_ell(lmax)
    tensor = spectra.bb_tensor[: lmax + 1]
    ell = np.arange(2, lmax + 1)
    weight = (2 * ell + 1) * (tensor[2:] / total[2:]) ** 2  # inverse variance of (C - C) / T
    np.random.seed(5)  # healpy.synalm draws from numpy's global generator
    estimates = []
    for _ in range(400):
        alm = hp.synalm(total, lmax=lmax)
        r_ell = (hp.alm2cl(alm)[2:] - total[2:]) / tensor[2:]
        estimates.append(np.sum(weight * r_ell) / np.sum(weight))
    expected = noise.sigma_r(n, spectra, edges)
    assert np.std(estimates, ddof=1) == pytest.approx(expected, rel=3 / np.sqrt(798))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(depth_uk_arcmin=-1.0), "depth_uk_arcmin"),
        (dict(net_uk_sqrt_s=-300.0, n_detectors=10, years=1.0), "net_uk_sqrt_s"),
        (dict(net_uk_sqrt_s=300.0, n_detectors=10), "all of"),
        (dict(depth_uk_arcmin=2.0, net_uk_sqrt_s=300.0, n_detectors=10, years=1.0), "exactly one"),
        (dict(), "exactly one"),
        (dict(depth_uk_arcmin=2.0, sigma_r=0.003), "exactly one"),
        (dict(sigma_r=-0.1), "sigma_r"),
        (dict(nl_bb_file="/nonexistent/nl.txt"), "nl_bb_file"),
        (dict(depth_uk_arcmin=float("nan")), "depth_uk_arcmin"),
    ],
)
def test_bad_noise_is_one_clear_error(kwargs, message):
    with pytest.raises((ValueError, TypeError), match=message):
        noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, **kwargs)


def _table(tmp_path, rows, name="nl.txt"):
    path = tmp_path / name
    path.write_text("# ell  N_ell [muK^2]\n" + "\n".join(f"{a}, {b}" for a, b in rows) + "\n")
    return str(path)


def test_a_noise_table_of_the_white_model_gives_its_sigma_r(tmp_path, theory):
    """N_ell read from a table (every second ell, interpolated) of the white + 1/f model gives
    that model's sigma(r): the table route against the formula (tolerance: the interpolation's
    error on a curve this smooth)."""
    model = noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, depth_uk_arcmin=3.0, ell_knee=50.0)
    ell = np.arange(0, 402, 2)
    rows = [(int(e), v) for e, v in zip(ell, model.n_ell(401)[ell])]
    table = noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, nl_bb_file=_table(tmp_path, rows))
    edges = np.array([30, 301])
    assert noise.sigma_r(table, theory, edges) == pytest.approx(
        noise.sigma_r(model, theory, edges), rel=2e-3
    )
    on_table = ell[(ell >= 2) & (ell <= 300)]  # ell < 2 hold the ell = 2 value in both
    np.testing.assert_allclose(table.n_ell(300)[on_table], model.n_ell(300)[on_table])
    with pytest.raises(ValueError, match="reaches ell = 400"):
        table.n_ell(500)


def test_a_given_sigma_r_is_the_yardstick(theory):
    given = noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, sigma_r=0.003)
    assert noise.sigma_r(given, theory, np.array([30, 301])) == 0.003
    assert not given.has_spectrum
    with pytest.raises(ValueError, match="no N_ell"):
        given.n_ell(100)


@pytest.mark.parametrize(
    "rows, message",
    [
        ([(2, 1e-5)], "increase"),
        ([(5, 1e-5), (10, 1e-5)], "increase"),
        ([(2, 1e-5), (3, -1.0)], "> 0"),
    ],
)
def test_a_bad_noise_table_is_one_clear_error(tmp_path, rows, message):
    with pytest.raises(ValueError, match=message):
        noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, nl_bb_file=_table(tmp_path, rows))


@pytest.mark.parametrize(
    "value, message",
    [
        (0, "as a string"),  # open(0) would read standard input
        (True, "as a string"),
        (["nl.txt"], "as a string"),
        ("DIRECTORY", "not a regular file"),
        ("FIFO", "not a regular file"),  # open() would block on it
        ("BINARY", "binary"),
        ("UTF16", "UTF-16"),
        ("LATIN1", "not UTF-8"),
    ],
)
def test_a_noise_table_that_is_no_text_file_is_refused_without_reading_it(tmp_path, value, message):
    import os

    if value == "DIRECTORY":
        value = str(tmp_path)
    elif value == "FIFO":
        value = str(tmp_path / "fifo")
        os.mkfifo(value)
    elif value in ("BINARY", "UTF16", "LATIN1"):
        path = tmp_path / "nl.txt"
        data = {"BINARY": b"\x00\x01\x02", "UTF16": "2 1e-5\n3 1e-5\n".encode("utf-16"),
                "LATIN1": "# \xe9t\xe9\n2 1e-5\n".encode("latin-1")}[value]  # fmt: skip
        path.write_bytes(data)
        value = str(path)
    with pytest.raises(ValueError, match=message):
        noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, nl_bb_file=value)


def test_a_table_short_of_the_bands_is_a_config_error(tmp_path):
    from boresight.validation import ConfigError

    table = noise.SurveyNoise(
        fsky=0.1, fwhm_arcmin=30.0, nl_bb_file=_table(tmp_path, [(2, 1e-5), (100, 1e-5)])
    )
    with pytest.raises(ConfigError, match="reaches ell = 100, the bands need 300"):
        table.n_ell(300)


def test_a_survey_says_itself_in_a_few_words(tmp_path):
    assert noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, depth_uk_arcmin=3.0).summary() == (
        "3 muK arcmin, fsky 0.1, beam 30 arcmin"
    )
    given = noise.SurveyNoise(fsky=0.2, fwhm_arcmin=0.0, sigma_r=0.003)
    assert given.summary() == "sigma(r) 0.003, fsky 0.2, beam 0 arcmin"
    table = _table(tmp_path, [(2, 1e-6), (500, 1e-6)])
    assert (
        noise.SurveyNoise(fsky=0.1, fwhm_arcmin=30.0, nl_bb_file=table)
        .summary()
        .startswith(f"N_ell of {table}")
    )
