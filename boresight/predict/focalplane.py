"""The prediction for a focal plane whose pairs each cross the sky at their own angles.

The map-maker bins every pair's samples per pixel, so with N_i(p) hits of pair i and N = sum_i
N_i, the Y of :mod:`boresight.predict` becomes a hit-weighted sum over pairs, each with its own
moments h_n,i and its own coefficient shares (:func:`pair_shares`)::

  Y = sum_i (N_i / N) [t2_i h_2,i T + s2_i h_2,i S + g1_i h_1,i G + g3_i h_3,i G*
                       + p0_i P + p4_i h_4,i P*]
  dP = (Y - H_4 Y*) / (1 - ``|H_4|^2``),   H_4 = sum_i (N_i / N) m4_i h_4,i

(:func:`delta_p`), which is :func:`boresight.predict.delta_p` when every pair shares one h_n.
dP is real-linear in each pair's gain, leak and pointing amplitude. Over pairs drawn
independently with {mean, rms}, the expected masked pseudo-C_ell of dP is therefore exactly the
spectrum of dP at the means (the coherent part, through the focal-plane combination) plus, per
drawn parameter, rms^2 times the sum over pairs of the spectrum of that pair's unit leak
(the scattered part, through each pair's own (N_i / N) h_n,i): :func:`expected_leak_bb`. With
every pair on the axis the scattered part is the rms^2 / N_pairs of
:func:`boresight.predict.expected_power`, and rotation cancels the pairs' h_n together; off the
axis each pair keeps its own. Detector beams add sum_n (N_i / N) h_n,i G_n,i to Y, each pair's
own beam fields through its own h_n (:func:`beam_terms`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import healpy as hp
import numpy as np

from .. import harmonics
from ..beams import PARTS
from ..constants import DEG
from ..hwp import check_systematics as check_hwp_systematics
from ..hwp import reflected_systematics
from ..instrument import LIMITS, UNITS, PairParameters, Spread, Systematics
from ..mapmaking import check_mapmaker, solve_iqu
from ..scanstats import (
    BEAM_BEHIND_TERMS,
    BEAM_N_MAX,
    IP_BEHIND_TERMS,
    POINTING_BEHIND_TERMS,
    T_BEHIND_TERMS,
)
from ..spectra import as_footprint
from . import field_products as fp_products
from .beam_fields import beam_field, pairs_beam_filters
from .coefficients import pair_terms
from .expectation import (
    TERM_FIELDS,
    ExpectedResidual,
    budget_terms,
    fields_by_kind,
    offset_weights,
    sky_fields,
    smoothed_spectra,
)
from .windows import hit_spread_window

if TYPE_CHECKING:
    from ..cosmology import Spectra
    from ..hwp import HWP
    from ..scanstats import FocalPlaneStats
    from ..sky import Sky

#: the drawn parameters the expectation covers: those dP is linear in
LINEAR = ("dg", "leak", "rho_arcmin")
#: the coefficient shares and the moment each multiplies
TERMS = (("t2", 2), ("s2", 2), ("g1", 1), ("g3", 3), ("p0", 0), ("p4", 4))


def _check(stats, systematics):
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


def _behind_plate(stats):
    """Whether the pairs sit behind a plate, whose pointing and beam terms take their own
    moments (:meth:`boresight.scanstats.FocalPlaneStats.behind`)."""
    return stats.hwp is not None and stats.hwp.present


def pair_shares(params, focalplane) -> dict:
    """Each pair's coefficient shares (:func:`boresight.predict.coefficients`' terms of one pair),
    for drawn parameters ``params`` (:class:`boresight.instrument.PairParameters`), (n_pairs,)
    complex each; no rotation repeat (a schedule's h_n hold its rotations)."""
    angles = np.asarray(focalplane.pair_angles_deg) * DEG
    return pair_terms(params, angles, np.zeros(1), np.zeros(1))


class BeamTerm(NamedTuple):
    """One beam term h_n G_n of Y: its moment n, each pair's share (n_pairs,) complex,
    e^{i n gamma_i} on the pairs of one beam and 0 elsewhere, and the filter (3, band + 1) of G_n
    of a pair of that beam at angle 0 (:func:`boresight.predict.beam_fields.pairs_beam_filters`)."""

    moment: int
    shares: np.ndarray
    filter: np.ndarray


def beam_terms(params, focalplane, fwhm_arcmin, band, *, n_max, part="all") -> dict:
    """The pairs' beam terms, keyed ("beam", group, n), abs(n) <= n_max.

    A pair's G_n turns with its angle gamma as e^{i n gamma} (the filters' phase of
    :func:`boresight.predict.beam_fields.pairs_beam_filters`), so the pairs whose beams, gain and
    angle errors are alike share one field per n, each with its own phase in its share: a focal
    plane of one beam makes one field per moment, however many pairs and angles. The moments are
    those the focal plane's statistics hold (n_max): the ellipticity's eth^2 P at h_6 is left
    out, a polarisation-sized term; h_{-n} is conj(h_n). Empty without beams.

    Parameters
    ----------
    params : boresight.instrument.PairParameters
        Each pair's parameters (the means of drawn ones).
    focalplane : boresight.focalplane.FocalPlane
    fwhm_arcmin : float
        The sky's beam.
    band, n_max : int
    part : {"all", "T", "P"}
        The terms of the whole sky, of its T alone or of its polarisation alone
        (:data:`boresight.beams.PARTS`).

    Returns
    -------
    dict of tuple to BeamTerm
    """
    beams = ("dfwhm_a", "dfwhm_b", "ellipticity_a", "ellipticity_b")
    if not any(np.any(getattr(params, k)) for k in beams):
        return {}
    angles = np.asarray(focalplane.pair_angles_deg, dtype=np.float64) * DEG
    _, first, which = np.unique(
        np.column_stack(params), axis=0, return_index=True, return_inverse=True
    )
    zero = np.zeros(1)
    out = {}
    for g, i in enumerate(first):
        one = PairParameters(*(np.asarray(p)[i : i + 1] for p in params))
        filters = pairs_beam_filters(
            one, zero, zero, zero, fwhm_arcmin=fwhm_arcmin, lmax=band, n_max=n_max
        )
        alike = which.ravel() == g
        for n, filt in filters.items():
            filt = np.where(np.isin(np.arange(3), PARTS[part])[:, None], filt, 0.0)
            if np.any(filt):
                out["beam", g, n] = BeamTerm(n, np.where(alike, np.exp(1j * n * angles), 0), filt)
    return out


def _pair_moment(stats, n):
    """Each pair's h_n (pairs, npix); h_-n = conj(h_n)."""
    h = stats.pair_h[:, abs(n)]
    return h if n >= 0 else np.conj(h)


def beam_sky_field(filt, n, window):
    """G_n of a filter as a sky field, read through ``window``: spin 2 - n (n > 2: conj(H_n))."""
    return fp_products.SkyField(2 - n, filt * window[: filt.shape[1]])


def _spread_window(sky):
    """The amplitude window of a field's mean over hits spread uniformly over a pixel."""
    return np.sqrt(np.clip(hit_spread_window(sky.nside, sky.lmax), 0.0, None))


def _sky_beam_y(sky, stats, params, weights, spread, nthreads, offsets=None):
    """The beams' part of Y on this sky, sum over the beam terms of their weight times G_n (npix,),
    each G_n read exactly at the hits (their pixel mean with ``spread``), with its first-order
    change across the pixel where ``offsets`` are given (as :func:`delta_p` has them); behind a
    HWP, from :func:`_beam_parts_behind`, the T part read across the pixel to second order."""
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    n_max = stats.pair_h.shape[1] - 1
    window = _spread_window(sky) if spread else np.ones(sky.lmax + 1)
    parts = (
        [(params, "all", lambda n: ((1.0, _pair_moment(stats, n)),), False)]
        if not _behind_plate(stats)
        else _beam_parts_behind(stats, params)
    )
    for pair_params, part, moments, across in parts:
        if _behind_plate(stats):
            n_max = BEAM_N_MAX[4] if across else BEAM_N_MAX[0]
        terms = beam_terms(
            pair_params, stats.focalplane, sky.fwhm_arcmin, sky.lmax, n_max=n_max, part=part
        )
        for term in terms.values():
            n = term.moment
            if not across:
                field = beam_sky_field(term.filter, n, window)
                h = sum(scale * moment for scale, moment in moments(n))
                y += _mean(term.shares, weights, h) * _field_map(sky, field, nthreads)
                if offsets is not None:
                    maps = _derivative_maps(sky, field, nthreads)
                    for by, value in zip(offset_weights(offsets, n), maps):
                        y += 0.5 * value * _mean(term.shares, weights, by)
                continue
            # read at the samples: G at the centre and its Taylor terms to second order
            centre = beam_sky_field(term.filter, n, np.ones(sky.lmax + 1))
            for offset, (scale, field) in _taylor(centre).items():
                h = stats.behind(n, 4, offset)
                y += scale * _mean(term.shares, weights, h) * _field_map(sky, field, nthreads)
    return y


def _taylor(field):
    """A field read at an offset delta from where it is known, to second order, as
    {offset: (scale, field)}: F + (conj(delta) d F + delta dbar F) / 2 + (conj(delta)^2 d d F
    + delta^2 dbar dbar F + 2 ``|delta|^2`` dbar d F) / 8
    (:func:`boresight.predict.field_products.derivative`; the offsets' names as
    :func:`boresight.scanstats.beams_behind` weights its moments)."""
    up, down = _derivative_fields(field)
    return {
        None: (1.0, field),
        "conj": (0.5, up),
        "delta": (0.5, down),
        "conj2": (0.125, fp_products.derivative(up, raising=True)),
        "delta2": (0.125, fp_products.derivative(down, raising=False)),
        "abs2": (0.25, fp_products.derivative(up, raising=False)),
    }


def _mean(shares, weights, h):
    """sum_i share_i N_i / N h_i (npix,) of each pair's map h (pairs, npix)."""
    return np.einsum("i,ip,ip->p", shares, weights, h)


def _beam_parts_behind(stats, params):
    """Behind a HWP, the beams' terms as (pair parameters, part, moments of n, across): each a
    bare pair's filters of that part, whose h_n become sums of scale x h_{n,m}, the T part's
    with the fields' change across the pixel (:func:`_sky_beam_y`).

    A beam's shape turns with the pair's own crossing angle psi, its polarisation axis with
    a = psi' + 2 delta_h (the reflected angle, and the plate's angle offset); the map-maker
    demodulates with psi'. So the T part's h_n is h_{n,4}. The polarised part is
    Re(exp(-2 i (a - psi)) C), with C = S_0 + i S_45: S_0 the bare beam's, S_45 that of the beam
    whose polarisation axis is 45 deg further from its shape (polarisation angle + 45 deg,
    ellipticity angle - 45 deg). Its Y is (exp(-4 i delta_h) sum_n h_{n,0} (G_0,n + i G_45,n)
    + exp(4 i delta_h) sum_n h_{n,8} (G_0,n - i G_45,n)) / 2 (docs/conventions.md); detectors
    at their nominal angles (:func:`boresight.hwp.check_systematics`)."""
    nominal = params._replace(
        pol_angle=np.zeros_like(params.pol_angle), nonortho=np.zeros_like(params.nonortho)
    )
    quarter = 0.25 * np.pi
    turned = nominal._replace(
        pol_angle=nominal.pol_angle + quarter,
        ellipticity_angle_a=nominal.ellipticity_angle_a - quarter,
        ellipticity_angle_b=nominal.ellipticity_angle_b - quarter,
    )
    turn = np.exp(4j * stats.hwp.angle_offset_deg * DEG)

    def moments(*scales):
        def of(n):
            return tuple((scale, stats.behind(n, m)) for m, scale in scales)

        return of

    return [
        (nominal, "T", moments((4, 1.0)), True),
        (nominal, "P", moments((0, 0.5 / turn), (8, 0.5 * turn)), False),
        (turned, "P", moments((0, 0.5j / turn), (8, -0.5j * turn)), False),
    ]


def _fields(sky, systematics, template, spread, nthreads):
    """The sky's fields each term multiplies: T, P and P*, the leak's template, the gradient G
    and G*; with ``spread``, each as its mean over hits spread uniformly over a pixel (its alm
    times the square root of :func:`~boresight.predict.windows.hit_spread_window`)."""
    alm = sky.alm
    if spread:
        window = _spread_window(sky)
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


def _weights(stats):
    """Each pair's share of a pixel's hits, N_i / N, (pairs, npix)."""
    return stats.pair_hits / np.maximum(stats.combined.hits, 1)


def _y(stats, weights, shares, fields, pairs=slice(None)):
    """Y of coefficient shares (pairs,) per term, over ``pairs`` (a slice; default all): the h_0
    term's moment is 1 where seen."""
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    for name, n in TERMS:
        if name in fields:
            h = _term_h(stats, name, n, pairs)
            y += fields[name] * _mean(shares[name][pairs], weights[pairs], h)
    return y


def _term_h(stats, name, n, pairs=slice(None)):
    """Each pair's moment of a term (pairs, npix): its h_n; behind a HWP a pointing term's own
    (the offset turns with the pair's crossing angle, the map-maker with its reflected one)."""
    if _behind_plate(stats) and name in ("g1", "g3"):
        return stats.behind(n, 4)[pairs]
    return stats.pair_h[pairs, n]


def _solve(y, h4):
    det = 1.0 - np.abs(h4) ** 2
    ok = det > 1e-12
    return np.where(ok, (y - h4 * np.conj(y)) / np.where(ok, det, 1.0), 0.0)


def _h4(stats, weights, shares):
    return _mean(shares["m4"], weights, stats.pair_h[:, 4])


def delta_p(
    sky: Sky,
    stats: FocalPlaneStats,
    systematics: Systematics,
    *,
    template: np.ndarray | None = None,
    spread: bool = True,
    offsets: np.ndarray | None = None,
    second_order: bool = False,
    nthreads: int = 0,
) -> np.ndarray:
    """The spurious P = Q + i U of a focal plane's own draw of its pairs' systematics: the
    module's dP, pointing to first order in rho (to second with ``second_order``), the beams to
    first order in their ellipticity and FWHM change (up to h_4: the ellipticity's eth^2 P at
    h_6 is left out).

    Parameters
    ----------
    sky : boresight.sky.Sky
    stats : boresight.scanstats.FocalPlaneStats
        With the per-pair maps (``characterise_focalplane(..., per_pair=True)``).
    systematics : boresight.instrument.Systematics
        Pair i takes its i-th draw, as in :func:`boresight.engine.simulate_focalplane`.
    template : numpy.ndarray, shape (npix,), optional
        The leak's template [muK] (default: the sky's I).
    spread : bool
        Read the fields as averages over hits spread uniformly over each pixel, as a real scan's
        samples are (the default); else at pixel centres, where the formula is exact (with the
        template as given).
    offsets : numpy.ndarray, complex, shape (pairs, 2, >= 5, npix), optional
        Each pair's samples' offsets from their pixel centres weighted as its h_n are
        (:func:`boresight.scanstats.centroid_moments` with the focal plane), for a sky read
        exactly at each sample: each term of Y gains its field's first-order change across the
        pixel, as :func:`expected_residual` has it, the beams' terms too. Not behind a HWP, whose
        pointing terms and beams carry their own (:func:`boresight.scanstats.pointing_behind`,
        :func:`~boresight.scanstats.beams_behind`), and not with a template.
    second_order : bool
        Add a pointing offset's second order in rho (:func:`_pointing_second_order_y`), all that
        is left where the boresight's rotation cancels h_1 and h_3 (0/180), bare or behind a
        plate.
    nthreads : int

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
        [muK], 0 off the observed pixels.
    """
    _check(stats, systematics)
    if offsets is not None and (stats.hwp is not None or template is not None):
        raise ValueError("the samples' offsets: not behind a HWP or with a template")
    if stats.hwp is not None:
        systematics = reflected_systematics(stats.hwp, systematics, own_angles=True)
    params = systematics.per_pair(stats.focalplane.n_pairs)
    shares = pair_shares(params, stats.focalplane)
    fields = _fields(sky, systematics, template, spread, nthreads)
    weights = _weights(stats)
    across = 0.0
    if _behind_plate(stats):
        fields, across = _temperature_across(
            sky, stats, shares, weights, fields, template, nthreads
        )
    y = (
        _y(stats, weights, shares, fields)
        + across
        + _sky_beam_y(sky, stats, params, weights, spread, nthreads, offsets)
    )
    if systematics.has_pointing and _behind_plate(stats):
        y = y + _pointing_behind_y(sky, stats, params, shares, weights, spread, nthreads)
    if systematics.has_pointing and second_order:
        y = y + _pointing_second_order_y(sky, stats, params, weights, spread, offsets, nthreads)
    if offsets is not None:
        window = _spread_window(sky) if spread else np.ones(sky.lmax + 1)
        kinds = fields_by_kind(window, window)
        for name, n in TERMS:
            if name in fields:
                up, down = _derivative_maps(sky, kinds[TERM_FIELDS[name][1]], nthreads)
                for by, field in zip(offset_weights(offsets, n), (up, down)):
                    y = y + 0.5 * field * _mean(shares[name], weights, by)
    return _solve(y, _h4(stats, weights, shares))


def _temperature_across(sky, stats, shares, weights, fields, template, nthreads):
    """Behind a HWP, the pairs' leaks of T (a gain's t2, an additive leak's s2 of the sky's T)
    read across each pixel to second order (:func:`_taylor`, the moments of
    :data:`boresight.scanstats.T_BEHIND_TERMS`): behind a spinning plate their h_{2,4} are
    incoherent sums, for which the spread window's mean over the pixel does not hold. Returns the
    fields with T at the pixels' centres, and the rest of the series' part of Y (npix,)."""
    names = [n for n in ("t2", "s2") if n in fields and (n == "t2" or template is None)]
    series = _taylor(fp_products.temperature(np.ones(sky.lmax + 1)))
    fields = dict(fields)
    for name in names:
        fields[name] = _field_map(sky, series[None][1], nthreads).real
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    for offset, (scale, field) in series.items():
        if offset is not None and names:
            value = _field_map(sky, field, nthreads)
            for name in names:
                y += scale * _mean(shares[name], weights, stats.behind(2, 4, offset)) * value
    return fields, y


def _pointing_behind_y(sky, stats, params, shares, weights, spread, nthreads):
    """Behind a HWP, the parts of a pointing offset's Y that its moments of
    :func:`boresight.scanstats.pointing_behind` add to the T gradient's terms (npix,) complex:
    those terms' first-order change across the pixels, (conj(delta) d G + delta dbar G) / 2
    weighted as each term is (:func:`boresight.predict.field_products.derivative`; d G* =
    conj(dbar G)), and what detector B reads of P off its place
    (:func:`_polarisation_offset_y`)."""
    window = _spread_window(sky) if spread else np.ones(sky.lmax + 1)
    up, down = _derivative_maps(sky, fp_products.gradient(window), nthreads)

    def mean(name, n, offset):
        return _mean(shares[name], weights, stats.behind(n, 4, offset))

    y = 0.5 * (mean("g1", 1, "conj") * up + mean("g1", 1, "delta") * down)
    y += 0.5 * (mean("g3", 3, "conj") * np.conj(down) + mean("g3", 3, "delta") * np.conj(up))
    return y + _polarisation_offset_y(sky, stats, params, weights, spread, nthreads, order=1)


def _pointing_second_order_y(sky, stats, params, weights, spread, offsets, nthreads):
    """A pointing offset to second order in rho, its part of Y (npix,) complex.

    Detector B looks one step delta = rho exp(i beta) away in the coordinates, beta = psi +
    gamma + chi_rho, and reads T there to second order as conj(delta)^2 C + delta^2 conj(C)
    + ``|delta|^2`` A (:func:`boresight.predict.field_products.coordinate_step`: C = d^2 T / 8
    and A = dbar d T / 4 on a great circle, with the step's own cot(theta) terms). The pair
    difference's -(1/2) of it, demodulated with a = psi + gamma, gives::

      Y += -rho^2 [e^{-2 i chi_rho} h_0 C + e^{i (4 gamma + 2 chi_rho)} h_4 conj(C)
                   + e^{2 i gamma} h_2 A]

    The h_0 term, d^2 T turned by the offset's angle, is what no rotation cancels: where 0/180
    cancels the first order's h_1 and h_3, this is the leak (docs/conventions.md). Behind a
    plate the map-maker demodulates with a = psi' + gamma, which turns each h_n into h_{n,4}
    (:func:`boresight.scanstats.pointing_behind`): incoherent sums behind a spinning plate, so
    each field is read across the pixel to second order, as the beams' T part is
    (:func:`_taylor`, cot(theta) at the pixel's centre); and B's P off its place adds its own
    second order (:func:`_polarisation_offset_y`)."""
    behind = _behind_plate(stats)
    window = _spread_window(sky) if spread and not behind else np.ones(sky.lmax + 1)
    step = fp_products.coordinate_step(fp_products.temperature(window))
    gamma = np.asarray(stats.focalplane.pair_angles_deg, dtype=np.float64) * DEG
    rho2, chi = params.rho**2, params.chi
    terms = (  # (n, each pair's coefficient, the step's terms h_n multiplies)
        (0, -rho2 * np.exp(-2j * chi), step["conj2"]),
        (4, -rho2 * np.exp(4j * gamma + 2j * chi), step["delta2"]),
        (2, -rho2 * np.exp(2j * gamma), step["abs2"]),
    )
    geometry, read = _geometry(sky.nside), _field_maps(sky, nthreads)
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    for n, share, parts in terms:
        for part in parts:
            factor = part.scale * geometry(part)
            if behind:
                for offset, (scale, value) in _taylor(part.field).items():
                    h = _mean(share, weights, stats.behind(n, 4, offset))
                    y += factor * scale * h * read(value)
                continue
            y += factor * _mean(share, weights, stats.pair_h[:, n]) * read(part.field)
            if offsets is not None:
                fields = _derivative_fields(part.field)
                for by, value in zip(offset_weights(offsets, n), fields):
                    y += factor * 0.5 * read(value) * _mean(share, weights, by)
    if behind:
        y += _polarisation_offset_y(sky, stats, params, weights, spread, nthreads, order=2)
    return y


def _geometry(nside):
    """A :class:`boresight.predict.field_products.StepTerm`'s factor of cot(theta) and 1 /
    sin^2(theta) at the pixels' centres (npix,), as a function of the term."""
    theta = hp.pix2ang(nside, np.arange(12 * nside**2))[0]
    cot, csc2 = 1.0 / np.tan(theta), 1.0 / np.sin(theta) ** 2
    return lambda part: cot**part.cot * csc2**part.csc2


def _derivative_fields(field):
    """A sky field's raising and lowering derivatives, d F and dbar F
    (:func:`boresight.predict.field_products.derivative`)."""
    return tuple(fp_products.derivative(field, raising=raising) for raising in (True, False))


def _derivative_maps(sky, field, nthreads):
    """The maps of a sky field's raising and lowering derivatives d F and dbar F (npix,) complex
    each (:func:`boresight.predict.field_products.derivative`)."""
    return tuple(_field_map(sky, f, nthreads) for f in _derivative_fields(field))


def _field_map(sky, field, nthreads):
    """The map of a sky field (npix,) complex; a negative spin is a conjugate."""
    value = beam_field(sky, field.filters, abs(field.spin), nthreads)
    return value if field.spin >= 0 else np.conj(value)


def _field_maps(sky, nthreads):
    """:func:`_field_map` that synthesises each field once: the coordinate step's and the pixel's
    Taylor series share most of their derivatives."""
    made = {}

    def read(field):
        key = (field.spin, np.asarray(field.filters).tobytes())
        if key not in made:
            made[key] = _field_map(sky, field, nthreads)
        return made[key]

    return read


def _polarisation_offset_y(sky, stats, params, weights, spread, nthreads, *, order):
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
    window = _spread_window(sky) if spread else np.ones(sky.lmax + 1)
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
    geometry, read = _geometry(sky.nside), _field_maps(sky, nthreads)
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    for share, moment, parts, conjugated in terms:
        mean = _mean(share, weights, moment)
        for part in parts:
            value = read(part.field)
            y += part.scale * geometry(part) * mean * (np.conj(value) if conjugated else value)
    return y


def _pair_mean_w(moments, terms, what, pair_angles_deg, k=4):
    """<exp(-k i gamma)> over the pairs on the axis, once the moments hold ``terms``; 1 for a
    focal plane's combined moments, which carry each pair's (``pair_angles_deg`` None)."""
    missing = [t for t in terms if t not in moments]
    if missing:
        raise ValueError(f"the HWP's {what} needs h_(n,m) {missing}")
    if pair_angles_deg is None:
        return 1.0
    return np.mean(np.exp(-1j * k * np.radians(np.asarray(pair_angles_deg, dtype=np.float64))))


#: the h_{n,m} of (psi, chi) the plate's instrumental polarisation reaches a pair's map through
IP_TERMS = ((2, 0), (2, 8), (4, 8))
#: with detector A alone (the "single" map-maker), those of its I row too, which a plate that
#: does not spin within a pixel's samples couples to P
SINGLE_IP_TERMS = IP_TERMS + ((0, 4), (2, 4))
#: below this rcond a pixel's 3x3 system has no solution (the map-maker flags it)
SINGULAR = 1e-12


def ip_delta_p(
    sky: Sky,
    moments: dict,
    hwp: HWP,
    pair_angles_deg,
    *,
    mapmaker: str = "pairs",
    spread: bool = True,
    nthreads: int = 0,
) -> np.ndarray:
    """The spurious P = Q + i U of a HWP's instrumental polarisation (:func:`boresight.hwp.plate_signals`)
    in the map of pairs on the axis, as ``mapmaker`` (:data:`boresight.mapmaking.MAPMAKERS`)
    makes it.

    A pair at gamma behind the plate sees a = psi - gamma + 2 chi and the plate's epsilon I
    exp(i (2 psi + phase)) on the sky, so with w_i = exp(-4 i gamma_i) averaged over the pairs::

      Y = epsilon T [exp(i phase) h_{2,0} + exp(-i phase) <w> h_{2,8}],   H_4 = <w> h_{4,8}
      dP = (Y - H_4 Y*) / (1 - ``|H_4|^2``)

    the 2x2 solve of :func:`delta_p`, for the pair differences and for both detectors' own maps
    (whose I rows cancel). A spinning plate leaves h_{2,8} and h_{4,8} near zero:
    dP = epsilon T exp(i phase) h_{2,0}, the crossing angles' own moment, which boresight
    rotation cancels as it cancels a bare pair's h_2 (0/90 to rounding).

    Detector A alone (``mapmaker="single"``) solves I beside P from its one angle per sample, and
    sees the IP as epsilon T cos(4 chi - 2 gamma - phase), so its 3x3 system per pixel
    (:func:`boresight.mapmaking.solve_iqu`) couples I to P through <exp(2 i a)> =
    <exp(-2 i gamma)> h_{2,4} and takes the IP's mean, Re[epsilon T exp(i phase)
    <exp(2 i gamma)> h_{0,4}*], in its I row: both near zero behind a spinning plate, not behind
    one that steps per CES.

    Pairs off the axis, each on its own samples, take the map-maker's combination of their
    moments, each weighted by its exp(-i m gamma / 2): those of chi - gamma / 2
    (``hwp_moments(..., focalplane=, relative=True)``), with ``pair_angles_deg`` None.

    Parameters
    ----------
    sky : boresight.sky.Sky
    moments : dict
        (n, m) -> (npix,) h_{n,m} with :data:`IP_TERMS` (:data:`SINGLE_IP_TERMS` for detector A
        alone; :func:`boresight.scanstats.hwp_moments`): of the boresight's samples, or a focal
        plane's relative ones.
    hwp : boresight.hwp.HWP
    pair_angles_deg : sequence of float, or None
        Detector A's angle gamma of each pair [deg], all on the axis sharing the samples; None
        for a focal plane's relative moments, which carry them.
    mapmaker : {"pairs", "detectors", "single"}
    spread, nthreads
        As in :func:`delta_p`.

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
        [muK], 0 off the observed pixels.
    """
    check_mapmaker(mapmaker)
    single = mapmaker == "single"
    terms = SINGLE_IP_TERMS if single else IP_TERMS
    w = _pair_mean_w(moments, terms, "instrumental polarisation", pair_angles_deg)
    t = _fields(sky, Systematics(), None, spread, nthreads)["t2"]
    phase = np.exp(1j * hwp.ip_phase_deg * DEG)
    y = hwp.ip * t * (phase * moments[2, 0] + np.conj(phase) * w * moments[2, 8])
    if not single:
        return _solve(y, w * moments[4, 8])
    w2 = _pair_mean_w(moments, terms, "instrumental polarisation", pair_angles_deg, k=2)
    z2, z4 = w2 * moments[2, 4], w * moments[4, 8]
    mean = np.real(hwp.ip * t * phase * np.conj(w2 * moments[0, 4]))
    ones = np.ones_like(t)
    normal = np.stack(
        [ones, z2.real, z2.imag, (1 + z4.real) / 2, z4.imag / 2, (1 - z4.real) / 2, mean]
        + [y.real / 2, y.imag / 2],
        axis=1,
    )  # per sample, as the map-maker's sums over them: unseen pixels solve to 0
    _, q, u, _ = solve_iqu(normal, rcond_min=SINGULAR)
    return np.where(q != hp.UNSEEN, q + 1j * u, 0.0)  # 0 where the map-maker has no solution


def ip_delta_p_across(sky: Sky, stats: FocalPlaneStats, hwp: HWP, *, nthreads: int = 0):
    """The spurious P of a HWP's instrumental polarisation in the pair differences' map of a focal
    plane, from each pair's own moments with T read across the pixel.

    Pair i on its own samples gives, with the moments of :func:`boresight.scanstats.
    _moments_behind` (chi - gamma)::

      Y = epsilon sum_i (N_i / N) [exp(i phase) <T h_{2,0}> + exp(-i phase) exp(4 i gamma_i)
          <T h_{2,8}>],   H_4 = sum_i (N_i / N) exp(4 i gamma_i) h_{4,8}

    :func:`ip_delta_p`'s formula with T read at each pair's samples to second order in their
    offsets from the pixel's centre (:func:`_taylor`) rather than as its mean over the pixel: few
    samples per pixel, and h_{2,8} an incoherent sum behind a spinning plate, make that mean
    10 % off on a short schedule (docs/conventions.md).

    Parameters
    ----------
    sky : boresight.sky.Sky
    stats : boresight.scanstats.FocalPlaneStats
        Behind the plate with the IP's moments (``characterise_focalplane(..., per_pair=True,
        hwp=, ip=True)``).
    hwp : boresight.hwp.HWP
        Its ``ip`` and ``ip_phase_deg``.
    nthreads : int

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
        [muK], 0 off the observed pixels.
    """
    if not (_behind_plate(stats) and stats.has_behind(IP_BEHIND_TERMS)):
        raise ValueError(
            "the IP across the pixel needs characterise_focalplane(..., hwp=, ip=True)"
        )
    weights = _weights(stats)
    turn = np.exp(4j * np.radians(np.asarray(stats.focalplane.gamma_deg, dtype=np.float64)))
    phase = np.exp(1j * hwp.ip_phase_deg * DEG)
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    for offset, (scale, field) in _taylor(fp_products.temperature(np.ones(sky.lmax + 1))).items():
        h = phase * _mean(np.ones_like(turn), weights, stats.behind(2, 0, offset))
        h += np.conj(phase) * _mean(turn, weights, stats.behind(2, 8, offset))
        y += scale * h * _field_map(sky, field, nthreads)
    return _solve(hwp.ip * y, _mean(turn, weights, stats.pair_h[:, 4]))


#: the h_{n,m} the plate's synchronous 2 chi signal reaches a pair's map through
SYNCHRONOUS_TERMS = ((2, 2), (2, 6), (4, 8))


def synchronous_weights(focalplane) -> np.ndarray:
    """Each pair's weights of :data:`SYNCHRONOUS_TERMS` in the map-maker's combination, 1,
    exp(-4 i gamma) and exp(-4 i gamma), (pairs, 3) complex
    (``boresight.scanstats.hwp_moments(..., focalplane=, pair_weights=)``)."""
    w = np.exp(-4j * np.radians(np.asarray(focalplane.gamma_deg, dtype=np.float64)))
    return np.stack([np.ones_like(w), w, w], axis=1)


def synchronous_delta_p(moments: dict, hwp: HWP, pair_angles_deg) -> np.ndarray:
    """The spurious P of a HWP's synchronous signal (:func:`boresight.hwp.plate_signals`) in the
    pair differences' map, the plate at its nominal angle.

    The 4 chi part is common to a pair and leaves its difference. The 2 chi part, A_2 cos(2 chi -
    2 gamma - phi_2), is its difference; with a = psi - gamma + 2 chi and w = exp(-4 i gamma)
    averaged over the pairs on the axis::

      Y = A_2 [exp(i phi_2) h_{2,2} + exp(-i phi_2) <w> h_{2,6}],   H_4 = <w> h_{4,8}

    solved as in :func:`delta_p`. Pairs off the axis, each on its own samples, take the
    map-maker's combination of their moments, each pair's h_{2,6} and h_{4,8} weighted by its own
    w (:func:`synchronous_weights`), with ``pair_angles_deg`` None. A spinning plate takes every
    term to zero; a stepped one leaves h_{2,2} = exp(2 i chi_k) h_2 per step, which boresight
    rotation cancels with h_2.

    Parameters
    ----------
    moments : dict
        (n, m) -> (npix,) h_{n,m} with :data:`SYNCHRONOUS_TERMS`
        (:func:`boresight.scanstats.hwp_moments`): of the boresight's samples, or a focal
        plane's weighted ones.
    hwp : boresight.hwp.HWP
    pair_angles_deg : sequence of float, or None
        Detector A's angle gamma of each pair [deg], all on the axis sharing the samples; None
        for a focal plane's weighted moments, which carry them.

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
        [muK], 0 off the observed pixels.
    """
    w = _pair_mean_w(moments, SYNCHRONOUS_TERMS, "synchronous signal", pair_angles_deg)
    phase = np.exp(1j * hwp.synchronous_phase_deg[0] * DEG)
    a2 = hwp.synchronous_muk[0]
    y = a2 * (phase * moments[2, 2] + np.conj(phase) * w * moments[2, 6])
    return _solve(y, w * moments[4, 8])


#: the h_{n,m} a HWP angle's jitter reaches a pair's map through
JITTER_TERMS = ((4, 8), (8, 16))


def angle_jitter_leak(
    sky: Sky, hits: np.ndarray, moments: dict, hwp: HWP, *, pair_angles_deg, mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """What a HWP angle's white jitter (:func:`boresight.hwp.plate_signals`) leaves in the pair
    differences' map, over its draws: the spurious P of its mean, and the
    variance and white pseudo-C_BB of the rest.

    A jitter j of rms sigma turns the pair's P to P exp(-4 i j), whose mean over the draws is
    mu P, mu = exp(-8 sigma^2): the mean leaves dP = (mu - 1) P, whatever the moments. The rest,
    X = P e with e = exp(-4 i j) - mu, E``|e|^2`` = v = 1 - exp(-16 sigma^2) and E[e^2] = c =
    exp(-32 sigma^2) - exp(-16 sigma^2), is the same for every pair at a sample. With z =
    exp(4 i a) of a pair at gamma = 0, W = <exp(-4 i gamma)> over the pairs and n_t the samples
    of a pixel, Y = (1 / n_t) sum_t (X + X* W z), so over the draws, with P the pixel's and
    h = h_{4,8}, H_4 = W h::

      E``|Y|^2`` = (v ``|P|^2`` (1 + ``|W|^2``) + 2 Re(c P^2 W* h*)) / n_t
      E[Y^2] = (c P^2 + 2 v ``|P|^2`` W h + c* P*^2 W^2 h_{8,16}) / n_t
      E``|dP|^2`` = (E``|Y|^2`` (1 + ``|H_4|^2``) - 2 Re(H_4* E[Y^2])) / (1 - ``|H_4|^2``)^2

    through the 2x2 solve (as :func:`jitter_bb` has it for a gain's jitter), white from pixel to
    pixel; half of it is B. Pairs off the axis, each on its own samples, see a pixel at other
    times, so their draws there are independent: each sample is its own pair's, with its own
    exp(-4 i gamma), which moments of chi - gamma / 2 carry (``hwp_moments(..., focalplane=,
    relative=True)``, ``pair_angles_deg`` None): the same formulas with W = 1 and n_t every
    pair's samples (pairs sharing a pixel at one time, closer than a pixel, are left out).

    Parameters
    ----------
    sky : boresight.sky.Sky
    hits : numpy.ndarray, shape (npix,)
        The boresight's samples per pixel, or every pair's off the axis
        (:func:`boresight.scanstats.hwp_moments`).
    moments : dict
        (n, m) -> (npix,) h_{n,m} with :data:`JITTER_TERMS`.
    hwp : boresight.hwp.HWP
        Its ``angle_jitter_deg``; no angle offset (the offset's own is :func:`delta_p`'s).
    pair_angles_deg : sequence of float, or None
        Detector A's angle of each pair on the axis [deg]; None off the axis (above).
    mask : numpy.ndarray, shape (npix,)
        The weights of the solved pixels.

    Returns
    -------
    dp : numpy.ndarray, complex128, shape (npix,)
        The mean's [muK], 0 off the observed pixels.
    variance : numpy.ndarray, shape (npix,)
        E``|dP - dp|^2`` [muK^2], 0 off the mask.
    white : float
        Its pseudo-C_BB, the same at every multipole [muK^2].
    """
    w = _pair_mean_w(moments, JITTER_TERMS, "angle jitter", pair_angles_deg)
    sigma = hwp.angle_jitter_deg * DEG
    mu, v = np.exp(-8.0 * sigma**2), -np.expm1(-16.0 * sigma**2)
    c = np.exp(-32.0 * sigma**2) - np.exp(-16.0 * sigma**2)
    p = sky.maps[1] + 1j * sky.maps[2]
    dp = np.where(hits > 0, (mu - 1.0) * p, 0.0)
    on = (mask != 0) & (hits > 0)
    p, n, h, h8 = p[on], hits[on], moments[4, 8][on], moments[8, 16][on]
    h4 = w * h
    yy = (v * np.abs(p) ** 2 * (1 + abs(w) ** 2) + 2 * np.real(c * p**2 * np.conj(w * h))) / n
    y2 = (c * p**2 + 2 * v * np.abs(p) ** 2 * h4 + np.conj(c * p**2) * w**2 * h8) / n
    h4_sq = np.abs(h4) ** 2
    variance = np.zeros(mask.size)
    variance[on] = (yy * (1 + h4_sq) - 2 * np.real(np.conj(h4) * y2)) / (1 - h4_sq) ** 2
    white = 0.5 * (4 * np.pi / mask.size) * np.sum(mask**2 * variance) / mask.size
    return dp, variance, float(white)


def at_means(systematics, n_pairs):
    """Each pair's parameters with every drawn one at its mean, and the drawn ones' (name,
    rms in the engine's units)."""
    params = systematics.per_pair(n_pairs)
    drawn, values = [], params._asdict()
    for k, name in enumerate(LIMITS):
        spread = getattr(systematics, name)
        if isinstance(spread, Spread) and spread.rms > 0 and name != "dg_jitter":
            if name not in LINEAR:
                raise ValueError(
                    f"{name} drawn per pair: a focal plane's expectation covers "
                    f"{', '.join(LINEAR)}; give {name} as numbers"
                )
            field = params._fields[k]
            values[field] = np.full(n_pairs, spread.mean * UNITS[name])
            drawn.append((field, spread.rms * UNITS[name]))
    return type(params)(**values), drawn


def expected_leak_bb(
    sky: Sky,
    stats: FocalPlaneStats,
    systematics: Systematics,
    mask: np.ndarray,
    lmax: int,
    *,
    template: np.ndarray | None = None,
    spread: bool = True,
    nthreads: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """The expected masked pseudo-C_BB of a focal plane's leaked polarisation over its pairs'
    draws, for this sky: the coherent and the scattered parts (module docstring).

    dP is the whole change of the maps, its h_0 term (which rotates and rescales the sky's own P)
    included, as the auto part of :func:`boresight.spectra.residual_bb_parts` measures it in a
    TOD simulation.

    Parameters
    ----------
    sky : boresight.sky.Sky
    stats : boresight.scanstats.FocalPlaneStats
        With the per-pair maps.
    systematics : boresight.instrument.Systematics
        {mean, rms} of dg, leak and rho_arcmin allowed; other parameters as numbers.
    mask : numpy.ndarray, shape (npix,)
    lmax : int
    template, spread, nthreads
        As :func:`delta_p`.

    Returns
    -------
    coherent, scattered : numpy.ndarray, shape (lmax + 1,)
        [muK^2] from ell = 0.
    """
    _check(stats, systematics)
    footprint = as_footprint(mask)
    plane = stats.focalplane
    params, drawn = at_means(systematics, plane.n_pairs)
    fields = _fields(sky, systematics, template, spread, nthreads)
    shares = pair_shares(params, plane)
    weights = _weights(stats)
    h4 = _h4(stats, weights, shares)

    def bb(y):
        d = _solve(y, h4)[footprint.pixels]
        b = footprint.alm(np.array([d.real, d.imag]), lmax, 2, nthreads=nthreads)[1]
        return harmonics.alm2cl(b)

    beams = _sky_beam_y(sky, stats, params, weights, spread, nthreads)
    coherent = bb(_y(stats, weights, shares, fields) + beams)
    scattered = np.zeros(lmax + 1)
    for field, rms in drawn:
        unit = params._asdict()
        unit[field] = unit[field] + 1.0
        delta = {k: v - shares[k] for k, v in pair_shares(type(params)(**unit), plane).items()}
        for i in range(plane.n_pairs):  # a unit of the parameter on pair i alone
            scattered += rms**2 * bb(_y(stats, weights, delta, fields, slice(i, i + 1)))
    return coherent, scattered


#: the least condition (1 - ``|H_4|``) / (1 + ``|H_4|``) of a pixel's 2x2 system that
#: :func:`expected_residual` keeps (the engine's rcond; 0.05 is ``|H_4|`` < 0.905): nearer
#: singular, 1 / (1 - ``|H_4|^2``) spikes that the weights' harmonics cannot hold, so such pixels
#: are invalid, as in the engine run with ``rcond_min`` = this
RCOND_EXPECTATION = 0.05


def valid(stats: FocalPlaneStats) -> np.ndarray:
    """The pixels whose 2x2 system :func:`expected_residual` solves (npix,) bool: seen, with
    :func:`rcond` at least :data:`RCOND_EXPECTATION`."""
    return (stats.combined.hits > 0) & (rcond(stats) >= RCOND_EXPECTATION)


def rcond(stats: FocalPlaneStats) -> np.ndarray:
    """Each pixel's 2x2 condition (1 - ``|H_4|``) / (1 + ``|H_4|``) (npix,), 0 where unseen:
    the engine's ``rcond`` of the focal plane's combined samples."""
    focal = stats.focalplane
    h4 = np.abs(
        _h4(stats, _weights(stats), pair_shares(Systematics().per_pair(focal.n_pairs), focal))
    )
    return np.where(stats.combined.hits > 0, (1 - h4) / (1 + h4), 0.0)


class FocalPlaneResidual(NamedTuple):
    """The expected masked pseudo-C_BB [muK^2], (lmax + 1,) each, of a focal plane over the sky's
    realisations and the pairs' draws: ``coherent``, the leaked and total residual with every
    drawn parameter at its mean (:class:`boresight.predict.ExpectedResidual`), and ``scattered``,
    the leaked power of the draws' departures from their means, which have no cross term with the
    sky."""

    coherent: ExpectedResidual
    scattered: np.ndarray

    @property
    def leaked(self) -> np.ndarray:
        return self.coherent.leaked + self.scattered

    @property
    def residual(self) -> np.ndarray:
        return self.coherent.residual + self.scattered


def expected_residual(
    stats: FocalPlaneStats,
    mask: np.ndarray,
    systematics: Systematics,
    theory: Spectra,
    fwhm_arcmin: float,
    *,
    lmax: int,
    band: int | None = None,
    evaluation: str | None = "interp",
    offsets: np.ndarray | None = None,
    nthreads: int = 0,
) -> FocalPlaneResidual:
    """The exact expected leaked and total residual pseudo-C_BB of a focal plane's own h_n maps,
    over the sky's realisations and the pairs' draws: the focal-plane form of
    :func:`boresight.predict.expected_residual` (docs/conventions.md).

    dP = (Y - H_4 Y*) / (1 - ``|H_4|^2``) is, term by term, a weight times a sky field:
    (sum_i share_i N_i h_n,i / N) / (1 - ``|H_4|^2``) on the term's field, and minus H_4 times
    its conjugate on the conjugate field (spin 4 - n). Both are fixed by the schedule, so the
    expectation over skies is exact (:func:`boresight.predict.field_products.expected_pseudo_cl_alm`),
    with no condition on the pairs' 4 x angles. Over the pairs' draws dP is real-linear in each
    drawn parameter: the coherent part is dP at the means, with its cross terms with the sky's own
    E and B, and the scattered part is rms^2 times the sum over pairs of the leaked power of a unit
    of the parameter on that pair alone (:func:`expected_leak_bb` for one sky).

    Parameters
    ----------
    stats : boresight.scanstats.FocalPlaneStats
        With the per-pair maps.
    mask : numpy.ndarray, shape (npix,)
        The analysis mask (RING). Its pixels whose 2x2 system is near singular (:func:`rcond`
        below :data:`RCOND_EXPECTATION`) are invalid, 0 in the maps with and without the
        systematics, as in :func:`boresight.engine.simulate_focalplane` with that ``rcond_min``.
    systematics : boresight.instrument.Systematics
        {mean, rms} of dg, leak, rho_arcmin and dg_jitter allowed, beams as numbers (their
        terms through each pair's own h_n, :func:`beam_terms`). A gain jitter adds its white
        power (:func:`jitter_bb`).
    theory : boresight.cosmology.Spectra
    fwhm_arcmin : float
        The sky's beam.
    lmax : int
        The pseudo-spectra's band limit.
    band : int, optional
        The sky's band limit (default lmax).
    evaluation : str or None
        How the engine reads the sky at a schedule's samples spread over their pixels:
        "interp" (its default) or "exact" (:func:`boresight.engine.simulate_focalplane`),
        with the h_0 terms' in-pixel scatter (as :func:`boresight.predict.expected_residual` with
        hits; pairs at one place share their samples' departures, pairs apart do not); None for
        the fields at the pixel centres, where it is exact.
    offsets : numpy.ndarray, complex, shape (pairs, 2, >= 5, npix), optional
        Each pair's samples' offsets from their pixel centres weighted as its h_n are
        (:func:`boresight.scanstats.centroid_moments` with the focal plane), for a sky read
        exactly at each sample: every term of Y gains its fields' first-order change across the
        pixel, as in :func:`boresight.predict.expected_residual`, each pair through its own
        offsets.
    nthreads : int

    Returns
    -------
    FocalPlaneResidual
    """
    _check(stats, systematics)
    if stats.hwp is not None and (systematics.has_pointing or systematics.has_beams):
        raise ValueError(
            "a pointing offset or a beam behind a HWP: its expectation over skies is not built "
            "yet (delta_p predicts it for a sky)"
        )
    if offsets is not None and stats.hwp is not None:
        raise ValueError("the samples' offsets behind a HWP: not yet predicted")
    band = lmax if band is None else band
    nside, lw = hp.npix2nside(mask.size), lmax + band
    focal = stats.focalplane
    params, drawn = at_means(systematics, focal.n_pairs)
    shares = pair_shares(params, focal)
    weights = _weights(stats)
    h4 = _h4(stats, weights, shares)
    solved = mask * valid(stats)
    inverse = solved / np.where(solved != 0, 1.0 - np.abs(h4) ** 2, 1.0)
    conjugate = bool(np.max(np.abs(h4)) > 1e-12)  # pairs whose 4 x angles cancel: H_4 = 0
    spread = evaluation is not None
    read = sky_fields(
        nside, band, hits=stats.combined.hits if spread else None, evaluation=evaluation or "interp"
    )
    fields, terms = read[0], budget_terms(systematics, read)
    sky_cl = smoothed_spectra(theory, fwhm_arcmin, band)

    def weighted(items):
        """The weights' alm, spins and fields of dP for terms (y, n, field, conjugate field) of
        Y: y F and, where H_4 != 0, -H_4 conj(y) conj(F)."""
        alms, spins, term_fields = [], [], []
        for y, n, field, conj_field in items:
            alms.append(
                fp_products.weight_alm(fp_products.Weight(n, inverse * y, None), lw, nthreads)
            )
            spins.append(n)
            term_fields.append(field)
            if conjugate:
                z = -inverse * h4 * np.conj(y)
                alms.append(
                    fp_products.weight_alm(fp_products.Weight(4 - n, z, None), lw, nthreads)
                )
                spins.append(4 - n)
                term_fields.append(conj_field)
        return alms, spins, term_fields

    def items(share, h, n, field, pairs):
        """The terms of Y of a moment n over ``pairs``, each pair's ``share`` (pairs,) times its
        h_n (pairs, npix), on ``field``; read exactly, also its first-order change across the
        pixels (:func:`boresight.predict.expectation.offset_weights`); none where every share
        is 0 (a unit of a drawn parameter moves only its own terms)."""
        if not np.any(share):
            return []
        w = weights[pairs]
        out = [(np.einsum("i,ip,ip->p", share, w, h), n, field, fp_products.conjugate(field))]
        if offsets is not None:
            for by, raising in zip(offset_weights(offsets[pairs], n), (True, False)):
                moved = fp_products.derivative(field, raising=raising)
                spin = n - 1 if raising else n + 1
                out.append((0.5 * np.einsum("i,ip,ip->p", share, w, by), spin, moved,
                            fp_products.conjugate(moved)))  # fmt: skip
        return out

    def leak(term_shares, pairs=slice(None)):
        """The terms of Y for coefficient shares over ``pairs``."""
        return [
            item
            for name, (n, kind, _) in terms.items()
            for item in items(
                term_shares[name][pairs], _term_h(stats, name, n, pairs), n, fields[kind], pairs
            )
        ]

    exact = read[2]
    beam = beam_terms(params, focal, fwhm_arcmin, band, n_max=stats.pair_h.shape[1] - 1)
    beams = [
        item
        for term in beam.values()
        for item in items(
            term.shares,
            _pair_moment(stats, term.moment),
            term.moment,
            beam_sky_field(term.filter, term.moment, exact.window),
            slice(None),
        )
    ]

    def bb(alms, spins, term_fields):
        if not alms:  # no term has a share
            return np.zeros(lmax + 1)
        return fp_products.expected_pseudo_cl_alm(alms, spins, term_fields, sky_cl, lmax).bb

    alms, spins, term_fields = weighted(leak(shares) + beams)
    sky = [fp_products.weight_alm(fp_products.Weight(0, solved + 0j, None), lw, nthreads)]
    sky_terms = ([0], [fields["polarisation"]])
    scatter = 0.0
    if spread:
        scatter = _scatter(stats, terms, fields, sky_cl, solved, shares, params, drawn)
        scatter += _beam_scatter(stats, beam, exact, sky_cl, solved)
    scatter = scatter + jitter_bb(stats, systematics, solved, sky_cl, shares=shares, h4=h4)
    leaked = bb(alms, spins, term_fields) + scatter
    total = bb(alms + sky, spins + sky_terms[0], term_fields + sky_terms[1])
    residual = total - bb(sky, *sky_terms) + scatter
    scattered = np.zeros(lmax + 1)
    for _, rms, delta in unit_shares(params, drawn, shares, focal):
        summed = {}  # the pairs' unit leaks are alike in their terms: their spectra add
        for i in range(focal.n_pairs):
            alms, spins, term_fields = weighted(leak(delta, slice(i, i + 1)))
            key = tuple(name for name in terms if np.any(delta[name][i]))
            if not alms:
                continue
            w, v = fp_products.weight_cross_spectra(alms, spins, lw)
            if key in summed:
                summed[key][0][:] += w
                summed[key][1][:] += v
            else:
                summed[key] = (w, v, spins, term_fields)
        for w, v, spins, term_fields in summed.values():
            scattered += (
                rms**2
                * fp_products.expected_pseudo_cl_spectra(
                    (w, v), spins, term_fields, sky_cl, lmax
                ).bb
            )
    return FocalPlaneResidual(ExpectedResidual(leaked, residual), scattered)


def jitter_bb(stats, systematics, mask, sky_cl, *, shares, h4) -> float:
    """The gain jitter's white pseudo-C_BB [muK^2] (the on-axis one of
    :class:`boresight.predict.LeakModel`, with each pair's own hits).

    A deviate z of rms s_i on a sample of pair i adds z T / 2 to its pair difference, so
    Y = (1 / N) sum_samples exp(2 i a) z T, whose E``|Y|^2`` = S T^2 and E[Y^2] = G T^2 with
    S = sum_i N_i E[s_i^2] / N^2 and G = sum_i N_i E[s_i^2] m4_i h_4,i / N^2. Through the 2x2
    solve, E``|dP|^2`` = T^2 (S (1 + ``|H_4|^2``) - 2 Re(conj(H_4) G)) / (1 - ``|H_4|^2``)^2, white
    from pixel to pixel; half of it is B, and E[T^2] is the sky's variance.

    Parameters
    ----------
    stats : boresight.scanstats.FocalPlaneStats
        With the per-pair maps.
    systematics : boresight.instrument.Systematics
        ``dg_jitter`` a number, one per pair, or {mean, rms} (E[s^2] = mean^2 + rms^2).
    mask : numpy.ndarray, shape (npix,)
        The weights of the solved pixels.
    sky_cl : numpy.ndarray
        The sky's smoothed spectra, TT first.
    shares, h4
        The pairs' coefficient shares at the means and H_4 per pixel.

    Returns
    -------
    float
        The same at every multipole.
    """
    if not systematics.has_jitter:
        return 0.0
    jitter = systematics.dg_jitter
    n_pairs = stats.focalplane.n_pairs
    if isinstance(jitter, Spread):
        power = np.full(n_pairs, jitter.mean**2 + jitter.rms**2)
    else:
        power = systematics.per_pair(n_pairs).dg_jitter ** 2
    hits = np.maximum(stats.combined.hits, 1).astype(np.float64)
    s = np.einsum("i,ip->p", power, stats.pair_hits) / hits**2
    g = np.einsum("i,ip,ip->p", power * shares["m4"], stats.pair_hits, stats.pair_h[:, 4])
    g = g / hits**2
    h4_sq = np.abs(h4) ** 2
    solved = mask != 0
    v = np.zeros(mask.size)
    v[solved] = (s * (1 + h4_sq) - 2 * np.real(np.conj(h4) * g))[solved] / (1 - h4_sq[solved]) ** 2
    ell = np.arange(sky_cl.shape[1])
    variance_t = np.sum((2 * ell + 1) / (4 * np.pi) * sky_cl[0])
    return 0.5 * (4 * np.pi / mask.size) * variance_t * np.sum(mask**2 * v) / mask.size


def unit_shares(params, drawn, shares, focal):
    """Per drawn parameter: its name, rms and each pair's change of shares for a unit of it."""
    for field, rms in drawn:
        unit = params._asdict()
        unit[field] = unit[field] + 1.0
        moved = pair_shares(type(params)(**unit), focal)
        yield field, rms, {k: v - shares[k] for k, v in moved.items()}


def _scatter(stats, terms, fields, sky_cl, mask, shares, params, drawn):
    """The h_0 term's in-pixel scatter (:meth:`boresight.predict.LeakModel.scatter`): a pixel's
    departures add per place in the focal plane, so its power per pair-sample is sum over places
    of E``|sum_i c_i|^2`` (its pairs' p0) over the number of pairs."""
    if "p0" not in terms:
        return 0.0
    places = _places(stats.focalplane)
    power = 0.0
    for g in np.unique(places):
        at = places == g
        power += abs(np.sum(shares["p0"][at])) ** 2
        for _, rms, delta in unit_shares(params, drawn, shares, stats.focalplane):
            power += rms**2 * np.sum(np.abs(delta["p0"][at]) ** 2)
    _, kind, reading = terms["p0"]
    return reading.scatter(fields[kind], sky_cl, power / stats.focalplane.n_pairs, mask)


def _places(focalplane):
    """Each pair's place in the focal plane, an index (n_pairs,): pairs at one place share their
    samples."""
    return np.unique(np.round(focalplane.vectors(), 12), axis=0, return_inverse=True)[1].ravel()


def _beam_scatter(stats, terms, reading, sky_cl, mask):
    """The beams' h_0 term's in-pixel scatter (as :func:`_scatter`'s): per place, the field
    sum over its pairs of G_0,i, each pair-sample's departure from its pixel's mean."""
    places = _places(stats.focalplane)
    total = 0.0
    for g in np.unique(places):
        filters = [
            np.sum(term.shares[places == g]).real * term.filter
            for term in terms.values()
            if term.moment == 0
        ]
        if filters:
            field = beam_sky_field(sum(filters), 0, reading.window)
            total += reading.scatter(field, sky_cl, 1.0 / stats.focalplane.n_pairs, mask)
    return total
