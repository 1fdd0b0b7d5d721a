"""The pixels a scan observes: a slot table that gives each pixel its own row on its first hit,
so that accumulators hold the observed pixels and not the sky, and the estimate of how many
there will be, made before the scan is streamed.

A focal plane's per-pair sums are (pairs, pixels, N_MAX + 1): on the full sky they are 88 bytes a
pixel a pair, 0.27 GiB a pair at Nside 512, for a field that covers a few per cent of it. On the
slots they are 88 bytes a pair an observed pixel, and a slot table of 4 bytes a pixel.
"""

from __future__ import annotations

import healpy as hp
import numpy as np

from .._util.jit import njit

#: the resolution of the footprint estimate (at most the map's own)
FOOTPRINT_NSIDE = 64


@njit
def _assign(pixels, slot, order, n_used):
    """The slot of each of ``pixels`` (1-d; -1 for a sample left out stays -1), a pixel seen for
    the first time taking the next free slot in sample order (``order[slot] = pixel``, ``order``
    with room for every new pixel); returns (slots, slots in use)."""
    out = np.empty(pixels.size, dtype=np.int64)
    for k in range(pixels.size):
        p = pixels[k]
        if p < 0:
            out[k] = -1
            continue
        s = slot[p]
        if s < 0:
            s = n_used
            slot[p] = s
            order[s] = p
            n_used += 1
        out[k] = s
    return out, n_used


class Slots:
    """Observed pixels numbered in the order they are first hit.

    Parameters
    ----------
    npix : int
        Pixels of the map (the slot table's length).
    """

    def __init__(self, npix: int):
        self.slot = np.full(npix, -1, dtype=np.int32)
        self.order = np.empty(0, dtype=np.int64)
        self.n = 0

    def index(self, pixels: np.ndarray) -> np.ndarray:
        """The slots of ``pixels`` (any shape; -1 stays -1), numbering the new ones."""
        flat = np.ascontiguousarray(pixels).ravel()
        if self.order.size < self.n + flat.size:  # room for every sample's pixel to be new
            grown = np.empty(max(2 * self.order.size, self.n + flat.size), dtype=np.int64)
            grown[: self.n] = self.order[: self.n]
            self.order = grown
        out, self.n = _assign(flat, self.slot, self.order, self.n)
        return out.reshape(pixels.shape)

    @property
    def pixels(self) -> np.ndarray:
        """The observed pixels in slot order, (n,)."""
        return self.order[: self.n]


def grow_rows(array: np.ndarray, rows: int, *, axis: int) -> np.ndarray:
    """``array`` with at least ``rows`` along ``axis`` (zeros added; half again as many as asked,
    so that a scan's slots filling one by one copy the array a few times, not once a chunk)."""
    have = array.shape[axis]
    if rows <= have:
        return array
    shape = list(array.shape)
    shape[axis] = max(rows, have + have // 2)
    grown = np.zeros(shape, dtype=array.dtype)
    grown[(slice(None),) * axis + (slice(0, have),)] = array
    return grown


def footprint_pixels(boresight_pixels: np.ndarray, nside: int, radius_deg: float) -> np.ndarray:
    """The pixels within ``radius_deg`` of any of ``boresight_pixels`` (RING, at ``nside``): where
    a focal plane of that radius can look when its boresight crosses those pixels. Only the
    edge of the set is widened (a pixel with a neighbour outside it), by the radius and a pixel's
    half-diagonal, every pixel the disc touches."""
    npix = 12 * nside**2
    inside = np.zeros(npix, dtype=bool)
    inside[boresight_pixels] = True
    neighbours = hp.get_all_neighbours(nside, boresight_pixels)
    edge = boresight_pixels[~np.all(inside[np.where(neighbours >= 0, neighbours, 0)], axis=0)]
    reach = np.radians(radius_deg) + hp.max_pixrad(nside)
    if radius_deg > 0 or edge.size:
        vectors = np.array(hp.pix2vec(nside, edge)).T
        for v in vectors:
            inside[hp.query_disc(nside, v, reach, inclusive=True)] = True
    return np.flatnonzero(inside)


def observed_estimate(
    boresight_pixels: np.ndarray, footprint_nside: int, nside: int, radius_deg: float
) -> int:
    """How many pixels at ``nside`` a focal plane of ``radius_deg`` observes where its boresight
    crosses ``boresight_pixels`` (at ``footprint_nside``): the footprint's area in pixels of the
    map, at least one pixel per pixel of the footprint."""
    seen = footprint_pixels(boresight_pixels, footprint_nside, radius_deg)
    ratio = (nside / footprint_nside) ** 2
    return int(min(12 * nside**2, np.ceil(seen.size * max(ratio, 1.0))))


class Union:
    """Arrays over the union of the pixels added so far, in RING order: each part's rows (its
    pixels', the first along each array's pixel axis) added to the union's, or or-ed into them
    for the arrays named in ``joins`` (angle bitmaps). A part whose pixels the union holds
    already is added in place; one with new pixels grows the union once. The union's rows take
    the parts' values in the order they are added, so their rounding is fixed by that order.

    Parameters
    ----------
    axes : tuple of int
        The pixel axis of each array.
    joins : tuple of bool, optional
        Which arrays join by bitwise or (default: none; they add).

    Attributes
    ----------
    pixels : numpy.ndarray or None
        The union, (n,).
    arrays : list of numpy.ndarray
        Each array's sums, in the layout added; the first ``n`` along its pixel axis are the
        union's (the first part is kept as it came, rows to spare included).
    """

    def __init__(self, axes: tuple[int, ...], joins: tuple[bool, ...] | None = None):
        self.axes = axes
        self.joins = joins if joins is not None else (False,) * len(axes)
        self.pixels = None
        self.arrays = []

    def _at(self, k, index):
        return (slice(None),) * self.axes[k] + (index,)

    def add(self, pixels: np.ndarray, *arrays: np.ndarray) -> None:
        """Add the rows of ``pixels`` (distinct, RING order; an array may have more rows than
        pixels, the first ones theirs)."""
        if self.pixels is None:  # the first part as it is, no copy
            self.pixels, self.arrays = pixels, list(arrays)
            return
        union = np.union1d(self.pixels, pixels)
        if union.size > self.pixels.size:
            old = np.searchsorted(union, self.pixels)
            grown = []
            for k, a in enumerate(self.arrays):
                shape = list(a.shape)
                shape[self.axes[k]] = union.size
                b = np.zeros(shape, dtype=a.dtype)
                b[self._at(k, old)] = a[self._at(k, slice(0, old.size))]
                grown.append(b)
            self.pixels, self.arrays = union, grown
        new = np.searchsorted(self.pixels, pixels)
        for k, part in enumerate(arrays):
            rows = part[self._at(k, slice(0, pixels.size))]
            if self.joins[k]:
                self.arrays[k][self._at(k, new)] |= rows
            else:
                self.arrays[k][self._at(k, new)] += rows
