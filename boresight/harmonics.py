"""Spherical-harmonic transforms on HEALPix RING maps through ducc0 (healpy's alm ordering).

Polarisation follows healpy: spin-2 transforms take (E, B) alm and give (Q, U) in the HEALPix
(COSMO) convention; ``map2alm`` mirrors healpy.map2alm with ``iter`` Jacobi iterations and no
ring weights, so that spectra agree with healpy.anafast.
"""

from functools import lru_cache

import ducc0
import numpy as np


@lru_cache(maxsize=8)
def healpix_geometry(nside):
    """ducc0 ring geometry (theta, phi0, nphi, ringstart) of a RING HEALPix map."""
    if nside < 1 or nside & (nside - 1):
        raise ValueError(f"nside must be a positive power of two, got {nside}")
    return ducc0.healpix.Healpix_Base(nside, "RING").sht_info()


def n_alm(lmax):
    """Number of alm with m <= l <= lmax (healpy ordering)."""
    return (lmax + 1) * (lmax + 2) // 2


def alm_lmax(nalm):
    """lmax of a healpy-ordered alm array of length ``nalm``."""
    return int((np.sqrt(8 * nalm + 1) - 3) / 2)


def alm2map(alm, nside, spin=0, nthreads=0):
    """alm -> map. spin 0: alm (nalm,) -> (npix,); spin >= 1: alm (2, nalm) -> (2, npix)."""
    alm = np.atleast_2d(alm)
    out = ducc0.sht.synthesis(
        alm=alm,
        lmax=alm_lmax(alm.shape[-1]),
        spin=spin,
        nthreads=nthreads,
        **healpix_geometry(nside),
    )
    return out[0] if spin == 0 else out


def alm2map_gradient(alm, nside, nthreads=0):
    """Gradient of a spin-0 field: (dT/dtheta, dT/dphi / sin theta) maps, shape (2, npix)."""
    return ducc0.sht.synthesis(
        alm=np.atleast_2d(alm),
        lmax=alm_lmax(alm.shape[-1]),
        spin=1,
        mode="DERIV1",
        nthreads=nthreads,
        **healpix_geometry(nside),
    )


def map2alm(maps, lmax, spin=0, iterations=3, nthreads=0):
    """Map -> alm as healpy.map2alm(iter=iterations, use_weights=False)."""
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


def evaluate(alm, theta, phi, spin=0, epsilon=1e-12, nthreads=0):
    """Exact band-limited evaluation of alm at arbitrary points (ducc0 synthesis_general).

    spin 0: alm (nalm,) -> (npoints,); spin 2: (E, B) alm (2, nalm) -> (Q, U), shape (2, npoints).
    ``epsilon`` is ducc0's requested relative accuracy.
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
def ell_of_alm(lmax):
    """ell of every healpy-ordered alm index up to lmax (read-only; cached per lmax)."""
    ell = np.concatenate([np.arange(m, lmax + 1) for m in range(lmax + 1)])
    ell.flags.writeable = False
    return ell


def almxfl(alm, fl):
    """Multiply alm (..., nalm) by a function of ell, fl (lmax+1,)."""
    return alm * fl[ell_of_alm(alm_lmax(alm.shape[-1]))]


def alm2cl(alm1, alm2=None):
    """Cross power spectrum of healpy-ordered alm: (lmax+1,) real, as healpy.alm2cl."""
    alm2 = alm1 if alm2 is None else alm2
    lmax = alm_lmax(alm1.shape[-1])
    prod = (alm1 * np.conj(alm2)).real
    cl = np.zeros(lmax + 1)
    cl += prod[: lmax + 1]  # m = 0
    ell = ell_of_alm(lmax)[lmax + 1 :]
    cl += 2 * np.bincount(ell, weights=prod[lmax + 1 :], minlength=lmax + 1)
    return cl / (2 * np.arange(lmax + 1) + 1)
