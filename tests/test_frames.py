"""Sky frames: the ICRS -> Galactic rotation is astropy's, CIRS is the identity, and the per-chunk
rotation CIRS -> ICRS is astropy's CIRS -> GCRS direction change without aberration."""

import numpy as np
import pytest
from helpers import T0

from boresight import frames


def test_icrs_to_galactic_is_astropys_and_a_rotation():
    from astropy import units as u
    from astropy.coordinates import ICRS, Galactic

    rng = np.random.default_rng(2)
    ra, dec = rng.uniform(0, 360, 50), np.degrees(np.arcsin(rng.uniform(-1, 1, 50)))
    gal = ICRS(ra=ra * u.deg, dec=dec * u.deg).transform_to(Galactic()).cartesian
    vec = ICRS(ra=ra * u.deg, dec=dec * u.deg).cartesian
    rot = frames.icrs_to_galactic()
    got = rot @ np.array([vec.x.value, vec.y.value, vec.z.value])
    np.testing.assert_allclose(got, [gal.x.value, gal.y.value, gal.z.value], atol=1e-12)
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-14)


def test_cirs_terms_are_the_identity_without_aberration():
    terms = frames.frame_terms(np.array([T0, T0 + 3600.0]), -22.96, "cirs")
    np.testing.assert_array_equal(terms[:, :9], np.tile(np.eye(3).ravel(), (2, 1)))
    np.testing.assert_array_equal(terms[:, 9:], 0.0)


def test_the_rotation_to_icrs_is_astropys_cirs_to_gcrs():
    """The rotation of frame_terms against astropy's CIRS -> GCRS for a geocentric observer at
    rest (astropy adds aberration and light deflection, at most 20.5 arcsec together; the
    rotation alone must agree to 1 mas once they are taken out, i.e. to 2e-5 deg here)."""
    from astropy import units as u
    from astropy.coordinates import CIRS, GCRS
    from astropy.time import Time

    time = Time(T0, format="unix")
    rot = frames.frame_terms(np.array([T0]), 0.0, "icrs")[0, :9].reshape(3, 3)
    rng = np.random.default_rng(5)
    ra, dec = rng.uniform(0, 360, 20), np.degrees(np.arcsin(rng.uniform(-0.9, 0.9, 20)))
    cirs = CIRS(ra=ra * u.deg, dec=dec * u.deg, obstime=time)
    gcrs = cirs.transform_to(GCRS(obstime=time)).cartesian.xyz.value
    ours = rot @ cirs.cartesian.xyz.value
    # astropy's GCRS holds annual aberration: at most 20.5 arcsec = 1e-4 rad
    assert np.max(np.linalg.norm(gcrs - ours, axis=0)) < 1.1e-4
    # and the rotation is 0.15 deg of RA in 2026: leaving it out would be 30 times that
    assert np.max(np.linalg.norm(cirs.cartesian.xyz.value - ours, axis=0)) > 2e-3


def test_unknown_frames_are_refused():
    with pytest.raises(ValueError, match="allowed"):
        frames.frame_terms(np.array([T0]), 0.0, "fk5")
