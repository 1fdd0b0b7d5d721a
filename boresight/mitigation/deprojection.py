"""Template deprojection, as BICEP/Keck run it: templates of the temperature sky regressed from
each pair difference, block by block, and the fit subtracted.

A pair whose detectors differ in gain, pointing or beam leaks the temperature sky T into its pair
difference through a fixed combination of T and its derivatives at the pair's centre. In the
engine's picture of a pair (:func:`boresight.kernels.cpu.offset_points`: detector B displaced by
rho along beta = psi + chi in (theta, phi sin theta)), to second order in rho::

    T(B) - T(A) = rho [cos beta T_t + sin beta T_p] + rho^2 / 4 [(T_tt + T_pp)
                  + cos 2 beta (T_tt - T_pp) + sin 2 beta 2 T_tp]

with T_t = dT/dtheta, T_p = dT/dphi / sin theta and T_tt, T_tp, T_pp the second derivatives in the
same coordinates. Each term is a constant times a template once beta is split into the pair's
angle psi (which varies along the scan) and the offset's own angle chi (constant):

=================  =====================================================================
``gain``           T
``pointing``       x: cos psi T_t + sin psi T_p; y: -sin psi T_t + cos psi T_p
``width``          T_tt + T_pp
``ellipticity``    plus: cos 2 psi (T_tt - T_pp) + sin 2 psi 2 T_tp; cross: the same at psi + 45 deg
=================  =====================================================================

(BK-III's six templates: relative gain, differential pointing in focal-plane x and y, beam width,
ellipticity plus and cross.) A leak whose coefficients are constant within a block is removed by
the regression exactly, whatever the scan's h_n; what remains is the leak beyond these orders,
the systematic's drift within the block, and the sky's own polarisation that the templates
happen to fit (the cost).

T is the value the engine reads for detector A (interpolated, exact or per pixel, as the run's
``evaluation``); its derivatives are the sky's beam-smoothed alm evaluated exactly at the samples
(ducc0 ``synthesis_general``: spin 1 for the gradient, spin 2 and the Laplacian for the second
derivatives). A template of a pair at another angle is a constant rotation of these, which spans
the same space. With ``template_map`` (a HEALPix FITS map of T, a Planck-like map with its own
noise and beam) the templates are read from that map instead, T and its derivatives from its alm
(:func:`template_alm`): what is left of a leak is then the leak of T less the template.

Written as text (the CLI's ``--deproject``), a deprojection is its template sets joined by
``,`` or ``+``: ``gain,pointing``; ``bk`` is all four. A pipeline's filters carry it
(:class:`~boresight.mitigation.filtering.Filtering`, ``deproject(gain,pointing)`` in its text). The block is one CES, as the filters' (BICEP/Keck
regress per phase, a few CESs). The regression leaves a CES's turnarounds out of the fit, as the
filters do, and subtracts the fit from every sample.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import healpy as hp
import numpy as np

from .. import harmonics, validation
from .._util.io import FRAME_CARDS

#: each template set and the templates it regresses, in the regression's order
TEMPLATES = {
    "gain": ("gain",),
    "pointing": ("pointing x", "pointing y"),
    "width": ("width",),
    "ellipticity": ("ellipticity plus", "ellipticity cross"),
}

#: what ``bk`` stands for
BK = tuple(TEMPLATES)

#: a block whose normalised templates have a smallest singular value below this fraction of the
#: largest is degenerate (collinear templates)
DEGENERATE = 1e-9

#: ducc0's accuracy for the templates' derivatives
EPSILON = 1e-12


@dataclass(frozen=True)
class Deprojection:
    """The templates a pipeline regresses from each pair difference, per CES.

    Parameters
    ----------
    templates : tuple of str
        Template sets from :data:`TEMPLATES` (none by default); kept in that order.
    block_hours : float, optional
        Regress once per this many hours of consecutive CESs; None: once per CES.
    template_map : str, optional
        A HEALPix FITS map of T to read the templates from (the sky's own T by default); not
        part of the text.
    """

    templates: tuple[str, ...] = ()
    block_hours: float | None = None
    template_map: str | None = None

    def __post_init__(self):
        if self.block_hours is not None:
            hours = validation.number("deprojection block_hours", self.block_hours, 0.0, 1e5)
            if hours <= 0:
                raise ValueError(f"deprojection block_hours = {hours} must be > 0")
        names = tuple(self.templates)
        unknown = [name for name in names if name not in TEMPLATES]
        if unknown:
            raise ValueError(
                f"deprojection templates {unknown}: choose from {', '.join(TEMPLATES)} "
                "(or bk for all), joined by ','"
            )
        if len(set(names)) != len(names):
            raise ValueError(f"deprojection templates {list(names)}: one of them twice")
        object.__setattr__(self, "templates", tuple(n for n in TEMPLATES if n in names))

    def __bool__(self) -> bool:
        return bool(self.templates)

    @property
    def names(self) -> tuple[str, ...]:
        """Every template regressed, in order (two for pointing and for ellipticity)."""
        return tuple(one for name in self.templates for one in TEMPLATES[name])

    @property
    def n_templates(self) -> int:
        return len(self.names)

    @property
    def derivatives(self) -> int:
        """The highest derivative of T its templates need (0, 1 or 2)."""
        order = {"gain": 0, "pointing": 1, "width": 2, "ellipticity": 2}
        return max((order[name] for name in self.templates), default=0)

    @classmethod
    def parse(cls, text: str) -> Deprojection:
        """A deprojection from its text (the module's docstring), e.g. ``"gain+pointing"`` or
        ``"bk/10h"``."""
        text = text.strip().lower()
        text, _, block = text.partition("/")
        hours = None
        if block.strip() not in ("", "ces"):
            match = re.fullmatch(r"([0-9.]+(?:e[-+]?[0-9]+)?)h", block.strip())
            if match is None:
                raise ValueError(
                    f"deprojection block {block!r}: write ces or <hours>h after '/' (e.g. bk/10h)"
                )
            hours = float(match.group(1))
        if text.strip() in ("", "none"):
            return cls(block_hours=hours)
        if text.strip() == "bk":
            return cls(BK, hours)
        return cls(tuple(part.strip() for part in text.replace("+", ",").split(",")), hours)

    def __str__(self) -> str:
        names = "bk" if self.templates == BK else ",".join(self.templates) or "none"
        return names if self.block_hours is None else f"{names}/{self.block_hours:g}h"

    def blocks(self, ces) -> list:
        """The blocks of a schedule's CESs: (name, indices of its CESs), in order.

        Parameters
        ----------
        ces : sequence of boresight.schedule.CES
            In observing order.

        Returns
        -------
        list of (str, list of int)
        """
        if self.block_hours is None:
            return [(f"CES {i}", [i]) for i in range(len(ces))]
        out, first = [], None
        for i, one in enumerate(ces):
            if first is None or one.start_unix >= first + 3600.0 * self.block_hours:
                first = one.start_unix
                out.append([])
            out[-1].append(i)
        return [(f"block {k} (CES {m[0]}-{m[-1]})", m) for k, m in enumerate(out)]

    def templates_at(
        self,
        alm: np.ndarray,
        value: np.ndarray,
        theta: np.ndarray,
        phi: np.ndarray,
        psi: np.ndarray,
        *,
        nthreads: int = 0,
    ) -> np.ndarray:
        """The templates along one stream of samples.

        Parameters
        ----------
        alm : numpy.ndarray, complex128, shape (nalm,)
            The temperature sky's beam-smoothed alm (or the template map's).
        value : numpy.ndarray, shape (n,)
            T as the engine reads it at the samples (the gain template; the template map's alm
            at the samples).
        theta, phi, psi : numpy.ndarray, shape (n,)
            The pair's pointing and angle [rad].
        nthreads : int

        Returns
        -------
        numpy.ndarray, shape (n_templates, n)
            In the order of :attr:`names`.
        """
        out, rows = [], {}
        if self.derivatives >= 1:
            rows["t"], rows["p"] = gradient(alm, theta, phi, nthreads=nthreads)
        if self.derivatives >= 2:
            rows["tt"], rows["tp"], rows["pp"] = second_derivatives(
                alm, theta, phi, gradient=(rows["t"], rows["p"]), nthreads=nthreads
            )
        cos, sin = np.cos(psi), np.sin(psi)
        for name in self.templates:
            if name == "gain":
                out.append(np.asarray(value, dtype=np.float64))
            elif name == "pointing":
                out += [cos * rows["t"] + sin * rows["p"], -sin * rows["t"] + cos * rows["p"]]
            elif name == "width":
                out.append(rows["tt"] + rows["pp"])
            else:
                minus, cross = rows["tt"] - rows["pp"], 2.0 * rows["tp"]
                cos2, sin2 = cos**2 - sin**2, 2.0 * sin * cos
                out += [cos2 * minus + sin2 * cross, -sin2 * minus + cos2 * cross]
        return np.array(out)

    def apply(self, signal: np.ndarray, templates: np.ndarray, fit: np.ndarray, *, block: str):
        """One block's streams with their templates' least-squares fit subtracted.

        Parameters
        ----------
        signal : numpy.ndarray, shape (n_signals, n)
        templates : numpy.ndarray, shape (n_templates, n) or (n_signals, n_templates, n)
            One set for every stream, or each stream's own.
        fit : numpy.ndarray of bool, shape (n,)
            The samples the fit sees (its result is subtracted from all).
        block : str
            The block's name, for the error.

        Returns
        -------
        numpy.ndarray
            A new array shaped as ``signal``.

        Raises
        ------
        ValueError
            A block with no more samples to fit than templates, or whose templates are collinear.
        """
        signal = np.atleast_2d(np.asarray(signal, dtype=np.float64))
        shared = templates.ndim == 2
        n_fit = int(np.count_nonzero(fit))
        if n_fit <= self.n_templates:
            raise ValueError(
                f"deprojection ({self}) of {block}: {n_fit} samples to fit, no more than its "
                f"{self.n_templates} templates"
            )
        out = np.empty_like(signal)
        for m in range(1 if shared else signal.shape[0]):
            x = templates if shared else templates[m]
            rows = slice(None) if shared else slice(m, m + 1)
            coefficients = _least_squares(x[:, fit], signal[rows, fit], self.names, block)
            out[rows] = signal[rows] - coefficients.T @ x
        return out


def template_alm(path: str, *, nside: int, lmax: int, frame: str) -> np.ndarray:
    """The T alm of a template map file, checked against the sky it deprojects.

    Parameters
    ----------
    path : str
        A HEALPix FITS map (its first column is T, RING or NESTED as its header says).
    nside, lmax : int
        The sky's.
    frame : str
        The schedule's sky frame (:data:`boresight.frames.FRAMES`); a COORDSYS card, where the
        file has one, must name it.

    Returns
    -------
    numpy.ndarray, complex128, shape (nalm,)

    Raises
    ------
    ValueError
        A file that is not a full-sky map of the sky's Nside in its frame, naming the file.
    """
    try:
        values, header = hp.read_map(path, field=0, h=True, dtype=np.float64)
    except (OSError, ValueError, TypeError, IndexError) as err:
        raise ValueError(f"deprojection template map {path}: {err}") from None
    found = hp.npix2nside(values.size)
    if found != nside:
        raise ValueError(f"deprojection template map {path} has Nside {found}; the sky has {nside}")
    cards = dict(header)
    want = dict((key, value) for key, value, _ in FRAME_CARDS[frame])["COORDSYS"]
    coordsys = str(cards.get("COORDSYS", want)).strip().upper()[:1]
    if coordsys != want:
        raise ValueError(
            f"deprojection template map {path} is in COORDSYS {cards['COORDSYS']!r}; the "
            f"schedule's pointing is {frame} ({want})"
        )
    if np.any(values == hp.UNSEEN) or not np.all(np.isfinite(values)):
        raise ValueError(f"deprojection template map {path} has unseen or non-finite pixels")
    return harmonics.map2alm(values, lmax)


def _least_squares(x, y, names, block):
    """Coefficients (n_templates, n_signals) of templates x (T, n) fitted to y (S, n), the
    templates scaled to unit norm first so that units (muK, muK/rad^2) do not count."""
    norm = np.sqrt(np.einsum("tn,tn->t", x, x))
    if np.any(norm == 0.0):
        zero = [names[i] for i in np.flatnonzero(norm == 0.0)]
        raise ValueError(f"deprojection of {block}: template {', '.join(zero)} is zero there")
    scaled = x / norm[:, None]
    u, s, vt = np.linalg.svd(scaled.T, full_matrices=False)
    if s[-1] < DEGENERATE * s[0]:
        raise ValueError(
            f"deprojection of {block}: templates {', '.join(names)} are collinear there "
            f"(condition {s[0] / s[-1]:.1e})"
        )
    return (vt.T @ ((u.T @ y.T) / s[:, None])) / norm[:, None]


def gradient(alm, theta, phi, *, nthreads=0):
    """(dT/dtheta, dT/dphi / sin theta) of a spin-0 alm at points, exactly (ducc0 DERIV1)."""
    return harmonics.evaluate(
        alm, theta, phi, spin=1, mode="DERIV1", epsilon=EPSILON, nthreads=nthreads
    )


def second_derivatives(alm, theta, phi, *, gradient, nthreads=0):
    """(T_tt, T_tp, T_pp) at points: d^2T/dtheta^2, d^2T/dtheta dphi / sin theta and
    d^2T/dphi^2 / sin^2 theta, from the covariant Hessian (the Laplacian, spin 0, and its
    trace-free part, spin 2 of alm sqrt((l-1) l (l+1) (l+2))) less its connection terms.

    ``gradient`` is (T_t, T_p) at the same points (:func:`gradient`).
    """
    lmax = harmonics.alm_lmax(alm.size)
    ell = np.arange(lmax + 1, dtype=np.float64)
    laplacian = harmonics.evaluate(
        harmonics.almxfl(alm, -ell * (ell + 1)), theta, phi, epsilon=EPSILON, nthreads=nthreads
    )
    spin2 = np.sqrt(np.maximum((ell - 1) * ell * (ell + 1) * (ell + 2), 0.0))
    # ducc0's spin-2 synthesis of the E-like alm gives -(H_tt - H_pp), -2 H_tp
    minus, cross = harmonics.evaluate(
        harmonics.almxfl(alm, spin2),
        theta,
        phi,
        spin=2,
        mode="GRAD_ONLY",
        epsilon=EPSILON,
        nthreads=nthreads,
    )
    h_tt = 0.5 * (laplacian - minus)
    h_pp = 0.5 * (laplacian + minus)
    h_tp = -0.5 * cross
    cot = 1.0 / np.tan(theta)
    t_t, t_p = gradient
    return h_tt, h_tp + cot * t_p, h_pp - cot * t_t
