"""Detector beams: elliptical Gaussian beams and their convolution with the sky by ducc0.

A detector's beam, in a frame whose x axis is its polarisation axis, is an elliptical Gaussian of
mean width sigma = FWHM / sqrt(8 ln 2), ellipticity e = (sigma_maj - sigma_min) / (sigma_maj +
sigma_min) (Shimon et al. 2008), so sigma_maj = sigma (1 + e) and sigma_min = sigma (1 - e), with
its major axis at ``angle`` from the polarisation axis, in the sense of the pointing offset's chi.
The polarised part co-rotates: the detector responds to Q cos 2 psi + U sin 2 psi over the same
shape. Its harmonic coefficients b_lk (T, E, B; k <= kmax) come from a Gauss-Legendre analysis of
the beam on the sphere (ducc0), unit integral; a circular beam gives healpy's ``blm_gauss`` window
(with the polarised part scaled by -sqrt(2), its response convention).

The engine samples each detector's sky through its own beam at every hit and at the hit's
orientation with ``ducc0.totalconvolve``: the sky's maps carry the nominal beam (the sky's FWHM),
so :class:`BeamConvolver` convolves the un-smoothed sky with the difference between a detector's
beam and the nominal one and adds that to the detector's sample.

A detector's extra signal is, exactly, a sum over the beam's azimuthal moments k of spin-k
fields of the sky times e^{-i k psi} (:func:`moment_filters`). Its temperature part is W +
Re[D* e^{2 i beta}] to the k = 4 moment, with beta its polarisation angle plus ``angle``
(docs/conventions.md): W ~ 1/2 (sigma_X^2 (1 + e^2) - sigma^2) nabla^2 T and D ~ sigma_X^2 e
eth^2 T, spin 2. Its polarised part smooths P and, for an elliptical beam, adds a spin-0 and a
spin-4 field of ~ sigma_X^2 e eth-bar^2 P and eth^2 P.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from typing import NamedTuple

import ducc0
import healpy as hp
import numpy as np

from .. import harmonics
from .._util.threads import default_threads
from ..constants import ARCMIN
from .pairs import MAX_ELLIPTICITY, PairParameters

FWHM_PER_SIGMA = np.sqrt(8.0 * np.log(2.0))
BEAM_TOLERANCE = 1e-7  #: b_lk of higher k than kmax are below this times the largest
KMAX_LIMIT = 24  #: azimuthal moments of a beam at most (e <= 0.5 needs far fewer)
MAX_RINGS = 200_000  #: Gauss-Legendre rings of a beam's analysis at most (a 0.32' axis)
MIN_AXIS_FWHM = 8.0 / MAX_RINGS * FWHM_PER_SIGMA  #: the narrowest beam axis analysed [rad]
CONVOLUTION_EPSILON = 1e-8  #: ducc0 totalconvolve accuracy, relative to the convolved signal
#: the cube's oversampling: ducc0's default search (for 1e9 samples) picks up to 2.6, with 3.5x
#: the memory and 5x the build time at Nside 512 (bench/bench_beams.py)
CUBE_OVERSAMPLING = 1.5


class Beam(NamedTuple):
    """One detector's elliptical Gaussian beam.

    fwhm : mean FWHM [rad], > 0.
    ellipticity : e in [0, 1).
    angle : direction of the major axis from the polarisation axis [rad].
    """

    fwhm: float
    ellipticity: float = 0.0
    angle: float = 0.0


def pair_beams(params: PairParameters, nominal_fwhm: float) -> list[tuple[Beam, Beam]]:
    """Detector A's and B's beam of every pair.

    Parameters
    ----------
    params : boresight.instrument.pairs.PairParameters
    nominal_fwhm : float
        The sky's FWHM [rad].

    Returns
    -------
    list of (Beam, Beam)
        One (A, B) per pair; a circular beam has angle 0.

    Raises
    ------
    ValueError
        No sky beam, a FWHM <= 0 or a (drawn) ellipticity outside [0, MAX_ELLIPTICITY].
    """
    if not nominal_fwhm >= MIN_AXIS_FWHM:
        raise ValueError(
            f"beam systematics need a sky beam: set [sky] fwhm_arcmin > 0 (at least "
            f"{MIN_AXIS_FWHM / ARCMIN:.2f})"
        )
    detectors = []
    for name, dfwhm, e, angle in (
        ("a", params.dfwhm_a, params.ellipticity_a, params.ellipticity_angle_a),
        ("b", params.dfwhm_b, params.ellipticity_b, params.ellipticity_angle_b),
    ):
        fwhm = nominal_fwhm + dfwhm
        for bad, message in (
            (~(fwhm > 0), "detector {X}'s beam FWHM is {fwhm:.4g} arcmin; dfwhm_{x}_arcmin must "
                          "keep it above 0"),
            (~((e >= 0) & (e <= MAX_ELLIPTICITY)), "ellipticity_{x} = {e:.4g} (drawn) is outside "
                                                    f"[0, {MAX_ELLIPTICITY}]"),
            (fwhm * (1 - e) < MIN_AXIS_FWHM, "detector {X}'s narrow axis, FWHM x (1 - e) = "
                                             "{axis:.3g} arcmin, is below "
                                             f"{MIN_AXIS_FWHM / ARCMIN:.2f} arcmin"),
        ):  # fmt: skip
            if bad.any():
                i = int(np.argmax(bad))
                raise ValueError(
                    f"pair {i}: "
                    + message.format(
                        X=name.upper(),
                        x=name,
                        fwhm=fwhm[i] / ARCMIN,
                        e=e[i],
                        axis=fwhm[i] * (1 - e[i]) / ARCMIN,
                    )
                )
        # one Beam per distinct (FWHM, e, angle): a focal plane of 10^6 equal pairs makes two
        rows = np.stack([fwhm, e, np.where(e > 0, angle, 0.0)], axis=1)
        if (rows == rows[:1]).all():  # equal pairs (numbers, not draws): one beam
            detectors.append([Beam(*map(float, rows[0]))] * rows.shape[0])
            continue
        unique, which = np.unique(rows, axis=0, return_inverse=True)
        beams = [Beam(float(f), float(ell), float(a)) for f, ell, a in unique]
        detectors.append([beams[j] for j in which.ravel()])
    return list(zip(*detectors))


def _axes(beam):
    """sigma_maj, sigma_min [rad] of a beam."""
    sigma = beam.fwhm / FWHM_PER_SIGMA
    return sigma * (1 + beam.ellipticity), sigma * (1 - beam.ellipticity)


def grid_points(beam: Beam, lmax: int, kmax: int = KMAX_LIMIT) -> int:
    """Points of the Gauss-Legendre grid :func:`beam_alm` analyses the beam on (its memory).

    Parameters
    ----------
    beam : Beam
    lmax, kmax : int
        As in :func:`beam_alm`.

    Returns
    -------
    int
    """
    s_maj, s_min = _axes(beam)
    nphi = 2 * (kmax + int(8 * s_maj / s_min) + 16) + 1
    return (lmax + 1 + int(np.ceil(8.0 / s_min))) * nphi


def _grid(sigma_min, lmax, kmax_guess):
    """Gauss-Legendre rings fine enough for the beam's narrowest axis, and enough azimuths for
    its elongation."""
    if 8.0 / sigma_min > MAX_RINGS:
        raise ValueError(
            f"a beam axis of sigma {sigma_min / ARCMIN:.3g} arcmin is too narrow to analyse "
            f"(FWHM x (1 - e) must be >= {8.0 / MAX_RINGS * FWHM_PER_SIGMA / ARCMIN:.2f} arcmin)"
        )
    ntheta = lmax + 1 + int(np.ceil(8.0 / sigma_min))
    nphi = 2 * (kmax_guess + 16) + 1
    return ducc0.misc.GL_thetas(ntheta), 2 * np.pi * np.arange(nphi) / nphi


@lru_cache(maxsize=16)
def beam_alm(beam: Beam, lmax: int, kmax: int = KMAX_LIMIT) -> np.ndarray:
    """Harmonic coefficients of an elliptical Gaussian polarised beam pointing at the north pole
    (cached and read-only: a schedule search predicts the same beams many times).

    Parameters
    ----------
    beam : Beam
    lmax, kmax : int
        Band limit and highest azimuthal moment.

    Returns
    -------
    numpy.ndarray, complex128, shape (3, nalm)
        T, E, B coefficients, healpy ordering with mmax = kmax, unit integral: convolving I, Q,
        U gives I + Q cos 2 psi + U sin 2 psi for a circular beam.
    """
    alpha = beam.angle
    s_maj, s_min = _axes(beam)
    theta, phi = _grid(s_min, lmax, kmax + int(8 * s_maj / s_min))
    t, p = np.meshgrid(theta, phi, indexing="ij")
    b = np.exp(
        -0.5 * t**2 * (np.cos(p - alpha) ** 2 / s_maj**2 + np.sin(p - alpha) ** 2 / s_min**2)
    )
    out = np.empty((3, hp.Alm.getsize(lmax, kmax)), dtype=np.complex128)
    out[0] = ducc0.sht.analysis_2d(map=b[None], spin=0, lmax=lmax, mmax=kmax, geometry="GL")[0]
    # polarisation along the frame's x axis, in the (e_theta, e_phi) basis
    pol = b * np.exp(-2j * p)
    out[1:] = ducc0.sht.analysis_2d(
        map=np.stack([pol.real, pol.imag]), spin=2, lmax=lmax, mmax=kmax, geometry="GL"
    )
    out /= out[0, 0].real * np.sqrt(4 * np.pi)
    out.flags.writeable = False
    return out


def _moment(blm, lmax, k):
    """b_lk for l = k..lmax of one component (healpy ordering with mmax >= k)."""
    return blm[..., hp.Alm.getidx(lmax, np.arange(k, lmax + 1), k)]


def truncate(blm: np.ndarray, lmax: int, kmax: int, tolerance: float = BEAM_TOLERANCE):
    """A beam's coefficients cut at the last azimuthal moment above ``tolerance``.

    Parameters
    ----------
    blm : numpy.ndarray, shape (3, nalm)
        Healpy ordering with mmax = kmax.
    lmax, kmax : int
    tolerance : float
        Relative to the largest ``|b_lk|``.

    Returns
    -------
    blm : numpy.ndarray, shape (3, nalm)
        Healpy ordering with mmax = k.
    k : int
        The kept kmax.
    """
    limit = tolerance * np.abs(blm).max()
    keep = max([k for k in range(kmax + 1) if np.abs(_moment(blm, lmax, k)).max() > limit] or [0])
    out = np.zeros((blm.shape[0], hp.Alm.getsize(lmax, keep)), dtype=blm.dtype)
    for k in range(keep + 1):
        out[:, hp.Alm.getidx(lmax, np.arange(k, lmax + 1), k)] = _moment(blm, lmax, k)
    return out, keep


def cube_moments(beam: Beam, nominal_fwhm: float, lmax: int) -> int:
    """The azimuthal moments of a beam's convolution cube: (beam - nominal beam)'s kmax above
    :data:`BEAM_TOLERANCE` (its analysis is cached for the convolution).

    Parameters
    ----------
    beam : Beam
    nominal_fwhm : float
        [rad].
    lmax : int

    Returns
    -------
    int
    """
    return _difference(beam, Beam(float(nominal_fwhm)), lmax)[1]


def _difference(beam, nominal, lmax):
    """(beam - nominal)'s coefficients truncated at its last moment, and that kmax."""
    return truncate(beam_alm(beam, lmax) - beam_alm(nominal, lmax), lmax, KMAX_LIMIT)


def moment_filters(beam: Beam, nominal_fwhm: float, lmax: int, kmax: int) -> np.ndarray:
    """The harmonic filters of a detector's extra signal, moment by moment in its angle.

    The signal of (beam - nominal beam) at a point, for a detector at polarisation angle psi,
    is F_0 + sum_{k > 0} 2 Re[F_k e^{-i k psi}], where F_k is a spin-k field whose harmonic
    coefficients are sum_c g[k, c, l] a^c_lm over the un-smoothed sky's T, E, B alm (healpy's
    spin-k (E', B') = -(Re, Im) of that sum; for k = 0 the sum's real and imaginary parts are
    two spin-0 fields). g = sqrt(4 pi / (2l + 1)) (b_lk - b_lk,nominal) of :func:`beam_alm` at
    the beam's own angle; the E and B rows carry the beam's smoothing of P (docs/conventions.md).

    Parameters
    ----------
    beam : Beam
    nominal_fwhm : float
        [rad].
    lmax, kmax : int

    Returns
    -------
    numpy.ndarray, complex128, shape (kmax + 1, 3, lmax + 1)
        0 below l = k, and for moments below :data:`BEAM_TOLERANCE` of the largest.
    """
    ell = np.arange(lmax + 1)
    norm = np.sqrt(4 * np.pi / (2 * ell + 1))
    diff = beam_alm(beam, lmax, kmax) - beam_alm(Beam(nominal_fwhm), lmax, kmax)
    out = np.zeros((kmax + 1, 3, lmax + 1), dtype=np.complex128)
    for k in range(kmax + 1):
        out[k, :, k:] = norm[k:] * _moment(diff, lmax, k)
    small = np.abs(out).max(axis=(1, 2)) < BEAM_TOLERANCE * np.abs(out).max()
    out[small] = 0.0  # the analysis' rounding in moments the beam has not (odd k, by symmetry)
    return out


def unsmoothed_alm(alm: np.ndarray, fwhm: float) -> np.ndarray:
    """A sky's T, E, B alm with its Gaussian beam (healpy.gauss_beam, polarised) divided out.

    Parameters
    ----------
    alm : numpy.ndarray, complex128, shape (3, nalm)
    fwhm : float
        [rad].

    Returns
    -------
    numpy.ndarray, complex128, shape (3, nalm)
    """
    lmax = harmonics.alm_lmax(alm.shape[1])
    beam = hp.gauss_beam(fwhm, lmax=lmax, pol=True)
    if beam[-1, 0] < 1e-280:
        raise ValueError(
            f"a {fwhm / ARCMIN:.4g} arcmin beam leaves nothing of the sky at l = {lmax}: lower lmax"
        )
    return np.stack([harmonics.almxfl(alm[c], 1.0 / beam[:, c]) for c in range(3)])


#: the sky's components each part of a detector's signal comes from (T, E, B)
PARTS = {"all": (0, 1, 2), "T": (0,), "P": (1, 2)}


def turned(beam: Beam, angle: float) -> Beam:
    """The beam with its major axis ``angle`` [rad] further from its polarisation axis (a
    circular beam as it is)."""
    return beam._replace(angle=beam.angle + angle) if beam.ellipticity > 0 else beam


class BeamConvolver:
    """Each detector's extra signal from its beam: the sky convolved with (beam - nominal beam).

    Parameters
    ----------
    alm : numpy.ndarray, complex128, shape (3, nalm)
        The sky's T, E, B with the nominal beam [muK].
    nominal_fwhm : float
        The sky's beam [rad], > 0.
    nthreads : int

    Notes
    -----
    One convolution cube per distinct beam, built on first use and kept: (2 kmax + 1) planes of
    the sky on a (theta, phi) grid oversampled 1.5 times, in doubles, whatever the number of
    components: 2.9 GiB for e = 0.03 at Nside 512 (``bench/bench_beams.py`` measures it to
    Nside 1024). ducc0's plane transforms round differently on different thread counts (3e-13),
    so each plane is made on one thread, the planes in parallel, the components added in a fixed
    order: the cube, and ducc0's interpolation from it, do not depend on ``nthreads``.
    """

    def __init__(self, alm, nominal_fwhm, nthreads=0):
        if not nominal_fwhm > 0:
            raise ValueError("beam systematics need a sky beam: set [sky] fwhm_arcmin > 0")
        self.lmax = harmonics.alm_lmax(alm.shape[1])
        self.nominal = Beam(float(nominal_fwhm))
        self.nthreads = nthreads if nthreads > 0 else default_threads()
        self._sky = unsmoothed_alm(alm, nominal_fwhm)
        self._cubes = {}

    def _plan(self, kmax, nthreads):
        return ducc0.totalconvolve.ConvolverPlan(
            self.lmax,
            kmax,
            sigma=CUBE_OVERSAMPLING,
            epsilon=CONVOLUTION_EPSILON,
            nthreads=nthreads,
        )

    def _cube(self, beam, part):
        """(plan, cube) of one beam: the planes of (beam - nominal) x the sky's components of
        ``part`` (:data:`PARTS`), prepared for psi."""
        if (beam, part) in self._cubes:
            return self._cubes[beam, part]
        diff, kmax = _difference(beam, self.nominal, self.lmax)
        components = [c for c in PARTS[part] if c < diff.shape[0]]
        plan = self._plan(kmax, 1)
        cube = np.zeros((plan.Npsi(), plan.Ntheta(), plan.Nphi()))

        def planes(k):  # moment k of the beam: 1 plane for k = 0, else re and im
            rows = slice(0, 1) if k == 0 else slice(2 * k - 1, 2 * k + 1)
            own, out = self._plan(kmax, 1), np.empty_like(cube[rows])
            for c in components:
                own.getPlane(self._sky[c], diff[c], k, out)
                cube[rows] += out

        with ThreadPoolExecutor(max_workers=self.nthreads) as pool:
            list(pool.map(planes, range(kmax + 1)))
        plan.prepPsi(cube)
        self._cubes[beam, part] = (self._plan(kmax, self.nthreads), cube)
        return self._cubes[beam, part]

    def extra(
        self, beam: Beam, theta: np.ndarray, phi: np.ndarray, psi: np.ndarray, *, part: str = "all"
    ) -> np.ndarray:
        """A detector's extra signal where it looks.

        Parameters
        ----------
        beam : Beam
        theta, phi : numpy.ndarray, shape (n,)
            Where the detector looks [rad]; phi in [0, 2 pi).
        psi : numpy.ndarray, shape (n,)
            Its polarisation angle [rad], any value.
        part : {"all", "T", "P"}
            The signal from the whole sky, its T alone or its polarisation alone (their sum is
            the whole; behind a HWP they turn with different angles, :func:`behind_hwp`).

        Returns
        -------
        numpy.ndarray, shape (n,)
            [muK]; zero for the nominal beam.
        """
        out = np.zeros(np.size(theta))
        if beam == self.nominal:
            return out
        plan, cube = self._cube(beam, part)
        as_array = (np.ascontiguousarray(x, dtype=np.float64) for x in (theta, phi, psi))
        plan.interpol(cube, 0, 0, *as_array, out)
        return out

    def behind_hwp(self, beam, theta, phi, *, shape, delta) -> np.ndarray:
        """A detector's extra signal behind a HWP: its beam's shape at ``shape`` (its own
        polarisation angle, with the focal plane), its polarisation axis at ``shape + delta``
        (where the HWP turns it).

        The T part turns with the shape alone. The polarised part is Re(exp(-2 i delta) C), C of
        the beam with both axes at ``shape``, so it is cos 2 delta times that beam's and
        sin 2 delta times that of the beam whose polarisation axis is 45 deg further from its
        major axis (:func:`turned` by -45 deg), read at ``shape`` + 45 deg (docs/conventions.md).

        Parameters
        ----------
        beam : Beam
        theta, phi, shape, delta : numpy.ndarray, shape (n,)
            [rad].

        Returns
        -------
        numpy.ndarray, shape (n,)
            [muK].
        """
        quarter = 0.25 * np.pi
        return (
            self.extra(beam, theta, phi, shape, part="T")
            + np.cos(2 * delta) * self.extra(beam, theta, phi, shape, part="P")
            + np.sin(2 * delta)
            * self.extra(turned(beam, -quarter), theta, phi, shape + quarter, part="P")
        )
