"""Characterising any scan from its samples: hits, h_n, distinct crossing angles and their range,
and the synthetic scan with the same (N_phi, R) per pixel (the paper's section 3.1 check).

Crossing angles are binned per pixel into ``tolerance_deg`` bins on the circle (a bitmap, so
samples can stream in chunks). A run of occupied neighbouring bins counts as one distinct angle.
The range R is the arc between the centres of the first and last occupied bins of the smallest arc
that holds them all, and the centre is that arc's midpoint. Angles closer than the tolerance
therefore count as one.
"""

from dataclasses import dataclass

import healpy as hp
import numba
import numpy as np

from .engine import group_by_pixel
from .scan import SyntheticScan

N_MAX = 4
_WORD = 64


@numba.njit(cache=True)
def _mark(occupancy, pixels, offsets, psi, nbins):
    for k in range(pixels.size):
        for h in range(offsets[k], offsets[k + 1]):
            b = int((psi[h] % (2 * np.pi)) / (2 * np.pi) * nbins) % nbins
            occupancy[pixels[k], b // _WORD] |= np.uint64(1) << np.uint64(b % _WORD)


@numba.njit(parallel=True, cache=True)
def _runs(occupancy, nbins):
    npix = occupancy.shape[0]
    n_distinct = np.zeros(npix, dtype=np.int64)
    range_bins = np.zeros(npix, dtype=np.int64)
    centre_bin = np.zeros(npix)
    for p in numba.prange(npix):
        occ = np.zeros(nbins, dtype=np.bool_)
        count = 0
        for b in range(nbins):
            occ[b] = (occupancy[p, b // _WORD] >> np.uint64(b % _WORD)) & np.uint64(1)
            count += occ[b]
        if count == 0:
            continue
        runs = 0
        for b in range(nbins):
            if occ[b] and not occ[(b - 1) % nbins]:
                runs += 1
        n_distinct[p] = max(runs, 1)
        # Largest circular gap of empty bins; the occupied arc is its complement.
        best_len, best_end = 0, 0
        length = 0
        for b in range(2 * nbins):
            if not occ[b % nbins]:
                length += 1
                if length > best_len:
                    best_len, best_end = length, b
            else:
                length = 0
        best_len = min(best_len, nbins)
        first = (best_end + 1) % nbins  # first occupied bin after the largest gap
        span = nbins - best_len - 1
        range_bins[p] = span
        centre_bin[p] = first + 0.5 * span + 0.5
    return n_distinct, range_bins, centre_bin


@dataclass(frozen=True)
class ScanStats:
    """Per-pixel statistics of a scan (RING maps): samples, h_n (n = 0..4), distinct angles,
    range R [rad] and centre [rad] of the crossing angles."""

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
        """The paper's survey means over observed pixels (inside ``mask`` if given)."""
        sel = self.observed if mask is None else self.observed & (np.asarray(mask) > 0)
        out = {"pixels": int(sel.sum()), "mean_hits": float(self.hits[sel].mean()),
               "mean_n_phi": float(self.n_distinct[sel].mean()),
               "mean_range_rad": float(self.range_rad[sel].mean())}
        for n in range(1, N_MAX + 1):
            out[f"mean_abs_h{n}_sq"] = float(np.mean(np.abs(self.h[n, sel]) ** 2))
        return out

    def synthetic_twin(self, per_pixel=True, seed=0, in_pixel="random"):
        """The synthetic scan with this scan's N_phi and R: per pixel (maps) or survey means."""
        obs = self.observed
        if per_pixel:
            return SyntheticScan(n_phi=np.where(obs, np.maximum(self.n_distinct, 1), 1),
                                 range_rad=np.where(obs, self.range_rad, 0.0),
                                 centre_rad=np.where(obs, self.centre_rad, 0.0), seed=seed,
                                 in_pixel=in_pixel)
        means = self.survey_means()
        return SyntheticScan(n_phi=max(1, int(round(means["mean_n_phi"]))),
                             range_rad=means["mean_range_rad"], seed=seed, in_pixel=in_pixel)


def characterise(sample_chunks, nside, tolerance_deg=1.0):
    """ScanStats of streams of (theta, phi, psi) samples [rad] at ``nside``."""
    if not 0 < tolerance_deg <= 180:
        raise ValueError(f"tolerance_deg must be in (0, 180], got {tolerance_deg}")
    npix = 12 * nside**2
    nbins = int(round(360.0 / tolerance_deg))
    occupancy = np.zeros((npix, (nbins + _WORD - 1) // _WORD), dtype=np.uint64)
    sums = np.zeros((N_MAX + 1, npix), dtype=np.complex128)
    hits = np.zeros(npix, dtype=np.int64)
    for theta, phi, psi in sample_chunks:
        pix = hp.ang2pix(nside, theta, phi)
        hits += np.bincount(pix, minlength=npix)
        for n in range(N_MAX + 1):
            sums[n] += np.bincount(pix, np.cos(n * psi), npix) + 1j * np.bincount(
                pix, np.sin(n * psi), npix)
        upix, offsets, _, _, psi_sorted = group_by_pixel(nside, theta, phi, psi)
        _mark(occupancy, upix, offsets, psi_sorted, nbins)
    h = np.where(hits > 0, sums / np.maximum(hits, 1), 0)
    n_distinct, range_bins, centre_bin = _runs(occupancy, nbins)
    width = 2 * np.pi / nbins
    return ScanStats(hits=hits, h=h, n_distinct=n_distinct, range_rad=range_bins * width,
                     centre_rad=np.mod(centre_bin * width, 2 * np.pi), tolerance_deg=tolerance_deg)
