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
axis each pair keeps its own.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .. import harmonics
from ..constants import DEG
from ..instrument import LIMITS, UNITS, Spread
from ..spectra import as_footprint
from .coefficients import _pair_terms
from .windows import hit_spread_window

if TYPE_CHECKING:
    from ..instrument import Systematics
    from ..scanstats import FocalPlaneStats
    from ..sky import Sky

#: the drawn parameters the expectation covers: those dP is linear in
LINEAR = ("dg", "leak", "rho_arcmin")
#: the coefficient shares and the moment each multiplies
TERMS = (("t2", 2), ("s2", 2), ("g1", 1), ("g3", 3), ("p0", 0), ("p4", 4))


def _check(stats, systematics):
    if stats.pair_h is None:
        raise ValueError("the focal plane's per-pair maps are needed: characterise with per_pair")
    if systematics.has_beams:
        raise ValueError("beam systematics are not yet predicted for a focal plane")


def pair_shares(params, focalplane) -> dict:
    """Each pair's coefficient shares (:func:`boresight.predict.coefficients`' terms of one pair),
    for drawn parameters ``params`` (:class:`boresight.instrument.PairParameters`), (n_pairs,)
    complex each; no rotation repeat (a schedule's h_n hold its rotations)."""
    angles = np.asarray(focalplane.pair_angles_deg) * DEG
    return _pair_terms(params, angles, np.zeros(1), np.zeros(1))


def _fields(sky, systematics, template, spread, nthreads):
    """The sky's fields each term multiplies: T, P and P*, the leak's template, the gradient G
    and G*; with ``spread``, each as its mean over hits spread uniformly over a pixel (its alm
    times the square root of :func:`~boresight.predict.windows.hit_spread_window`)."""
    alm = sky.alm
    if spread:
        window = np.sqrt(np.clip(hit_spread_window(sky.nside, sky.lmax), 0.0, None))
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
            h = stats.pair_h[pairs, n]
            y += fields[name] * np.einsum("i,ip,ip->p", shares[name][pairs], weights[pairs], h)
    return y


def _solve(y, h4):
    det = 1.0 - np.abs(h4) ** 2
    ok = det > 1e-12
    return np.where(ok, (y - h4 * np.conj(y)) / np.where(ok, det, 1.0), 0.0)


def _h4(stats, weights, shares):
    return np.einsum("i,ip,ip->p", shares["m4"], weights, stats.pair_h[:, 4])


def delta_p(
    sky: Sky,
    stats: FocalPlaneStats,
    systematics: Systematics,
    *,
    template: np.ndarray | None = None,
    spread: bool = True,
    nthreads: int = 0,
) -> np.ndarray:
    """The spurious P = Q + i U of a focal plane's own draw of its pairs' systematics: the
    module's dP, pointing to first order in rho.

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
    nthreads : int

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
        [muK], 0 off the observed pixels.
    """
    _check(stats, systematics)
    shares = pair_shares(systematics.per_pair(stats.focalplane.n_pairs), stats.focalplane)
    fields = _fields(sky, systematics, template, spread, nthreads)
    weights = _weights(stats)
    return _solve(_y(stats, weights, shares, fields), _h4(stats, weights, shares))


def _at_means(systematics, n_pairs):
    """Each pair's parameters with every drawn one at its mean, and the drawn ones' (name,
    rms in the engine's units)."""
    params = systematics.per_pair(n_pairs)
    drawn, values = [], params._asdict()
    for k, name in enumerate(LIMITS):
        spread = getattr(systematics, name)
        if isinstance(spread, Spread) and spread.rms > 0:
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
    fp = stats.focalplane
    params, drawn = _at_means(systematics, fp.n_pairs)
    fields = _fields(sky, systematics, template, spread, nthreads)
    shares = pair_shares(params, fp)
    weights = _weights(stats)
    h4 = _h4(stats, weights, shares)

    def bb(y):
        d = _solve(y, h4)[footprint.pixels]
        b = footprint.alm(np.array([d.real, d.imag]), lmax, 2, nthreads=nthreads)[1]
        return harmonics.alm2cl(b)

    coherent = bb(_y(stats, weights, shares, fields))
    scattered = np.zeros(lmax + 1)
    for field, rms in drawn:
        unit = params._asdict()
        unit[field] = unit[field] + 1.0
        delta = {k: v - shares[k] for k, v in pair_shares(type(params)(**unit), fp).items()}
        for i in range(fp.n_pairs):  # a unit of the parameter on pair i alone
            scattered += rms**2 * bb(_y(stats, weights, delta, fields, slice(i, i + 1)))
    return coherent, scattered
