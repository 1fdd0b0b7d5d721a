"""How a mask couples full-sky spectra into pseudo-C_ell (spin 0 and spin 2).

M_{l l'} = (2 l' + 1) / (4 pi) sum_L (2 L + 1) W_L (l l' L; s -s 0)^2 x parity factor, with W_L the
mask's power spectrum, so that <pseudo C_l> = sum_l' M_{l l'} C_l'. For spin 2 the even-parity
part is M^{EE,EE} = M^{BB,BB} and the odd part M^{EE,BB} = M^{BB,EE} (Brown, Castro & Taylor 2005).

A :class:`Coupling` applies M in real space, where it is a product: the pseudo-spectrum's
correlation functions are the full-sky ones times the mask's,
``xi~_+-(theta) = xi_W(theta) xi_+-(theta)``, with
``xi_+ = sum_l (2l+1)/(4 pi) (C^EE + C^BB) d^l_22`` and ``xi_-`` the same with C^EE - C^BB and
``d^l_2-2`` (Chon et al. 2004). The full-sky spectra may reach a higher band limit than the
pseudo-spectra (``band`` >= ``lmax``): a mask mixes the sky's power above lmax down into it, and a
prediction that stopped at lmax would miss it. The integrand of the way back,
``xi_W xi_+- d^l_2+-2``, is a polynomial in cos(theta) of degree <= 2 (lmax + band), with the
mask's spectrum to lmax + band (the 3j triangle's reach), so Gauss-Legendre quadrature on
lmax + band + 1 rings is exact; ducc0's ``alm2leg`` and ``leg2alm`` do the Legendre sums (one m).
That is O(lmax band), against O(lmax^2 band) for the matrices, which ducc0's
``coupling_matrix_rect`` (the routine NaMaster 2 uses) builds on first access.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import ducc0
import numpy as np
from ducc0.misc.experimental import coupling_matrix_rect
from ducc0.sht.experimental import alm2leg, leg2alm

from . import harmonics
from ._util.threads import default_threads

_M0, _M2 = np.zeros(1, dtype=np.uintp), np.full(1, 2, dtype=np.uintp)  #: ducc0's m = 0 and m = 2


@dataclass(frozen=True)
class Coupling:
    """How a mask couples full-sky spectra into pseudo-C_ell, up to ``lmax``.

    Parameters
    ----------
    mask_cl : numpy.ndarray, shape (lmax + band + 1,)
        The mask's pseudo power spectrum W_L from L = 0 (:func:`mask_spectrum`).
    lmax : int
        The pseudo-spectra's band limit.
    nthreads : int
        Threads of the transforms and of the matrices (0: all cores).
    band : int, optional
        The full-sky spectra's band limit, >= lmax (default lmax): the sky's.
    """

    mask_cl: np.ndarray
    lmax: int
    nthreads: int = 0
    band: int = None

    def __post_init__(self):
        band = self.lmax if self.band is None else self.band
        if band < self.lmax:
            raise ValueError(f"the coupling's band {band} is below its lmax {self.lmax}")
        object.__setattr__(self, "band", int(band))

    def pseudo_bb(self, cl_bb: np.ndarray, cl_ee: np.ndarray) -> np.ndarray:
        """Expected pseudo-C_BB of full-sky spectra: M^{BB,BB} C^BB + M^{BB,EE} C^EE.

        Applied in real space (module docstring); it agrees with the matrices to about 1e-15 of
        the spectrum's peak (double precision), so a spectrum that falls steeply agrees less,
        relative to itself, where it is small (7.5e-6 at l = 3998 for the r = 1 template at
        lmax 4000; docs/conventions.md). By symmetry,
        ``pseudo_bb(cl_ee, cl_bb)`` is the pseudo-C_EE.

        Parameters
        ----------
        cl_bb, cl_ee : numpy.ndarray, shape (lmax + 1,) to (band + 1,)
            [muK^2] from ell = 0, to at most the band (zero beyond where shorter); l < 2 are
            ignored.

        Returns
        -------
        numpy.ndarray, shape (lmax + 1,)
            [muK^2]; zero at l < 2.
        """
        if self.lmax < 2:
            return np.zeros(self.lmax + 1)
        theta, weighted_xi_w = self._quadrature
        n = self.band + 1
        bb, ee = np.zeros((2, n))
        m_bb, m_ee = min(n, np.size(cl_bb)), min(n, np.size(cl_ee))
        bb[2:m_bb], ee[2:m_ee] = cl_bb[2:m_bb], cl_ee[2:m_ee]
        # E <- C^EE + C^BB and B <- C^EE - C^BB give, at m = 2, xi_+ and xi_- in the two legs
        alm = (_ylm_norm(self.band) * np.array([ee + bb, ee - bb])).astype(np.complex128)
        leg = alm2leg(alm=alm, **self._legendre(self.band), theta=theta)[:, :, 0]
        xi_p = -(leg[0].real + leg[1].imag) * weighted_xi_w
        xi_m = -(leg[1].real + leg[0].imag) * weighted_xi_w
        # leg2alm is alm2leg's adjoint: these legs give E = A u + B v and B = i (A u - B v)
        back = np.array([-(xi_p + xi_m), -1j * (xi_p - xi_m)])[:, :, None]
        out = leg2alm(leg=back, **self._legendre(self.lmax), theta=theta)[1].imag
        out /= 2 * _ylm_norm(self.lmax)
        out[:2] = 0.0
        return out

    @property
    def _threads(self):
        """Threads for ducc0, which reads 0 as 1 in these routines."""
        return self.nthreads if self.nthreads > 0 else default_threads()

    def _legendre(self, lmax):
        """ducc0's Legendre-sum arguments at spin 2, m = 2, to lmax."""
        return dict(lmax=lmax, spin=2, mval=_M2, mstart=_M0, nthreads=self._threads)

    @cached_property
    def _quadrature(self):
        """Gauss-Legendre colatitudes (lmax + band + 1,) and xi_W times the weights (2 pi w_i)."""
        n_ring, lmax_w = self.lmax + self.band + 1, self.mask_cl.size - 1
        theta = ducc0.misc.GL_thetas(n_ring)
        alm = (_ylm_norm(lmax_w) * self.mask_cl)[None].astype(np.complex128)
        xi_w = alm2leg(
            alm=alm, lmax=lmax_w, theta=theta, mval=_M0, mstart=_M0, nthreads=self._threads
        )
        return theta, xi_w[0, :, 0].real * ducc0.misc.GL_weights(n_ring, 1)

    def _matrices(self, spin: int) -> np.ndarray:
        """ducc0's matrices of one spin, [l, l'] from l = 0 (l to lmax, l' to the band): (1, ...)
        TT or (2, ...) even, odd."""
        res = np.zeros((1 if spin == 0 else 2, self.lmax + 1, self.band + 1))
        coupling_matrix_rect(self.mask_cl[None], [2 * spin], res, nthreads=self._threads)
        res *= (2 * np.arange(self.band + 1) + 1)[None, None, :]
        if spin:
            res[:, :2, :] = res[:, :, :2] = 0.0  # spin-2 spectra start at l = 2
        return res

    @cached_property
    def _spin2(self):
        return self._matrices(2)

    @property
    def even(self) -> np.ndarray:
        """M^{EE,EE} = M^{BB,BB}, (lmax + 1, band + 1), built on first access (O(lmax^2 band))."""
        return self._spin2[0]

    @property
    def odd(self) -> np.ndarray:
        """M^{EE,BB} = M^{BB,EE}, (lmax + 1, band + 1), built on first access."""
        return self._spin2[1]

    @cached_property
    def tt(self) -> np.ndarray:
        """M^{TT,TT}, (lmax + 1, band + 1), built on first access."""
        return self._matrices(0)[0]


def _ylm_norm(lmax):
    """sqrt((2 l + 1) / (4 pi)), (lmax + 1,): the spherical harmonics' normalisation."""
    return np.sqrt((2 * np.arange(lmax + 1) + 1) / (4 * np.pi))


def mask_spectrum(mask: np.ndarray, lmax: int, nthreads: int = 0) -> np.ndarray:
    """Pseudo power spectrum W_L (lmax + 1,) of the mask (iteration-free, as NaMaster);
    parameters as :func:`mask_coupling`.
    """
    return harmonics.alm2cl(
        harmonics.map2alm(mask, lmax, spin=0, analysis="jacobi", iterations=0, nthreads=nthreads)
    )


def mask_coupling(
    mask: np.ndarray, lmax: int, nthreads: int = 0, *, band: int | None = None
) -> Coupling:
    """The coupling of a mask of full-sky spectra to ``band`` into pseudo-spectra to ``lmax``: its
    power spectrum to lmax + band, the 3j triangle's reach.

    Parameters
    ----------
    mask : numpy.ndarray, shape (npix,)
        RING ordering.
    lmax : int
    nthreads : int
        0: all cores.
    band : int, optional
        The full-sky spectra's band limit, >= lmax (default lmax): the sky's, so that the power
        the mask mixes down from above lmax is counted.

    Returns
    -------
    Coupling
    """
    band = lmax if band is None else band
    return Coupling(mask_spectrum(mask, lmax + band, nthreads), lmax, nthreads, band)
