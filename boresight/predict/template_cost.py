"""What TOD template deprojection costs the sky: the share of E a spin-2 template takes.

Deprojection (:class:`boresight.mitigation.Deprojection`) fits each template x to the pair
difference per block, c = <x d> / <x x>, and the sky's own polarisation s = Re[e^{-2 i psi} P]
(P = Q + i U) is in d. What the fit takes of s depends on the template's spin in the pair's
angle psi. Write each template as Re[e^{-i k psi} F] with F a spin-k field of T: the gain T and
the width T_tt + T_pp (k = 0), the pointing's gradient (k = 1), the ellipticity's second
derivatives D = (T_tt - T_pp) + 2 i T_tp (k = 2, plus and cross at psi and psi + 45 deg). Then

    <x s> = 1/2 Re[<e^{i (2 - k) psi}> <F P*>] + 1/2 Re[<e^{-i (2 + k) psi}> <F P>]

over a block, and over the sky's statistics (isotropic, parity even) <F P*> is a zero-lag
correlation of spins k and 2, which vanishes unless k = 2, and <F P> one of spins k and -2,
which vanishes for every k >= 0. So the spin-0 and spin-1 templates take no definite share of
the sky, only the zero-mean chance projection of each block (not predicted here; its mean power
is of order templates x blocks / modes). The ellipticity's plus template takes::

    c = Re <D P*> / <|D|^2> = sum_l w_l lambda_l C_l^TE / sum_l w_l lambda_l^2 C_l^TT

with w_l = (2 l + 1) / (4 pi) B_l^2 (B_l the sky's beam) and lambda_l = sqrt((l + 2)! / (l - 2)!),
the E of eth^2 T (its B vanishes), its cross template nothing (<D P*> is real for a parity-even
sky). The fit removes c D from every block's Q and U: a pure E field c lambda_l T_lm, leaving

    C_l^EE,left = C_l^EE - 2 c lambda_l C_l^TE + c^2 lambda_l^2 C_l^TT,

C^BB untouched: a definite share of E, the same in every block, that neither a longer block nor a
rotation removes. The zero-lag correlation rho = <x s> / sqrt(<x x><s s>) of the plus template
with the sky's polarisation (:attr:`TemplateCost.correlation`,
``Re <D P*> / sqrt(<|D|^2> <|P|^2>)``) is the spin rule's number for the spin-2 template (-0.284
for a 60 arcmin sky at lmax 256). Checked against the mean of TOD skies
(:func:`boresight.jobs.template_check.template_cost_check`) and against numpy's regression of
Gaussian fields (``tests/predict/test_template_cost.py``).
"""

from __future__ import annotations

from typing import NamedTuple

import healpy as hp
import numpy as np

from ..constants import ARCMIN
from ..cosmology import Spectra
from ..coupling import Coupling
from ..mitigation.deprojection import TEMPLATES
from ..spectra import bin_spectrum

#: the spin in the pair's angle of each template set's templates
SPIN = {"gain": 0, "width": 0, "pointing": 1, "ellipticity": 2}


class TemplateCost(NamedTuple):
    """What the templates take of the sky's E, per ell, as the TOD reads it (beam applied).

    Attributes
    ----------
    ee, ee_left : numpy.ndarray, shape (lmax + 1,)
        C_ell^EE of the sky and of what the fit leaves [muK^2].
    bb : numpy.ndarray, shape (lmax + 1,)
        The sky's (lensing) C_ell^BB, which the fit leaves alone [muK^2].
    coefficient : float
        The ellipticity plus template's expected fit c (0 without a spin-2 template).
    correlation : float
        Its zero-lag correlation with the sky's polarisation (0 without one).
    """

    ee: np.ndarray
    ee_left: np.ndarray
    bb: np.ndarray
    coefficient: float
    correlation: float

    @property
    def kept(self) -> np.ndarray:
        """C^EE,left / C^EE per ell (1 where the sky has no E: l < 2)."""
        out = np.ones_like(self.ee)
        np.divide(self.ee_left, self.ee, out=out, where=self.ee > 0)
        return out

    def pseudo_kept(self, coupling: Coupling, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pseudo-C_EE and pseudo-C_BB kept per band through a mask's coupling: the E left
        with the sky's B over the sky's E and B (the mask leaks E into the pseudo-C_BB, so the E
        the fit takes lowers it too).

        Parameters
        ----------
        coupling : boresight.coupling.Coupling
            The footprint's, to this cost's lmax at least.
        edges : numpy.ndarray
            Bands, ``edges[i] <= ell < edges[i + 1]``.

        Returns
        -------
        (numpy.ndarray, numpy.ndarray)
            EE and BB kept per band.
        """

        def pseudo(ee):  # pseudo_bb(e, b) is the pseudo-C_EE of E and B spectra, by symmetry
            pair = (coupling.pseudo_bb(ee, self.bb), coupling.pseudo_bb(self.bb, ee))
            return np.array([bin_spectrum(x, edges)[1] for x in pair])

        kept = pseudo(self.ee_left) / pseudo(self.ee)
        return kept[0], kept[1]

    def pseudo_bb_taken(self, coupling: Coupling, window: np.ndarray | None = None) -> np.ndarray:
        """What the E taken changes in the pseudo-C_BB through a mask, per ell: M^{BB,EE}
        (C^EE,left - C^EE), the E the mask no longer leaks into B (an unpurified pipeline's; a
        purified one's B does not change).

        Parameters
        ----------
        coupling : boresight.coupling.Coupling
        window : numpy.ndarray, optional
            The maps' pixel window per ell (:func:`boresight.predict.windows.pixel_window`), to
            the cost's lmax at least; none by default.

        Returns
        -------
        numpy.ndarray, shape (coupling.lmax + 1,)
            [muK^2].
        """
        change = self.ee_left - self.ee
        if window is not None:
            change = change * np.asarray(window)[: change.size] ** 2
        return coupling.pseudo_bb(np.zeros_like(change), change)


def eth2_eigenvalue(lmax: int) -> np.ndarray:
    """lambda_l = sqrt((l + 2)! / (l - 2)!), the E of eth^2 T per T_lm, l = 0..lmax (0 at l < 2)."""
    ell = np.arange(lmax + 1, dtype=float)
    return np.sqrt(np.clip((ell + 2) * (ell + 1) * ell * (ell - 1), 0.0, None))


def template_cost(
    theory: Spectra, *, lmax: int, fwhm_arcmin: float, templates: tuple[str, ...]
) -> TemplateCost:
    """The definite share of the sky's E that deprojecting ``templates`` takes (module docstring).

    Parameters
    ----------
    theory : boresight.cosmology.Spectra
        The sky's spectra before its beam [muK^2], to at least ``lmax``.
    lmax : int
    fwhm_arcmin : float
        The sky's beam, which the TOD and the templates read it through.
    templates : tuple of str
        Template sets (:data:`boresight.mitigation.deprojection.TEMPLATES`' keys).

    Returns
    -------
    TemplateCost
    """
    unknown = sorted(set(templates) - set(TEMPLATES))
    if unknown:
        raise ValueError(f"template_cost: unknown template sets {unknown}; known: {list(SPIN)}")
    if lmax < 2 or min(theory.tt.size, theory.ee.size, theory.te.size) < lmax + 1:
        raise ValueError(f"template_cost: lmax {lmax} needs the theory's spectra to it")
    ell = np.arange(lmax + 1)
    beam2 = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=lmax) ** 2
    tt, ee, te = (
        np.array(x[: lmax + 1], dtype=float) * beam2 for x in (theory.tt, theory.ee, theory.te)
    )
    bb = np.array(theory.bb_lens[: lmax + 1], dtype=float) * beam2
    tt[:2] = ee[:2] = te[:2] = bb[:2] = 0.0
    if not any(SPIN[name] == 2 for name in templates):
        return TemplateCost(ee, ee.copy(), bb, 0.0, 0.0)
    lam = eth2_eigenvalue(lmax)
    weight = (2 * ell + 1) / (4 * np.pi)
    cross, template = np.sum(weight * lam * te), np.sum(weight * lam**2 * tt)
    c = float(cross / template)
    correlation = float(cross / np.sqrt(template * np.sum(weight * (ee + bb))))
    left = ee - 2.0 * c * lam * te + c**2 * lam**2 * tt
    return TemplateCost(ee, left, bb, c, correlation)
