import healpy as hp
import numpy as np
import pytest

from boresight import masks
from boresight.config import MaskSpec


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
