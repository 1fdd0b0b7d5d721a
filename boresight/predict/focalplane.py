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
from ..constants import DEG
from ..instrument.beams import PARTS
from ..instrument.hwp import reflected_systematics
from ..instrument.pairs import LIMITS, UNITS, PairParameters, Spread, Systematics
from ..moments.hwp import (
    BEAM_N_MAX,
)
from ..spectra import as_footprint
from . import field_products as fp_products
from .beam_fields import pairs_beam_filters
from .expectation import (
    OFFSETS_BEHIND_HWP,
    ExpectedResidual,
    budget_terms,
    fields_by_kind,
    offset_weights,
    sky_fields,
    smoothed_spectra,
)
from .hwp import beam_parts_behind, pointing_behind_y, temperature_across
from .pair_fields import (
    LINEAR,
    beam_sky_field,
    behind_plate,
    check_supported,
    derivative_fields,
    derivative_maps,
    field_map,
    field_maps,
    hit_mean,
    hit_weights,
    leak_fields,
    leak_y,
    mean_h4,
    pair_moment,
    pair_shares,
    pixel_geometry,
    polarisation_offset_y,
    solve_pairs,
    spread_window,
    taylor,
    term_h,
)
from .terms import TERMS

if TYPE_CHECKING:
    from ..cosmology import Spectra
    from ..moments.focalplane import FocalPlaneStats
    from ..sky import Sky


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
    params : boresight.instrument.pairs.PairParameters
        Each pair's parameters (the means of drawn ones).
    focalplane : boresight.instrument.focalplane.FocalPlane
    fwhm_arcmin : float
        The sky's beam.
    band, n_max : int
    part : {"all", "T", "P"}
        The terms of the whole sky, of its T alone or of its polarisation alone
        (:data:`boresight.instrument.beams.PARTS`).

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


def _sky_beam_y(sky, stats, params, weights, spread, nthreads, offsets=None):
    """The beams' part of Y on this sky, sum over the beam terms of their weight times G_n (npix,),
    each G_n read exactly at the hits (their pixel mean with ``spread``), with its first-order
    change across the pixel where ``offsets`` are given (as :func:`delta_p` has them); behind a
    HWP, from :func:`beam_parts_behind`, the T part read across the pixel to second order."""
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    n_max = stats.pair_h.shape[1] - 1
    window = spread_window(sky) if spread else np.ones(sky.lmax + 1)
    parts = (
        [(params, "all", lambda n: ((1.0, pair_moment(stats, n)),), False)]
        if not behind_plate(stats)
        else beam_parts_behind(stats, params)
    )
    for pair_params, part, moments, across in parts:
        if behind_plate(stats):
            n_max = BEAM_N_MAX[4] if across else BEAM_N_MAX[0]
        terms = beam_terms(
            pair_params, stats.focalplane, sky.fwhm_arcmin, sky.lmax, n_max=n_max, part=part
        )
        for term in terms.values():
            n = term.moment
            if not across:
                field = beam_sky_field(term.filter, n, window)
                h = sum(scale * moment for scale, moment in moments(n))
                y += hit_mean(term.shares, weights, h) * field_map(sky, field, nthreads)
                if offsets is not None:
                    maps = derivative_maps(sky, field, nthreads)
                    for by, value in zip(offset_weights(offsets, n), maps):
                        y += 0.5 * value * hit_mean(term.shares, weights, by)
                continue
            # read at the samples: G at the centre and its Taylor terms to second order
            centre = beam_sky_field(term.filter, n, np.ones(sky.lmax + 1))
            for offset, (scale, field) in taylor(centre).items():
                h = stats.behind(n, 4, offset)
                y += scale * hit_mean(term.shares, weights, h) * field_map(sky, field, nthreads)
    return y


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
    stats : boresight.moments.FocalPlaneStats
        With the per-pair maps (``characterise_focalplane(..., per_pair=True)``).
    systematics : boresight.instrument.pairs.Systematics
        Pair i takes its i-th draw, as in :func:`boresight.engine.simulate_focalplane`.
    template : numpy.ndarray, shape (npix,), optional
        The leak's template [muK] (default: the sky's I).
    spread : bool
        Read the fields as averages over hits spread uniformly over each pixel, as a real scan's
        samples are (the default); else at pixel centres, where the formula is exact (with the
        template as given).
    offsets : numpy.ndarray, complex, shape (pairs, 2, >= 5, npix), optional
        Each pair's samples' offsets from their pixel centres weighted as its h_n are
        (:func:`boresight.moments.centroid_moments` with the focal plane), for a sky read
        exactly at each sample: each term of Y gains its field's first-order change across the
        pixel, as :func:`expected_residual` has it, the beams' terms too. Not behind a HWP, whose
        pointing terms and beams carry their own (:func:`boresight.moments.pointing_behind`,
        :func:`~boresight.moments.beams_behind`), and not with a template.
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
    check_supported(stats, systematics)
    if offsets is not None and (stats.hwp is not None or template is not None):
        raise ValueError("the samples' offsets: not behind a HWP or with a template")
    if stats.hwp is not None:
        systematics = reflected_systematics(stats.hwp, systematics, own_angles=True)
    params = systematics.per_pair(stats.focalplane.n_pairs)
    shares = pair_shares(params, stats.focalplane)
    fields = leak_fields(sky, systematics, template, spread=spread, nthreads=nthreads)
    weights = hit_weights(stats)
    across = 0.0
    if behind_plate(stats):
        fields, across = temperature_across(
            sky, stats, shares, weights, fields, template=template, nthreads=nthreads
        )
    y = (
        leak_y(stats, weights, shares, fields)
        + across
        + _sky_beam_y(sky, stats, params, weights, spread, nthreads, offsets)
    )
    if systematics.has_pointing and behind_plate(stats):
        y = y + pointing_behind_y(
            sky, stats, params, shares, weights, spread=spread, nthreads=nthreads
        )
    if systematics.has_pointing and second_order:
        y = y + _pointing_second_order_y(sky, stats, params, weights, spread, offsets, nthreads)
    if offsets is not None:
        window = spread_window(sky) if spread else np.ones(sky.lmax + 1)
        kinds = fields_by_kind(window, window)
        for term in TERMS:
            if term.name in fields:
                up, down = derivative_maps(sky, kinds[term.field], nthreads)
                for by, field in zip(offset_weights(offsets, term.n), (up, down)):
                    y = y + 0.5 * field * hit_mean(shares[term.name], weights, by)
    return solve_pairs(y, mean_h4(stats, weights, shares))


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
    (:func:`boresight.moments.pointing_behind`): incoherent sums behind a spinning plate, so
    each field is read across the pixel to second order, as the beams' T part is
    (:func:`taylor`, cot(theta) at the pixel's centre); and B's P off its place adds its own
    second order (:func:`polarisation_offset_y`)."""
    behind = behind_plate(stats)
    window = spread_window(sky) if spread and not behind else np.ones(sky.lmax + 1)
    step = fp_products.coordinate_step(fp_products.temperature(window))
    gamma = np.asarray(stats.focalplane.pair_angles_deg, dtype=np.float64) * DEG
    rho2, chi = params.rho**2, params.chi
    terms = (  # (n, each pair's coefficient, the step's terms h_n multiplies)
        (0, -rho2 * np.exp(-2j * chi), step["conj2"]),
        (4, -rho2 * np.exp(4j * gamma + 2j * chi), step["delta2"]),
        (2, -rho2 * np.exp(2j * gamma), step["abs2"]),
    )
    geometry, read = pixel_geometry(sky.nside), field_maps(sky, nthreads)
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    for n, share, parts in terms:
        for part in parts:
            factor = part.scale * geometry(part)
            if behind:
                for offset, (scale, value) in taylor(part.field).items():
                    h = hit_mean(share, weights, stats.behind(n, 4, offset))
                    y += factor * scale * h * read(value)
                continue
            y += factor * hit_mean(share, weights, stats.pair_h[:, n]) * read(part.field)
            if offsets is not None:
                fields = derivative_fields(part.field)
                for by, value in zip(offset_weights(offsets, n), fields):
                    y += factor * 0.5 * read(value) * hit_mean(share, weights, by)
    if behind:
        y += polarisation_offset_y(
            sky, stats, params, weights, spread=spread, nthreads=nthreads, order=2
        )
    return y


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
    stats : boresight.moments.FocalPlaneStats
        With the per-pair maps.
    systematics : boresight.instrument.pairs.Systematics
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
    check_supported(stats, systematics)
    footprint = as_footprint(mask)
    plane = stats.focalplane
    params, drawn = at_means(systematics, plane.n_pairs)
    fields = leak_fields(sky, systematics, template, spread=spread, nthreads=nthreads)
    shares = pair_shares(params, plane)
    weights = hit_weights(stats)
    h4 = mean_h4(stats, weights, shares)

    def bb(y):
        d = solve_pairs(y, h4)[footprint.pixels]
        b = footprint.alm(np.array([d.real, d.imag]), lmax, 2, nthreads=nthreads)[1]
        return harmonics.alm2cl(b)

    beams = _sky_beam_y(sky, stats, params, weights, spread, nthreads)
    coherent = bb(leak_y(stats, weights, shares, fields) + beams)
    scattered = np.zeros(lmax + 1)
    for field, rms in drawn:
        unit = params._asdict()
        unit[field] = unit[field] + 1.0
        delta = {k: v - shares[k] for k, v in pair_shares(type(params)(**unit), plane).items()}
        for i in range(plane.n_pairs):  # a unit of the parameter on pair i alone
            scattered += rms**2 * bb(leak_y(stats, weights, delta, fields, pairs=slice(i, i + 1)))
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
        mean_h4(
            stats, hit_weights(stats), pair_shares(Systematics().per_pair(focal.n_pairs), focal)
        )
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
    stats : boresight.moments.FocalPlaneStats
        With the per-pair maps.
    mask : numpy.ndarray, shape (npix,)
        The analysis mask (RING). Its pixels whose 2x2 system is near singular (:func:`rcond`
        below :data:`RCOND_EXPECTATION`) are invalid, 0 in the maps with and without the
        systematics, as in :func:`boresight.engine.simulate_focalplane` with that ``rcond_min``.
    systematics : boresight.instrument.pairs.Systematics
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
        (:func:`boresight.moments.centroid_moments` with the focal plane), for a sky read
        exactly at each sample: every term of Y gains its fields' first-order change across the
        pixel, as in :func:`boresight.predict.expected_residual`, each pair through its own
        offsets.
    nthreads : int

    Returns
    -------
    FocalPlaneResidual
    """
    check_supported(stats, systematics)
    if stats.hwp is not None and (systematics.has_pointing or systematics.has_beams):
        raise ValueError(
            "a pointing offset or a beam behind a HWP: its expectation over skies is not built "
            "yet (delta_p predicts it for a sky)"
        )
    if offsets is not None and stats.hwp is not None:
        raise ValueError(OFFSETS_BEHIND_HWP)
    band = lmax if band is None else band
    nside, lw = hp.npix2nside(mask.size), lmax + band
    focal = stats.focalplane
    params, drawn = at_means(systematics, focal.n_pairs)
    shares = pair_shares(params, focal)
    weights = hit_weights(stats)
    h4 = mean_h4(stats, weights, shares)
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
                term_shares[name][pairs], term_h(stats, name, n, pairs), n, fields[kind], pairs
            )
        ]

    exact = read[2]
    beam = beam_terms(params, focal, fwhm_arcmin, band, n_max=stats.pair_h.shape[1] - 1)
    beams = [
        item
        for term in beam.values()
        for item in items(
            term.shares,
            pair_moment(stats, term.moment),
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
    stats : boresight.moments.FocalPlaneStats
        With the per-pair maps.
    systematics : boresight.instrument.pairs.Systematics
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
