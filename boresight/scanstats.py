"""Characterising any scan from its samples: hits, h_n, distinct crossing angles and their range,
and the synthetic scan with the same (N_phi, R) per pixel (the paper's section 3.1 check).

Crossing angles are binned per pixel into ``tolerance_deg`` bins on the circle (a bitmap, so
samples can stream in chunks). A run of occupied neighbouring bins counts as one distinct angle.
The range R is the arc between the centres of the first and last occupied bins of the smallest arc
that holds them all, and the centre is that arc's midpoint. Angles closer than the tolerance
therefore count as one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import healpy as hp
import numba
import numpy as np

from . import interrupts, tasks
from .constants import N_MAX
from .engine import check_samples
from .hwp import chunk_angles
from .jit import njit
from .kernels.pixels import ang2pix_array, zphi2pix
from .pointing import (
    ces_chunks,
    chunk_arguments,
    detector_pointing,
    offset_sample,
    pointing,
    sample_pointing,
)
from .scan import SyntheticScan
from .validation import integer

if TYPE_CHECKING:
    from collections.abc import Iterable

    from .focalplane import FocalPlane
    from .hwp import HWP
    from .schedule import Schedule


_WORD = 64


@numba.njit(inline="always")
def _angle_bin(c, s, nbins):
    """Bin of the angle whose (cos, sin) is (c, s) among nbins bins on [0, 2 pi)."""
    a = np.arctan2(s, c)
    if a < 0:  # what a % (2 pi) gives for a in [-pi, 0), without the float modulo
        a += 2 * np.pi
    return int(a / (2 * np.pi) * nbins) % nbins


@njit(parallel=True)
def _unit_angles(psi, nbins):
    """cos psi, sin psi and the angle bin of each sample."""
    c = np.empty(psi.size)
    s = np.empty(psi.size)
    b = np.empty(psi.size, dtype=np.int32)
    for k in numba.prange(psi.size):
        c[k], s[k] = np.cos(psi[k]), np.sin(psi[k])
        b[k] = _angle_bin(c[k], s[k], nbins)
    return c, s, b


@njit(parallel=True)
def _bin(pixels, cos_psi, sin_psi, angle_bin, sums, hits, occupancy, nparts):
    """Add samples to per-pixel sums of exp(i n psi) (n = 0..N_MAX), counts and angle bitmaps.

    Each thread owns a range of pixel indices and scans every sample, so no two threads write the
    same pixel; exp(i n psi) follows from exp(i psi) by multiplication. Pixel -1 (a sample left
    out) is skipped.
    """
    npix = hits.size
    for part in numba.prange(nparts):
        lo = part * npix // nparts
        hi = (part + 1) * npix // nparts
        for k in range(pixels.size):
            p = pixels[k]
            if p < lo or p >= hi:
                continue
            hits[p] += 1
            c, s = cos_psi[k], sin_psi[k]
            re, im = 1.0, 0.0
            for n in range(sums.shape[1]):
                sums[p, n] += complex(re, im)
                re, im = re * c - im * s, re * s + im * c
            b = angle_bin[k]
            occupancy[p, b // _WORD] |= np.uint64(1) << np.uint64(b % _WORD)


@njit(parallel=True)
def ces_hits(k0, n, chunk, terms, nside, nbins, exclude_turnarounds):
    """Pixel, cos psi, sin psi and angle bin of samples k0..k0+n-1 of a CES
    (:func:`boresight.pointing.sample_pointing`), without forming theta or psi; pixel -1 for a
    sample in a turnaround when they are excluded."""
    pix = np.empty(n, dtype=np.int64)
    cos_psi = np.empty(n)
    sin_psi = np.empty(n)
    angle_bin = np.empty(n, dtype=np.int32)
    cb, sb = np.cos(chunk[10]), np.sin(chunk[10])
    for i in numba.prange(n):
        z, r, phi, c, s, turning = sample_pointing(k0 + i, chunk, terms)
        pix[i] = -1 if exclude_turnarounds and turning else zphi2pix(nside, z, r, phi)
        cos_psi[i] = c * cb - s * sb
        sin_psi[i] = c * sb + s * cb
        angle_bin[i] = _angle_bin(cos_psi[i], sin_psi[i], nbins)
    return pix, cos_psi, sin_psi, angle_bin


@njit(parallel=True)
def ces_hits_pairs(k0, n, chunk, terms, nside, nbins, exclude_turnarounds, vectors, chi, gammas):
    """:func:`ces_hits` of each pair of a focal plane at ``vectors`` (m, 6)
    (:func:`boresight.pointing.offset_sample`): arrays (m, n). Behind a HWP at ``chi`` (n,)
    (empty: none), pair d's angle is :func:`boresight.hwp.reflected`'s, with ``gammas`` (m,)
    the pairs' angles [rad]."""
    m = vectors.shape[0]
    pix = np.empty((m, n), dtype=np.int64)
    cos_psi = np.empty((m, n))
    sin_psi = np.empty((m, n))
    angle_bin = np.empty((m, n), dtype=np.int32)
    cb, sb = np.cos(chunk[10]), np.sin(chunk[10])
    for i in numba.prange(n):
        z, r, phi, c, s, turning = sample_pointing(k0 + i, chunk, terms)
        c, s = c * cb - s * sb, c * sb + s * cb
        cp, sp = np.cos(phi), np.sin(phi)
        for d in range(m):
            zd, rd, phd, cd, sd = offset_sample(z, r, cp, sp, c, s, vectors[d])
            pix[d, i] = -1 if exclude_turnarounds and turning else zphi2pix(nside, zd, rd, phd)
            if chi.size:  # psi + 2 chi - 2 gamma
                turn = 2.0 * (chi[i] - gammas[d])
                ct, st = np.cos(turn), np.sin(turn)
                cd, sd = cd * ct - sd * st, cd * st + sd * ct
            cos_psi[d, i], sin_psi[d, i] = cd, sd
            angle_bin[d, i] = _angle_bin(cd, sd, nbins)
    return pix, cos_psi, sin_psi, angle_bin


@njit(parallel=True)
def _bin_pairs(
    pixels, cos_psi, sin_psi, angle_bin, acc_sums, acc_hits, occupancy, sums, hits, nparts
):
    """:func:`_bin` of every pair's samples (m, n) together, and each pair's own per-pixel sums
    (m, npix, N_MAX + 1) and counts (m, npix), in one pass: each thread owns a range of pixel
    indices and walks the pairs in turn, so the combined sums add in the order :func:`_bin` of
    the pairs' samples one after another would, and no two threads write one pixel."""
    m, npix = hits.shape
    for part in numba.prange(nparts):
        lo = part * npix // nparts
        hi = (part + 1) * npix // nparts
        for d in range(m):
            for k in range(pixels.shape[1]):
                p = pixels[d, k]
                if p < lo or p >= hi:
                    continue
                hits[d, p] += 1
                acc_hits[p] += 1
                c, s = cos_psi[d, k], sin_psi[d, k]
                re, im = 1.0, 0.0
                for n in range(sums.shape[2]):
                    z = complex(re, im)
                    sums[d, p, n] += z
                    acc_sums[p, n] += z
                    re, im = re * c - im * s, re * s + im * c
                b = angle_bin[d, k]
                occupancy[p, b // _WORD] |= np.uint64(1) << np.uint64(b % _WORD)


@njit(parallel=True)
def _runs(occupancy, nbins, observed):
    """Distinct angles, range and centre [bins] of each observed pixel's angle bitmap.

    Walks the set bits only; runs of neighbouring occupied bins are one angle, and the occupied
    arc is the complement of the largest circular gap.
    """
    npix, nwords = occupancy.shape
    n_distinct = np.zeros(npix, dtype=np.int64)
    range_bins = np.zeros(npix, dtype=np.int64)
    centre_bin = np.zeros(npix)
    for i in numba.prange(observed.size):
        p = observed[i]
        bins = np.empty(nbins, dtype=np.int64)
        count = 0
        for w in range(nwords):
            x = occupancy[p, w]
            while x:
                low = x & (~x + np.uint64(1))
                bins[count] = w * _WORD + int(np.log2(np.float64(low)))
                count += 1
                x ^= low
        if count == 0:
            continue
        # Gap before bins[j] (empty bins between it and its predecessor, circularly).
        runs, best_gap, best_j = 0, -1, 0
        for j in range(count):
            prev = bins[j - 1] if j > 0 else bins[count - 1] - nbins
            gap = bins[j] - prev - 1
            if gap > 0:
                runs += 1
            if gap > best_gap:
                best_gap, best_j = gap, j
        n_distinct[p] = max(runs, 1)
        span = nbins - best_gap - 1
        range_bins[p] = span
        centre_bin[p] = bins[best_j] + 0.5 * span + 0.5
    return n_distinct, range_bins, centre_bin


@dataclass(frozen=True)
class ScanStats:
    """Per-pixel statistics of a scan, RING maps (npix,).

    Parameters
    ----------
    hits : numpy.ndarray, int64
        Samples per pixel.
    h : numpy.ndarray, complex128, shape (5, npix)
        h_n, n = 0..4.
    n_distinct : numpy.ndarray, int64
        Distinct crossing angles (within the tolerance).
    range_rad, centre_rad : numpy.ndarray
        Range R and centre of the crossing angles [rad].
    tolerance_deg : float
    """

    hits: np.ndarray
    h: np.ndarray
    n_distinct: np.ndarray
    range_rad: np.ndarray
    centre_rad: np.ndarray
    tolerance_deg: float

    @property
    def observed(self):
        return self.hits > 0

    def survey_means(self, mask=None):
        """The paper's survey means over observed pixels.

        Parameters
        ----------
        mask : numpy.ndarray, shape (npix,), optional
            Restrict to mask > 0.

        Returns
        -------
        dict
            pixels, mean_hits, mean_n_phi, mean_range_rad and mean_abs_h{n}_sq (n = 1..4).
        """
        sel = self.observed if mask is None else self.observed & (np.asarray(mask) > 0)
        out = {
            "pixels": int(sel.sum()),
            "mean_hits": float(self.hits[sel].mean()),
            "mean_n_phi": float(self.n_distinct[sel].mean()),
            "mean_range_rad": float(self.range_rad[sel].mean()),
        }
        for n in range(1, N_MAX + 1):
            out[f"mean_abs_h{n}_sq"] = float(np.mean(np.abs(self.h[n, sel]) ** 2))
        return out

    def synthetic_twin(self, per_pixel=True, seed=0, in_pixel="random"):
        """The synthetic scan with this scan's N_phi and R.

        Parameters
        ----------
        per_pixel : bool
            Per-pixel maps of N_phi, R and centre, or the survey means.
        seed : int
        in_pixel : {"random", "centre"}

        Returns
        -------
        boresight.scan.SyntheticScan
        """
        obs = self.observed
        if per_pixel:
            return SyntheticScan(
                n_phi=np.where(obs, np.maximum(self.n_distinct, 1), 1),
                range_rad=np.where(obs, self.range_rad, 0.0),
                centre_rad=np.where(obs, self.centre_rad, 0.0),
                seed=seed,
                in_pixel=in_pixel,
            )
        means = self.survey_means()
        return SyntheticScan(
            n_phi=max(1, int(round(means["mean_n_phi"]))),
            range_rad=means["mean_range_rad"],
            seed=seed,
            in_pixel=in_pixel,
        )


class _Accumulator:
    """Per-pixel sums of exp(i n psi), counts and angle bitmaps, filled chunk by chunk."""

    def __init__(self, nside, tolerance_deg):
        if not 0 < tolerance_deg <= 180:
            raise ValueError(f"tolerance_deg must be in (0, 180], got {tolerance_deg}")
        npix = 12 * nside**2
        self.tolerance_deg = tolerance_deg
        self.nbins = int(round(360.0 / tolerance_deg))
        self.occupancy = np.zeros((npix, (self.nbins + _WORD - 1) // _WORD), dtype=np.uint64)
        self.sums = np.zeros((npix, N_MAX + 1), dtype=np.complex128)  # pixel-major: a cache line
        self.hits = np.zeros(npix, dtype=np.int64)

    def merge(self, other):
        """Add another accumulator's samples: sums and counts add, bitmaps join."""
        self.sums += other.sums
        self.hits += other.hits
        self.occupancy |= other.occupancy

    def add(self, pixels, cos_psi, sin_psi, angle_bin):
        interrupts.check()
        _bin(
            pixels,
            cos_psi,
            sin_psi,
            angle_bin,
            self.sums,
            self.hits,
            self.occupancy,
            numba.get_num_threads(),
        )

    def stats(self):
        hits = self.hits
        observed = np.flatnonzero(hits)
        h = np.zeros((N_MAX + 1, hits.size), dtype=np.complex128)
        h[:, observed] = (self.sums[observed] / hits[observed, None]).T
        n_distinct, range_bins, centre_bin = _runs(self.occupancy, self.nbins, observed)
        width = 2 * np.pi / self.nbins
        return ScanStats(
            hits=hits,
            h=h,
            n_distinct=n_distinct,
            range_rad=range_bins * width,
            centre_rad=np.mod(centre_bin * width, 2 * np.pi),
            tolerance_deg=self.tolerance_deg,
        )


def _stats(nside, tolerance_deg, binned_chunks):
    """ScanStats from chunks of (pixels, cos psi, sin psi, angle bins) for nbins bins."""
    acc = _Accumulator(nside, tolerance_deg)
    for chunk in binned_chunks(acc.nbins):
        acc.add(*chunk)
    return acc.stats()


def characterise(sample_chunks: Iterable, nside: int, tolerance_deg: float = 1.0) -> ScanStats:
    """Statistics of streams of samples.

    Parameters
    ----------
    sample_chunks : iterable of (theta, phi, psi)
        Arrays (n,) [rad], checked by :func:`boresight.engine.check_samples`.
    nside : int
    tolerance_deg : float
        Angles closer than this count as one, in (0, 180].

    Returns
    -------
    ScanStats
    """

    def binned(nbins):
        for chunk in sample_chunks:
            theta, phi, psi = check_samples(*chunk)
            yield (ang2pix_array(nside, theta, phi), *_unit_angles(psi, nbins))

    return _stats(nside, tolerance_deg, binned)


def characterise_schedule(
    schedule: Schedule,
    nside: int,
    tolerance_deg: float = 1.0,
    chunk_samples: int = 1 << 20,
    *,
    progress: bool = False,
) -> ScanStats:
    """Statistics of a CES schedule, pointing fused into the binning (no theta, phi, psi arrays);
    equal to characterise(pointing.pointing(schedule), ...) up to rounding.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    nside : int
    tolerance_deg : float
    chunk_samples : int
    progress : bool
        Show a progress bar over the schedule's samples.

    Returns
    -------
    ScanStats
    """
    from tqdm import tqdm

    exclude = schedule.turnarounds == "exclude"

    def binned(nbins):
        with tqdm(
            total=schedule.n_samples, unit="sample", unit_scale=True, disable=not progress
        ) as bar:
            for args in chunk_arguments(schedule, chunk_samples):
                yield ces_hits(*args, nside, nbins, exclude)
                bar.update(args[1])

    return _stats(nside, tolerance_deg, binned)


def sample_offsets(theta: np.ndarray, phi: np.ndarray, nside: int) -> tuple:
    """Each sample's RING pixel and its offset delta [rad] from the pixel's centre in the tangent
    plane there, (n - c_p) . e_theta + i (n - c_p) . e_phi (:func:`centroid_moments`).

    Parameters
    ----------
    theta, phi : numpy.ndarray
        The samples' colatitude and longitude [rad].
    nside : int

    Returns
    -------
    pix : numpy.ndarray, int64
    delta : numpy.ndarray, complex128
    """
    pix = hp.ang2pix(nside, theta, phi)
    c_theta, c_phi = hp.pix2ang(nside, pix)
    d = hp.ang2vec(theta, phi) - hp.ang2vec(c_theta, c_phi)
    e_theta = np.array(
        [np.cos(c_theta) * np.cos(c_phi), np.cos(c_theta) * np.sin(c_phi), -np.sin(c_theta)]
    )
    e_phi = np.array([-np.sin(c_phi), np.cos(c_phi), np.zeros_like(c_phi)])
    return pix, np.einsum("ij,ji->i", d, e_theta) + 1j * np.einsum("ij,ji->i", d, e_phi)


def centroid_moments(
    schedule: Schedule,
    nside: int,
    n_max: int = N_MAX,
    chunk_samples: int = 1 << 20,
    *,
    focalplane: FocalPlane | None = None,
) -> np.ndarray:
    """The samples' offsets from their pixel centres, weighted as the h_n are.

    delta_j = (n_j - c_p) . e_theta + i (n_j - c_p) . e_phi is sample j's offset [rad] in the
    tangent plane at its pixel's centre c_p (the spin-1 quantity of
    :func:`boresight.harmonics.alm2map_gradient`'s frame), so that a field read at the sample is
    F(c_p) + Re(conj(delta_j) grad F) to first order. Real scans cross a pixel along a few lines,
    and where they cross depends on the crossing angle: these moments carry what that does to a
    leak (:func:`boresight.predict.expected_residual`'s ``offsets``).

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
        With its boresight angles and repeats (:func:`boresight.pointing.pointing`).
    nside, n_max, chunk_samples : int
    focalplane : boresight.focalplane.FocalPlane, optional
        Each pair's own, on its own samples and crossing angles
        (:func:`boresight.pointing.detector_pointing`), one pair at a time: the ``offsets`` of
        :func:`boresight.predict.focalplane.expected_residual`.

    Returns
    -------
    numpy.ndarray, complex128, shape (2, n_max + 1, npix), or (pairs, 2, n_max + 1, npix)
        (1/N) sum_j exp(i n psi_j) delta_j and (1/N) sum_j exp(i n psi_j) conj(delta_j), n = 0..
        n_max (0 where N = 0).
    """
    if focalplane is None:
        return _centroids(pointing(schedule, chunk_samples), nside, n_max)
    return np.array(
        [
            _centroids(
                (
                    tuple(x[0] for x in chunk)
                    for chunk in detector_pointing(schedule, focalplane.subset([i]), chunk_samples)
                ),
                nside,
                n_max,
            )
            for i in range(focalplane.n_pairs)
        ]
    )


def _centroids(chunks, nside, n_max):
    """:func:`centroid_moments` of the (theta, phi, psi) chunks of one pointing."""
    npix = 12 * nside**2
    sums = np.zeros((2, n_max + 1, npix), dtype=np.complex128)
    hits = np.zeros(npix)
    for theta, phi, psi in chunks:
        interrupts.check()
        pix, delta = sample_offsets(theta, phi, nside)
        hits += np.bincount(pix, minlength=npix)
        turn, spin = np.exp(1j * psi), np.ones(psi.size, dtype=np.complex128)
        for n in range(n_max + 1):
            for k, value in enumerate((delta, np.conj(delta))):
                w = spin * value
                sums[k, n] += np.bincount(pix, w.real, npix) + 1j * np.bincount(pix, w.imag, npix)
            spin = spin * turn
    return np.where(hits > 0, sums / np.maximum(hits, 1), 0.0)


#: the (n, m) of :func:`hwp_moments` by default: n = 0..4 against m = 0, +-4, +-8 (h_{-n,-m} is
#: the conjugate of h_{n,m}), which hold the map-maker's weights (2, 4) and 2x2 system (4, 8)
#: behind the plate, a gain's or a leak's T leak (2, 4), and a signal fixed to the plate at
#: 4 chi, as its instrumental polarisation, seen through (2, 0) (:mod:`boresight.hwp`)
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
    (:mod:`boresight.hwp`); h_{n,m} is h_n at m = 0.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    hwp : boresight.hwp.HWP
        Continuous or stepped.
    nside : int
    terms : sequence of (int, int)
        The (n, m) to compute.
    chunk_samples : int
    focalplane : boresight.focalplane.FocalPlane, optional
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
        :func:`boresight.predict.focalplane.synchronous_weights`).
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


@dataclass(frozen=True)
class FocalPlaneStats:
    """Per-pixel statistics of a focal plane's scan, RING maps (npix,).

    Parameters
    ----------
    combined : ScanStats
        Every pair's samples binned together, as the map-maker combines them: hits N = sum_i N_i
        and h_n = sum_i N_i h_{n,i} / N, the hit-weighted mean over pairs.
    sum_sq : numpy.ndarray, float64, shape (N_MAX + 1, npix)
        sum_i N_i^2 ``|h_{n,i}|^2``: with N^2 the weight of a systematic scattered from pair to pair.
    focalplane : boresight.focalplane.FocalPlane
    pair_weights : numpy.ndarray, float64, shape (pairs, N_MAX + 1)
        Per pair, sum_p N_i ``|h_{n,i}|^2`` over pixels (n = 0: its hits).
    pair_hits : numpy.ndarray, int64, shape (pairs, npix), or None
        Each pair's hits N_i, where asked.
    pair_h : numpy.ndarray, complex128, shape (pairs, N_MAX + 1, npix), or None
        Each pair's h_{n,i}, where asked.
    hwp : boresight.hwp.HWP, optional
        The HWP in front of the pairs: their moments are of their reflected angles.
    pair_behind_h : numpy.ndarray, complex128, shape (pairs, len(behind_terms), npix), or None
        Behind ``hwp``, with the per-pair maps: each pair's moments of its T leaks' terms
        (:data:`T_BEHIND_TERMS`), and with ``pointing`` or ``beams`` of a pointing offset's terms
        (:func:`pointing_behind`) and the beams' (:func:`beams_behind`), each once
        (:meth:`behind`).
    behind_terms : tuple of (int, int, str or None)
        The (n, m, offset) of each of ``pair_behind_h``'s moments (:func:`_moments_behind`).
    """

    combined: ScanStats
    sum_sq: np.ndarray
    focalplane: FocalPlane
    pair_weights: np.ndarray
    pair_hits: np.ndarray | None = None
    pair_h: np.ndarray | None = None
    hwp: HWP | None = None
    pair_behind_h: np.ndarray | None = None
    behind_terms: tuple = ()

    def behind(self, n: int, m: int, offset: str | None = None) -> np.ndarray:
        """Each pair's moment (n, m, offset) behind the plate, (pairs, npix) (:func:`_moments_behind`)."""
        return self.pair_behind_h[:, self.behind_terms.index((n, m, offset))]

    def has_behind(self, terms) -> bool:
        """Whether every (n, m, offset) of ``terms`` was characterised behind the plate."""
        return self.pair_behind_h is not None and set(terms) <= set(self.behind_terms)

    def scattered(self) -> np.ndarray:
        """sum_i N_i^2 ``|h_{n,i}|^2`` / N^2 per pixel, (N_MAX + 1, npix): n = 0 is the effective 1 /
        (number of pairs) of a pixel, and for a focal plane on the axis it is ``|h_n|^2`` / n_pairs."""
        hits = self.combined.hits
        return np.where(hits > 0, self.sum_sq / np.maximum(hits, 1) ** 2, 0.0)

    def pair_means(self) -> list[dict]:
        """Per pair: its name, distance from the boresight [deg], hits and hit-weighted
        <``|h_n|^2``> = sum_p N_i ``|h_{n,i}|^2`` / sum_p N_i over its pixels (n = 1..N_MAX)."""
        rows = []
        for i, name in enumerate(self.focalplane.names):
            row = {"pair": name, "radius_deg": float(self.focalplane.radius_deg[i])}
            hits = self.pair_weights[i, 0]
            row["hits"] = int(hits)
            for n in range(1, N_MAX + 1):  # NaN for a pair that saw nothing
                row[f"abs_h{n}_sq"] = float(self.pair_weights[i, n] / hits) if hits else np.nan
            rows.append(row)
        return rows


#: per-pair maps held at once while summing a focal plane's scattered weights [bytes]
PAIR_BLOCK_BYTES = 1 << 30


def pair_blocks(n_pairs: int, nside: int, *, per_pair: bool = False) -> list[range]:
    """The blocks of pairs :func:`characterise_focalplane` streams the schedule for: all pairs at
    once when their maps are kept, else as many as :data:`PAIR_BLOCK_BYTES` holds."""
    per = 12 * nside**2 * (16 * (N_MAX + 1) + 8)
    size = n_pairs if per_pair else max(1, min(n_pairs, PAIR_BLOCK_BYTES // per))
    return [range(a, min(a + size, n_pairs)) for a in range(0, n_pairs, size)]


def _block_stats(schedule, pairs, nside, tolerance_deg, chunk_samples, per_pair, update=None):
    """One block of pairs, ``pairs`` = (their ``vectors`` (m, 6), their angles (m,) [rad], the
    HWP or None), over the whole
    schedule: its combined sums (an :class:`_Accumulator`), its share of ``sum_sq`` and its
    pairs' weights, and where asked its pairs' hits and h_n; behind ``hwp``, of the pairs'
    reflected angles. An independent task (:mod:`boresight.tasks`)."""
    exclude = schedule.turnarounds == "exclude"
    vectors, gammas, hwp = pairs
    npix, m = 12 * nside**2, vectors.shape[0]
    acc = _Accumulator(nside, tolerance_deg)
    sums = np.zeros((m, npix, N_MAX + 1), dtype=np.complex128)
    hits = np.zeros((m, npix), dtype=np.int64)
    nparts = numba.get_num_threads()
    none = np.zeros(0)
    for repeat, index, args in ces_chunks(schedule, max(1, chunk_samples // m)):
        chi = (
            none
            if hwp is None
            else chunk_angles(hwp, schedule, repeat, index, first=args[0], n=args[1])
        )
        pix, c, s, b = ces_hits_pairs(*args, nside, acc.nbins, exclude, vectors, chi, gammas)
        interrupts.check()
        _bin_pairs(pix, c, s, b, acc.sums, acc.hits, acc.occupancy, sums, hits, nparts)
        if update is not None:
            update(args[1] * m)
    sum_sq, weights = np.zeros((npix, N_MAX + 1)), np.zeros((m, N_MAX + 1))
    for d in range(m):  # one pair's (npix, N_MAX + 1) at a time: no block-sized temporaries
        power = sums[d].real ** 2 + sums[d].imag ** 2  # N_i^2 |h_n,i|^2
        sum_sq += power
        weights[d] = np.sum(power / np.maximum(hits[d], 1)[:, None], axis=0)
        if per_pair:
            sums[d] /= np.maximum(hits[d], 1)[:, None]  # h_n,i in place
    out = {"combined": acc, "sum_sq": sum_sq.T, "weights": weights}
    if per_pair:
        out["hits"], out["h"] = hits, np.swapaxes(sums, 1, 2)
    return out


def characterise_focalplane(
    schedule: Schedule,
    focalplane: FocalPlane,
    nside: int,
    tolerance_deg: float = 1.0,
    chunk_samples: int = 1 << 20,
    *,
    per_pair: bool = False,
    hwp: HWP | None = None,
    pointing: bool = False,
    beams: bool = False,
    ip: bool = False,
    scheduler: str | None = "serial",
    workers: int = 2,
    progress: bool = False,
) -> FocalPlaneStats:
    """Statistics of a schedule seen by every pair of a focal plane, each from its own place
    (:func:`boresight.pointing.detector_pointing`, fused into the binning).

    Behind a HWP each pair's moments are those of its reflected angle
    (:func:`boresight.hwp.reflected`): the angle at which a bare pair sees the sky as it does, so
    that :mod:`boresight.predict.focalplane` predicts what it carries through the HWP
    (:data:`boresight.hwp.THROUGH_HWP`).

    Pairs are streamed in blocks (:func:`pair_blocks`), so memory holds one block's maps, not one
    per pair. The blocks are independent tasks, run in this process or on Dask
    (:mod:`boresight.tasks`); their sums add in block order, so the result is the same wherever
    they run.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    focalplane : boresight.focalplane.FocalPlane
    nside : int
    tolerance_deg : float
    chunk_samples : int
        Detector-samples per chunk.
    per_pair : bool
        Keep each pair's hits and h_n.
    hwp : boresight.hwp.HWP, optional
        A continuous or stepped HWP in front of every pair.
    pointing : bool
        Behind ``hwp``, with ``per_pair``: also each pair's moments of a pointing offset's terms
        (:func:`pointing_behind`, 31 maps per pair), which its prediction behind the plate
        needs.
    beams : bool
        Likewise for the beams' terms (:func:`beams_behind`, 44 maps per pair). Behind a plate
        with ``per_pair`` each pair keeps :data:`T_BEHIND_TERMS` too (5 maps), the pairs' leaks
        of T read across the pixel; every moment is kept once (:meth:`FocalPlaneStats.behind`).
    ip : bool
        Likewise for the plate's instrumental polarisation (:data:`IP_BEHIND_TERMS`, 12 maps per
        pair), for :func:`boresight.predict.focalplane.ip_delta_p_across`.
    scheduler : str, optional
        "serial" (this process), None (a local Dask cluster of ``workers`` processes) or a Dask
        scheduler's address.
    workers : int
    progress : bool

    Returns
    -------
    FocalPlaneStats
    """
    from tqdm import tqdm

    vectors = focalplane.vectors()
    npix = 12 * nside**2
    blocks = pair_blocks(focalplane.n_pairs, nside, per_pair=per_pair)
    total = schedule.n_samples * focalplane.n_pairs
    combined = _Accumulator(nside, tolerance_deg)
    sum_sq = np.zeros((N_MAX + 1, npix))
    weights = np.zeros((focalplane.n_pairs, N_MAX + 1))
    kept = {}  # with per_pair there is one block, whose maps are kept as they are
    pending, merged = {}, [0]
    with tqdm(total=total, unit="sample", unit_scale=True, disable=not progress) as bar:
        serial = scheduler == "serial"

        def finish(i, result):
            pending[i] = result
            if not serial:
                bar.update(schedule.n_samples * len(blocks[i]))
            while merged[0] in pending:  # in block order: the sums' rounding is fixed
                part, block = pending.pop(merged[0]), blocks[merged[0]]
                combined.merge(part["combined"])
                sum_sq[...] += part["sum_sq"]
                weights[block.start : block.stop] = part["weights"]
                if per_pair:
                    kept.update(pair_hits=part["hits"], pair_h=part["h"])
                merged[0] += 1

        gammas = np.radians(focalplane.gamma_deg)
        arguments = [
            (
                schedule,
                (
                    np.ascontiguousarray(vectors[b.start : b.stop]),
                    np.ascontiguousarray(gammas[b.start : b.stop]),
                    hwp,
                ),
                nside,
                tolerance_deg,
                chunk_samples,
                per_pair,
                bar.update if serial else None,
            )
            for b in blocks
        ]
        tasks.run(_block_stats, arguments, finish, scheduler=scheduler, workers=workers)
    terms = ()  # the moments behind the plate: T's, the pointing's and the beams', each once
    if per_pair and hwp is not None and hwp.present:
        wanted = (POINTING_BEHIND_TERMS if pointing else ()) + (BEAM_BEHIND_TERMS if beams else ())
        wanted += IP_BEHIND_TERMS if ip else ()
        terms = tuple(dict.fromkeys(T_BEHIND_TERMS + wanted))
    behind = (
        _moments_behind(schedule, focalplane, hwp, nside, terms, chunk_samples) if terms else None
    )
    return FocalPlaneStats(
        combined=combined.stats(),
        sum_sq=sum_sq,
        focalplane=focalplane,
        pair_weights=weights,
        pair_hits=kept.get("pair_hits"),
        pair_h=kept.get("pair_h"),
        hwp=hwp,
        pair_behind_h=behind,
        behind_terms=terms,
    )


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
    (:func:`boresight.hwp.reflected`), so exp(i m (psi' - psi) / 2) = exp(i m (chi - gamma)):

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
    return _moments_behind(schedule, focalplane, hwp, nside, POINTING_BEHIND_TERMS, chunk_samples)


#: a sample's weight for each kind of offset moment, of its offset delta from its pixel's centre
OFFSET_WEIGHTS = {
    "conj": np.conj,
    "delta": lambda delta: delta,
    "conj2": lambda delta: np.conj(delta) ** 2,
    "delta2": lambda delta: delta**2,
    "abs2": lambda delta: np.abs(delta) ** 2,
}


def _moments_behind(schedule, focalplane, hwp, nside, terms, chunk_samples):
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
    return _moments_behind(schedule, focalplane, hwp, nside, BEAM_BEHIND_TERMS, chunk_samples)
