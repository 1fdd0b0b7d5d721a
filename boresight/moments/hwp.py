"""The moments h_{n,m} behind a half-wave plate: of the boresight's or each pair's samples, and
weighted by their offsets from the pixel's centre (the moments the predictions behind a plate
read).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .._util import interrupts
from .._util.jit import njit
from ..constants import N_MAX
from ..kernels.pixels import ang2pix_array
from ..pointing import (
    detector_pointing,
    pointing,
)
from ..validation import integer
from .offsets import sample_offsets

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane
    from ..instrument.hwp import HWP
    from ..schedule import Schedule


#: the (n, m) of :func:`hwp_moments` by default: n = 0..4 against m = 0, +-4, +-8 (h_{-n,-m} is
#: the conjugate of h_{n,m}), which hold the map-maker's weights (2, 4) and 2x2 system (4, 8)
#: behind the plate, a gain's or a leak's T leak (2, 4), and a signal fixed to the plate at
#: 4 chi, as its instrumental polarisation, seen through (2, 0) (:mod:`boresight.instrument.hwp`)
HWP_TERMS = ((0, 0), (0, 4), (0, 8)) + tuple(
    (n, m) for n in range(1, N_MAX + 1) for m in (-8, -4, 0, 4, 8)
)


@njit
def _bin_spins(pix, psi, chi, terms, sums, hits, weights=None, kinds=None):
    """sums[k, p] += exp(i (n_k psi + m_k chi)) w_k and hits[p] += 1 over samples, in sample
    order; w_k = 1, or with ``weights`` (K, samples) the sample's weights[kinds[k]] where
    kinds[k] >= 0."""
    for j in range(pix.size):
        p = pix[j]
        hits[p] += 1
        for k in range(terms.shape[0]):
            angle = terms[k, 0] * psi[j] + terms[k, 1] * chi[j]
            value = complex(np.cos(angle), np.sin(angle))
            if weights is not None and kinds[k] >= 0:
                value *= weights[kinds[k], j]
            sums[k, p] += value


def _integer_terms(terms):
    """(n, m) pairs of integers, one or more: 1.5 was taken as 1, a bare pair as two terms."""
    try:
        pairs = [tuple(t) for t in terms]
    except TypeError:
        raise TypeError(f"terms = {terms!r}: a sequence of (n, m) pairs of integers") from None
    if not pairs or any(len(t) != 2 for t in pairs):
        raise ValueError(f"terms = {terms!r}: one or more (n, m) pairs of integers")
    return [
        (integer("a term's n", n, -64, 64), integer("a term's m", m, -64, 64)) for n, m in pairs
    ]


def hwp_moments(
    schedule: Schedule,
    hwp: HWP,
    nside: int,
    terms=HWP_TERMS,
    *,
    chunk_samples: int = 1 << 20,
    focalplane: FocalPlane | None = None,
    relative: bool = False,
    pair_weights: np.ndarray | None = None,
    each=None,
    progress: bool = False,
) -> tuple[np.ndarray, dict]:
    """The moments h_{n,m} = <exp(i n psi + i m chi)> over each pixel's samples of a schedule, with
    psi boresight's crossing angle and chi the HWP's angle in the focal plane
    (:mod:`boresight.instrument.hwp`); h_{n,m} is h_n at m = 0.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    hwp : boresight.instrument.hwp.HWP
        Continuous or stepped.
    nside : int
    terms : sequence of (int, int)
        The (n, m) to compute.
    chunk_samples : int
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        Each pair on its own samples, psi its own crossing angle
        (:func:`boresight.pointing.detector_pointing`), one pair at a time, so memory is one
        pair's maps and the combination's; default: the boresight's samples (the pairs on the
        axis).
    relative : bool
        With a focal plane: chi is the plate's angle from each pair's half angle, chi - gamma / 2,
        so that the reflected angle is psi + 2 chi, and the combination carries each pair's
        exp(-i m gamma / 2) (the plate's IP on a focal plane,
        :func:`boresight.predict.focalplane.ip_delta_p`): each pair's sums weighted by
        exp(-i m gamma / 2).
    pair_weights : numpy.ndarray, complex, shape (pairs, len(terms)), optional
        With a focal plane and not ``relative``: each pair's weight of each term in the
        combination (the plate's synchronous signal,
        :func:`synchronous_weights`).
    each : callable, optional
        With a focal plane, called as ``each(i, hits_i, h_i)`` with pair i's own moments as they
        are made (weighted as they enter the combination).
    progress : bool

    Returns
    -------
    hits : numpy.ndarray, int64, shape (npix,)
    h : dict
        (n, m) -> (npix,) complex128, 0 where unseen: with a focal plane, the combination the
        map-maker makes, every pair's samples binned together.
    """
    from tqdm import tqdm

    if not hwp.present:
        raise ValueError("h_{n,m} needs a continuous or a stepped HWP")
    if (relative or pair_weights is not None) and focalplane is None:
        raise ValueError(
            "relative or weighted h_{n,m} are of a focal plane's pairs: give focalplane"
        )
    if relative and pair_weights is not None:
        raise ValueError("relative h_{n,m} carry their own weights: not with pair_weights")
    table = np.array(_integer_terms(terms), dtype=np.float64).reshape(-1, 2)
    if len({tuple(t) for t in table}) != len(table):
        raise ValueError(f"repeated (n, m) in {list(terms)}")
    if relative:
        half = np.radians(np.asarray(focalplane.gamma_deg, dtype=np.float64)) / 2
        pair_weights = np.exp(-1j * np.outer(half, table[:, 1]))
    if pair_weights is not None:
        pair_weights = np.asarray(pair_weights, dtype=np.complex128)
        if pair_weights.shape != (focalplane.n_pairs, len(table)):
            raise ValueError(
                f"pair_weights: shape {pair_weights.shape}, want "
                f"{(focalplane.n_pairs, len(table))} (pairs, terms)"
            )
    npix = 12 * nside**2
    sums = np.zeros((len(table), npix), dtype=np.complex128)
    hits = np.zeros(npix, dtype=np.int64)
    pairs = 1 if focalplane is None else focalplane.n_pairs
    with tqdm(
        total=schedule.n_samples * pairs, unit="sample", unit_scale=True, disable=not progress
    ) as bar:
        if focalplane is None:
            for theta, phi, psi, chi in pointing(schedule, chunk_samples, hwp=hwp):
                interrupts.check()
                _bin_spins(ang2pix_array(nside, theta, phi), psi, chi, table, sums, hits)
                bar.update(theta.size)
        for i in range(pairs if focalplane is not None else 0):
            own_sums, own_hits = np.zeros_like(sums), np.zeros_like(hits)
            one = focalplane.subset([i])
            for theta, phi, psi, chi in detector_pointing(schedule, one, chunk_samples, hwp=hwp):
                interrupts.check()
                pix = ang2pix_array(nside, theta[0], phi[0])
                _bin_spins(pix, psi[0], chi, table, own_sums, own_hits)
                bar.update(theta.size)
            if pair_weights is not None:
                own_sums *= pair_weights[i][:, None]
            if each is not None:
                each(i, own_hits, _moments(own_sums, own_hits, table))
            sums += own_sums
            hits += own_hits
        bar.update(bar.total - bar.n)  # the samples of excluded turnarounds, never yielded
    return hits, _moments(sums, hits, table)


def _moments(sums, hits, table):
    h = np.where(hits > 0, sums / np.maximum(hits, 1), 0.0)
    return {(int(n), int(m)): h[k] for k, (n, m) in enumerate(table)}


#: the offsets from a pixel's centre a moment behind a plate can be weighted by, to second order
OFFSETS = (None, "conj", "delta", "conj2", "delta2", "abs2")
#: the moments behind a plate of the pairs' leaks of T (a gain, an additive leak): h_{2,4}, the
#: reflected angles' h_2, weighted by each sample's offset from its pixel's centre to second
#: order, for T read across the pixel where the spinning plate leaves incoherent sums
T_BEHIND_TERMS = tuple((2, 4, o) for o in OFFSETS[1:])
#: the moments of the plate's instrumental polarisation on a pair's samples: h_{2,0} of its own
#: crossing angles and its h_{2,8}, each weighted by the samples' offsets to second order
IP_BEHIND_TERMS = tuple((2, m, o) for m in (0, 8) for o in OFFSETS)
#: :func:`pointing_behind`'s moments, each (n, m, offset): the mean over a pair's samples per pixel
#: of exp(i n psi + i m (chi - gamma)), times the sample's offset from its pixel's centre as
#: ``offset`` names it (:data:`OFFSET_WEIGHTS`)
POINTING_BEHIND_TERMS = (
    (1, 4, None),  # the T gradient's
    (3, 4, None),
    (1, 0, None),  # the P gradient's
    (3, 8, None),
    (5, 8, None),
    (1, 4, "conj"),  # the T gradient's change across the pixel
    (1, 4, "delta"),
    (3, 4, "conj"),
    (3, 4, "delta"),
)
POINTING_BEHIND_TERMS += tuple((n, 4, o) for o in OFFSETS for n in (0, 2, 4))  # T's second order
POINTING_BEHIND_TERMS += ((2, 0, None), (2, 8, None), (4, 8, None), (6, 8, None))  # P's


def pointing_behind(
    schedule: Schedule,
    focalplane: FocalPlane,
    hwp: HWP,
    nside: int,
    *,
    chunk_samples: int = 1 << 20,
) -> np.ndarray:
    """Each pair's moments of a pointing offset's terms behind a HWP, on its own samples.

    Detector B's offset turns with the pair's own crossing angle psi, and the map-maker
    demodulates with its reflected angle psi' = psi + 2 chi - 2 gamma
    (:func:`boresight.instrument.hwp.reflected`), so exp(i m (psi' - psi) / 2) = exp(i m (chi - gamma)):

    * the T gradient's terms, a bare pair's h_1 G and h_3 G*, take ``g1`` = <exp(i (2 psi' -
      psi))> and ``g3`` = <exp(i (2 psi' + psi))>, (n, m) = (1, 4) and (3, 4), which a spinning
      plate averages away;
    * the P gradient's, which that leaves, take ``h1`` = h_{1,0} of the pairs' own crossing
      angles and ``q3``, ``q5`` = <exp(i (4 psi' -+ psi))>, (3, 8) and (5, 8);
    * read exactly at each sample, the T gradient's terms gain their first-order change across
      the pixel: ``g1`` and ``g3`` weighted by each sample's offset delta from its pixel's centre
      and by its conjugate (:func:`sample_offsets`, :func:`centroid_moments`). Behind a spinning
      plate the terms are incoherent sums of the size of these (docs/conventions.md);
    * the offset's second order in rho, a bare pair's h_0 d^2 T, h_2 dbar d T and h_4 conj(d^2 T),
      takes <exp(i (2 psi' - 2 psi + n psi))>, (n, m) = (0, 4), (2, 4), (4, 4), with their
      change across the pixel to second order, as the beams' T part (:func:`beams_behind`); and
      what B reads of P off its place to second order, h_{2,0}, h_{2,8}, h_{4,8} and h_{6,8}:
      what is left where 0/180 cancels every odd n.

    Returns
    -------
    numpy.ndarray, complex128, shape (pairs, 31, npix)
        In :data:`POINTING_BEHIND_TERMS` order, 0 where a pair has no hits.
    """
    return moments_behind(
        schedule, focalplane, hwp, nside, terms=POINTING_BEHIND_TERMS, chunk_samples=chunk_samples
    )


#: a sample's weight for each kind of offset moment, of its offset delta from its pixel's centre
OFFSET_WEIGHTS = {
    "conj": np.conj,
    "delta": lambda delta: delta,
    "conj2": lambda delta: np.conj(delta) ** 2,
    "delta2": lambda delta: delta**2,
    "abs2": lambda delta: np.abs(delta) ** 2,
}


def moments_behind(schedule, focalplane, hwp, nside, *, terms, chunk_samples):
    """Each pair's means over its samples per pixel of ``terms`` ((n, m, offset) each:
    exp(i n psi + i m (chi - gamma)), times the sample's offset delta from its pixel's centre as
    ``offset`` says: "conj", "delta", "conj2", "delta2" or "abs2" for conj(delta), delta, their
    squares and ``|delta|^2``), (pairs, len(terms), npix), 0 where a pair has no hits."""
    npix = 12 * nside**2
    out = np.zeros((focalplane.n_pairs, len(terms), npix), dtype=np.complex128)
    gamma = np.radians(np.asarray(focalplane.gamma_deg, dtype=np.float64))
    table = np.array([(n, m) for n, m, _ in terms], dtype=np.float64)
    weighted = list(dict.fromkeys(offset for _, _, offset in terms if offset is not None))
    kinds = np.array([-1 if o is None else weighted.index(o) for _, _, o in terms], dtype=np.int64)
    for i in range(focalplane.n_pairs):
        hits = np.zeros(npix, dtype=np.int64)
        chunks = detector_pointing(schedule, focalplane.subset([i]), chunk_samples, hwp=hwp)
        for theta, phi, psi, chi in chunks:
            interrupts.check()
            pix, delta = sample_offsets(theta[0], phi[0], nside)
            weights = np.array([OFFSET_WEIGHTS[o](delta) for o in weighted], dtype=np.complex128)
            _bin_spins(
                pix,
                psi[0],
                chi - gamma[i],
                table,
                out[i],
                hits,
                weights.reshape(-1, pix.size),
                kinds,
            )
        out[i] /= np.maximum(hits, 1)  # unseen pixels summed nothing: 0
    return out


#: the largest abs(n) of a beam term behind a HWP, by m: its polarised part's (m = 0, 8) to h_6,
#: the ellipticity's eth^2 P that a bare pair's prediction leaves out; its T part's (m = 4) to
#: h_4, as a bare pair's
BEAM_N_MAX = {0: 6, 4: N_MAX, 8: 6}
#: :func:`beams_behind`'s moments, as :data:`POINTING_BEHIND_TERMS`: (n, m) for every moment an
#: elliptical Gaussian beam's term takes (n even, abs(n) <= BEAM_N_MAX[m]) and m = 0, 4, 8, and
#: the T part's (n, 4) weighted by each sample's offset from its pixel's centre to second order
BEAM_BEHIND_TERMS = tuple(
    (n, m, None) for m in (0, 4, 8) for n in range(-BEAM_N_MAX[m], BEAM_N_MAX[m] + 1, 2)
) + tuple((n, 4, o) for o in OFFSETS[1:] for n in range(-N_MAX, N_MAX + 1, 2))


def beams_behind(
    schedule: Schedule,
    focalplane: FocalPlane,
    hwp: HWP,
    nside: int,
    *,
    chunk_samples: int = 1 << 20,
) -> np.ndarray:
    """Each pair's moments of its beams' terms behind a HWP, on its own samples.

    A beam's shape turns with the pair's own crossing angle psi, its polarisation and the
    map-maker with the reflected psi' = psi + 2 chi - 2 gamma, so a bare pair's beam term at
    h_n takes, behind the plate, h_{n,4} for the sky's T, and h_{n,0} and h_{n,8} for its
    polarisation (:func:`boresight.predict.focalplane.delta_p`, docs/conventions.md). Behind a
    spinning plate the T part's are incoherent sums, which the fields' change across the pixel
    sets: so h_{n,4} weighted by the samples' offsets too, to second order (the beams' fields are
    the sky's second derivatives).

    Returns
    -------
    numpy.ndarray, complex128, shape (pairs, 44, npix)
        In :data:`BEAM_BEHIND_TERMS` order, 0 where a pair has no hits.
    """
    return moments_behind(
        schedule, focalplane, hwp, nside, terms=BEAM_BEHIND_TERMS, chunk_samples=chunk_samples
    )


#: the h_{n,m} of (psi, chi) the plate's instrumental polarisation reaches a pair's map through
IP_TERMS = ((2, 0), (2, 8), (4, 8))


#: the h_{n,m} the plate's synchronous 2 chi signal reaches a pair's map through
SYNCHRONOUS_TERMS = ((2, 2), (2, 6), (4, 8))


def synchronous_weights(focalplane) -> np.ndarray:
    """Each pair's weights of :data:`SYNCHRONOUS_TERMS` in the map-maker's combination, 1,
    exp(-4 i gamma) and exp(-4 i gamma), (pairs, 3) complex
    (``boresight.moments.hwp_moments(..., focalplane=, pair_weights=)``)."""
    w = np.exp(-4j * np.radians(np.asarray(focalplane.gamma_deg, dtype=np.float64)))
    return np.stack([np.ones_like(w), w, w], axis=1)


#: the h_{n,m} a HWP angle's jitter reaches a pair's map through
JITTER_TERMS = ((4, 8), (8, 16))


#: the moments the plate's own cases are predicted from
PLATE_TERMS = tuple(dict.fromkeys(IP_TERMS + SYNCHRONOUS_TERMS + JITTER_TERMS))


class PlateMoments(NamedTuple):
    """The moments the plate's own cases are predicted from: the hits, h_{n,m} of
    :data:`PLATE_TERMS`, those of the synchronous signal, and the pairs' angles the predictions
    average exp(-4 i gamma) over (None where the moments carry each pair's own)."""

    hits: np.ndarray
    h: dict
    synchronous: dict
    pair_angles_deg: tuple | None


def plate_moments(scan, plate, nside, pairs) -> PlateMoments:
    """:class:`PlateMoments` of ``pairs`` behind ``plate``: the boresight's where every pair is on
    the axis; else each pair on its own samples, combined as the map-maker combines them, those
    of chi - gamma / 2 (the IP's and the jitter's: each pair's exp(-i m gamma / 2)) and the
    synchronous signal's with :func:`synchronous_weights`. The
    jitter's white part then takes the pairs' samples in a pixel as independent draws, as they
    are for pairs more than a pixel apart."""
    if not np.any(pairs.radius_deg > 0):
        hits, h = hwp_moments(scan, plate, nside, PLATE_TERMS)
        return PlateMoments(hits, h, h, pairs.pair_angles_deg)
    hits, h = hwp_moments(scan, plate, nside, PLATE_TERMS, focalplane=pairs, relative=True)
    _, synchronous = hwp_moments(
        scan,
        plate,
        nside,
        SYNCHRONOUS_TERMS,
        focalplane=pairs,
        pair_weights=synchronous_weights(pairs),
    )
    return PlateMoments(hits, h, synchronous, None)
