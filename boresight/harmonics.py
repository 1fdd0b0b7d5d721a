"""Spherical-harmonic transforms on HEALPix RING maps through ducc0 (healpy's alm ordering).

Polarisation follows healpy: spin-2 transforms take (E, B) alm and give (Q, U) in the HEALPix
(COSMO) convention. ``map2alm`` offers three analyses (:data:`ANALYSES`): one pass with HEALPix
ring weights (the quadrature a band-limited integrand needs, exact enough at lmax <= 2 Nside), the
Jacobi iterations of healpy.map2alm (``iter``, no weights: healpy.anafast's spectra), and ducc0's
least-squares ``pseudo_analysis``; ``"auto"`` takes the first at lmax <= 2 Nside (away from the
poles) and the last above.
"""

from __future__ import annotations

import os
from functools import lru_cache

import ducc0
import healpy as hp
import numpy as np

#: map2alm's analyses (:func:`resolve_analysis` says what "auto" runs)
ANALYSES = ("auto", "ring_weights", "jacobi", "lsqr")
#: pseudo_analysis's relative tolerance and iteration cap: the residual pseudo-C_BB, a difference
#: of small maps, needs 1e-4 of its power; LSQR reaches 1e-8 in the map's norm in tens of steps
LSQR_EPSILON = 1e-8
LSQR_MAXITER = 100
#: "auto" keeps Jacobi iterations for maps with weight this close to a pole [rad]
POLE_GUARD_RAD = 0.1


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


@lru_cache(maxsize=8)
def ring_weights(nside: int) -> np.ndarray:
    """HEALPix ring weights 1 + w_ring (healpy's ``weight_ring_n*.fits``, shipped in its wheel),
    one per ring, north to south (cached, read-only).

    With them the sum over each ring of a map times 4 pi / npix is the quadrature of a
    pseudo-alm: at lmax <= 2 Nside and away from the poles it matches the exact integral to a few
    1e-6 in the spectra (tests/test_spectra.py).

    Parameters
    ----------
    nside : int

    Returns
    -------
    numpy.ndarray, shape (4 nside - 1,)
    """
    from astropy.io import fits

    path = os.path.join(os.path.dirname(hp.__file__), "data", f"weight_ring_n{nside:05d}.fits")
    with fits.open(path) as hdul:
        north = 1.0 + np.asarray(hdul[1].data.field(0), dtype=np.float64).ravel()
    out = np.concatenate([north, north[-2::-1]])  # rings 1..2 nside, mirrored about the equator
    out.flags.writeable = False
    return out


def resolve_analysis(analysis: str, maps: np.ndarray, lmax: int) -> str:
    """The analysis ``map2alm`` runs on ``maps``.

    ``"auto"`` is ring weights at lmax <= 2 Nside, unless the maps have weight within
    :data:`POLE_GUARD_RAD` of a pole, and LSQR otherwise. Near a pole the rings are too short
    for the quadrature: a mask that reaches the pole left 0.8 % in the pseudo-C_BB bands of an
    analytic test at Nside 256 (Jacobi: 6e-5), one that stops 6 degrees short 9e-5.

    Parameters
    ----------
    analysis : str
        One of :data:`ANALYSES`.
    maps : numpy.ndarray, shape (..., npix)
    lmax : int

    Returns
    -------
    str
        "ring_weights", "jacobi" or "lsqr".
    """
    nside = int(round(np.sqrt(maps.shape[-1] / 12)))
    return _resolve(analysis, maps, lmax, nside, np.arange(maps.shape[-1]))


def _resolve(analysis, values, lmax, nside, pixels):
    """:func:`resolve_analysis` of a map that is ``values`` (..., n) on increasing ``pixels`` (n,)
    and zero elsewhere."""
    if analysis not in ANALYSES:
        raise ValueError(f"analysis = {analysis!r}; allowed: {ANALYSES}")
    if analysis != "auto":
        return analysis
    if lmax > 2 * nside:
        return "lsqr"
    # the rings i with cos(theta) = 1 - i^2 / (3 nside^2) inside the guard hold 2 i (i + 1) pixels
    rings = int(np.ceil(nside * np.sqrt(3 * (1 - np.cos(POLE_GUARD_RAD)))))
    cap = 2 * rings * (rings + 1)
    north, south = np.searchsorted(pixels, [cap, 12 * nside**2 - cap])
    near_pole = np.any(values[..., :north]) or np.any(values[..., south:])
    return "jacobi" if near_pole else "ring_weights"


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


def alm2map(
    alm: np.ndarray,
    nside: int,
    *,
    spin: int = 0,
    nthreads: int = 0,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Synthesis: alm -> RING map.

    Parameters
    ----------
    alm : numpy.ndarray, complex128
        (nalm,) for spin 0; (2, nalm) (E, B) for spin >= 1.
    nside : int
    spin : int
    nthreads : int
    out : numpy.ndarray, float64, optional
        Where to write the map, of the returned shape; any strides (a view into an interleaved
        stack is written in place).

    Returns
    -------
    numpy.ndarray
        (npix,) for spin 0; (2, npix) (Q, U, COSMO) otherwise.
    """
    alm = np.atleast_2d(alm)
    maps = ducc0.sht.synthesis(
        alm=alm,
        lmax=alm_lmax(alm.shape[-1]),
        spin=spin,
        nthreads=nthreads,
        map=None if out is None else out[None] if out.ndim == 1 else out,
        **healpix_geometry(nside),
    )
    return maps[0] if spin == 0 else maps


def alm2map_gradient(
    alm: np.ndarray, nside: int, nthreads: int = 0, pixels: np.ndarray | None = None
) -> np.ndarray:
    """Gradient of a spin-0 field, on every pixel or, as :func:`alm2map_pixels`, on some.

    Parameters
    ----------
    alm : numpy.ndarray, complex128, shape (nalm,)
    nside : int
    nthreads : int
    pixels : numpy.ndarray of int, shape (n,), optional
        RING indices, increasing (default: every pixel).

    Returns
    -------
    numpy.ndarray, shape (2, npix) or (2, n)
        dT/dtheta and dT/dphi / sin(theta).
    """
    alm = np.atleast_2d(alm)
    options = dict(alm=alm, lmax=alm_lmax(alm.shape[-1]), spin=1, mode="DERIV1", nthreads=nthreads)
    if pixels is None:
        return ducc0.sht.synthesis(**options, **healpix_geometry(nside))
    return _synthesis_on_pixels(options, pixels, nside)


def map2alm(
    maps: np.ndarray,
    lmax: int,
    *,
    spin: int = 0,
    analysis: str = "auto",
    iterations: int = 3,
    nthreads: int = 0,
) -> np.ndarray:
    """Analysis: RING map -> alm.

    Parameters
    ----------
    maps : array_like
        (npix,) for spin 0; (2, npix) Q, U for spin 2.
    lmax : int
    spin : int
    analysis : str
        One of :data:`ANALYSES`: ``"ring_weights"``, one adjoint pass with the HEALPix ring
        weights; ``"jacobi"``, healpy.map2alm(iter=iterations, use_weights=False);
        ``"lsqr"``, ducc0's pseudo_analysis to :data:`LSQR_EPSILON`; ``"auto"``
        (:func:`resolve_analysis`).
    iterations : int
        Jacobi iterations (3 is anafast's default); ``"jacobi"`` only.
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
    analysis = resolve_analysis(analysis, maps, lmax)
    common = dict(lmax=lmax, spin=spin, nthreads=nthreads)
    if analysis == "ring_weights" or (analysis == "jacobi" and iterations == 0):
        keep = np.logical_or.reduceat(np.any(maps, axis=0), geom["ringstart"].astype(np.int64))
        alm = _single_pass(maps, geom, keep, analysis, **common)
    elif analysis == "lsqr":
        alm = ducc0.sht.pseudo_analysis(
            map=maps, maxiter=LSQR_MAXITER, epsilon=LSQR_EPSILON, **common, **geom
        )[0]
    else:
        alm = ducc0.sht.adjoint_synthesis(map=maps, **common, **geom)
        alm *= scale
        for _ in range(iterations):  # in place: full-sky temporaries cost as much as a transform
            resid = ducc0.sht.synthesis(alm=alm, **common, **geom)
            np.subtract(maps, resid, out=resid)
            step = ducc0.sht.adjoint_synthesis(map=resid, **common, **geom)
            step *= scale
            alm += step
    return alm[0] if spin == 0 else alm


def _single_pass(maps, geom, keep, analysis, **common):
    """One adjoint pass over the rings ``keep`` (nring,) of ``maps`` laid out as ``geom``.

    The rings left out must hold no data: they would add exactly nothing. A survey mask's rings are
    the wide one's 46 % and the deep one's 27 %; time and scratch memory scale with them.
    """
    nside = (len(keep) + 1) // 4
    keep = keep.copy()
    keep[0] = True  # ducc0 needs a ring: zero maps give zero alm
    weights = ring_weights(nside) if analysis == "ring_weights" else np.ones(keep.size)
    scale = 4 * np.pi / (12 * nside**2)
    return ducc0.sht.adjoint_synthesis(
        map=maps,
        ringfactor=scale * weights[keep],
        **{key: value[keep] for key, value in geom.items()},
        **common,
    )


class _PackedRings:
    """Some rings of a HEALPix RING map stored one after another, and where increasing
    ``pixels`` lie among them: a map that lives on those pixels is transformed through this
    layout, never as a full-sky map.

    Parameters
    ----------
    nside : int
    pixels : numpy.ndarray, int64, shape (n,)
        RING indices, increasing.
    values : numpy.ndarray, shape (..., n), optional
        Store only the rings where these are nonzero (the rings :func:`map2alm` reads); by
        default every ring that holds a pixel. Ring 0 always is stored (ducc0 needs a ring).
    """

    def __init__(self, nside, pixels, values=None):
        geom = healpix_geometry(nside)
        self._ringstart = geom["ringstart"].astype(np.int64)
        bounds = np.searchsorted(pixels, np.append(self._ringstart, 12 * nside**2))
        if values is None:
            self.keep = bounds[1:] > bounds[:-1]
        else:
            self.keep = np.array([np.any(values[..., a:b]) for a, b in zip(bounds, bounds[1:])])
        self.keep[0] = True
        self._bounds = bounds
        nphi = geom["nphi"][self.keep]
        self.size = int(nphi.sum())
        #: the full geometry with the kept rings' starts in the packed array (for _single_pass)
        self.geometry = dict(geom, ringstart=np.zeros_like(geom["ringstart"]))
        self.geometry["ringstart"][self.keep] = np.cumsum(nphi) - nphi
        self._pixels = pixels

    def _slices(self):
        """(slice of ``pixels``, their positions in the packed array) per kept ring."""
        starts = self.geometry["ringstart"].astype(np.int64)
        for ring in np.flatnonzero(self.keep):
            a, b = self._bounds[ring], self._bounds[ring + 1]
            yield slice(a, b), starts[ring] + self._pixels[a:b] - self._ringstart[ring]

    def pack(self, values):
        """(..., n) values on the pixels -> (..., size) packed rings, 0 elsewhere."""
        packed = np.zeros(values.shape[:-1] + (self.size,))
        for at, to in self._slices():
            packed[..., to] = values[..., at]
        return packed

    def unpack(self, packed):
        """(..., size) packed rings -> (..., n) values on the pixels."""
        values = np.empty(packed.shape[:-1] + (self._pixels.size,))
        for at, to in self._slices():
            values[..., at] = packed[..., to]
        return values


def map2alm_pixels(
    values: np.ndarray,
    pixels: np.ndarray,
    nside: int,
    lmax: int,
    *,
    spin: int = 0,
    analysis: str = "auto",
    nthreads: int = 0,
) -> np.ndarray:
    """:func:`map2alm` of a map given by its values on some pixels and zero elsewhere.

    A single-pass analysis packs the rings that hold data into one array and never makes the
    full-sky map (at Nside 2048 the wide survey's Q, U take 0.37 GB so, not 0.8 GB); the same
    rings are read as :func:`map2alm` reads, so the alm are the same to the last bit. Iterative
    analyses run on the full-sky map.

    Parameters
    ----------
    values : array_like
        (n,) for spin 0; (2, n) Q, U for spin 2.
    pixels : numpy.ndarray of int, shape (n,)
        RING indices, increasing.
    nside, lmax, spin : int
    analysis : str
        As :func:`map2alm` (Jacobi with its default 3 iterations).
    nthreads : int

    Returns
    -------
    numpy.ndarray, complex128
        (nalm,) for spin 0; (2, nalm) (E, B) otherwise.
    """
    values = np.atleast_2d(np.asarray(values, dtype=np.float64))
    pixels = np.asarray(pixels, dtype=np.int64)
    analysis = _resolve(analysis, values, lmax, nside, pixels)
    if analysis != "ring_weights":
        maps = np.zeros((values.shape[0], 12 * nside**2))
        maps[:, pixels] = values
        return map2alm(maps, lmax, spin=spin, analysis=analysis, nthreads=nthreads)
    rings = _PackedRings(nside, pixels, values)
    alm = _single_pass(
        rings.pack(values),
        rings.geometry,
        rings.keep,
        analysis,
        lmax=lmax,
        spin=spin,
        nthreads=nthreads,
    )
    return alm[0] if spin == 0 else alm


def alm2map_pixels(
    alm: np.ndarray, pixels: np.ndarray, nside: int, *, spin: int = 0, nthreads: int = 0
) -> np.ndarray:
    """:func:`alm2map` on some pixels only: the rings that hold them are synthesised into one
    packed array, so no full-sky map is made (at Nside 2048 the wide survey's Q, U take 0.37 GB
    so, not 0.8 GB). The values are the full-sky map's to rounding (2e-14 of its largest value
    in tests/test_spectra.py): ducc0 pairs each ring with its mirror ring only when both are
    synthesised.

    Parameters
    ----------
    alm : numpy.ndarray, complex128
        (nalm,) for spin 0; (2, nalm) (E, B) for spin >= 1.
    pixels : numpy.ndarray of int, shape (n,)
        RING indices, increasing.
    nside, spin, nthreads : int

    Returns
    -------
    numpy.ndarray
        (n,) for spin 0; (2, n) (Q, U, COSMO) otherwise.
    """
    alm = np.atleast_2d(alm)
    options = dict(alm=alm, lmax=alm_lmax(alm.shape[-1]), spin=spin, nthreads=nthreads)
    values = _synthesis_on_pixels(options, pixels, nside)
    return values[0] if spin == 0 else values


def _synthesis_on_pixels(options, pixels, nside):
    """ducc0's synthesis with ``options`` on the rings that hold ``pixels``, packed, then read at
    the pixels: (ncomp, n)."""
    rings = _PackedRings(nside, np.asarray(pixels, dtype=np.int64))
    geometry = {key: value[rings.keep] for key, value in rings.geometry.items()}
    packed = np.empty((1 if options["spin"] == 0 else 2, rings.size))
    return rings.unpack(ducc0.sht.synthesis(**options, map=packed, **geometry))


def evaluate(
    alm: np.ndarray,
    theta: np.ndarray,
    phi: np.ndarray,
    *,
    spin: int = 0,
    mode: str = "STANDARD",
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
    mode : str
        ducc0's: ``"STANDARD"``; ``"GRAD_ONLY"`` (a spin > 0 alm's gradient part alone, given as
        (nalm,)); ``"DERIV1"``, a spin-0 alm's gradient (dT/dtheta, dT/dphi / sin theta).
    epsilon : float
        ducc0's requested relative accuracy.
    nthreads : int

    Returns
    -------
    numpy.ndarray
        (n,) for spin 0; (2, n) Q, U for spin 2 (or the gradient's two components).
    """
    alm = np.atleast_2d(alm)
    loc = np.empty((theta.size, 2))
    loc[:, 0] = theta
    loc[:, 1] = phi
    out = ducc0.sht.synthesis_general(
        alm=alm,
        spin=1 if mode == "DERIV1" else spin,
        lmax=alm_lmax(alm.shape[-1]),
        loc=loc,
        epsilon=epsilon,
        nthreads=nthreads,
        mode=mode,
    )
    return out[0] if spin == 0 and mode == "STANDARD" else out


def m_runs(lmax: int):
    """Each m's run of healpy-ordered alm (l = m..lmax): the loops of :func:`almxfl` and
    :func:`alm2cl`, which need no (nalm,) index array (256 MB at lmax 8000).

    Parameters
    ----------
    lmax : int

    Yields
    ------
    m : int
    run : slice
        Its alm indices.
    """
    start = 0
    for m in range(lmax + 1):
        yield m, slice(start, start + lmax + 1 - m)
        start += lmax + 1 - m


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
    lmax = alm_lmax(alm.shape[-1])
    out = np.empty(alm.shape, dtype=np.result_type(alm, fl))
    for m, run in m_runs(lmax):
        out[..., run] = alm[..., run] * fl[m : lmax + 1]
    return out


@lru_cache(maxsize=8)
def _by_ell(lmax: int) -> tuple:
    """The healpy-ordered alm of lmax reordered by l (m = 0..l within each l): the permutation,
    each l's start in it, and each alm's weight in a real field's power (1 at m = 0, 2 else)."""
    ell, m = hp.Alm.getlm(lmax)
    order = np.lexsort((m, ell))
    starts = np.concatenate([[0], np.cumsum(np.arange(1, lmax + 2))])
    return order, starts, np.where(m[order] == 0, 1.0, 2.0)


def alm_cross_spectra(alms: np.ndarray, lmax: int | None = None) -> np.ndarray:
    """Every cross power spectrum of a set of healpy-ordered alm at once, as
    :func:`alm2cl` of each pair: C^ab_l = sum_m w_m Re(a_lm conj(b_lm)) / (2 l + 1), w_m = 1 at
    m = 0 and 2 else (one matrix product per l).

    Parameters
    ----------
    alms : numpy.ndarray, complex128, shape (J, nalm)
    lmax : int, optional
        The spectra's band limit (default the alm's).

    Returns
    -------
    numpy.ndarray, float64, shape (J, J, lmax + 1)
    """
    full = alm_lmax(alms.shape[-1])
    lmax = full if lmax is None else lmax
    order, starts, weight = _by_ell(full)
    x = alms[:, order[: starts[lmax + 1]]]
    out = np.empty((alms.shape[0], alms.shape[0], lmax + 1))
    for ell in range(lmax + 1):
        run = slice(starts[ell], starts[ell + 1])
        y = x[:, run]
        out[:, :, ell] = ((y * weight[run]) @ y.conj().T).real / (2 * ell + 1)
    return out


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
    cl = np.zeros(lmax + 1)  # m = 0
    m_sum = np.zeros(lmax + 1)  # m >= 1, summed in order of m
    for m, run in m_runs(lmax):  # Re(a1 conj(a2)) one run at a time: no (nalm,) temporaries
        a, b = alm1[run], alm2[run]
        prod = a.real * b.real + a.imag * b.imag
        if m:
            m_sum[m:] += prod
        else:
            cl += prod
    cl += 2 * m_sum
    return cl / (2 * np.arange(lmax + 1) + 1)
