"""The input sky: a seeded Gaussian I, Q, U realisation of the CMB spectra, beam-smoothed.

Harmonic coefficients are drawn with numpy's Philox generator keyed by the seed (correlated T and E,
independent B), smoothed by a Gaussian beam (healpy.gauss_beam, polarised factors) and synthesised
on a HEALPix RING grid with ducc0. The alm are kept for exact evaluation at arbitrary points.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from . import harmonics, validation
from .constants import ARCMIN
from .cosmology import load_spectra
from .validation import option

if TYPE_CHECKING:
    from collections.abc import Sequence

    from .cosmology import Spectra


MAX_NSIDE = 8192
MAX_SEED = 2**63 - 1  #: seeds key 64-bit counter-based generators
MAX_FWHM_ARCMIN = 10800.0  #: a beam wider than the sphere's half-circumference is no beam
MAX_AMPLITUDE = 100.0  #: upper bound on r and A_lens (either far beyond any physical value)


@dataclass(frozen=True)
class SkyConfig:
    """What sky to simulate: the ``[sky]`` table. Paper values by default.

    Parameters
    ----------
    nside : int
        HEALPix Nside, a power of two in [1, 8192].
    lmax : int
        Band limit, 2..3 nside - 1.
    fwhm_arcmin : float
        Gaussian beam FWHM [arcmin].
    seed : int
        Seed of the realisation, >= 0.
    r : float
        Tensor-to-scalar ratio.
    a_lens : float
        Lensing B-mode amplitude.
    polarised : bool
        False sets Q = U = 0 (the paper's zero-polarisation check).
    """

    nside: int = option(2048, f"HEALPix Nside, a power of two in [1, {MAX_NSIDE}]")
    lmax: int = option(4000, "band limit of the sky, 2..3 nside - 1")
    fwhm_arcmin: float = option(7.0, "Gaussian beam FWHM [arcmin], >= 0")
    seed: int = option(0, "seed of the sky realisation, >= 0")
    r: float = option(0.0, "tensor-to-scalar ratio, >= 0")
    a_lens: float = option(1.0, "lensing B-mode amplitude, >= 0")
    polarised: bool = option(True, "false sets Q = U = 0 (the paper's zero-polarisation check)")

    def __post_init__(self):
        nside = validation.integer("nside", self.nside, 1, MAX_NSIDE)
        if nside & (nside - 1):
            raise ValueError(f"nside must be a power of two in [1, {MAX_NSIDE}], got {nside}")
        validation.integer("lmax", self.lmax, 2, 3 * nside - 1)
        validation.number("fwhm_arcmin", self.fwhm_arcmin, 0.0, MAX_FWHM_ARCMIN)
        validation.integer("seed", self.seed, 0, MAX_SEED)
        validation.number("r", self.r, 0.0, MAX_AMPLITUDE)
        validation.number("a_lens", self.a_lens, 0.0, MAX_AMPLITUDE)
        if not isinstance(self.polarised, (bool, np.bool_)):
            raise TypeError(f"polarised must be true or false, got {self.polarised!r}")


@dataclass(frozen=True)
class Sky:
    """A beam-smoothed sky.

    Parameters
    ----------
    alm : numpy.ndarray, complex128, shape (3, nalm)
        T, E, B [muK], healpy ordering.
    maps : numpy.ndarray, float64, shape (3, npix)
        I, Q, U [muK], RING, COSMO. :func:`make_sky` and :meth:`from_maps` make it a view of an
        interleaved (npix, 3) array, so that :attr:`interleaved` costs no copy.
    nside : int
    lmax : int
    fwhm_arcmin : float
    """

    alm: np.ndarray
    maps: np.ndarray
    nside: int
    lmax: int
    fwhm_arcmin: float

    @cached_property
    def interleaved(self):
        """I, Q, U per pixel, shape (npix, 3): the layout the interpolation kernels read (a pixel's
        fields share a cache line). ``maps`` itself where it is a view of one (no copy), else
        built on first use and kept."""
        return np.ascontiguousarray(self.maps.T)

    def kept_on(self, first: int, stop: int) -> Sky:
        """This sky with its maps kept on the RING pixels [first, stop) and 0 elsewhere, in new
        memory of which only those pages are ever written: a job that reads the maps there alone
        holds that share of them (:func:`boresight.masks.survey_span`; the paper's two surveys
        keep 62 % of the 1.1 GiB at Nside 2048). The kept values are this sky's, bit for bit; the
        alm are shared.

        Parameters
        ----------
        first, stop : int
            RING pixels, 0 <= first < stop <= npix.

        Returns
        -------
        Sky
        """
        npix = 12 * self.nside**2
        validation.integer("first", first, 0, npix - 1)
        validation.integer("stop", stop, first + 1, npix)
        maps = np.zeros((npix, 3))  # calloc'd: the pages outside [first, stop) stay unallocated
        maps[first:stop] = self.interleaved[first:stop]
        return replace(self, maps=maps.T)

    def without_polarisation(self):
        """This sky with Q = U = 0 and E = B = 0: the paper's check that a systematic's residual
        comes from the polarised sky.

        Returns
        -------
        Sky
            A new sky in the same layout (the caller frees it after use: at Nside 2048 it holds
            1.2 GB).
        """
        maps = np.zeros_like(self.maps)
        maps[0] = self.maps[0]
        alm = np.zeros_like(self.alm)
        alm[0] = self.alm[0]
        return replace(self, alm=alm, maps=maps)

    @classmethod
    def from_maps(cls, maps, lmax=None, fwhm_arcmin=0.0, nthreads=0):
        """Wrap user I, Q, U maps; their alm are computed for exact evaluation.

        Parameters
        ----------
        maps : array_like, shape (3, npix)
            I, Q, U [muK], RING, finite.
        lmax : int, optional
            Band limit of the alm (default 3 nside - 1).
        fwhm_arcmin : float
            The maps' beam [arcmin] (for predictions).
        nthreads : int

        Returns
        -------
        Sky
        """
        maps = np.asarray(maps, dtype=np.float64)
        if maps.ndim != 2 or maps.shape[0] != 3:
            raise ValueError(f"maps must have shape (3, npix), got {maps.shape}")
        maps = np.ascontiguousarray(maps.T).T  # interleaved, as make_sky's
        if not np.isfinite(maps).all():
            raise ValueError("maps contain NaN or infinite values")
        nside = hp.npix2nside(maps.shape[1])
        lmax = 3 * nside - 1 if lmax is None else lmax
        alm = np.empty((3, harmonics.n_alm(lmax)), dtype=np.complex128)
        # full-sky maps as healpy.map2alm reads them (3 Jacobi iterations)
        alm[0] = harmonics.map2alm(maps[0], lmax, spin=0, analysis="jacobi", nthreads=nthreads)
        alm[1:] = harmonics.map2alm(maps[1:], lmax, spin=2, analysis="jacobi", nthreads=nthreads)
        return cls(alm=alm, maps=maps, nside=nside, lmax=lmax, fwhm_arcmin=fwhm_arcmin)


def gaussian_alm(cls: Sequence[np.ndarray], lmax: int, seed: int) -> np.ndarray:
    """Seeded Gaussian T, E, B alm of given spectra (correlated T and E, independent B).

    Parameters
    ----------
    cls : sequence of numpy.ndarray
        TT, EE, BB, TE [muK^2] from ell = 0.
    lmax : int
    seed : int
        Key of numpy's Philox generator.

    Returns
    -------
    numpy.ndarray, complex128, shape (3, nalm)
    """
    tt, ee, bb, te = (np.asarray(c[: lmax + 1], dtype=np.float64) for c in cls)
    rng = np.random.Generator(np.random.Philox(key=seed))
    nalm = harmonics.n_alm(lmax)
    real = np.arange(nalm) <= lmax  # m = 0: real coefficients of unit variance
    g = rng.standard_normal((3, nalm)) + 1j * rng.standard_normal((3, nalm))
    g[:, real] = g[:, real].real * np.sqrt(2.0)
    g *= np.sqrt(0.5)
    safe_tt = np.where(tt > 0, tt, 1.0)
    t_amp = np.sqrt(np.maximum(tt, 0.0))
    e_corr = np.where(tt > 0, te / np.sqrt(safe_tt), 0.0)
    e_amp = np.sqrt(np.maximum(ee - e_corr**2, 0.0))
    alm = np.empty((3, nalm), dtype=np.complex128)
    alm[0] = harmonics.almxfl(g[0], t_amp)
    alm[1] = harmonics.almxfl(g[0], e_corr) + harmonics.almxfl(g[1], e_amp)
    alm[2] = harmonics.almxfl(g[2], np.sqrt(np.maximum(bb, 0.0)))
    return alm


def make_sky(
    config: SkyConfig = SkyConfig(), spectra: Spectra | None = None, nthreads: int = 0
) -> Sky:
    """Draw, smooth and synthesise a sky.

    Parameters
    ----------
    config : SkyConfig
    spectra : boresight.cosmology.Spectra, optional
        Default: the cached CAMB spectra.
    nthreads : int

    Returns
    -------
    Sky
    """
    spectra = load_spectra() if spectra is None else spectra
    alm = gaussian_alm(
        spectra.total(r=config.r, a_lens=config.a_lens, lmax=config.lmax), config.lmax, config.seed
    )
    if not config.polarised:
        alm[1:] = 0
    return sky_of_alm(alm, config.nside, fwhm_arcmin=config.fwhm_arcmin, nthreads=nthreads)


def sky_of_alm(alm: np.ndarray, nside: int, *, fwhm_arcmin: float, nthreads: int = 0) -> Sky:
    """A sky of given T, E, B alm, smoothed by a Gaussian beam and synthesised.

    Parameters
    ----------
    alm : numpy.ndarray, complex128, shape (3, nalm)
        T, E, B [muK] before the beam, healpy ordering; smoothed in place.
    nside : int
    fwhm_arcmin : float
    nthreads : int

    Returns
    -------
    Sky
    """
    lmax = harmonics.alm_lmax(alm.shape[-1])
    beam = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=lmax, pol=True)
    alm[0] = harmonics.almxfl(alm[0], beam[:, 0])
    alm[1] = harmonics.almxfl(alm[1], beam[:, 1])
    alm[2] = harmonics.almxfl(alm[2], beam[:, 2])
    maps = np.empty((12 * nside**2, 3)).T  # interleaved: Sky.interleaved is this array
    harmonics.alm2map(alm[0], nside, nthreads=nthreads, out=maps[0])
    harmonics.alm2map(alm[1:], nside, spin=2, nthreads=nthreads, out=maps[1:])
    return Sky(alm=alm, maps=maps, nside=nside, lmax=lmax, fwhm_arcmin=fwhm_arcmin)
