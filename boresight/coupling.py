"""Pseudo-C_ell mode-coupling matrices of a mask (spin 0 and spin 2).

M_{l l'} = (2 l' + 1) / (4 pi) sum_L (2 L + 1) W_L (l l' L; s -s 0)^2 x parity factor, with W_L the
mask's power spectrum, so that <pseudo C_l> = sum_l' M_{l l'} C_l'. The Wigner-3j sums run in
ducc0's ``coupling_matrix_rect`` (the routine NaMaster 2 uses); for spin 2 the even-parity part
is M^{EE,EE} = M^{BB,BB} and the odd part M^{EE,BB} = M^{BB,EE} (Brown, Castro & Taylor 2005).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from ducc0.misc.experimental import coupling_matrix_rect

from . import harmonics


@dataclass(frozen=True)
class Coupling:
    """Pseudo-C_ell coupling matrices of a mask, each (lmax + 1, lmax + 1), [l, l'] from l = 0.

    Parameters
    ----------
    even : numpy.ndarray
        M^{EE,EE} = M^{BB,BB}.
    odd : numpy.ndarray
        M^{EE,BB} = M^{BB,EE}.
    tt : numpy.ndarray or None
        M^{TT,TT}, when asked for (no prediction uses it).
    """

    even: np.ndarray  #: M^{EE,EE} = M^{BB,BB}
    odd: np.ndarray  #: M^{EE,BB} = M^{BB,EE}
    tt: np.ndarray | None = None

    @property
    def lmax(self):
        return self.even.shape[0] - 1

    def pseudo_bb(self, cl_bb: np.ndarray, cl_ee: np.ndarray) -> np.ndarray:
        """Expected pseudo-C_BB of full-sky spectra: M^{BB,BB} C^BB + M^{BB,EE} C^EE.

        Parameters
        ----------
        cl_bb, cl_ee : numpy.ndarray, shape (>= lmax + 1,)
            [muK^2] from ell = 0.

        Returns
        -------
        numpy.ndarray, shape (lmax + 1,)
        """
        n = self.lmax + 1
        return self.even @ cl_bb[:n] + self.odd @ cl_ee[:n]


def mask_spectrum(mask: np.ndarray, lmax: int, nthreads: int = 0) -> np.ndarray:
    """Pseudo power spectrum W_L (lmax + 1,) of the mask (iteration-free, as NaMaster);
    parameters as :func:`coupling_matrices`.
    """
    return harmonics.alm2cl(harmonics.map2alm(mask, lmax, 0, "jacobi", 0, nthreads))


def coupling_matrices(mask: np.ndarray, lmax: int, nthreads: int = 0, tt: bool = False) -> Coupling:
    """The spin-2 (and TT) coupling matrices of a mask (ducc0's Wigner-3j routine, as NaMaster 2).

    Parameters
    ----------
    mask : numpy.ndarray, shape (npix,)
    lmax : int
    nthreads : int
    tt : bool
        Also M^{TT,TT} (7-18 % more time).

    Returns
    -------
    Coupling
    """
    w = mask_spectrum(mask, 2 * lmax, nthreads)
    res = np.zeros((3, lmax + 1, lmax + 1))
    threads = nthreads if nthreads > 0 else os.cpu_count()  # ducc0 reads 0 here as 1 thread
    if tt:
        coupling_matrix_rect(w[None], [0], res[0:1], nthreads=threads)
    coupling_matrix_rect(w[None], [4], res[1:3], nthreads=threads)
    res *= (2 * np.arange(lmax + 1) + 1)[None, None, :]
    res[1:, :2, :] = 0.0  # spin-2 spectra start at l = 2
    res[1:, :, :2] = 0.0
    return Coupling(even=res[1], odd=res[2], tt=res[0] if tt else None)
