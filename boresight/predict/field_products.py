"""The exact expected pseudo-C_ell of a spurious polarisation that is a sum of weights times the
sky's Gaussian fields.

Every leak of a pair-differencing systematic through the map-maker is, per pixel,

    dP(p) = sum_k g_k(p) F_k(p),

with g_k a fixed spin-s_k weight (the mask times a coefficient times the schedule's h_n map) and
F_k a spin-t_k field of the sky (T, its gradient, P, their conjugates), s_k + t_k = 2. Over sky
realisations the expected pseudo-C_ell of dP is exact and bilinear: it pairs the weights' cross
spectra with the fields' through spin-weighted 3j couplings. In real space that is a product, as
for a mask (:mod:`boresight.coupling`):

    A(x) = sum_kk' xi^W_kk'(x) xi^C_kk'(x),   B(x) = sum_kk' xi^V_kk'(x) xi^D_kk'(x),
    xi^W_kk' = sum_l (2l+1) W^kk'_l d^l_{s_k s_k'},    xi^C_kk' = sum_l (2l+1) C^kk'_l d^l_{t_k t_k'},
    xi^V_kk' = sum_l (2l+1) V^kk'_l d^l_{s_k,-s_k'},   xi^D_kk' = sum_l (2l+1) D^kk'_l d^l_{t_k,-t_k'},
    <C~^BB_L> = 1 / (16 pi) int dx [d^L_22(x) A(x) - d^L_2-2(x) Re B(x)]   (+ for EE),

with W^kk'_l = sum_m g^k_lm conj(g^k'_lm) / (2l+1) and V^kk'_l = sum_m (-1)^m g^k_lm g^k'_l-m / (2l+1)
the weights' spectra in their own spin-s harmonics, and C^kk', D^kk' the same of the fields,
which follow from the sky's TT, EE, BB, TE. The integrand is a polynomial of degree at most
2 (lmax + band) in x, so Gauss-Legendre quadrature on lmax + band + 1 nodes is exact, with the
weights' spectra to lmax + band. The derivation, the spin conventions and the tests behind them
are in docs/conventions.md ("The exact expectation of a leak").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, NamedTuple

import ducc0
import healpy as hp
import numpy as np

from .. import harmonics
from .._util.jit import njit

if TYPE_CHECKING:
    from collections.abc import Sequence

OUTPUT_SPIN = 2  #: the spurious polarisation P = Q + i U


@dataclass(frozen=True)
class SkyField:
    """A Gaussian field of the sky, linear in its T, E, B harmonic coefficients.

    ``filters`` give the spin-abs(t) field's own coefficients, sum_X filters[X, l] a^X_lm over the
    sky's T, E, B (healpy's sign: for abs(t) > 0 they are -(E_F + i B_F)). A negative ``spin`` is
    the conjugate of that field (the P* of the h_4 term, the conjugate gradient of the h_3 term,
    the beams' G_n of n > 2). Spin 0 is a complex scalar, Re from E_F and Im from B_F.

    Parameters
    ----------
    spin : int
    filters : numpy.ndarray, complex128, shape (3, band + 1)
        On T, E, B from l = 0 [field units per muK]; :func:`boresight.predict.beam_filters`'
        layout.
    """

    spin: int
    filters: np.ndarray

    @property
    def band(self) -> int:
        return self.filters.shape[1] - 1

    @property
    def coefficients(self) -> np.ndarray:
        """phi (3, band + 1): the field's own spin-t coefficients F_lm = sum_X phi[X] a^X_lm; for
        t < 0, those of the conjugate, (-1)^t conj(filters)."""
        if self.spin >= 0:
            return np.asarray(self.filters, dtype=np.complex128)
        return (-1.0) ** self.spin * np.conj(self.filters)

    def alm(self, sky_alm: np.ndarray) -> np.ndarray:
        """(E_F, B_F) (2, nalm) of the spin-abs(t) field from the sky's T, E, B alm (3, nalm):
        -(Re, Im) of the filtered sum for abs(t) > 0 (as ``beam_field``), (Re, Im) at spin 0."""
        ell = hp.Alm.getlm(harmonics.alm_lmax(sky_alm.shape[-1]))[0]
        keep = ell <= self.band
        total = np.zeros(sky_alm.shape[-1], dtype=np.complex128)
        out = np.zeros((2, sky_alm.shape[-1]), dtype=np.complex128)
        sign = 1.0 if self.spin == 0 else -1.0
        for part, f in enumerate((self.filters.real, self.filters.imag)):
            total[:] = 0.0
            for x in range(3):
                total[keep] += f[x][ell[keep]] * sky_alm[x, keep]
            out[part] = sign * total
        return out


def temperature(window: np.ndarray) -> SkyField:
    """T smoothed by ``window`` (band + 1,) [1]: spin 0."""
    filters = np.zeros((3, window.size), dtype=np.complex128)
    filters[0] = window
    return SkyField(0, filters)


def gradient(window: np.ndarray, *, conjugate: bool = False) -> SkyField:
    """The gradient of the smoothed T, dT/dtheta + i dT/dphi / sin(theta) (ducc0's DERIV1,
    :func:`boresight.harmonics.alm2map_gradient`): spin 1 with E_F = sqrt(l (l + 1)) T, or its
    conjugate (spin -1)."""
    ell = np.arange(window.size)
    filters = np.zeros((3, window.size), dtype=np.complex128)
    filters[0] = -np.sqrt(ell * (ell + 1.0)) * window
    return SkyField(-1 if conjugate else 1, filters)


def polarisation(window: np.ndarray, *, conjugate: bool = False) -> SkyField:
    """P = Q + i U smoothed by ``window``: spin 2 with E_F = E and B_F = B, or P* (spin -2)."""
    filters = np.zeros((3, window.size), dtype=np.complex128)
    filters[1], filters[2] = -window, -1j * window
    filters[:, :2] = 0.0  # spin 2 starts at l = 2
    return SkyField(-2 if conjugate else 2, filters)


def derivative(field: SkyField, *, raising: bool) -> SkyField:
    """The field's covariant derivative that raises its spin by one, d F = -edth F (on T: the
    gradient of :func:`gradient`), or lowers it, dbar F = -edth-bar F, so that F read at an
    offset delta = delta_theta + i delta_phi is F + (conj(delta) d F + delta dbar F) / 2 to first
    order. On spin-s coefficients, edth multiplies by sqrt((l - s)(l + s + 1)) and edth-bar by
    -sqrt((l + s)(l - s + 1)); a conjugate field takes the other one, conjugated:
    d conj(F) = conj(dbar F)."""
    t, phi = field.spin, np.asarray(field.filters, dtype=np.complex128)
    ell = np.arange(phi.shape[1])
    if t < 0:  # conj(F_a): d conj(F_a) = conj(dbar F_a), dbar conj(F_a) = conj(d F_a)
        inner = derivative(SkyField(-t, phi), raising=not raising)
        return conjugate(inner)
    if raising:
        return SkyField(t + 1, -np.sqrt(np.maximum((ell - t) * (ell + t + 1.0), 0.0)) * phi)
    if t == 0:  # dbar F = conj(d conj(F)), conj(F) of spin 0 having the conjugate filters
        return conjugate(derivative(SkyField(0, np.conj(phi)), raising=True))
    return SkyField(t - 1, np.sqrt(np.maximum((ell + t) * (ell - t + 1.0), 0.0)) * phi)


def conjugate(field: SkyField) -> SkyField:
    """conj(F): spin -s with F's filters (a negative spin is already a conjugate), or for spin 0
    the scalar with conjugate filters (the sky's T, E, B being real fields)."""
    if field.spin == 0:
        return SkyField(0, np.conj(field.filters))
    return SkyField(-field.spin, field.filters)


class StepTerm(NamedTuple):
    """One term of :func:`coordinate_step`: ``scale`` cot(theta)^``cot`` sin(theta)^(-2 ``csc2``)
    times ``field``."""

    scale: float
    cot: int
    csc2: int
    field: SkyField


def coordinate_step(field: SkyField) -> dict:
    """A spin-s field F read one step away in the coordinates, (theta + rho cos(beta), phi + rho
    sin(beta) / sin(theta)) as detector B of a pair looks
    (:func:`boresight.kernels.cpu.offset_points`), in its components there, to second order in
    delta = rho exp(i beta): F(step) - F = sum over kinds of w(delta) times the sum of that kind's
    :class:`StepTerm`, the weights w = conj(delta), delta, conj(delta)^2, delta^2 and
    ``|delta|^2`` for ``"conj"``, ``"delta"``, ``"conj2"``, ``"delta2"`` and ``"abs2"``.

    The step is a Taylor series in the coordinates: with M = delta_theta d_theta + delta_phi
    (1 / sin(theta)) d_phi = (conj(delta) (d + s cot(theta)) + delta (dbar - s cot(theta))) / 2
    on spin s (:func:`derivative`), F(step) - F = M F + (M^2 F + delta_theta delta_phi cot(theta)
    (1 / sin(theta)) d_phi F) / 2. Beside the covariant terms (d^2 F, dbar^2 F, dbar d F, d dbar F
    over 8), a step along the great circle would not have the cot(theta) and 1 / sin^2(theta) ones.
    """
    t = field.spin
    up, down = derivative(field, raising=True), derivative(field, raising=False)
    return {
        "conj": (StepTerm(0.5, 0, 0, up), StepTerm(0.5 * t, 1, 0, field)),
        "delta": (StepTerm(0.5, 0, 0, down), StepTerm(-0.5 * t, 1, 0, field)),
        "conj2": (
            StepTerm(1 / 8, 0, 0, derivative(up, raising=True)),
            StepTerm((4 * t + 3) / 16, 1, 0, up),
            StepTerm(-1 / 16, 1, 0, down),
            StepTerm((t * t + t) / 8, 2, 0, field),
            StepTerm(-t / 8, 0, 1, field),
        ),
        "delta2": (
            StepTerm(1 / 8, 0, 0, derivative(down, raising=False)),
            StepTerm(-(4 * t - 3) / 16, 1, 0, down),
            StepTerm(-1 / 16, 1, 0, up),
            StepTerm((t * t - t) / 8, 2, 0, field),
            StepTerm(t / 8, 0, 1, field),
        ),
        "abs2": (
            StepTerm(1 / 8, 0, 0, derivative(up, raising=False)),
            StepTerm(1 / 8, 0, 0, derivative(down, raising=True)),
            StepTerm(-(2 * t + 1) / 8, 1, 0, up),
            StepTerm((2 * t - 1) / 8, 1, 0, down),
            StepTerm(-t * t / 4, 2, 0, field),
        ),
    }


class Weight(NamedTuple):
    """A fixed spin-s weight field g (a RING map, complex) and the sky field it multiplies."""

    spin: int
    map: np.ndarray
    field: SkyField


class PseudoSpectra(NamedTuple):
    """Expected pseudo-C_ell [muK^2], (lmax + 1,) each, from l = 0."""

    ee: np.ndarray
    bb: np.ndarray


def spin_pair(spin: int) -> tuple:
    """(alpha, beta): a spin-s field's own coefficients are alpha E + beta B of its (E, B) alm, in
    healpy's sign (-(E + i B) for s > 0; E + i B for a complex scalar). A negative spin is the
    conjugate of the spin-abs(s) field, whose coefficients are (-1)^s (-(E - i B))."""
    if spin == 0:
        return 1.0, 1j
    if spin > 0:
        return -1.0, -1j
    sign = -((-1.0) ** spin)
    return sign, -1j * sign


def weight_alm(weight: Weight, lmax: int, nthreads: int = 0) -> np.ndarray:
    """The weight's (E, B) of its spin abs(s) to ``lmax``, (2, nalm): of g, or of conj(g) where
    s < 0; with the HEALPix ring weights' single pass, as for a mask's own spectrum
    (:func:`boresight.coupling.mask_spectrum`)."""
    g = np.asarray(weight.map)
    g = np.conj(g) if weight.spin < 0 else g
    options = dict(analysis="jacobi", iterations=0, nthreads=nthreads)
    if weight.spin == 0:
        return np.array([harmonics.map2alm(part, lmax, **options) for part in (g.real, g.imag)])
    maps = np.array([g.real, g.imag])
    return harmonics.map2alm(maps, lmax, spin=abs(weight.spin), **options)


def weight_cross_spectra(alms: Sequence[np.ndarray], spins: Sequence[int], lmax: int) -> tuple:
    """W^kk' and V^kk', (K, K, lmax + 1) complex each, of the weights' (E, B) alm (2, nalm).

    W^kk'_l = sum_m g^k_lm conj(g^k'_lm) / (2 l + 1) and V^kk'_l = sum_m (-1)^m g^k_lm g^k'_l-m
    / (2 l + 1) in the weights' own spin harmonics; with g_lm = alpha E + beta B they are
    sums of the real cross spectra of E and B (healpy's ``alm2cl``)."""
    k = len(alms)
    cl = harmonics.alm_cross_spectra(np.reshape(alms, (2 * k, -1)), lmax)
    cl = cl.reshape(k, 2, k, 2, lmax + 1)
    pairs = np.array([spin_pair(s) for s in spins], dtype=np.complex128)  # (K, 2)
    w = np.einsum("ip,jq,ipjql->ijl", pairs, np.conj(pairs), cl)
    v = np.einsum("ip,jq,ipjql->ijl", pairs, pairs, cl)
    return w, v


def field_cross_spectra(fields: Sequence[SkyField], sky_cl: np.ndarray) -> tuple:
    """C^kk' = E[F^k_lm conj(F^k'_lm)] and D^kk' = E[(-1)^m F^k_lm F^k'_l-m], (K, K, band + 1).

    Parameters
    ----------
    fields : sequence of SkyField
        All to one band.
    sky_cl : numpy.ndarray, shape (4, >= band + 1)
        TT, EE, BB, TE [muK^2] (EB = TB = 0).
    """
    band = fields[0].band
    tt, ee, bb, te = (np.asarray(c, dtype=float)[: band + 1] for c in sky_cl)
    cov = np.zeros((3, 3, band + 1))
    cov[0, 0], cov[1, 1], cov[2, 2], cov[0, 1], cov[1, 0] = tt, ee, bb, te, te
    phi = np.array([f.coefficients for f in fields])  # (K, 3, band + 1)
    c = np.einsum("ixl,xyl,jyl->ijl", phi, cov, np.conj(phi))
    d = np.einsum("ixl,xyl,jyl->ijl", phi, cov, phi)
    return c, d


def expected_pseudo_cl(
    weights: Sequence[Weight],
    sky_cl: np.ndarray,
    lmax: int,
    *,
    nthreads: int = 0,
) -> PseudoSpectra:
    """The expected pseudo-C_EE and C_BB of P = sum_k g_k F_k over the sky's realisations.

    Parameters
    ----------
    weights : sequence of Weight
        Each weight g_k (mask included) and its field F_k; spins with s_k + t_k = 2, fields to
        one band.
    sky_cl : numpy.ndarray, shape (4, >= band + 1)
        TT, EE, BB, TE of the sky [muK^2], from l = 0.
    lmax : int
        The pseudo-spectra's band limit; the weights are analysed to lmax + band.
    nthreads : int

    Returns
    -------
    PseudoSpectra
    """
    if not weights:
        raise ValueError("expected_pseudo_cl needs at least one weight")
    lw = lmax + max(w.field.band for w in weights)
    alms = [weight_alm(w, lw, nthreads) for w in weights]
    return expected_pseudo_cl_alm(
        alms, [w.spin for w in weights], [w.field for w in weights], sky_cl, lmax
    )


def expected_pseudo_cl_alm(
    alms: Sequence[np.ndarray],
    spins: Sequence[int],
    fields: Sequence[SkyField],
    sky_cl: np.ndarray,
    lmax: int,
    *,
    second: np.ndarray | None = None,
    pseudo: np.ndarray | None = None,
) -> PseudoSpectra:
    """:func:`expected_pseudo_cl` of weights given by their (E, B) alm (2, nalm) to at least
    lmax + band (:func:`weight_alm`), with their spins and fields.

    ``second`` and ``pseudo`` (K, K) are E[c_k conj(c_k')] and E[c_k c_k'] of random
    coefficients that multiply the weights (default: ones, the coefficients in the weights):
    the expectation is bilinear, through W^kk' c_k conj(c_k') and V^kk' c_k c_k'."""
    spectra = weight_cross_spectra(alms, spins, lmax + fields[0].band)
    return expected_pseudo_cl_spectra(
        spectra, spins, fields, sky_cl, lmax, second=second, pseudo=pseudo
    )


def expected_pseudo_cl_spectra(
    spectra: tuple,
    spins: Sequence[int],
    fields: Sequence[SkyField],
    sky_cl: np.ndarray,
    lmax: int,
    *,
    second: np.ndarray | None = None,
    pseudo: np.ndarray | None = None,
) -> PseudoSpectra:
    """:func:`expected_pseudo_cl_alm` from the weights' cross spectra ``spectra`` = (W, V),
    (K, K, lmax + band + 1) each (:func:`weight_cross_spectra`). It is linear in them, so the spectra of many sets
    of weights with the same spins and fields, summed, give the sum of their expectations in one
    quadrature (a focal plane's pairs' scattered leaks)."""
    w_cl, v_cl = spectra
    q = _Quadrature(spins, fields, sky_cl, lmax, second, pseudo)
    a = np.zeros(q.x.size, dtype=np.complex128)
    b = np.zeros(q.x.size, dtype=np.complex128)
    for i, j, s, sp in q.pairs():
        a += (q.lw_norm * w_cl[i, j]) @ q.tables(s, sp, q.lw) * q.xi_c[i, j]
        b += (q.lw_norm * v_cl[i, j]) @ q.tables(s, -sp, q.lw) * q.xi_d[i, j]
    plus = q.tables(2, 2, lmax) @ (q.nodes * a.real) / (16 * np.pi)
    minus = q.tables(2, -2, lmax) @ (q.nodes * b.real) / (16 * np.pi)
    ee, bb = plus + minus, plus - minus
    ee[:2] = bb[:2] = 0.0
    return PseudoSpectra(ee, bb)


def bb_kernels(
    spins: Sequence[int],
    fields: Sequence[SkyField],
    sky_cl: np.ndarray,
    weight_l: np.ndarray,
    *,
    second: np.ndarray | None = None,
    pseudo: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The kernels of a linear functional of the expected pseudo-C_BB in the weights' spectra.

    sum_L weight_l[L] <C~^BB_L> = Re sum_kk'l [kappa_W[k, k', l] W^kk'_l - kappa_V[k, k', l]
    V^kk'_l] for any weights of these spins and fields (:func:`weight_cross_spectra`): what a design
    objective needs once per budget, so that an assignment costs only its weights' spectra.

    Parameters
    ----------
    spins, fields, sky_cl, second, pseudo
        As :func:`expected_pseudo_cl_alm`.
    weight_l : numpy.ndarray, shape (lmax + 1,)
        The functional's weight per L from L = 0 (for delta_r, the template over its range
        divided by the template's power).

    Returns
    -------
    kappa_w, kappa_v : numpy.ndarray, complex128, shape (K, K, lmax + band + 1)
    """
    lmax = weight_l.size - 1
    q = _Quadrature(spins, fields, sky_cl, lmax, second, pseudo)
    alpha = q.nodes * (np.asarray(weight_l) @ q.tables(2, 2, lmax)) / (16 * np.pi)
    beta = q.nodes * (np.asarray(weight_l) @ q.tables(2, -2, lmax)) / (16 * np.pi)
    k = len(spins)
    kappa_w = np.zeros((k, k, q.lw + 1), dtype=np.complex128)
    kappa_v = np.zeros_like(kappa_w)
    for i, j, s, sp in q.pairs():
        kappa_w[i, j] = q.lw_norm * (q.tables(s, sp, q.lw) @ (alpha * q.xi_c[i, j]))
        kappa_v[i, j] = q.lw_norm * (q.tables(s, -sp, q.lw) @ (beta * q.xi_d[i, j]))
    return kappa_w, kappa_v


class _Quadrature:
    """What both routes share: the checks, the Gauss-Legendre nodes on lmax + band + 1 points
    (dx weights), the Wigner d tables, and the fields' correlation functions times their
    coefficients' moments, xi_c = E[c c'^*] xi^C and xi_d = E[c c'] xi^D, (K, K, n)."""

    def __init__(self, spins, fields, sky_cl, lmax, second, pseudo):
        bands = {f.band for f in fields}
        if len(bands) != 1:
            raise ValueError(f"every field must have one band, got {sorted(bands)}")
        band = bands.pop()
        for s, f in zip(spins, fields):
            if s + f.spin != OUTPUT_SPIN:
                raise ValueError(f"a spin-{s} weight times a spin-{f.spin} field is not spin 2")
        self.spins, self.lw = list(spins), lmax + band
        k = len(spins)
        second = np.ones((k, k)) if second is None else np.asarray(second)
        pseudo = np.ones((k, k)) if pseudo is None else np.asarray(pseudo)
        n_nodes = self.lw + 1
        self.tables = _gl_tables(n_nodes)
        self.x = self.tables.x
        self.nodes = ducc0.misc.GL_weights(n_nodes, 1) / (2 * np.pi)
        self.lw_norm = 2 * np.arange(self.lw + 1) + 1.0
        band_norm = 2 * np.arange(band + 1) + 1.0
        c_cl, d_cl = field_cross_spectra(fields, sky_cl)
        self.xi_c = np.zeros((k, k, n_nodes), dtype=np.complex128)
        self.xi_d = np.zeros_like(self.xi_c)
        for i, j, _, _ in self.pairs():
            t, tp = fields[i].spin, fields[j].spin
            self.xi_c[i, j] = second[i, j] * ((band_norm * c_cl[i, j]) @ self.tables(t, tp, band))
            self.xi_d[i, j] = pseudo[i, j] * ((band_norm * d_cl[i, j]) @ self.tables(t, -tp, band))

    def pairs(self):
        """(k, k', s_k, s_k') over every ordered pair of terms."""
        for i, s in enumerate(self.spins):
            for j, sp in enumerate(self.spins):
                yield i, j, s, sp


@lru_cache(maxsize=2)
def _gl_tables(n_nodes: int) -> _Tables:
    """The Wigner d tables on n Gauss-Legendre nodes, kept for the next expectation of the same
    band limits (a design's strategies, a residual's leaked and total parts)."""
    return _Tables(np.cos(ducc0.misc.GL_thetas(n_nodes)))


class _Tables:
    """Wigner d^l_{m m'}(x) on the quadrature's nodes, (lmax + 1, n), each made once."""

    def __init__(self, x):
        self.x = x
        self._made = {}

    def __call__(self, m, mp, lmax):
        key = (m, mp)
        have = self._made.get(key)
        if have is None or have.shape[0] < lmax + 1:
            have = wigner_d(m, mp, lmax, self.x)
            self._made[key] = have
        return have[: lmax + 1]


def wigner_d(m: int, mp: int, lmax: int, x: np.ndarray) -> np.ndarray:
    """Wigner's d^l_{m m'}(theta) for l = 0..lmax at x = cos(theta), (lmax + 1, n), zero below
    max(abs(m), abs(m')), in Varshalovich's convention (the matrix element of exp(-i theta J_y)
    between the states l m and l m'; d^1_10 = -sin(theta) / sqrt(2)), by the three-term
    recursion in l."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    out = np.zeros((lmax + 1, x.size))
    l0 = max(abs(m), abs(mp))
    if l0 > lmax:
        return out
    if abs(m) >= abs(mp):
        big, small, sign = m, mp, 1.0
    else:  # d^l_{m m'} = (-1)^(m - m') d^l_{m' m}
        big, small, sign = mp, m, (-1.0) ** (m - mp)
    half_c, half_s = np.sqrt((1 + x) / 2), np.sqrt((1 - x) / 2)
    if big >= 0:
        norm = math.sqrt(math.comb(2 * l0, l0 + small))
        start = norm * half_c ** (l0 + small) * (-half_s) ** (l0 - small)
    else:  # d^j_{-j m'} = (-1)^(j + m') d^j_{j, -m'}
        norm = math.sqrt(math.comb(2 * l0, l0 - small))
        start = (-1.0) ** (l0 + small) * norm * half_c ** (l0 - small) * (-half_s) ** (l0 + small)
    _recurse(sign * start, m, mp, l0, x, out)
    return out


@njit
def _recurse(start, m, mp, l0, x, out):
    """d^l for l > l0 from d^l0 = start (Varshalovich 4.8.2 (3)), into out."""
    lmax = out.shape[0] - 1
    out[l0] = start
    if l0 == lmax:
        return
    if l0 == 0:  # d^1_00 = x
        out[1] = x
        l0 = 1
    for ll in range(l0, lmax):
        a = (2 * ll + 1) * (ll * (ll + 1) * x - m * mp)
        b = (ll + 1) * np.sqrt((ll * ll - m * m) * (ll * ll - mp * mp))
        c = ll * np.sqrt(((ll + 1) ** 2 - m * m) * ((ll + 1) ** 2 - mp * mp))
        out[ll + 1] = (a * out[ll] - b * out[ll - 1]) / c
