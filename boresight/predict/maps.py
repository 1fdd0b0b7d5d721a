"""The map-level prediction: the spurious P = Q + i U of a systematic from the scan's h_n maps and
the sky, with the map-maker's h_4 coupling, exact for pixel-centre hits (pointing to first order
in rho)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np

from .. import harmonics
from .._util.jit import njit
from .._util.threads import numba_threads
from ..instrument.pairs import Instrument
from .beam_fields import beam_field, beam_filters
from .coefficients import coefficients
from .terms import TERMS

if TYPE_CHECKING:
    from collections.abc import Sequence

    from ..instrument.pairs import Systematics
    from ..sky import Sky


def delta_p(
    sky: Sky,
    h: np.ndarray,
    systematics: Systematics,
    instrument: Instrument | None = None,
    *,
    template: np.ndarray | None = None,
    nthreads: int = 0,
    rotations_deg: Sequence[float] = (0.0,),
    pixels: np.ndarray | None = None,
    gradient: np.ndarray | None = None,
) -> np.ndarray:
    """Predicted spurious polarisation P = Q + i U from h_n and the sky, map-maker included.

    Gain, leak and angle terms are exact for pixel-centre hits; pointing is first order in rho.
    Gain jitter, a random term, has zero mean and is left out. Added systematics
    (:mod:`boresight.instrument.added`) join Y through their own term.

    Parameters
    ----------
    sky : boresight.sky.Sky
    h : numpy.ndarray, complex128, shape (>= 5, npix)
        h_n maps of one repeat's hits (:func:`boresight.engine.scan_moments` of
        ``scan.one_repeat()``), or of a real schedule with its rotations.
    systematics : boresight.instrument.pairs.Systematics
    instrument : boresight.instrument.pairs.Instrument, optional
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
    beam = np.empty(0, dtype=np.complex128)  # Y's terms beyond the table: beams, added ones
    if systematics.has_beams:
        beam = _beam_y(sky, h, systematics, instrument, rotations_deg, nthreads)
    if systematics.added:
        beam = _added_y(sky, h, systematics, instrument, rotations_deg) + (beam if beam.size else 0)
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
            np.array([*(getattr(c, term.name) for term in TERMS), c.m4]),
            out,
        )
    return out


def _added_y(sky, h, systematics, instrument, rotations_deg):
    """The added systematics' part of Y (:meth:`boresight.instrument.added.PairSystematic.y`),
    (npix,) complex."""
    instrument = Instrument() if instrument is None else instrument
    rotations = np.deg2rad(np.asarray(rotations_deg, dtype=np.float64))
    out = np.zeros(h.shape[1], dtype=np.complex128)
    for one, amplitude in systematics.added_per_pair(instrument.n_pairs):
        coefficient = one.coefficient(amplitude, rotations, instrument.pair_angles_rad)
        out += one.y(sky, h, coefficient)
    return out


def _beam_y(sky, h, systematics, instrument, rotations_deg, nthreads):
    """The beam terms' part of Y: sum_n h_n G_n over the n that h holds (:func:`beam_filters`),
    (npix,) complex."""
    n_max = h.shape[0] - 1
    filters = beam_filters(
        systematics, instrument, rotations_deg, sky.fwhm_arcmin, sky.lmax, n_max=n_max
    )
    out = np.zeros(h.shape[1], dtype=np.complex128)
    for n, filt in filters.items():
        if np.any(filt):
            field = beam_field(sky, filt, abs(2 - n), nthreads)
            field = np.conj(field) if n > 2 else field
            out += (h[n] if n >= 0 else np.conj(h[-n])) * field
    return out


@njit(parallel=True)
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
