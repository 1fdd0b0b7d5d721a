"""Analytic prediction of the spurious polarisation from the spin moments h_n (paper eqs. 5-10).

A sample j of pair m in rotation repeat k has the assumed angle phi_j = psi_j + alpha_k + a_m.
Its pair difference departs from the ideal Re[P* e^{2 i phi}] by (docs/conventions.md)::

  dd = 1/2 dg_km T + 1/2 l_m S - 1/2 rho_m Re[G e^{-i beta}] + Re[P* e^{2 i phi} gamma_km]

with dg_km = dg_m + dg_repeat_k, beta = phi + chi_m, G = dT/dtheta + i dT/dphi / sin(theta) and
gamma_km = (e^{2i(delta - eps/2)} + (1 - dg_km) e^{2i(delta + eps/2)}) / 2 - 1 (angle errors
delta, eps). The least-squares map-maker turns Y = 2 <e^{2 i phi} dd> into
dP = (Y - H_4 Y*) / (1 - ``|H_4|^2``) with H_4 = m_4 h_4, and to first order in rho::

  Y = t_2 h_2 T + s_2 h_2 S + g_1 h_1 G + g_3 h_3 G* + p_0 P + p_4 h_4 P*

where h_n = <exp(i n psi)> over one repeat's crossings of a pixel and every coefficient is a mean
over (k, m) (:func:`coefficients`): t_2 = <dg e^{2i(alpha+a)}>, s_2 = <l e^{2i(alpha+a)}>,
g_1 = -1/2 <rho e^{i(alpha+a-chi)}>, g_3 = -1/2 <rho e^{i(3(alpha+a)+chi)}>, p_0 = <conj gamma>,
p_4 = <gamma e^{4i(alpha+a)}>, m_4 = <e^{4i(alpha+a)}>. For the paper's pairs at (0, 45) deg and
no repeat these are the paper's eq. 5-9 (its eq. 6 is the complex conjugate of these forms: its
h_n and gradient use the opposite orientation; amplitudes are identical). Gain, leak and angle
terms are exact for pixel-centre hits; pointing is first order in rho.

Detector beams (:mod:`boresight.beams`): detector X's extra signal is a sum over its beam's
azimuthal moments k of spin-k fields F_k of the sky (T, E and B) times e^{-i k psi_X}, so Y gains
the terms h_n G_n, n = 2 -+ k (:func:`beam_filters`): the width's nabla^2 T and the ellipticity's
eth-bar^2 P at h_2 (joining the gain's h_2 T), the ellipticity's eth^2 T at h_0 (which no rotation
changes) and h_4, its eth^2 P at h_{-2} and h_6, and higher orders in e beyond. Exact to the
moments h holds (:data:`BEAM_N_MAX` covers every term of first order in e).

Power spectra: each term c h_n F contributes C^EE = C^BB = ``|c|^2`` / 2 * [coh_n C^FF_l +
(``<|h_n|^2>`` - coh_n) Omega_pix sigma_F^2]: a coherent part from h_n smoothed over blocks of
pixels (what Wallis et al. 2017 write as ``<|h_n|^2>`` C^FF) and a white part from the
pixel-to-pixel scatter of h_n. A beam pair h_n G_n + h_{-n} G_{-n} splits its coherent part
unequally: B takes ``|g_n - (-1)^n conj(g_-n)|^2`` and E the sum (docs/conventions.md). The
h_0 term rotates and rescales the sky's own polarisation, u P with u = 1 + p_0. Gain jitter of
rms sigma adds white noise of variance ``<sigma^2>`` T^2 / N_samples per pixel. Masked
pseudo-C_ell follow through M^{BB,BB} and M^{BB,EE} (paper eq. 10). The C_ell level needs m_4 = 0
(pairs whose 4 x angles cancel, e.g. (0, 45) deg or any "uniform" focal plane of 2 or more pairs,
or a repeat that cancels h_4); the map level has no such limit.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from typing import TYPE_CHECKING, NamedTuple

import healpy as hp
import numba
import numpy as np

from . import harmonics
from .beams import moment_filters, pair_beams
from .constants import ARCMIN, DEG
from .instrument import Instrument
from .spectra import Footprint, as_footprint, masked_pol_alm, pseudo_spectra
from .threads import numba_threads

if TYPE_CHECKING:
    from collections.abc import Sequence

    from .cosmology import Spectra
    from .coupling import Coupling
    from .instrument import Systematics
    from .sky import Sky


N_MAX = 4  #: highest spin moment the predictions use
COHERENT_BLOCK = 8  #: h_n is smoothed over (COHERENT_BLOCK)^2 pixels for the coherent part
M4_TOLERANCE = 1e-9  #: ``|m_4|`` below which the map-maker's h_4 coupling vanishes


@dataclass(frozen=True)
class Coefficients:
    """The coefficients of every term of the spurious polarisation (module docstring).

    Parameters
    ----------
    t2, s2, g1, g3, p0, p4 : complex
        Of h_2 T, h_2 S, h_1 G [rad], h_3 G* [rad], P and h_4 P*.
    m4 : complex
        The map-maker's <e^{4i(alpha + a)}> over (repeat, pair).
    jitter_var : float
        ``<sigma^2>`` of the gain jitter over pairs.
    n_samples : int
        Samples per crossing: repeats x pairs.
    """

    t2: complex
    s2: complex
    g1: complex
    g3: complex
    p0: complex
    p4: complex
    m4: complex
    jitter_var: float
    n_samples: int


def coefficients(
    systematics: Systematics,
    instrument: Instrument | None = None,
    rotations_deg: Sequence[float] = (0.0,),
) -> Coefficients:
    """The coefficients of the spurious polarisation of an instrument's systematics.

    Parameters
    ----------
    systematics : boresight.instrument.Systematics
    instrument : boresight.instrument.Instrument, optional
        Default: the paper's pairs at (0, 45) deg.
    rotations_deg : sequence of float
        The boresight rotation of each repeat [deg]; (0,) for a scan whose h_n already include
        its rotations (a real schedule).

    Returns
    -------
    Coefficients
    """
    instrument, alpha, par = _drawn(systematics, instrument, rotations_deg)
    terms = _pair_terms(par, instrument.pair_angles_rad, alpha, systematics.per_repeat(alpha.size))
    return Coefficients(
        **{name: complex(np.mean(f)) for name, f in terms.items()},
        jitter_var=float(np.mean(par.dg_jitter**2)),
        n_samples=int(alpha.size * instrument.n_pairs),
    )


def _drawn(systematics, instrument, rotations_deg):
    """(instrument, rotations [rad], the pairs' parameters): the paper's pairs by default."""
    instrument = Instrument() if instrument is None else instrument
    alpha = np.asarray(rotations_deg, dtype=np.float64) * DEG
    return instrument, alpha, systematics.per_pair(instrument.n_pairs)


def _pair_terms(par, pair_angles, alpha, dg_repeat):
    """Each coefficient's share from every pair: its mean over the repeats, (n_pairs,) complex
    (a coefficient is the mean of these over the pairs)."""
    ang = alpha[:, None] + pair_angles[None, :]
    dg = par.dg[None, :] + dg_repeat[:, None]
    off = par.pol_angle[None, :]
    half = 0.5 * par.nonortho[None, :]
    gamma = 0.5 * (np.exp(2j * (off - half)) + (1 - dg) * np.exp(2j * (off + half))) - 1
    e2 = np.exp(2j * ang)
    terms = dict(
        t2=dg * e2,
        s2=par.leak * e2,
        g1=-0.5 * par.rho * np.exp(1j * (ang - par.chi)),
        g3=-0.5 * par.rho * np.exp(1j * (3 * ang + par.chi)),
        p0=np.conj(gamma),
        p4=gamma * e2**2,
        m4=e2**2,
    )
    return {name: np.mean(f, axis=0) for name, f in terms.items()}


QUADRATURE_NODES = 3  #: Gauss-Hermite nodes per drawn parameter (exact for powers of linear terms)


class ExpectedPower(NamedTuple):
    """The power of each coefficient averaged over the per-pair draws of {mean, rms} parameters:
    E``|c|^2`` of t2, s2, g1, g3, p4, and of the h_0 term E Re p0, E Im p0, E (Re p0)^2,
    E (Im p0)^2, E Re p0 Im p0; t2_mean, E t2, gives the cross term with the beams' h_2 fields
    (:func:`leak_terms`)."""

    t2_mean: complex
    t2: float
    s2: float
    g1: float
    g3: float
    p4: float
    re_p0: float
    im_p0: float
    re_p0_2: float
    im_p0_2: float
    re_im_p0: float


def jitter_variance(systematics: Systematics, coefs: Coefficients, expected: bool) -> float:
    """<sigma^2> of the gain jitter over the focal plane.

    Parameters
    ----------
    systematics : boresight.instrument.Systematics
    coefs : Coefficients
        Of the drawn pairs.
    expected : bool
        The expectation over the draws of a {mean, rms} jitter, mean^2 + rms^2, rather than the
        drawn pairs' mean of sigma^2.

    Returns
    -------
    float
    """
    from .instrument import Spread

    jitter = systematics.dg_jitter
    if expected and isinstance(jitter, Spread):
        return jitter.mean**2 + jitter.rms**2
    return coefs.jitter_var


def expected_coefficients(coefs: Coefficients, power: ExpectedPower) -> Coefficients:
    """Coefficients whose ``|c|^2`` are the expected powers (their phases are dropped): what the
    spectra of the terms c h_n F need, which see ``|c|^2`` only.

    Parameters
    ----------
    coefs : Coefficients
    power : ExpectedPower

    Returns
    -------
    Coefficients
    """
    return replace(coefs, **{k: np.sqrt(getattr(power, k)) for k in ("t2", "s2", "g1", "g3", "p4")})


def expected_power(
    systematics: Systematics,
    instrument: Instrument | None = None,
    rotations_deg: Sequence[float] = (0.0,),
) -> ExpectedPower:
    """What a focal plane's coefficients give on average over its pairs' random draws.

    A coefficient c is the mean over N pairs of independent shares F_m, so
    E``|c|^2`` = ``|E c|^2`` (coherent: the means of the parameters) + sum_m Var(F_m) / N^2
    (incoherent: rms^2 / N for a linear term). E F_m and E``|F_m|^2`` are Gauss-Hermite sums over
    the pair's drawn parameters (:data:`QUADRATURE_NODES` per parameter).

    Parameters
    ----------
    systematics : boresight.instrument.Systematics
        With numbers for the beams and ``dg_repeat`` (the filters of :func:`beam_filters` and the
        drift are taken as given).
    instrument : boresight.instrument.Instrument, optional
    rotations_deg : sequence of float

    Returns
    -------
    ExpectedPower
    """
    from .instrument import BEAM_KEYS, LIMITS, UNITS, Spread

    shared = ("dg_repeat",) + BEAM_KEYS["a"] + BEAM_KEYS["b"]
    if any(isinstance(getattr(systematics, k), Spread) for k in shared):
        raise ValueError(
            "the expected focal-plane power covers per-pair gain, pointing, leak and angle "
            "errors: give the beams and dg_repeat as numbers"
        )
    instrument, alpha, par = _drawn(systematics, instrument, rotations_deg)
    n = instrument.n_pairs
    drawn = [
        name
        for name in LIMITS
        if isinstance(getattr(systematics, name), Spread) and getattr(systematics, name).rms > 0
    ]
    z, w = np.polynomial.hermite_e.hermegauss(QUADRATURE_NODES)
    grids = np.meshgrid(*([z] * len(drawn)), indexing="ij")
    nodes = np.stack([g.ravel() for g in grids], axis=1) if drawn else np.zeros((1, 0))
    weight = np.prod(np.meshgrid(*([w] * len(drawn)), indexing="ij"), axis=0).ravel()
    weight = np.atleast_1d(weight) / np.sum(weight)
    values = {}
    for name, column in zip(par._fields, par):
        values[name] = np.repeat(column, nodes.shape[0])
    for j, name in enumerate(drawn):
        spread = getattr(systematics, name)
        field = par._fields[list(LIMITS).index(name)]
        values[field] = np.tile((spread.mean + spread.rms * nodes[:, j]) * UNITS[name], n)
    virtual = type(par)(**values)
    terms = _pair_terms(
        virtual,
        np.repeat(instrument.pair_angles_rad, nodes.shape[0]),
        alpha,
        systematics.per_repeat(alpha.size),
    )

    def moments(f):
        f = f.reshape(n, -1)
        return f @ weight, (f.real**2) @ weight, (f.imag**2) @ weight, (f.real * f.imag) @ weight

    out, means = {}, {}
    for name in ("t2", "s2", "g1", "g3", "p4", "p0"):
        mean, re2, im2, reim = moments(terms[name])
        means[name] = complex(np.mean(mean))
        re, im = np.mean(mean.real), np.mean(mean.imag)
        out[name] = (
            abs(np.mean(mean)) ** 2 + np.sum(re2 + im2 - np.abs(mean) ** 2) / n**2,
            re**2 + np.sum(re2 - mean.real**2) / n**2,
            im**2 + np.sum(im2 - mean.imag**2) / n**2,
            re * im + np.sum(reim - mean.real * mean.imag) / n**2,
        )
    p0 = out.pop("p0")
    return ExpectedPower(
        t2_mean=means["t2"],
        **{name: float(v[0]) for name, v in out.items()},
        re_p0=means["p0"].real,
        im_p0=means["p0"].imag,
        re_p0_2=float(p0[1]),
        im_p0_2=float(p0[2]),
        re_im_p0=float(p0[3]),
    )


BEAM_N_MAX = 6  #: the beams' terms reach h_6 at first order in the ellipticity (eth^2 P)


def beam_filters(
    systematics: Systematics,
    instrument: Instrument | None,
    rotations_deg: Sequence[float],
    fwhm_arcmin: float,
    lmax: int,
    n_max: int = BEAM_N_MAX,
) -> dict[int, np.ndarray]:
    """The filters of the detectors' beam terms h_n G_n of Y, -n_max <= n <= n_max.

    Detector X's extra signal is F_0 + sum_k 2 Re[F_k e^{-i k psi_X}]
    (:func:`boresight.beams.moment_filters`), so with psi_X = phi + c_X Y gains, from each
    detector, s_X g_X [h_2 F_0 + sum_k (h_{2-k} e^{-i k c_X} F_k + h_{2+k} e^{i k c_X} F_k*)],
    each h_n carrying its repeat's and pair's phase e^{i n (alpha + a)}, means over (repeat, pair)
    (docs/conventions.md). G_n is a spin-(2 - n) field for n <= 2, and for n > 2 the conjugate
    of a spin-(n - 2) field H_n; the filters give G_n's (or H_n's) harmonic coefficients as
    sum_c filter[c, l] a^c_lm over the sky's beam-smoothed T, E, B alm.

    Parameters
    ----------
    systematics : boresight.instrument.Systematics
    instrument : boresight.instrument.Instrument or None
    rotations_deg : sequence of float
    fwhm_arcmin : float
        The sky's beam.
    lmax, n_max : int

    Returns
    -------
    dict of int to numpy.ndarray
        n -> complex array of shape (3, lmax + 1); h_{-n} = conj(h_n).
    """
    instrument, alpha, par = _drawn(systematics, instrument, rotations_deg)
    nominal = fwhm_arcmin * ARCMIN
    smoothing = hp.gauss_beam(nominal, lmax=lmax, pol=True).T[:3]  # (T, E, B), (3, lmax + 1)
    kmax = n_max + 2
    ang = alpha[:, None] + instrument.pair_angles_rad[None, :]  # (K, M)
    gain_b = 1 - (par.dg[None, :] + systematics.per_repeat(alpha.size)[:, None])
    offset = {  # c_X: the detector's angle from the assumed one
        "a": par.pol_angle - 0.5 * par.nonortho,
        "b": par.pol_angle + 0.5 * par.nonortho + np.pi / 2,
    }
    out = {n: np.zeros((3, lmax + 1), dtype=np.complex128) for n in range(-n_max, n_max + 1)}
    cache = {}
    for m, beam_pair in enumerate(pair_beams(par, nominal)):
        for detector, beam, sign, gain in zip("ab", beam_pair, (1, -1), (1.0, gain_b[:, m])):
            if beam not in cache:
                cache[beam] = moment_filters(beam, nominal, lmax, kmax)
            g = cache[beam]
            weight = sign * gain * np.ones(alpha.size)  # (K,)
            c = offset[detector][m]
            for k in range(kmax + 1):
                # F_k enters at h_{2-k}; F_k* at h_{2+k}, as H_n = conj(weight) F_k
                for n, phase in ((2 - k, 1j * (2 - k)), (2 + k, -1j * (2 + k)))[: 1 + (k > 0)]:
                    if abs(n) <= n_max:
                        out[n] += np.mean(weight * np.exp(phase * ang[:, m] - 1j * k * c)) * g[k]
    n = instrument.n_pairs
    return {key: f / n / np.where(smoothing > 0, smoothing, np.inf) for key, f in out.items()}


def beam_power(filt: np.ndarray, cl: np.ndarray) -> np.ndarray:
    """The power spectrum of a field whose coefficients are sum_c filt[c] a^c_lm.

    Parameters
    ----------
    filt : numpy.ndarray, shape (3, lmax + 1)
        On T, E, B; real or complex.
    cl : numpy.ndarray, shape (4, >= lmax + 1)
        TT, EE, BB, TE [muK^2].

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    tt, ee, bb, te = cl[:, : filt.shape[1]]
    t, e, b = filt
    return (
        np.abs(t) ** 2 * tt
        + np.abs(e) ** 2 * ee
        + np.abs(b) ** 2 * bb
        + 2 * np.real(t * np.conj(e)) * te
    )


def supports(instrument: Instrument | None, rotations_deg: Sequence[float] = (0.0,)) -> bool:
    """Whether the C_ell-level prediction covers an instrument and repeats: m_4 = 0.

    Parameters
    ----------
    instrument : boresight.instrument.Instrument or None
        None stands for the paper's pairs.
    rotations_deg : sequence of float

    Returns
    -------
    bool
    """
    from .instrument import Systematics

    return abs(coefficients(Systematics(), instrument, rotations_deg).m4) < M4_TOLERANCE


def _check_supported(coefs):
    if abs(coefs.m4) >= M4_TOLERANCE:
        raise ValueError(
            "the C_ell-level prediction needs pair angles whose 4 x angles cancel over the pairs "
            f"and repeats (m_4 = {coefs.m4:.3g}); use the map-level delta_p"
        )


def delta_p(
    sky: Sky,
    h: np.ndarray,
    systematics: Systematics,
    instrument: Instrument | None = None,
    template: np.ndarray | None = None,
    nthreads: int = 0,
    rotations_deg: Sequence[float] = (0.0,),
    pixels: np.ndarray | None = None,
    gradient: np.ndarray | None = None,
) -> np.ndarray:
    """Predicted spurious polarisation P = Q + i U from h_n and the sky, map-maker included.

    Gain, leak and angle terms are exact for pixel-centre hits; pointing is first order in rho.
    Gain jitter, a random term, has zero mean and is left out.

    Parameters
    ----------
    sky : boresight.sky.Sky
    h : numpy.ndarray, complex128, shape (>= 5, npix)
        h_n maps of one repeat's hits (:func:`boresight.engine.scan_moments` of
        ``scan.one_repeat()``), or of a real schedule with its rotations.
    systematics : boresight.instrument.Systematics
    instrument : boresight.instrument.Instrument, optional
        Default: the paper's pairs.
    template : numpy.ndarray, shape (npix,), optional
        The leak's template [muK] (default: the sky's I).
    nthreads : int
    rotations_deg : sequence of float
        The repeats' boresight rotations [deg].
    pixels : numpy.ndarray of int, shape (n,), optional
        RING indices to predict at (default: every pixel).
    gradient : numpy.ndarray, shape (2, npix) or (2, n), optional
        The sky's T gradient where the prediction is made
        (:func:`boresight.harmonics.alm2map_gradient`), when already made; computed here by
        default.

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,) or (n,)
        [muK].
    """
    if h.shape[0] < 5 or h.shape[1] != sky.maps.shape[1]:
        raise ValueError(f"h must have shape (>= 5, {sky.maps.shape[1]}), got {h.shape}")
    c = coefficients(systematics, instrument, rotations_deg)
    t = sky.maps[0]
    s, grad = np.empty(0), np.empty((2, 0))  # an empty field switches its term off
    if systematics.has_leak:
        s = t if template is None else np.asarray(template, dtype=np.float64)
    if systematics.has_pointing:
        grad = gradient
        if grad is None:
            grad = harmonics.alm2map_gradient(sky.alm[0], sky.nside, nthreads, pixels)
    beam = np.empty(0, dtype=np.complex128)
    if systematics.has_beams:
        beam = _beam_y(sky, h, systematics, instrument, rotations_deg, nthreads)
    every = pixels is None
    pixels = np.empty(0, dtype=np.int64) if every else np.asarray(pixels, dtype=np.int64)
    out = np.empty(t.size if every else pixels.size, dtype=np.complex128)
    if grad.shape[1] not in (0, out.size):
        raise ValueError(f"gradient of shape {grad.shape} for {out.size} pixels")
    with numba_threads(nthreads):
        _delta_p(
            every,
            pixels,
            h,
            t,
            sky.maps[1],
            sky.maps[2],
            s,
            grad[0],
            grad[1],
            beam,
            np.array([c.t2, c.s2, c.g1, c.g3, c.p0, c.p4, c.m4]),
            out,
        )
    return out


def _beam_y(sky, h, systematics, instrument, rotations_deg, nthreads):
    """The beam terms' part of Y: sum_n h_n G_n over the n that h holds (:func:`beam_filters`),
    (npix,) complex."""
    n_max = h.shape[0] - 1
    filters = beam_filters(systematics, instrument, rotations_deg, sky.fwhm_arcmin, sky.lmax, n_max)
    out = np.zeros(h.shape[1], dtype=np.complex128)
    for n, filt in filters.items():
        if np.any(filt):
            field = _beam_field(sky, filt, abs(2 - n), nthreads)
            field = np.conj(field) if n > 2 else field
            out += (h[n] if n >= 0 else np.conj(h[-n])) * field
    return out


def _beam_field(sky, filt, spin, nthreads):
    """The spin-``spin`` field with coefficients sum_c filt[c] a^c_lm of the sky's T, E, B,
    (npix,) complex (for spin > 0, Q + i U of healpy's (E', B') = -(Re, Im) of the sum)."""
    n = min(filt.shape[1], sky.lmax + 1)
    padded = np.zeros((3, sky.lmax + 1), dtype=np.complex128)  # nothing beyond the filter's band
    padded[:, :n] = filt[:, :n]
    parts = [
        sum(harmonics.almxfl(sky.alm[c], getattr(padded[c], part)) for c in range(3))
        for part in ("real", "imag")
    ]
    if spin == 0:
        return harmonics.alm2map(parts[0], sky.nside, nthreads=nthreads) + 1j * harmonics.alm2map(
            parts[1], sky.nside, nthreads=nthreads
        )
    qu = harmonics.alm2map(-np.stack(parts), sky.nside, spin=spin, nthreads=nthreads)
    return qu[0] + 1j * qu[1]


@numba.njit(parallel=True, cache=True)
def _delta_p(every, pixels, h, t, q, u, s, grad_theta, grad_phi, beam, c, out):
    """dP at ``pixels`` (or every pixel) into ``out``: the leak term if s is not empty,
    pointing if grad (given where out is) is not empty, the beams' part of Y if beam is not
    empty; c holds (t2, s2, g1, g3, p0, p4, m4)."""
    for k in numba.prange(out.size):
        i = np.int64(k) if every else pixels[k]
        p = complex(q[i], u[i])
        y = c[0] * h[2, i] * t[i] + c[4] * p + c[5] * h[4, i] * p.conjugate()
        if beam.size:
            y += beam[i]
        if s.size:
            y += c[1] * h[2, i] * s[i]
        if grad_theta.size:
            g = complex(grad_theta[k], grad_phi[k])
            y += c[2] * h[1, i] * g + c[3] * h[3, i] * g.conjugate()
        h4 = c[6] * h[4, i]
        det = 1.0 - (h4.real**2 + h4.imag**2)
        if h4 == 0:
            out[k] = y
        elif det > 1e-12:
            out[k] = (y - h4 * y.conjugate()) / det
        else:  # one angle only: the simulation flags the pixel invalid
            out[k] = 0.0


class PixelBlocks:
    """A mask's observed pixels grouped in blocks of block^2 pixels (NEST parents at nside / block),
    built once per mask and used for every h_n.

    Parameters
    ----------
    mask : numpy.ndarray, shape (npix,), or boresight.spectra.Footprint
        The mask, or its footprint (whose pixels and weights the blocks then share).
    block : int
        Side of a block in pixels.
    """

    def __init__(self, mask, block=COHERENT_BLOCK):
        footprint = as_footprint(mask)
        nside = footprint.nside
        self.obs, self.weight = footprint.pixels, footprint.weights
        self.parent = footprint.parents(block) if nside >= block else None
        if self.parent is not None:
            self.block_weight = np.bincount(self.parent, weights=self.weight)
            self.used = self.block_weight > 0

    def coherent_power(self, hn):
        """``<|h_n|^2>`` over the mask and its coherent part.

        Parameters
        ----------
        hn : numpy.ndarray, complex128, shape (npix,)

        Returns
        -------
        total : float
            Mask-weighted mean of ``|h_n|^2``.
        coherent : float
            The same of h_n averaged in blocks (equal to total when Nside < block).
        """
        wo = self.weight
        parent = self.parent if self.parent is not None else np.zeros(0, dtype=np.int64)
        nblock = 0 if self.parent is None else self.block_weight.size
        power, sum_re, sum_im = _block_sums(hn, self.obs, wo, parent, nblock)
        total = np.sum(power) / wo.sum()
        if self.parent is None:
            return total, total
        mean_re, mean_im = sum_re[self.used], sum_im[self.used]
        coherent = np.sum((mean_re**2 + mean_im**2) / self.block_weight[self.used]) / wo.sum()
        return total, coherent


@numba.njit(parallel=True, cache=True)
def _block_sums(hn, obs, weight, parent, nblock):
    """w |h|^2 at each observed pixel, and the sums of w h over each block (none when nblock is
    0) in pixel order, as numpy's bincount adds them: the same sums whatever the thread count."""
    power = np.empty(obs.size)
    for i in numba.prange(obs.size):
        h = hn[obs[i]]
        power[i] = weight[i] * (h.real * h.real + h.imag * h.imag)
    sum_re, sum_im = np.zeros(nblock), np.zeros(nblock)
    if nblock > 0:
        for i in range(obs.size):
            h = hn[obs[i]]
            sum_re[parent[i]] += weight[i] * h.real
            sum_im[parent[i]] += weight[i] * h.imag
    return power, sum_re, sum_im


def field_spectra(spectra, lmax, fwhm_arcmin):
    """Beam-smoothed spectra of the sky.

    Parameters
    ----------
    spectra : boresight.cosmology.Spectra
    lmax : int
    fwhm_arcmin : float

    Returns
    -------
    tt, ee, bb : numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    tt, ee, bb, _ = spectra.total(lmax=lmax)
    beam = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=lmax, pol=True)
    return tt * beam[:, 0] ** 2, ee * beam[:, 1] ** 2, bb * beam[:, 2] ** 2


class Term(NamedTuple):
    """One term c h_n F of the spurious P (with, for a pair of beam terms, its partner
    c' h_{-n} F'): its moment n (h_{-n} = conj h_n), coefficient c, the spectra [muK^2] whose
    halves its E and B modes take (equal but for such a pair), and whether the engine reads its
    field exactly at the hits (the beams' fields) rather than by interpolation of the sky's maps."""

    n: int
    c: complex
    cl_e: np.ndarray
    cl_b: np.ndarray
    exact: bool = False


def leak_terms(
    coefs, systematics, cl_tt, cl_pol, template_cl=None, beam=None, beam_cl=None, t2_mean=None
):
    """The terms c h_n F of the spurious P whose spectra add (all but the h_0 terms).

    Parameters
    ----------
    coefs : Coefficients
    systematics : boresight.instrument.Systematics
        Which terms are on (leak, pointing).
    cl_tt, cl_pol : numpy.ndarray, shape (lmax + 1,)
        Spectra of T and of P (EE + BB) [muK^2].
    template_cl : numpy.ndarray, optional
        Spectrum of the leak's template (default: TT).
    beam : dict of int to numpy.ndarray, optional
        The beam terms' filters (:func:`beam_filters`): G_2 joins the gain's h_2 T term, every
        other n but 0 is a term of its own.
    beam_cl : numpy.ndarray, shape (4, >= lmax + 1), optional
        The TT, EE, BB, TE those terms scale (:func:`beam_spectra`); required with ``beam``.
    t2_mean : complex, optional
        E t2 when ``coefs`` holds expected powers (:func:`expected_coefficients`): the h_2 term is
        then E``|t2 T + G_2|^2`` = ``|coefs.t2|^2`` TT + 2 Re(E t2 conj(g_T)) TT
        + 2 Re(E t2 conj(g_E)) TE + ``|G_2|^2``.

    Returns
    -------
    list of Term
        With ``beam``, the first (h_2: gain and G_2) and those after the others carry the beams.
    """
    ell = np.arange(cl_tt.size)
    terms = [Term(2, coefs.t2, cl_tt, cl_tt), Term(4, coefs.p4, cl_pol, cl_pol)]
    if systematics.has_leak:
        template = cl_tt if template_cl is None else np.zeros(cl_tt.size)
        if template_cl is not None:  # zero beyond the template's own band limit
            n = min(cl_tt.size, template_cl.size)
            template[:n] = template_cl[:n]
        terms.append(Term(2, coefs.s2, template, template))
    if systematics.has_pointing:
        grad = ell * (ell + 1) * cl_tt
        terms += [Term(1, coefs.g1, grad, grad), Term(3, coefs.g3, grad, grad)]
    if beam is not None:
        terms[0] = Term(2, 1.0, *_gain_and_beam(coefs, beam, beam_cl, t2_mean), exact=True)
        for n, filt in beam.items():
            if n in (0, 2, -2) or (n < 0 and -n in beam):
                continue  # h_0 is beam_h0_bb's; a negative n with a partner goes with it
            partner = np.conj(beam.get(-n, np.zeros_like(filt))) * (-1) ** n
            if not (np.any(filt) or np.any(partner)):
                continue
            cl_e, cl_b = (beam_power(filt + sign * partner, beam_cl) for sign in (1, -1))
            terms.append(Term(n, 1.0, cl_e, cl_b, exact=True))
    return terms


def _gain_and_beam(coefs, beam, beam_cl, t2_mean):
    """E and B spectra of the h_2 terms with the beams: t2 T + G_2 and its partner G_{-2}, whose
    B modes subtract (docs/conventions.md); with ``t2_mean``, averaged over the gain's draws."""
    g2 = beam[2]
    partner = np.conj(beam.get(-2, np.zeros_like(g2)))
    out = []
    for v in (g2 + partner, g2 - partner):
        if t2_mean is None:
            out.append(beam_power(v + np.array([coefs.t2, 0, 0])[:, None], beam_cl))
            continue
        tt, te = beam_cl[0], beam_cl[3]
        cross = (
            2 * np.real(t2_mean * np.conj(v[0])) * tt + 2 * np.real(t2_mean * np.conj(v[1])) * te
        )
        out.append(abs(coefs.t2) ** 2 * tt + cross + beam_power(v, beam_cl))
    return out


class FieldSpectra(NamedTuple):
    """Beam-smoothed spectra of the fields a prediction scales [muK^2]: TT, EE + BB (the h_4 P*
    term) and EE, (lmax + 1,) each, as full-sky equivalents (pseudo-C_ell / <w^2>); the maps'
    own pseudo-C_ell EE, BB, EB through the mask, (3, lmax + 1) (the h_0 term,
    :func:`signal_bb`); and, for the beam terms (:func:`beam_spectra`), TT, EE, BB, TE through
    the apodized mask, (4, lmax + 1). ``read`` keeps, per window, the EE, BB, EB of the sky as the
    hits read it (windowed, then masked), made on first use by :func:`residual_pseudo_bb`."""

    tt: np.ndarray
    pol: np.ndarray
    ee: np.ndarray
    masked: np.ndarray | None = None
    apodized: np.ndarray | None = None
    read: dict | None = None


BEAM_APODIZATION_DEG = 2.0  #: apodization of the mask for the beam terms' local spectra


def local_cl(
    sky: Sky,
    mask: np.ndarray,
    lmax: int,
    nthreads: int = 0,
    beams: bool = False,
    analysis: str = "auto",
) -> FieldSpectra:
    """Beam-smoothed TT, EE + BB and EE of one sky inside a mask: pseudo-C_ell / <w^2>.

    Feeding these to :func:`systematic_cl` instead of the theory removes the patch's sample variance
    when a prediction is compared with a simulation of that sky.

    Parameters
    ----------
    sky : boresight.sky.Sky
    mask : numpy.ndarray, shape (npix,)
    lmax : int
    nthreads : int
    beams : bool
        Also TT, EE, BB, TE through the apodized mask, for beam systematics (one more analysis).
    analysis : str
        :func:`boresight.harmonics.map2alm`'s analysis, as the simulated maps'.

    Returns
    -------
    FieldSpectra
    """
    from .masks import apodize

    mask = np.asarray(mask, dtype=np.float64)
    pseudo = pseudo_spectra(sky.maps, mask, lmax, nthreads, analysis)
    cl = pseudo / np.mean(mask**2)
    masked = pseudo[[1, 2, 4]]
    if not beams:
        return FieldSpectra(cl[0], cl[1] + cl[2], cl[1], masked, read={})
    smooth = mask * apodize((mask > 0).astype(np.float64), BEAM_APODIZATION_DEG)
    apodized = pseudo_spectra(sky.maps, smooth, lmax, nthreads, analysis)[:4]
    apodized /= np.mean(smooth**2)
    return FieldSpectra(cl[0], cl[1] + cl[2], cl[1], masked, apodized, read={})


def systematic_cl(
    h: np.ndarray,
    mask: np.ndarray | Footprint,
    systematics: Systematics,
    spectra: Spectra,
    lmax: int,
    fwhm_arcmin: float,
    instrument: Instrument | None = None,
    template_cl: np.ndarray | None = None,
    field_cl: FieldSpectra | None = None,
    rotations_deg: Sequence[float] = (0.0,),
    crossings: np.ndarray | None = None,
    in_pixel: str = "centre",
    expected: bool = False,
    interpolated: bool = False,
) -> np.ndarray:
    """Full-sky spurious C^EE and C^BB predicted from h_n over a mask (all terms but h_0).

    Every term shares its power equally between E and B but the beams' pairs of terms h_n G_n
    and h_{-n} G_{-n}, whose B modes partly cancel (docs/conventions.md).

    Parameters
    ----------
    h : numpy.ndarray, complex128, shape (>= 5, npix)
        h_n of one repeat (as in :func:`delta_p`); the beams' terms use the moments it holds, to
        :data:`BEAM_N_MAX`.
    mask : numpy.ndarray, shape (npix,), or boresight.spectra.Footprint
    systematics : boresight.instrument.Systematics
    spectra : boresight.cosmology.Spectra
    lmax : int
        The sky's band limit: every field's power to it enters, also that a mask later mixes
        below a lower lmax of the pseudo-spectra (a :class:`boresight.coupling.Coupling`'s band).
    fwhm_arcmin : float
    instrument : boresight.instrument.Instrument, optional
    template_cl : numpy.ndarray, optional
        Spectrum of the leak's template.
    field_cl : FieldSpectra, optional
        Beam-smoothed spectra to use instead of the theory (:func:`local_cl`) where they reach.
    rotations_deg : sequence of float
        The repeats' boresight rotations [deg].
    crossings : numpy.ndarray, shape (npix,), optional
        Crossings per pixel in one repeat; needed with gain jitter or random in-pixel hits.
    in_pixel : {"centre", "random"}
        Where the scan's hits fall in their pixels (``SyntheticScan.in_pixel``): "random" adds
        the pixel window and the in-pixel scatter of every field (:class:`_HitSpread`).
    expected : bool
        The average over the per-pair draws of {mean, rms} parameters (:func:`expected_power`)
        instead of the drawn focal plane.
    interpolated : bool
        With random in-pixel hits: the sky's fields are read by bilinear interpolation of the
        maps (the engine's ``evaluation="interp"``), so the terms of T, P, the leak's template and
        the pointing take :func:`interpolation_window`; the beams' terms are read exactly.

    Returns
    -------
    numpy.ndarray, shape (2, lmax + 1)
        C^EE, C^BB [muK^2], 0 at ell < 2.

    Raises
    ------
    ValueError
        m_4 != 0 (:func:`supports`), or jitter or random hits without ``crossings``.
    """
    coefs = coefficients(systematics, instrument, rotations_deg)
    _check_supported(coefs)
    t2_mean = None
    if expected:
        power = expected_power(systematics, instrument, rotations_deg)
        coefs, t2_mean = expected_coefficients(coefs, power), power.t2_mean
    nside = hp.npix2nside(h.shape[1])
    band = lmax  # the fields' variance and spectra to the sky's band limit
    cl_tt, cl_pol = _field_cl(spectra, band, fwhm_arcmin, field_cl)
    omega_pix = 4 * np.pi / h.shape[1]
    ell = np.arange(band + 1)
    out = np.zeros((2, lmax + 1))
    footprint = as_footprint(mask)
    blocks = PixelBlocks(footprint)
    beam = beam_cl = None
    if systematics.has_beams:  # the patch's spectra through the apodized mask: beam_spectra
        n_max = min(BEAM_N_MAX, h.shape[0] - 1)
        beam = beam_filters(systematics, instrument, rotations_deg, fwhm_arcmin, band, n_max)
        beam_cl = beam_spectra(spectra, band, fwhm_arcmin, field_cl)
    inverse_hits = _inverse_hits(in_pixel, footprint, crossings)
    exact = _HitSpread(in_pixel, nside, band, inverse_hits)
    value = _HitSpread(in_pixel, nside, band, inverse_hits, interpolated)
    slope = value  # replaced for the pointing terms below
    if systematics.has_pointing:
        slope = _HitSpread(in_pixel, nside, band, inverse_hits, interpolated, gradient=True)
    terms = leak_terms(coefs, systematics, cl_tt, cl_pol, template_cl, beam, beam_cl, t2_mean)
    for n, c, cl_e, cl_b, read_exactly in terms:
        if c == 0:
            continue
        total, coherent = blocks.coherent_power(h[abs(n)])
        spread = exact if read_exactly else slope if n in (1, 3) else value  # 1, 3: pointing
        (cl_e, noise_e), (cl_b, noise_b) = spread(cl_e), spread(cl_b)
        variance = np.sum((2 * ell + 1) / (4 * np.pi) * (cl_e + cl_b)) / 2
        white = (total - coherent) * omega_pix * variance + (noise_e + noise_b) / 2
        for row, cl in enumerate((cl_e, cl_b)):
            out[row] += 0.5 * abs(c) ** 2 * (coherent * cl[: lmax + 1] + white)
    jitter_var = jitter_variance(systematics, coefs, expected)
    if jitter_var > 0:
        if crossings is None:
            raise ValueError(
                "the gain jitter's prediction needs the scan's crossings per pixel (crossings=)"
            )
        w2 = blocks.weight**2
        inverse_samples = np.sum(w2 / (crossings[blocks.obs] * coefs.n_samples)) / np.sum(w2)
        point = value.point if value.on else 1.0  # T's variance where the hits read it
        variance_t = np.sum((2 * ell + 1) / (4 * np.pi) * cl_tt * point)
        out += 0.5 * omega_pix * jitter_var * variance_t * inverse_samples
    out[:, :2] = 0.0
    return out


def _field_cl(spectra, band, fwhm_arcmin, field_cl):
    """TT and EE + BB to ``band``: the patch's own (``field_cl``) where it has them, else the
    theory's."""
    cl_tt, cl_ee, cl_bb = field_spectra(spectra, band, fwhm_arcmin)
    cl_pol = cl_ee + cl_bb
    if field_cl is not None:
        n = min(band + 1, field_cl.tt.size)
        cl_tt[:n], cl_pol[:n] = field_cl.tt[:n], field_cl.pol[:n]
    return cl_tt, cl_pol


SPREAD_PIXELS = 1 << 16  #: pixels whose hit pairs sample the window of hits spread over pixels


@lru_cache(maxsize=8)
def hit_spread_window(nside: int, band: int) -> np.ndarray:
    """w_l^2 = <P_l(cos gamma)> over two hits of one pixel, drawn as the engine draws them
    (uniform in the pixel's face coordinates): the window, squared, of a field averaged over its
    pixel's hits, and 1 - w_l^2 the share of C_l that scatters from hit to hit within a pixel.

    A quadrature over ``SPREAD_PIXELS`` pixels of the whole sphere (the HEALPix pixel shapes
    included), with a fixed seed.

    Parameters
    ----------
    nside, band : int

    Returns
    -------
    numpy.ndarray, shape (band + 1,)
    """
    from .tod_cpu import generate_hits

    npix = 12 * nside**2
    pixels = np.unique(np.linspace(0, npix - 1, min(npix, SPREAD_PIXELS)).astype(np.int64))
    offsets = 2 * np.arange(pixels.size + 1, dtype=np.int64)
    zeros = np.zeros(pixels.size)
    theta, phi, _ = generate_hits(0, nside, pixels, offsets, zeros, zeros, False)
    vec = np.array(hp.ang2vec(theta, phi))
    x = np.clip(np.sum(vec[0::2] * vec[1::2], axis=1), -1.0, 1.0)
    return _legendre_means(x, np.ones_like(x), band)


LEGENDRE_BLOCKS = 64  #: fixed blocks of the Legendre sums, added in order: no thread dependence


def _legendre_means(x, weight, band):
    """sum(weight P_l(x)) / n for l = 0..band, n the size of x's last axis (Legendre recurrence).

    Parameters
    ----------
    x, weight : numpy.ndarray, same shape
        Cosines of angles and their weights.
    band : int

    Returns
    -------
    numpy.ndarray, shape (band + 1,)
    """
    flat_x = np.ascontiguousarray(x, dtype=np.float64).ravel()
    flat_w = np.ascontiguousarray(weight, dtype=np.float64).ravel()
    partial = np.zeros((LEGENDRE_BLOCKS, band + 1))
    _legendre_sums(flat_x, flat_w, partial)
    return partial.sum(axis=0) / x.shape[-1]


@numba.njit(parallel=True, cache=True)
def _legendre_sums(x, weight, out):
    """out[k, l] = sum of weight P_l(x) over block k of x (the blocks fixed by out's rows); the
    recurrence runs over ell for a whole block at once, so the inner loop is SIMD."""
    blocks, band = out.shape[0], out.shape[1] - 1
    for k in numba.prange(blocks):
        lo, hi = k * x.size // blocks, (k + 1) * x.size // blocks
        xs, ws = x[lo:hi], weight[lo:hi]
        p_prev, p = np.ones(hi - lo), xs.copy()
        out[k, 0] = ws.sum()
        for ell in range(1, band + 1):
            a, b = (2 * ell + 1) / (ell + 1), ell / (ell + 1)
            acc = 0.0
            for i in range(hi - lo):
                acc += ws[i] * p[i]
                nxt = a * xs[i] * p[i] - b * p_prev[i]
                p_prev[i] = p[i]
                p[i] = nxt
            out[k, ell] = acc


def beam_spectra(
    spectra: Spectra, band: int, fwhm_arcmin: float, field_cl: FieldSpectra | None = None
) -> np.ndarray:
    """The beam-smoothed TT, EE, BB, TE that the beam terms scale: the patch's through the
    apodized mask where ``field_cl`` has them (:func:`local_cl` with ``beams=True``), else the
    theory's.

    The sharp mask's pseudo-C_ell / <w^2> carries the mask's mixing of low-ell power into high
    ell, which the l^4 weight of nabla^2 T and eth^2 T turned into a 20x overshoot at ell > 600
    for a 30 arcmin beam at Nside 512; the theory alone misses the patch's sample variance
    (11 % in a band at Nside 256).

    Parameters
    ----------
    spectra : boresight.cosmology.Spectra
    band : int
    fwhm_arcmin : float
    field_cl : FieldSpectra, optional

    Returns
    -------
    numpy.ndarray, shape (4, band + 1)
        [muK^2].
    """
    # healpy's TE window is sqrt(b_T b_E), so every column squared is the spectrum's window
    cl = spectra.total(lmax=band) * hp.gauss_beam(fwhm_arcmin * ARCMIN, band, pol=True).T ** 2
    if field_cl is not None and field_cl.apodized is not None:
        n = min(band + 1, field_cl.apodized.shape[1])
        cl[:, :n] = field_cl.apodized[:, :n]
    return cl


@lru_cache(maxsize=8)
def interpolation_window(
    nside: int, band: int, gradient: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """The windows of a field read by bilinear interpolation of its pixel-centre values
    (healpy.get_interp_weights, the engine's "interp" evaluation) at hits spread over the pixel.

    With f(x) = sum_c w_c(x) F(n_c) over the four neighbours c of x: ``point`` =
    <sum_cc' w_c(x) w_c'(x) P_l(n_c . n_c')> (the variance of f at a hit, per unit C_l) and
    ``pair`` = the same for two hits x, y of one pixel (the variance of the pixel's mean over
    many hits). With ``gradient``, the same for the gradient of the interpolated surface (what a
    pointing offset reads: f(x + rho) - f(x)), with grad w_c . grad w_c' in place of w_c w_c'
    and divided by l (l + 1), the gradient's own factor. A quadrature over ``SPREAD_PIXELS`` / 4
    pixels with the engine's hit draws; gradients by central differences of 1e-6 rad along
    e_theta and e_phi (hits whose neighbours change within that step are left out).

    Parameters
    ----------
    nside, band : int
    gradient : bool

    Returns
    -------
    pair, point : numpy.ndarray, shape (band + 1,)
    """
    from .tod_cpu import generate_hits

    npix = 12 * nside**2
    pixels = np.unique(np.linspace(0, npix - 1, min(npix, SPREAD_PIXELS // 4)).astype(np.int64))
    offsets = 2 * np.arange(pixels.size + 1, dtype=np.int64)
    zeros = np.zeros(pixels.size)
    theta, phi, _ = generate_hits(0, nside, pixels, offsets, zeros, zeros, False)
    neighbours, weights = hp.get_interp_weights(nside, theta, phi)  # (4, 2 n)
    keep = np.ones(theta.size, dtype=bool)
    if gradient:
        step, parts = 1e-6, []
        for d_theta, d_phi in ((step, 0.0), (0.0, step / np.sin(theta))):
            up, w_up = hp.get_interp_weights(nside, theta + d_theta, phi + d_phi)
            down, w_down = hp.get_interp_weights(nside, theta - d_theta, phi - d_phi)
            keep &= np.all(up == neighbours, axis=0) & np.all(down == neighbours, axis=0)
            parts.append((w_up - w_down) / (2 * step))
        weights = np.stack(parts)  # (2, 4, 2 n): d w_c / d e_theta, d w_c / d e_phi
    else:
        weights = weights[None]
    both = keep[0::2] & keep[1::2]
    vec = np.array(hp.pix2vec(nside, neighbours.ravel())).reshape(3, 4, -1)
    x_vec, y_vec = vec[:, :, 0::2][..., both], vec[:, :, 1::2][..., both]
    x_w, y_w = weights[:, :, 0::2][..., both], weights[:, :, 1::2][..., both]
    ell = np.arange(band + 1)
    norm = np.maximum(ell * (ell + 1), 1) if gradient else np.ones(band + 1)
    out = {}
    for key, (a, b, w_a, w_b) in {
        "pair": (x_vec, y_vec, x_w, y_w),
        "point": (x_vec, x_vec, x_w, x_w),
    }.items():
        x = np.clip(np.einsum("icn,idn->cdn", a, b), -1.0, 1.0)
        w = np.einsum("icn,idn->cdn", w_a, w_b)
        out[key] = _legendre_means(x, w, band) / norm
    if gradient:
        out["pair"][0] = out["point"][0] = 1.0  # the monopole has no gradient
    return out["pair"], out["point"]


def _inverse_hits(in_pixel, footprint, crossings):
    """<1 / N_hits> over the observed pixels, weighted by the mask squared, where hits spread
    over their pixels (``in_pixel`` "random" with ``crossings`` (npix,)); else None."""
    if in_pixel != "random" or crossings is None:
        return None
    w2 = footprint.weights**2
    return np.sum(w2 / crossings[footprint.pixels]) / np.sum(w2)


class _HitSpread:
    """What hits spread at random over their pixels do to a field F's term: its coherent part is
    F averaged over the pixel's hits (C^FF times the pair window), and each hit's departure from
    that average adds white noise of variance sigma_in^2 / N_hits per pixel, sigma_in^2 =
    sum_l (2l + 1) / 4 pi C^FF (point - pair). A field read exactly at the hit has point = 1 and
    pair = w_l^2 (:func:`hit_spread_window`); one interpolated from pixel centres has
    :func:`interpolation_window`. Nothing for pixel-centre hits."""

    def __init__(self, in_pixel, nside, band, inverse_hits, interpolated=False, gradient=False):
        if in_pixel not in ("centre", "random"):
            raise ValueError(f"in_pixel must be 'centre' or 'random', got {in_pixel!r}")
        self.on = in_pixel == "random"
        if self.on:
            if inverse_hits is None:
                raise ValueError("hits spread over their pixels need the crossings per pixel")
            if interpolated:
                self.pair, self.point = interpolation_window(nside, band, gradient)
            else:
                self.pair, self.point = hit_spread_window(nside, band), 1.0
            self.noise = 4 * np.pi / (12 * nside**2) * inverse_hits
            self.ell = np.arange(band + 1)

    def __call__(self, cl_ff):
        """(C^FF of the pixel-averaged field, the white power of the in-pixel scatter)."""
        if not self.on:
            return cl_ff, 0.0
        scatter = np.sum((2 * self.ell + 1) / (4 * np.pi) * cl_ff * (self.point - self.pair))
        return cl_ff * self.pair, self.noise * scatter


def signal_bb(
    coupling: Coupling,
    coefs: Coefficients,
    cl_ee: np.ndarray,
    cl_bb: np.ndarray,
    leaked: bool = False,
    expected: ExpectedPower | None = None,
    masked: np.ndarray | None = None,
) -> np.ndarray:
    """Pseudo-C_BB change of the h_0 term, which turns the sky's P into u P with u = 1 + p_0.

    E' + i B' = u (E + i B), so dB = Im(u) E + (Re(u) - 1) B. Its leaked power <dB, dB> is
    (Re u - 1)^2 BB + Im(u)^2 EE + 2 (Re u - 1) Im(u) EB; the whole change adds the cross terms
    2 (Re u - 1) BB + 2 Im(u) EB. For full-sky spectra (EB = 0) that is Im(u)^2 C^EE +
    (Re(u)^2 - 1) C^BB through the mask's coupling. As u is one number for the whole map, the
    maps' own masked pseudo-spectra (``masked``) give it exactly, the mask's E-to-B leakage of
    this very sky included.

    Parameters
    ----------
    coupling : boresight.coupling.Coupling
    coefs : Coefficients
    cl_ee, cl_bb : numpy.ndarray, shape (lmax + 1,)
        Full-sky spectra [muK^2], used without ``masked``.
    leaked : bool
        The leaked power <dB, dB> only.
    expected : ExpectedPower, optional
        Use its averages of p_0's powers over the per-pair draws instead of coefs'.
    masked : numpy.ndarray, shape (3, lmax + 1), optional
        The maps' pseudo-C_ell EE, BB, EB through the mask [muK^2].

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    if expected is None:
        w = coefs.p0
        re, im, re2, im2, reim = w.real, w.imag, w.real**2, w.imag**2, w.real * w.imag
    else:
        e = expected
        re, im, re2, im2, reim = e.re_p0, e.im_p0, e.re_p0_2, e.im_p0_2, e.re_im_p0
    if masked is None:
        ee, bb = coupling.pseudo_bb(cl_ee, cl_bb), coupling.pseudo_bb(cl_bb, cl_ee)
        eb = np.zeros_like(ee)
    else:
        ee, bb, eb = masked[:, : coupling.lmax + 1]
    out = re2 * bb + im2 * ee + 2 * reim * eb
    if not leaked:
        out = out + 2 * re * bb + 2 * im * eb
    return out


def residual_pseudo_bb(
    h: np.ndarray,
    mask: np.ndarray | Footprint,
    coupling: Coupling,
    systematics: Systematics,
    spectra: Spectra,
    fwhm_arcmin: float,
    instrument: Instrument | None = None,
    template_cl: np.ndarray | None = None,
    field_cl: FieldSpectra | None = None,
    rotations_deg: Sequence[float] = (0.0,),
    crossings: np.ndarray | None = None,
    leaked: bool = False,
    in_pixel: str = "centre",
    expected: bool = False,
    interpolated: bool = False,
    sky: Sky | None = None,
    analysis: str = "auto",
) -> np.ndarray:
    """Predicted masked residual C_BB(sys) - C_BB(no sys) (paper eq. 10).

    The leaked power M^{BB,BB} C^BB_sys + M^{BB,EE} C^EE_sys plus the h_0 term's change of the
    cosmological signal (:func:`signal_bb`; for the paper's gain (1 - (dg_1 + dg_2)/4)^2 - 1),
    plus the beams' h_0 field (:func:`beam_h0_bb`; its cross term with an angle error's
    rotation of E is left out). With ``field_cl`` the h_0 term of u uses the maps' own masked
    spectra (:func:`signal_bb`).

    Parameters
    ----------
    h, mask, systematics, spectra, fwhm_arcmin, instrument, template_cl, field_cl
        As in :func:`systematic_cl`; ``mask`` may be its :class:`boresight.spectra.Footprint`.
    coupling : boresight.coupling.Coupling
        The mask's coupling; its lmax is the prediction's, its band the sky's band limit, to
        which the fields' power enters (what the mask mixes down from above lmax included).
    rotations_deg, crossings, in_pixel, expected, interpolated
        As in :func:`systematic_cl`.
    leaked : bool
        Predict the leaked power <dB, dB> alone, without the h_0 term's rescaling of the sky's own
        B (:func:`signal_bb`).
    sky : boresight.sky.Sky, optional
        The simulated sky: the beams' h_0 field is then made on the sphere and masked
        (:func:`beam_h0_bb`), so its leaked power is this realisation's.
    analysis : str
        How that masked field becomes pseudo-alm (:func:`boresight.harmonics.map2alm`).

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    lmax, band = coupling.lmax, coupling.band
    mask = as_footprint(mask)  # the observed pixels, once for every use below
    inverse_hits = _inverse_hits(in_pixel, mask, crossings)
    cl_sys = systematic_cl(
        h,
        mask,
        systematics,
        spectra,
        band,
        fwhm_arcmin,
        instrument,
        template_cl,
        field_cl,
        rotations_deg,
        crossings,
        in_pixel,
        expected,
        interpolated,
    )
    nside = hp.npix2nside(h.shape[1])
    _, cl_ee, cl_bb = field_spectra(spectra, band, fwhm_arcmin)
    if field_cl is not None:  # the patch's E; its masked B would carry the mask's E-to-B leak
        n = min(band + 1, field_cl.ee.size)
        cl_ee[:n] = field_cl.ee[:n]
    masked = None if field_cl is None else field_cl.masked
    if masked is not None and masked.shape[1] < lmax + 1:
        raise ValueError(f"field_cl holds the maps' spectra to {masked.shape[1] - 1} < lmax {lmax}")
    if in_pixel == "random":  # the maps' P as the hits read it: windowed, plus in-pixel scatter
        spread = _HitSpread(in_pixel, nside, band, inverse_hits, interpolated)
        (cl_ee, noise_e), (cl_bb, noise_b) = spread(cl_ee), spread(cl_bb)
        white = 0.5 * (noise_e + noise_b)
        cl_ee, cl_bb = cl_ee + white, cl_bb + white
        if masked is not None:
            scatter = coupling.pseudo_bb(np.full(band + 1, white), np.full(band + 1, white))
            if sky is not None:  # the maps as the hits read them, masked: window, then mask
                read = {} if field_cl.read is None else field_cl.read
                key = (interpolated, lmax, analysis)
                if key not in read:
                    read[key] = _windowed_masked(sky, np.sqrt(spread.pair), mask, lmax, analysis)
                masked = read[key]
            else:
                masked = masked[:, : lmax + 1] * spread.pair[: lmax + 1]
            masked = masked + [
                scatter,
                scatter,
                np.zeros_like(scatter),
            ]
    coefs = coefficients(systematics, instrument, rotations_deg)
    power = expected_power(systematics, instrument, rotations_deg) if expected else None
    signal = signal_bb(coupling, coefs, cl_ee, cl_bb, leaked, power, masked)
    if systematics.has_beams:
        g0 = beam_filters(systematics, instrument, rotations_deg, fwhm_arcmin, band, 0)[0]
        beam_cl = beam_spectra(spectra, band, fwhm_arcmin, field_cl)
        spread = _HitSpread(in_pixel, nside, band, inverse_hits)
        h0 = beam_h0_bb(coupling, g0, beam_cl, leaked, spread, sky, mask, analysis)
        signal = signal + h0
    return coupling.pseudo_bb(cl_sys[1], cl_sys[0]) + signal


def _windowed_masked(sky, window, mask, lmax, analysis):
    """EE, BB, EB pseudo-C_ell (3, lmax + 1) of the sky's Q, U smoothed by ``window`` (per ell),
    then masked: the mask's E-to-B leakage of the maps the hits read."""
    n = min(window.size, sky.lmax + 1)
    alm = harmonics.almxfl(sky.alm[1:], np.pad(window[:n], (0, sky.lmax + 1 - n)))
    footprint = as_footprint(mask)  # the maps on the observed pixels only
    qu = harmonics.alm2map_pixels(alm, footprint.pixels, sky.nside, spin=2)
    e, b = footprint.alm(qu, lmax, 2, analysis=analysis, overwrite=True)
    return np.array([harmonics.alm2cl(e), harmonics.alm2cl(b), harmonics.alm2cl(e, b)])


def beam_h0_bb(
    coupling: Coupling,
    g0: np.ndarray,
    cl: np.ndarray,
    leaked: bool = False,
    spread: _HitSpread | None = None,
    sky: Sky | None = None,
    mask: np.ndarray | None = None,
    analysis: str = "auto",
) -> np.ndarray:
    """Pseudo-C_BB of the beams' h_0 term, which no rotation changes.

    G_0 = sum_c g0[c] a^c is a spin-2 field: its E' and B' have the real filters -Re g0 and
    -Im g0 on (T, E, B) (a pure-E field rotated by the phase of g0; for an ellipticity,
    E' + i B' = -g0_T T to first order). Its leaked power is C^E'E', C^B'B'; the whole residual
    adds the cross terms 2 C^EE' and 2 C^BB' with the sky's own E and B (a smoothing of P).

    Parameters
    ----------
    coupling : boresight.coupling.Coupling
    g0 : numpy.ndarray, complex128, shape (3, band + 1)
        The h_0 filter of :func:`beam_filters`.
    cl : numpy.ndarray, shape (4, band + 1)
        TT, EE, BB, TE [muK^2] (:func:`beam_spectra`).
    leaked : bool
        The leaked power alone.
    spread : _HitSpread, optional
        Hits spread over their pixels, the field read exactly at each (default: pixel centres).
    sky, mask : optional
        The simulated sky and the mask: G_0 is then made on the sphere and its leaked power is
        its own masked pseudo-C_ell (windowed by the hits' spread, plus their scatter), this
        realisation's E-to-B leakage included, rather than the coupling's average.
    analysis : str
        How the masked field becomes pseudo-alm (:func:`boresight.harmonics.map2alm`).

    Returns
    -------
    numpy.ndarray, shape (coupling.lmax + 1,)
        [muK^2].
    """
    lmax, band = coupling.lmax, coupling.band
    e_filt, b_filt = -g0.real, -g0.imag
    (cl_e, noise_e), (cl_b, noise_b) = (
        (beam_power(f, cl), 0.0) if spread is None else spread(beam_power(f, cl))
        for f in (e_filt, b_filt)
    )
    white = 0.5 * (noise_b + noise_e)  # the scatter's phase is random: half in each of E, B
    if sky is not None:
        field = _beam_field(sky, g0, 2, 0)
        qu = np.array([field.real, field.imag])
        e_alm, b_alm = masked_pol_alm(qu, mask, lmax, analysis=analysis)
        window = spread.pair[: lmax + 1] if spread is not None and spread.on else 1.0
        scatter = coupling.pseudo_bb(np.full(band + 1, white), np.full(band + 1, white))
        out = harmonics.alm2cl(b_alm) * window + scatter
        if leaked:
            return out
        cl_e, cl_b = np.zeros(band + 1), np.zeros(band + 1)  # the cross terms below only
    else:
        out = 0.0
        cl_e, cl_b = cl_e[: band + 1] + white, cl_b[: band + 1] + white
    if not leaked:  # <E E'> = f_T TE + f_E EE, <B B'> = f_B BB, averaged over the pixel's hits
        window = spread.pair if spread is not None and spread.on else 1.0
        cross_e = 2 * (e_filt[0] * cl[3] + e_filt[1] * cl[1]) * window
        cross_b = 2 * b_filt[2] * cl[2] * window
        cl_e, cl_b = cl_e + cross_e[: band + 1], cl_b + cross_b[: band + 1]
    return out + coupling.pseudo_bb(cl_b, cl_e)


def rotation_suppression(n: int, rotations_deg: Sequence[float]) -> float:
    """``|h_n|^2`` after / before repeating every hit at each angle alpha_k:
    ``|<exp(i n alpha_k)>|^2``.

    For the schedule (0, alpha) this is cos^2(n alpha / 2).

    Parameters
    ----------
    n : int
    rotations_deg : sequence of float

    Returns
    -------
    float
    """
    alpha = np.radians(np.asarray(rotations_deg, dtype=np.float64))
    return float(np.abs(np.mean(np.exp(1j * n * alpha))) ** 2)


def pixel_window(nside: int, lmax: int) -> np.ndarray:
    """Window of a map that averages hits over its pixels: the window of a disc of the pixel's area,
    2 J_1(x) / x with x = ell sqrt(4 / npix) (healpy.pixwin needs a download).

    Parameters
    ----------
    nside, lmax : int

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
    """
    from scipy.special import j1

    x = np.arange(lmax + 1) * np.sqrt(4.0 / (12 * nside**2))
    return np.where(x > 0, 2 * j1(x) / np.where(x > 0, x, 1), 1.0)


def reference_bb(
    coupling: Coupling,
    spectra: Spectra,
    fwhm_arcmin: float,
    nside: int,
    r: float = 0.0,
    a_lens: float = 0.0,
) -> np.ndarray:
    """Pseudo-C_BB of the cosmological B-mode alone (E = 0), with beam and pixel window.

    Parameters
    ----------
    coupling : boresight.coupling.Coupling
    spectra : boresight.cosmology.Spectra
    fwhm_arcmin : float
    nside : int
    r, a_lens : float

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    band = coupling.band  # the sky's B above the spectra's lmax, which the mask mixes down
    beam = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=band, pol=True)[:, 2]
    pixwin = pixel_window(nside, band)
    cl = spectra.bb(r=r, a_lens=a_lens)[: band + 1] * (beam * pixwin) ** 2
    return coupling.pseudo_bb(cl, np.zeros_like(cl))


# The bias on the tensor-to-scalar ratio r that a residual B-mode spectrum implies.
#
# Estimator: the least-squares amplitude of the tensor template over a multipole range,
#     delta_r = sum_l R_l T_l / sum_l T_l^2,   lmin <= l <= lmax,
# with R_l the residual pseudo-C_BB and T_l the pseudo-C_BB of tensors at r = 1 through the same
# mask, beam and pixel window (reference_bb). Uniform weights: for the deep survey's
# 30 <= l <= 300 the template's shape dominates the weights that cosmic variance would give.

R_RANGE = (30, 300)  #: the deep survey's primordial range


def tensor_template(
    coupling: Coupling, spectra: Spectra, fwhm_arcmin: float, nside: int
) -> np.ndarray:
    """Pseudo-C_BB of tensors at r = 1 through the mask: the template of :func:`delta_r`.

    Parameters
    ----------
    coupling, spectra, fwhm_arcmin, nside
        As in :func:`reference_bb`.

    Returns
    -------
    numpy.ndarray, shape (lmax + 1,)
        [muK^2].
    """
    return reference_bb(coupling, spectra, fwhm_arcmin, nside, r=1.0)


def delta_r(
    residual: np.ndarray, template: np.ndarray, lmin: int = R_RANGE[0], lmax: int = R_RANGE[1]
) -> float:
    """The tensor-to-scalar ratio a residual pseudo-C_BB would fake: the least-squares amplitude of
    the template over lmin <= ell <= lmax.

    Parameters
    ----------
    residual, template : numpy.ndarray
        Pseudo-C_BB [muK^2] from ell = 0.
    lmin, lmax : int

    Returns
    -------
    float
    """
    lmax = min(lmax, residual.size - 1, template.size - 1)
    if lmin >= lmax:
        raise ValueError(f"empty multipole range [{lmin}, {lmax}] for delta_r")
    s = slice(lmin, lmax + 1)
    return float(np.sum(residual[s] * template[s]) / np.sum(template[s] ** 2))
