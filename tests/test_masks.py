import healpy as hp
import numpy as np
import pytest

from boresight import masks
from boresight.masks import MaskSpec


@pytest.mark.parametrize("name, fsky, tol", [("deep", 0.10, 0.01), ("wide", 0.40, 0.02)])
def test_survey_fsky(name, fsky, tol):
    for nside in (64, 256):
        assert abs(masks.fsky(masks.survey_mask(name, nside)) - fsky) < tol


def test_wide_mask_avoids_galactic_plane():
    nside = 64
    mask = masks.survey_mask("wide", nside)
    theta, phi = hp.pix2ang(nside, np.flatnonzero(mask))
    tg, _ = hp.Rotator(coord=["C", "G"])(theta, phi)
    assert np.all(np.abs(90 - np.degrees(tg)) > 20)


def _footprint_on_every_pixel(ra_deg, dec_deg, galactic_cut_deg, nside):
    """The footprint by brute force: every pixel centre, healpy's Rotator for |b|."""
    theta, phi = hp.pix2ang(nside, np.arange(12 * nside**2))
    dec, ra = 90 - np.degrees(theta), (np.degrees(phi) + 180) % 360 - 180
    keep = (ra >= ra_deg[0]) & (ra <= ra_deg[1]) & (dec >= dec_deg[0]) & (dec <= dec_deg[1])
    theta_g, _ = hp.Rotator(coord=["C", "G"])(theta, phi)
    return keep & (np.abs(90 - np.degrees(theta_g)) > galactic_cut_deg)


@pytest.mark.parametrize(
    "box",
    [
        masks.FOOTPRINTS["deep"],
        masks.FOOTPRINTS["wide"],
        dict(ra_deg=(-180, 180), dec_deg=(-90, 90), galactic_cut_deg=45),
        dict(ra_deg=(-10, 10), dec_deg=(89.9, 90), galactic_cut_deg=0),
        dict(ra_deg=(0, 30), dec_deg=(-90, -89.99), galactic_cut_deg=5),
    ],
)
def test_footprint_is_the_test_at_every_pixel_centre(box):
    """The footprint reads only the rings of its Dec range and |b| from a dot product with the
    Galactic pole: the same pixels as the test at every centre with healpy's Rotator."""
    for nside in (1, 4, 64, 256):
        want = _footprint_on_every_pixel(nside=nside, **box)
        assert np.array_equal(masks.footprint(nside=nside, **box), want.astype(float))


def test_apodize_and_read(tmp_path):
    mask = masks.survey_mask("deep", 32)
    apo = masks.apodize(mask, 5.0)
    assert apo.max() <= 1 and apo.min() >= 0 and np.all(apo[mask == 0] == 0)
    assert 0 < np.mean(apo) < np.mean(mask)
    path = str(tmp_path / "m.fits")
    hp.write_map(path, mask)
    assert np.array_equal(masks.read_mask(path), mask)
    assert masks.read_mask(path, nside=16).size == 12 * 16**2
    with pytest.raises(FileNotFoundError):
        masks.read_mask(str(tmp_path / "missing.fits"))
    with pytest.raises(ValueError, match="survey"):
        masks.survey_mask("ultra", 16)


def test_mask_from_a_study_config(tmp_path):
    nside = 32
    assert np.array_equal(masks.from_config(MaskSpec(), nside), np.ones(12 * nside**2))
    deep = masks.survey_mask("deep", nside)
    assert np.array_equal(masks.from_config(MaskSpec("deep"), nside), deep)
    apod = masks.from_config(MaskSpec("deep", apodize_fwhm_deg=5.0), nside)
    assert np.array_equal(apod, masks.apodize(deep, 5.0)) and 0 < apod.sum() < deep.sum()
    path = tmp_path / "mask.fits"
    hp.write_map(path, deep)
    assert np.array_equal(masks.from_config(MaskSpec(file=str(path)), nside), deep)


@pytest.mark.parametrize("nside", [16, 64, 256])
def test_a_survey_span_holds_its_pixels_their_neighbours_and_its_margin(nside):
    """survey_span's rings hold every pixel of the surveys' masks, with exactly ``margin`` whole
    rings either side beyond the rings the masks reach (at these Nside the Dec range's rings all
    hold some pixel of the mask); from 2 rings (the default is 4) they hold all eight neighbours
    of every pixel (the north and south ones lie two rings away; an interpolation reads the
    two rings around its point)."""
    rings = lambda pix: np.unique(hp.pix2ang(nside, pix)[0])  # noqa: E731 (a ring per colatitude)
    starts = set(hp.ringinfo(nside, np.arange(1, 4 * nside))[0]) | {12 * nside**2}
    for names in (["wide"], ["deep"], ["wide", "deep"]):
        pixels = np.flatnonzero(sum(masks.survey_mask(n, nside) for n in names))
        neighbours = hp.get_all_neighbours(nside, pixels).ravel()
        for margin in (0, 2, 4):
            first, stop = masks.survey_span(names, nside, margin)
            assert first <= pixels.min() and pixels.max() < stop
            if margin:
                assert first <= neighbours[neighbours >= 0].min()
                assert neighbours.max() < stop
            span = rings(np.arange(first, stop))
            assert span.size == rings(pixels).size + 2 * margin
            assert first in starts and stop in starts  # whole rings
    assert masks.survey_span(["none"], nside) == (0, 12 * nside**2)
    with pytest.raises(ValueError, match="survey must be"):
        masks.survey_span(["shallow"], nside)
