"""Shared low-resolution fixtures: CI runs on 2 cores, so skies here are Nside <= 512."""

import numpy as np
import pytest

from boresight import cosmology, sky


@pytest.fixture(scope="session")
def theory():
    return cosmology.load_spectra()


@pytest.fixture(scope="session")
def small_sky(theory):
    """Nside 64 sky with a 1-degree beam (smooth on the pixel scale)."""
    return sky.make_sky(sky.SkyConfig(nside=64, lmax=191, fwhm_arcmin=60.0, seed=7), theory)


@pytest.fixture(scope="session")
def small_sky_unpolarised(theory):
    return sky.make_sky(
        sky.SkyConfig(nside=64, lmax=191, fwhm_arcmin=60.0, seed=7, polarised=False), theory
    )


def rel_max(a, b):
    """Largest |a - b| relative to the largest |b|."""
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(b)))
