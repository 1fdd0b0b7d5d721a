"""Spherical-harmonic transforms on HEALPix RING maps through ducc0 (healpy's alm ordering).

Polarisation follows healpy: spin-2 transforms take (E, B) alm and give (Q, U) in the HEALPix
(COSMO) convention; ``map2alm`` mirrors healpy.map2alm with ``iter`` Jacobi iterations and no
ring weights, so that spectra agree with healpy.anafast.
"""

from __future__ import annotations

from functools import lru_cache

import ducc0
import numpy as np


@lru_cache(maxsize=8)
def healpix_geometry(nside: int) -> dict:
    """ducc0's ring geometry of a RING HEALPix map (cached).

    Parameters
    ----------
    nside : int

    Returns
    -------
    dict
        theta, phi0, nphi, ringstart: the keyword arguments of ducc0.sht's transforms.
    """
    if nside < 1 or nside & (nside - 1):
        raise ValueError(f"nside must be a positive power of two, got {nside}")
    return ducc0.healpix.Healpix_Base(nside, "RING").sht_info()


def n_alm(lmax: int) -> int:
    """Number of alm with m <= l <= lmax (healpy ordering).

    Parameters
    ----------
    lmax : int

    Returns
    -------
    int
    """
    return (lmax + 1) * (lmax + 2) // 2


def alm_lmax(nalm: int) -> int:
    """lmax of a healpy-ordered alm array.

    Parameters
    ----------
    nalm : int

    Returns
    -------
    int
    """
    return int((np.sqrt(8 * nalm + 1) - 3) / 2)


def alm2map(alm: np.ndarray, nside: int, spin: int = 0, nthreads: int = 0) -> np.ndarray:
    """Synthesis: alm -> RING map.

    Parameters
    ----------
    alm : numpy.ndarray, complex128
        (nalm,) for spin 0; (2, nalm) (E, B) for spin >= 1.
    nside : int
    spin : int
    nthreads : int

    Returns
    -------
    numpy.ndarray
        (npix,) for spin 0; (2, npix) (Q, U, COSMO) otherwise.
    """
    alm = np.atleast_2d(alm)
    out = ducc0.sht.synthesis(
        alm=alm,
        lmax=alm_lmax(alm.shape[-1]),
        spin=spin,
        nthreads=nthreads,
        **healpix_geometry(nside),
    )
    return out[0] if spin == 0 else out


def alm2map_gradient(alm: np.ndarray, nside: int, nthreads: int = 0) -> np.ndarray:
    """Gradient of a spin-0 field.

    Parameters
    ----------
    alm : numpy.ndarray, complex128, shape (nalm,)
    nside : int
    nthreads : int

    Returns
    -------
    numpy.ndarray, shape (2, npix)
        dT/dtheta and dT/dphi / sin(theta).
    """
    return ducc0.sht.synthesis(
        alm=np.atleast_2d(alm),
        lmax=alm_lmax(alm.shape[-1]),
        spin=1,
        mode="DERIV1",
        nthreads=nthreads,
        **healpix_geometry(nside),
    )


def map2alm(
    maps: np.ndarray, lmax: int, spin: int = 0, iterations: int = 3, nthreads: int = 0
) -> np.ndarray:
    """Analysis as healpy.map2alm(iter=iterations, use_weights=False).

    Parameters
    ----------
    maps : array_like
        (npix,) for spin 0; (2, npix) Q, U for spin 2.
    lmax : int
    spin : int
    iterations : int
        Jacobi iterations (3 is anafast's default).
    nthreads : int

    Returns
    -------
    numpy.ndarray, complex128
        (nalm,) for spin 0; (2, nalm) (E, B) otherwise.
    """
    maps = np.atleast_2d(np.asarray(maps, dtype=np.float64))
    nside = int(round(np.sqrt(maps.shape[-1] / 12)))
    geom = healpix_geometry(nside)
    scale = 4 * np.pi / maps.shape[-1]

    def adjoint(m):
        out = ducc0.sht.adjoint_synthesis(map=m, lmax=lmax, spin=spin, nthreads=nthreads, **geom)
        out *= scale
        return out

    alm = adjoint(maps)
    for _ in range(iterations):  # in place: full-sky temporaries cost as much as a transform
        resid = ducc0.sht.synthesis(alm=alm, lmax=lmax, spin=spin, nthreads=nthreads, **geom)
        np.subtract(maps, resid, out=resid)
        alm += adjoint(resid)
    return alm[0] if spin == 0 else alm


def evaluate(
    alm: np.ndarray,
    theta: np.ndarray,
    phi: np.ndarray,
    spin: int = 0,
    epsilon: float = 1e-12,
    nthreads: int = 0,
) -> np.ndarray:
    """Exact band-limited evaluation of alm at arbitrary points (ducc0 synthesis_general).

    Parameters
    ----------
    alm : numpy.ndarray, complex128
        (nalm,) for spin 0; (2, nalm) (E, B) for spin 2.
    theta, phi : numpy.ndarray, shape (n,)
        Points [rad].
    spin : int
    epsilon : float
        ducc0's requested relative accuracy.
    nthreads : int

    Returns
    -------
    numpy.ndarray
        (n,) for spin 0; (2, n) Q, U for spin 2.
    """
    alm = np.atleast_2d(alm)
    loc = np.empty((theta.size, 2))
    loc[:, 0] = theta
    loc[:, 1] = phi
    out = ducc0.sht.synthesis_general(
        alm=alm,
        spin=spin,
        lmax=alm_lmax(alm.shape[-1]),
        loc=loc,
        epsilon=epsilon,
        nthreads=nthreads,
    )
    return out[0] if spin == 0 else out


@lru_cache(maxsize=4)
def ell_of_alm(lmax: int) -> np.ndarray:
    """ell of every healpy-ordered alm index (read-only; cached per lmax).

    Parameters
    ----------
    lmax : int

    Returns
    -------
    numpy.ndarray, int, shape (nalm,)
    """
    ell = np.concatenate([np.arange(m, lmax + 1) for m in range(lmax + 1)])
    ell.flags.writeable = False
    return ell


def almxfl(alm: np.ndarray, fl: np.ndarray) -> np.ndarray:
    """Multiply alm by a function of ell.

    Parameters
    ----------
    alm : numpy.ndarray, complex128, shape (..., nalm)
    fl : numpy.ndarray, shape (lmax + 1,)

    Returns
    -------
    numpy.ndarray, complex128, shape (..., nalm)
    """
    return alm * fl[ell_of_alm(alm_lmax(alm.shape[-1]))]


def alm2cl(alm1: np.ndarray, alm2: np.ndarray | None = None) -> np.ndarray:
    """Cross power spectrum of healpy-ordered alm, as healpy.alm2cl.

    Parameters
    ----------
    alm1 : numpy.ndarray, complex128, shape (nalm,)
    alm2 : numpy.ndarray, complex128, shape (nalm,), optional
        Default: alm1 (the auto spectrum).

    Returns
    -------
    numpy.ndarray, float64, shape (lmax + 1,)
    """
    alm2 = alm1 if alm2 is None else alm2
    lmax = alm_lmax(alm1.shape[-1])
    prod = (alm1 * np.conj(alm2)).real
    cl = np.zeros(lmax + 1)
    cl += prod[: lmax + 1]  # m = 0
    ell = ell_of_alm(lmax)[lmax + 1 :]
    cl += 2 * np.bincount(ell, weights=prod[lmax + 1 :], minlength=lmax + 1)
    return cl / (2 * np.arange(lmax + 1) + 1)
