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
from typing import TYPE_CHECKING, NamedTuple

import numba
import numpy as np

from .. import engine
from .._util import interrupts
from .._util.jit import njit
from ..constants import N_MAX
from ..engine import check_samples
from ..kernels.pixels import ang2pix_array, zphi2pix
from ..pointing import (
    chunk_arguments,
    offset_sample,
    sample_pointing,
)
from ..scan import SyntheticScan
from ..schedule import Schedule

if TYPE_CHECKING:
    from collections.abc import Iterable


_WORD = 64
_POWER_CHUNK = 1 << 20  #: pixels per dot product of a mean power of h_n


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


#: coarse blocks of pixels the binning's threads are balanced over (at most; one per pixel below)
BALANCE_BLOCKS = 12 * 64**2


@njit
def pixel_ranges(pixels, npix, nparts):
    """Bounds (nparts + 1,) of pixel-index ranges holding about equal numbers of samples, from a
    histogram of ``pixels`` (1-d; -1 skipped) over coarse blocks of pixels: the binning's
    threads each own one range, so a field in one corner of the sky spreads over them all. The
    sums do not depend on the ranges (each pixel's samples add in sample order, by one thread).
    """
    blocks = min(npix, BALANCE_BLOCKS)
    size = (npix + blocks - 1) // blocks
    counts = np.zeros(blocks + 1, dtype=np.int64)
    for k in range(pixels.size):
        if pixels[k] >= 0:
            counts[pixels[k] // size + 1] += 1
    cum = np.cumsum(counts)
    bounds = np.empty(nparts + 1, dtype=np.int64)
    bounds[0], bounds[nparts] = 0, npix
    b = 0
    for part in range(1, nparts):
        target = cum[-1] * part // nparts
        while b < blocks and cum[b] < target:
            b += 1
        bounds[part] = max(bounds[part - 1], min(b * size, npix))
    return bounds


@njit(parallel=True)
def _bin(pixels, cos_psi, sin_psi, angle_bin, sums, hits, occupancy, bounds):
    """Add samples to per-pixel sums of exp(i n psi) (n = 0..N_MAX), counts and angle bitmaps.

    Each thread owns a range of pixel indices, ``bounds[part]:bounds[part + 1]`` (balanced by
    :func:`pixel_ranges`), and scans every sample, so no two threads write the same pixel;
    exp(i n psi) follows from exp(i psi) by multiplication. Pixel -1 (a sample left out) is
    skipped.
    """
    for part in numba.prange(bounds.size - 1):
        lo, hi = bounds[part], bounds[part + 1]
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
    (empty: none), pair d's angle is :func:`boresight.instrument.hwp.reflected`'s, with ``gammas`` (m,)
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
def bin_pairs(
    pixels, rows, cos_psi, sin_psi, angle_bin, acc_sums, acc_hits, occupancy, sums, hits, bounds
):
    """:func:`_bin` of every pair's samples (m, n) together into ``acc_sums``, ``acc_hits`` and
    ``occupancy`` (rows, ...), and each pair's own sums (m, rows, N_MAX + 1) and counts (m, rows),
    all on the samples' ``rows`` (m, n): their pixels' slots
    (:class:`~boresight.moments.observed.Slots`), one row per pixel. One pass: each thread
    owns a range of pixel indices (``bounds``, :func:`pixel_ranges`) and walks the pairs in turn,
    so the combined sums add in the order :func:`_bin` of the pairs' samples one after another
    would, and no two threads write one pixel or one row."""
    m = hits.shape[0]
    for part in numba.prange(bounds.size - 1):
        lo, hi = bounds[part], bounds[part + 1]
        for d in range(m):
            for k in range(pixels.shape[1]):
                p = pixels[d, k]
                if p < lo or p >= hi:
                    continue
                q = rows[d, k]
                hits[d, q] += 1
                acc_hits[q] += 1
                c, s = cos_psi[d, k], sin_psi[d, k]
                re, im = 1.0, 0.0
                for n in range(sums.shape[2]):
                    z = complex(re, im)
                    sums[d, q, n] += z
                    acc_sums[q, n] += z
                    re, im = re * c - im * s, re * s + im * c
                b = angle_bin[d, k]
                occupancy[q, b // _WORD] |= np.uint64(1) << np.uint64(b % _WORD)


@njit(parallel=True)
def _runs(occupancy, nbins, rows, pixels, npix):
    """Distinct angles, range and centre [bins] of each observed pixel's angle bitmap, maps of
    ``npix``: pixel ``pixels[i]``'s bitmap is row ``rows[i]`` of ``occupancy``.

    Walks the set bits only; runs of neighbouring occupied bins are one angle, and the occupied
    arc is the complement of the largest circular gap.
    """
    nwords = occupancy.shape[1]
    n_distinct = np.zeros(npix, dtype=np.int64)
    range_bins = np.zeros(npix, dtype=np.int64)
    centre_bin = np.zeros(npix)
    for i in numba.prange(pixels.size):
        p = pixels[i]
        bins = np.empty(nbins, dtype=np.int64)
        count = 0
        for w in range(nwords):
            x = occupancy[rows[i], w]
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


class Accumulator:
    """Per-pixel sums of exp(i n psi), counts and angle bitmaps, filled chunk by chunk."""

    def __init__(self, nside, tolerance_deg):
        if not 0 < tolerance_deg <= 180:
            raise ValueError(f"tolerance_deg must be in (0, 180], got {tolerance_deg}")
        npix = 12 * nside**2
        self.tolerance_deg = tolerance_deg
        self.nbins = self.bins(tolerance_deg)
        self.occupancy = np.zeros((npix, self.words(self.nbins)), dtype=np.uint64)
        self.sums = np.zeros((npix, N_MAX + 1), dtype=np.complex128)  # pixel-major: a cache line
        self.hits = np.zeros(npix, dtype=np.int64)

    @staticmethod
    def bins(tolerance_deg):
        """The angle bins of a tolerance [deg]."""
        return int(round(360.0 / tolerance_deg))

    @staticmethod
    def words(nbins):
        """The 64-bit words of a pixel's bitmap of ``nbins`` angle bins."""
        return (nbins + _WORD - 1) // _WORD

    def add_rows(self, pixels, sums, hits, occupancy):
        """Add the sums, counts and bitmaps of ``pixels`` (distinct RING indices), row by row."""
        self.sums[pixels] += sums
        self.hits[pixels] += hits
        self.occupancy[pixels] |= occupancy

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
            pixel_ranges(pixels, self.hits.size, numba.get_num_threads()),
        )

    def stats(self):
        observed = np.flatnonzero(self.hits)
        arrays = (self.sums, self.hits, self.occupancy)
        return stats_of_rows(
            self.hits.size, observed, observed, arrays, tolerance_deg=self.tolerance_deg
        )


def stats_of_rows(npix, pixels, rows, arrays, *, tolerance_deg):
    """ScanStats on the sky (``npix``) of ``arrays``: the sums (rows, N_MAX + 1), hits (rows,)
    and angle bitmaps (rows, words) that :class:`Accumulator` holds, pixel ``pixels[i]`` in row
    ``rows[i]`` (each pixel hit at least once): the sky's accumulator, or one on the observed
    pixels (:class:`~boresight.moments.observed.Union`)."""
    sums, hits, occupancy = arrays
    nbins = Accumulator.bins(tolerance_deg)
    full = np.zeros(npix, dtype=np.int64)
    full[pixels] = hits[rows]
    h = np.zeros((N_MAX + 1, npix), dtype=np.complex128)
    h[:, pixels] = (sums[rows] / hits[rows, None]).T
    n_distinct, range_bins, centre_bin = _runs(occupancy, nbins, rows, pixels, npix)
    width = 2 * np.pi / nbins
    return ScanStats(
        hits=full,
        h=h,
        n_distinct=n_distinct,
        range_rad=range_bins * width,
        centre_rad=np.mod(centre_bin * width, 2 * np.pi),
        tolerance_deg=tolerance_deg,
    )


def _stats(nside, tolerance_deg, binned_chunks):
    """ScanStats from chunks of (pixels, cos psi, sin psi, angle bins) for nbins bins."""
    acc = Accumulator(nside, tolerance_deg)
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


class Moments(NamedTuple):
    """What the predictions need of a scan's crossings.

    h : numpy.ndarray, complex64 (a synthetic scan's) or complex128, shape (N_MAX + 1, npix)
        h_n of one repeat's crossings (a real schedule's, rotations included), 0 where unobserved.
    crossings : numpy.ndarray, int32 (a synthetic scan's) or int64, shape (npix,)
        Crossings per pixel in one repeat.
    rotations_deg : tuple of float
        Boresight rotation of each repeat [deg]; (0,) for a real schedule.
    power : numpy.ndarray, shape (N_MAX + 1,)
        ``<|h_n|^2>`` of ``h`` over the pixels it was made on.
    """

    h: np.ndarray
    crossings: np.ndarray
    rotations_deg: tuple
    power: np.ndarray

    def rotated_power(self, n):
        """``<|h_n|^2>`` of all the repeats together: each repeat's h_n is the first's times
        e^{i n alpha}, so their mean is h_n <e^{i n alpha}>."""
        turn = np.mean(np.exp(1j * n * np.radians(self.rotations_deg)))
        return self.power[n] * abs(turn) ** 2


def compute_moments(
    scan: SyntheticScan | Schedule,
    nside: int,
    pixels: np.ndarray,
    *,
    n_max: int = N_MAX,
    nthreads: int = 0,
    backend: str = "cpu",
) -> Moments:
    """h_n of a synthetic or real scan.

    Parameters
    ----------
    scan : boresight.scan.SyntheticScan or boresight.schedule.Schedule
    nside : int
    pixels : numpy.ndarray
        Pixels of a synthetic scan, and those :attr:`Moments.power` averages over: a boolean
        map (npix,) or increasing RING indices.
    n_max : int
        The highest moment of a synthetic scan (:func:`boresight.jobs.residual.n_max_for`); a
        real schedule's are :data:`boresight.moments.N_MAX`.
    nthreads : int
        CPU threads, 0 for all cores; the result does not depend on it.
    backend : {"cpu", "gpu"}

    Returns
    -------
    Moments
    """
    if isinstance(scan, Schedule):
        stats = characterise_schedule(scan, nside)
        return Moments(stats.h, stats.hits, (0.0,), _mean_power(stats.h, pixels))
    h, crossings = engine.scan_moments(
        scan.one_repeat(),
        nside,
        n_max,
        pixels=pixels,
        nthreads=nthreads,
        backend=backend,
        dtype=np.complex64,  # |h_n| <= 1 to 6e-8: half of the Nside-2048 run's largest array
    )
    return Moments(h, _narrow(crossings, pixels), scan.rotations_deg, _mean_power(h, pixels))


def _narrow(crossings, pixels):
    """int32 ``crossings``, written on ``pixels`` only: the other pages stay untouched zeros (0.08
    GB less on the wide mask at Nside 2048). What reads them divides by them in float64."""
    pixels = np.flatnonzero(pixels) if pixels.dtype == bool else pixels
    out = np.zeros(crossings.size, dtype=np.int32)
    out[pixels] = crossings[pixels]
    return out


def _mean_power(h, pixels):
    """``<|h_n|^2>`` over ``pixels`` (a boolean map or RING indices) for each n of h."""
    pixels = np.flatnonzero(pixels) if pixels.dtype == bool else pixels
    out = np.zeros(h.shape[0])
    for n, hn in enumerate(h):
        for start in range(0, pixels.size, _POWER_CHUNK):  # in float64, whatever h's dtype
            values = hn[pixels[start : start + _POWER_CHUNK]].astype(np.complex128).view(np.float64)
            out[n] += np.dot(values, values)  # (re, im) pairs: |h|^2 summed is one dot product
    return out / max(pixels.size, 1)
