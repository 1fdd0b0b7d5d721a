"""What every focal-plane prediction shares: which systematics it covers, each pair's coefficient
shares, the hit-weighted means over pairs and the 2x2 solve of the map-maker, and the sky's fields a
systematic leaks with their derivatives, read at a pair's samples to second order in their offsets
from the pixel's centre (derived in docs/conventions.md, "Focal planes: pairs off the axis").
"""

from __future__ import annotations

import healpy as hp
import numpy as np

from .. import harmonics
from ..constants import DEG
from ..instrument.added import refuse as refuse_added
from ..instrument.hwp import check_systematics as check_hwp_systematics
from ..moments.hwp import (
    BEAM_BEHIND_TERMS,
    POINTING_BEHIND_TERMS,
    T_BEHIND_TERMS,
)
from . import field_products as fp_products
from .beam_fields import beam_field
from .coefficients import pair_terms
from .terms import TERMS
from .windows import hit_spread_window

#: the drawn parameters the expectation covers: those dP is linear in
LINEAR = ("dg", "leak", "rho_arcmin")


def check_supported(stats, systematics):
    refuse_added(systematics, "the focal-plane prediction")
    if stats.pair_h is None:
        raise ValueError("the focal plane's per-pair maps are needed: characterise with per_pair")
    if stats.hwp is not None:
        check_hwp_systematics(systematics, own_angles=True)
        if stats.hwp.present and not stats.has_behind(T_BEHIND_TERMS):
            raise ValueError(
                "pairs behind a HWP need each pair's moments behind it: characterise with "
                "per_pair and hwp"
            )
        if (
            systematics.has_pointing
            and stats.hwp.present
            and not stats.has_behind(POINTING_BEHIND_TERMS)
        ):
            raise ValueError(
                "a pointing offset behind a HWP needs each pair's pointing moments: "
                "characterise with per_pair and pointing"
            )
        if systematics.has_beams and stats.hwp.present and not stats.has_behind(BEAM_BEHIND_TERMS):
            raise ValueError(
                "beams behind a HWP need each pair's beam moments: characterise with per_pair "
                "and beams"
            )


def behind_plate(stats):
    """Whether the pairs sit behind a plate, whose pointing and beam terms take their own
    moments (:meth:`boresight.moments.FocalPlaneStats.behind`)."""
    return stats.hwp is not None and stats.hwp.present


def pair_shares(params, focalplane) -> dict:
    """Each pair's coefficient shares (:func:`boresight.predict.coefficients`' terms of one pair),
    for drawn parameters ``params`` (:class:`boresight.instrument.pairs.PairParameters`), (n_pairs,)
    complex each; no rotation repeat (a schedule's h_n hold its rotations)."""
    angles = np.asarray(focalplane.pair_angles_deg) * DEG
    return pair_terms(params, angles, np.zeros(1), np.zeros(1))


def pair_moment(stats, n):
    """Each pair's h_n (pairs, npix); h_-n = conj(h_n)."""
    h = stats.pair_h[:, abs(n)]
    return h if n >= 0 else np.conj(h)


def beam_sky_field(filt, n, window):
    """G_n of a filter as a sky field, read through ``window``: spin 2 - n (n > 2: conj(H_n))."""
    return fp_products.SkyField(2 - n, filt * window[: filt.shape[1]])


def spread_window(sky):
    """The amplitude window of a field's mean over hits spread uniformly over a pixel."""
    return np.sqrt(np.clip(hit_spread_window(sky.nside, sky.lmax), 0.0, None))


def taylor(field):
    """A field read at an offset delta from where it is known, to second order, as
    {offset: (scale, field)}: F + (conj(delta) d F + delta dbar F) / 2 + (conj(delta)^2 d d F
    + delta^2 dbar dbar F + 2 ``|delta|^2`` dbar d F) / 8
    (:func:`boresight.predict.field_products.derivative`; the offsets' names as
    :func:`boresight.moments.beams_behind` weights its moments)."""
    up, down = derivative_fields(field)
    return {
        None: (1.0, field),
        "conj": (0.5, up),
        "delta": (0.5, down),
        "conj2": (0.125, fp_products.derivative(up, raising=True)),
        "delta2": (0.125, fp_products.derivative(down, raising=False)),
        "abs2": (0.25, fp_products.derivative(up, raising=False)),
    }


def hit_mean(shares, weights, h):
    """sum_i share_i N_i / N h_i (npix,) of each pair's map h (pairs, npix)."""
    return np.einsum("i,ip,ip->p", shares, weights, h)


def leak_fields(sky, systematics, template, *, spread, nthreads):
    """The sky's fields each term multiplies: T, P and P*, the leak's template, the gradient G
    and G*; with ``spread``, each as its mean over hits spread uniformly over a pixel (its alm
    times the square root of :func:`~boresight.predict.windows.hit_spread_window`)."""
    alm = sky.alm
    if spread:
        window = spread_window(sky)
        alm = np.array([harmonics.almxfl(a, window) for a in alm])
        t = harmonics.alm2map(alm[0], sky.nside, nthreads=nthreads)
        q, u = harmonics.alm2map(alm[1:], sky.nside, spin=2, nthreads=nthreads)
    else:
        t, q, u = sky.maps
    p = q + 1j * u
    fields = {"t2": t, "p0": p, "p4": np.conj(p)}
    if systematics.has_leak:
        fields["s2"] = t if template is None else np.asarray(template, dtype=np.float64)
    if systematics.has_pointing:
        gradient = harmonics.alm2map_gradient(alm[0], sky.nside, nthreads)
        g = gradient[0] + 1j * gradient[1]
        fields["g1"], fields["g3"] = g, np.conj(g)
    return fields


def hit_weights(stats):
    """Each pair's share of a pixel's hits, N_i / N, (pairs, npix)."""
    return stats.pair_hits / np.maximum(stats.combined.hits, 1)


def leak_y(stats, weights, shares, fields, *, pairs=slice(None)):
    """Y of coefficient shares (pairs,) per term, over ``pairs`` (a slice; default all): the h_0
    term's moment is 1 where seen."""
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    for term in TERMS:
        if term.name in fields:
            h = term_h(stats, term.name, term.n, pairs)
            y += fields[term.name] * hit_mean(shares[term.name][pairs], weights[pairs], h)
    return y


def term_h(stats, name, n, pairs=slice(None)):
    """Each pair's moment of a term (pairs, npix): its h_n; behind a HWP a pointing term's own
    (the offset turns with the pair's crossing angle, the map-maker with its reflected one)."""
    if behind_plate(stats) and name in ("g1", "g3"):
        return stats.behind(n, 4)[pairs]
    return stats.pair_h[pairs, n]


def solve_pairs(y, h4):
    det = 1.0 - np.abs(h4) ** 2
    ok = det > 1e-12
    return np.where(ok, (y - h4 * np.conj(y)) / np.where(ok, det, 1.0), 0.0)


def mean_h4(stats, weights, shares):
    return hit_mean(shares["m4"], weights, stats.pair_h[:, 4])


def pixel_geometry(nside):
    """A :class:`boresight.predict.field_products.StepTerm`'s factor of cot(theta) and 1 /
    sin^2(theta) at the pixels' centres (npix,), as a function of the term."""
    theta = hp.pix2ang(nside, np.arange(12 * nside**2))[0]
    cot, csc2 = 1.0 / np.tan(theta), 1.0 / np.sin(theta) ** 2
    return lambda part: cot**part.cot * csc2**part.csc2


def derivative_fields(field):
    """A sky field's raising and lowering derivatives, d F and dbar F
    (:func:`boresight.predict.field_products.derivative`)."""
    return tuple(fp_products.derivative(field, raising=raising) for raising in (True, False))


def derivative_maps(sky, field, nthreads):
    """The maps of a sky field's raising and lowering derivatives d F and dbar F (npix,) complex
    each (:func:`boresight.predict.field_products.derivative`)."""
    return tuple(field_map(sky, f, nthreads) for f in derivative_fields(field))


def field_map(sky, field, nthreads):
    """The map of a sky field (npix,) complex; a negative spin is a conjugate."""
    value = beam_field(sky, field.filters, abs(field.spin), nthreads)
    return value if field.spin >= 0 else np.conj(value)


def field_maps(sky, nthreads):
    """:func:`field_map` that synthesises each field once: the coordinate step's and the pixel's
    Taylor series share most of their derivatives."""
    made = {}

    def read(field):
        key = (field.spin, np.asarray(field.filters).tobytes())
        if key not in made:
            made[key] = field_map(sky, field, nthreads)
        return made[key]

    return read


def polarisation_offset_y(sky, stats, params, weights, *, spread, nthreads, order):
    """Behind a HWP, what detector B reads of P off its place, its part of Y (npix,) complex, to
    first or second ``order`` in rho: at order 1 the term a spinning plate leaves of a pointing
    offset, where the T gradient's averages away (docs/conventions.md).

    B looks one step delta = rho exp(i beta) away in the coordinates, beta = psi + gamma +
    chi_rho, and reads P + Delta there, Delta = conj(delta) X + delta Z to first order and
    conj(delta)^2 C + delta^2 L + ``|delta|^2`` A to second
    (:func:`boresight.predict.field_products.coordinate_step`: X = d P / 2 + cot(theta) P, and
    Z = dbar P / 2 - cot(theta) P). The pair difference's (1/2) Re(Delta exp(-2 i a)),
    demodulated with a = psi' + gamma and beta' = gamma + chi_rho, gives::

      Y += rho/2 [e^{-i beta'} h_{-1,0} X + e^{i beta'} h_{1,0} Z
                  + e^{i (4 gamma + beta')} <e^{i (4 psi' + psi)}> conj(X)
                  + e^{i (4 gamma - beta')} <e^{i (4 psi' - psi)}> conj(Z)]
      Y += rho^2/2 [e^{-2 i beta'} h_{-2,0} C + e^{2 i beta'} h_{2,0} L + A
                    + e^{i (4 gamma + 2 beta')} <e^{i (4 psi' + 2 psi)}> conj(C)
                    + e^{i (4 gamma - 2 beta')} <e^{i (4 psi' - 2 psi)}> conj(L)
                    + e^{4 i gamma} <e^{4 i psi'}> conj(A)]

    h_{n,0} of the pairs' own crossing angles, which only the sky's and the boresight's rotation
    cancel, and at second order A, through no moment at all, which nothing cancels. These
    moments are coherent sums, so the fields are read as their means over hits spread over the
    pixel (``spread``). On a bare pair the term is P-sized against the T gradient's and left
    out, as :func:`boresight.predict.delta_p` does."""
    window = spread_window(sky) if spread else np.ones(sky.lmax + 1)
    step = fp_products.coordinate_step(fp_products.polarisation(window))
    gamma = np.asarray(stats.focalplane.pair_angles_deg, dtype=np.float64) * DEG
    beta = gamma + params.chi
    half = 0.5 * params.rho**order
    if order == 1:
        h = stats.behind(1, 0)
        terms = (  # (each pair's coefficient, its moment, the step's terms, conjugated)
            (half * np.exp(-1j * beta), np.conj(h), step["conj"], False),
            (half * np.exp(1j * beta), h, step["delta"], False),
            (half * np.exp(1j * (4 * gamma + beta)), stats.behind(5, 8), step["conj"], True),
            (half * np.exp(1j * (4 * gamma - beta)), stats.behind(3, 8), step["delta"], True),
        )
    else:
        h = stats.behind(2, 0)
        terms = (
            (half * np.exp(-2j * beta), np.conj(h), step["conj2"], False),
            (half * np.exp(2j * beta), h, step["delta2"], False),
            (half, stats.pair_h[:, 0], step["abs2"], False),  # h_0: 1 where a pair has hits
            (half * np.exp(4j * gamma + 2j * beta), stats.behind(6, 8), step["conj2"], True),
            (half * np.exp(4j * gamma - 2j * beta), stats.behind(2, 8), step["delta2"], True),
            (half * np.exp(4j * gamma), stats.behind(4, 8), step["abs2"], True),
        )
    geometry, read = pixel_geometry(sky.nside), field_maps(sky, nthreads)
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    for share, moment, parts, conjugated in terms:
        mean = hit_mean(share, weights, moment)
        for part in parts:
            value = read(part.field)
            y += part.scale * geometry(part) * mean * (np.conj(value) if conjugated else value)
    return y
