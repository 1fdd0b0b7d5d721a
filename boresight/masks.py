"""Survey footprints: SO-like deep (SAT) and wide (LAT) masks, apodisation, user FITS masks.

The footprints approximate those of Stevens et al. 2018 (SPIE 10708, 1070841), in equatorial
coordinates (the sky maps' frame):

* deep (SAT, fsky ~ 0.10): -60 deg <= RA <= 60 deg, -70 deg <= Dec <= -20 deg, a low-foreground
  patch in the southern sky away from the Galactic plane;
* wide (LAT, fsky ~ 0.40): -61 deg <= Dec <= 18 deg at all RA, with Galactic latitude
  ``|b|`` > 20 deg.

They are not official SO masks; they reproduce the paper's sky fractions and geometry.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

import healpy as hp
import numba
import numpy as np

from . import validation
from ._util import io
from ._util.jit import njit
from .constants import DEG
from .validation import ConfigError, option

if TYPE_CHECKING:
    from collections.abc import Sequence

FOOTPRINTS = {
    "deep": dict(ra_deg=(-60.0, 60.0), dec_deg=(-70.0, -20.0), galactic_cut_deg=0.0),
    "wide": dict(ra_deg=(-180.0, 180.0), dec_deg=(-61.0, 18.0), galactic_cut_deg=20.0),
}


def footprint(ra_deg: tuple, dec_deg: tuple, galactic_cut_deg: float, nside: int) -> np.ndarray:
    """Binary mask of an RA/Dec box minus a Galactic band, at pixel centres.

    Parameters
    ----------
    ra_deg, dec_deg : tuple of float
        (low, high) [deg], equatorial.
    galactic_cut_deg : float
        Pixels with ``|b|`` below this are removed [deg].
    nside : int

    Returns
    -------
    numpy.ndarray, float64, shape (npix,)
        0 or 1, RING.
    """
    # the rings that reach the Dec range (a superset), then the test at each pixel centre
    colatitudes = np.clip(np.radians(90.0 - np.array(dec_deg[::-1], dtype=float)), 0.0, np.pi)
    strip = hp.query_strip(nside, *colatitudes, inclusive=True)
    theta, phi = hp.pix2ang(nside, strip)
    cut = np.sin(galactic_cut_deg * DEG) if galactic_cut_deg > 0 else -1.0
    box = np.array([*ra_deg, *dec_deg], dtype=np.float64)
    inside = _inside(theta, phi, box, hp.Rotator(coord=["C", "G"]).mat[2], cut)
    mask = np.zeros(12 * nside**2)
    mask[strip[inside]] = 1.0
    return mask


@njit(parallel=True)
def _inside(theta, phi, box, pole, sin_cut):
    """Whether each point (theta, phi [rad], equatorial) lies in the RA/Dec box (RA low, high, Dec
    low, high [deg]) with ``|z|`` along the Galactic pole (a unit vector) above ``sin_cut`` (-1:
    no cut)."""
    out = np.empty(theta.size, dtype=np.bool_)
    for i in numba.prange(theta.size):
        dec = 90.0 - theta[i] / DEG
        ra = (phi[i] / DEG + 180.0) % 360.0 - 180.0
        ok = box[0] <= ra <= box[1] and box[2] <= dec <= box[3]
        if ok and sin_cut >= 0.0:  # |b| > cut: the point's z along the Galactic pole
            sin_theta = np.sin(theta[i])
            z = pole[0] * sin_theta * np.cos(phi[i])
            z += pole[1] * sin_theta * np.sin(phi[i])
            z += pole[2] * np.cos(theta[i])
            ok = abs(z) > sin_cut
        out[i] = ok
    return out


#: rings kept beyond a survey's own by :func:`survey_span`: a reading near the survey's edge
#: interpolates from the next ring, and the paper's pointing offset (0.1 arcmin) is a fraction of
#: one at any Nside
SPAN_MARGIN_RINGS = 4


def survey_span(names: Sequence[str], nside: int, margin: int = SPAN_MARGIN_RINGS) -> tuple:
    """The RING pixels [first, stop) of the rings whose centres lie in any of these surveys' Dec
    ranges, and ``margin`` rings more either side: every pixel of their footprints (a pixel's
    centre lies on its ring) and the neighbours a reading inside them interpolates from.

    Parameters
    ----------
    names : sequence of {"deep", "wide", "none"}
    nside : int
    margin : int
        Rings added either side, >= 0.

    Returns
    -------
    tuple of int
        (first, stop): one span, whole rings, from the first ring any survey reaches to the last.
    """
    validation.integer("margin", margin, 0, 4 * nside)
    npix = 12 * nside**2
    if "none" in names:
        return 0, npix
    rings = np.arange(1, 4 * nside)
    start, _, cos_theta, _, _ = hp.ringinfo(nside, rings)
    colatitude = np.arccos(cos_theta)
    reached = np.zeros(rings.size, dtype=bool)
    for name in names:
        if name not in FOOTPRINTS:
            raise ValueError(f"survey must be one of {sorted(SURVEYS)}, got {name!r}")
        low, high = np.radians(90.0 - np.array(FOOTPRINTS[name]["dec_deg"][::-1], dtype=float))
        reached |= (colatitude >= low) & (colatitude <= high)
    inside = np.flatnonzero(reached)
    first = max(inside[0] - margin, 0)
    last = min(inside[-1] + margin, rings.size - 1)
    return int(start[first]), int(start[last + 1]) if last + 1 < rings.size else npix


#: the names a study's [mask] survey may take; "none" is the full sky
SURVEYS = (*FOOTPRINTS, "none")
#: each survey's sky fraction (its footprint's, to 1e-3 from Nside 64 up; test_masks)
SURVEY_FSKY = {"deep": 0.0996, "wide": 0.404, "none": 1.0}


def survey_mask(name: str, nside: int) -> np.ndarray:
    """The SO-like survey mask.

    Parameters
    ----------
    name : {"deep", "wide"}
    nside : int

    Returns
    -------
    numpy.ndarray, float64, shape (npix,)
        0 or 1, RING.
    """
    if name not in FOOTPRINTS:
        raise ValueError(f"survey must be one of {sorted(FOOTPRINTS)}, got {name!r}")
    return footprint(nside=nside, **FOOTPRINTS[name])


def apodize(mask: np.ndarray, fwhm_deg: float) -> np.ndarray:
    """Smooth a binary mask's edges inwards: mask * clip(2 * smoothed - 1, 0, 1).

    Parameters
    ----------
    mask : numpy.ndarray, shape (npix,)
    fwhm_deg : float
        Gaussian smoothing FWHM [deg], in [0.001, 180].

    Returns
    -------
    numpy.ndarray, shape (npix,)
        Weights in [0, 1], zero outside the input mask.
    """
    validation.number("apodize fwhm_deg", fwhm_deg, 1e-3, 180.0)
    smooth = hp.smoothing(mask, fwhm=fwhm_deg * DEG, iter=0)
    return mask * np.clip(2.0 * smooth - 1.0, 0.0, 1.0)


def read_mask(path: str, nside: int | None = None) -> np.ndarray:
    """A user mask from a HEALPix FITS file.

    Parameters
    ----------
    path : str
    nside : int, optional
        Regrade to this Nside.

    Returns
    -------
    numpy.ndarray, float64, shape (npix,)
        Weights in [0, 1] (UNSEEN read as 0).
    """
    if not os.path.isfile(path):
        raise FileNotFoundError(f"mask file not found: {path}")
    io.fits_map_shape(path)  # a ValueError naming the file if it is no HEALPix map
    mask = hp.read_map(path, dtype=np.float64)
    mask[mask == hp.UNSEEN] = 0.0
    if not np.isfinite(mask).all() or mask.min() < 0 or mask.max() > 1:
        raise ValueError(f"mask {path} must hold finite values in [0, 1]")
    if nside is not None and hp.npix2nside(mask.size) != nside:
        mask = hp.ud_grade(mask, nside)
    return mask


@dataclass(frozen=True)
class MaskSpec:
    """Where a study looks: the ``[mask]`` table.

    Parameters
    ----------
    survey : {"deep", "wide", "none"}
        SO-like survey footprint (:mod:`boresight.masks`); "none" is the full sky.
    file : str, optional
        A HEALPix FITS mask with weights in [0, 1], instead of the survey.
    apodize_fwhm_deg : float, optional
        Apodisation FWHM [deg], in [0.001, 180].
    """

    survey: str = option("none", "survey footprint ('none': full sky)", choices=SURVEYS)
    file: str = option(
        None, "a HEALPix FITS mask with weights in [0, 1] (instead of survey)", (str,)
    )
    apodize_fwhm_deg: float = option(None, "apodisation FWHM [deg], in [0.001, 180]", (int, float))

    def __post_init__(self):
        if self.survey not in SURVEYS:
            raise ValueError(f"survey = {self.survey!r}; allowed: {SURVEYS}")
        if self.apodize_fwhm_deg is not None:
            validation.number("apodize_fwhm_deg", self.apodize_fwhm_deg, 1e-3, 180.0)


def from_config(spec: MaskSpec, nside: int) -> np.ndarray:
    """The mask a study's [mask] table describes.

    Parameters
    ----------
    spec : MaskSpec
    nside : int

    Returns
    -------
    numpy.ndarray, float64, shape (npix,)
        RING weights in [0, 1].

    Raises
    ------
    boresight.validation.ConfigError
        The mask leaves no observed pixel.
    """
    if spec.file is not None:
        mask = read_mask(spec.file, nside)
    elif spec.survey == "none":
        mask = np.ones(12 * nside**2)
    else:
        mask = survey_mask(spec.survey, nside)
    if spec.apodize_fwhm_deg is not None:
        mask = apodize(mask, spec.apodize_fwhm_deg)
    if not (mask > 0).any():
        what = f"mask.file = {spec.file}" if spec.file else f"mask.survey = {spec.survey!r}"
        raise ConfigError(f"[mask] {what} leaves no observed pixel at Nside {nside}")
    return mask


def fsky(mask: np.ndarray) -> float:
    """Observed sky fraction.

    Parameters
    ----------
    mask : numpy.ndarray, shape (npix,)

    Returns
    -------
    float
        The mean of the mask.
    """
    return float(np.mean(mask))
