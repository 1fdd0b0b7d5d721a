"""Per-pair statistics of a focal plane's scan: every pair's samples binned together as the
map-maker combines them, the pairs' own hits and h_n, and blocks of pairs streamed here or on
Dask.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING

import numba
import numpy as np

from .._util import interrupts, tasks
from .._util.jit import njit
from ..constants import N_MAX
from ..instrument.focalplane import off_centre
from ..instrument.hwp import chunk_angles
from ..pointing import ces_angle_deg, ces_chunks
from .axis import (
    Accumulator,
    ScanStats,
    bin_pairs,
    ces_hits,
    ces_hits_pairs,
    pixel_ranges,
    stats_of_rows,
)
from .hwp import (
    BEAM_BEHIND_TERMS,
    IP_BEHIND_TERMS,
    POINTING_BEHIND_TERMS,
    T_BEHIND_TERMS,
    moments_behind,
)
from .observed import FOOTPRINT_NSIDE, Slots, Union, grow_rows, observed_estimate

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane
    from ..instrument.hwp import HWP
    from ..schedule import Schedule


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
    focalplane : boresight.instrument.focalplane.FocalPlane
    pair_weights : numpy.ndarray, float64, shape (pairs, N_MAX + 1)
        Per pair, sum_p N_i ``|h_{n,i}|^2`` over pixels (n = 0: its hits).
    observed : numpy.ndarray, int64, shape (n_observed,), or None
        With the per-pair maps: the observed pixels (those of ``combined.hits > 0``, in RING
        order) on which ``observed_pair_hits`` and ``observed_pair_h`` are held.
    observed_pair_hits : numpy.ndarray, int64, shape (pairs, n_observed), or None
        Each pair's hits N_i on the observed pixels, where asked (:attr:`pair_hits` on the sky).
    observed_pair_h : numpy.ndarray, complex128, shape (pairs, N_MAX + 1, n_observed), or None
        Each pair's h_{n,i} on the observed pixels, where asked (:attr:`pair_h` on the sky).
    hwp : boresight.instrument.hwp.HWP, optional
        The HWP in front of the pairs: their moments are of their reflected angles.
    pair_behind_h : numpy.ndarray, complex128, shape (pairs, len(behind_terms), npix), or None
        Behind ``hwp``, with the per-pair maps: each pair's moments of its T leaks' terms
        (:data:`T_BEHIND_TERMS`), and with ``pointing`` or ``beams`` of a pointing offset's terms
        (:func:`pointing_behind`) and the beams' (:func:`beams_behind`), each once
        (:meth:`behind`).
    behind_terms : tuple of (int, int, str or None)
        The (n, m, offset) of each of ``pair_behind_h``'s moments (:func:`moments_behind`).
    """

    combined: ScanStats
    sum_sq: np.ndarray
    focalplane: FocalPlane
    pair_weights: np.ndarray
    observed: np.ndarray | None = None
    observed_pair_hits: np.ndarray | None = None
    observed_pair_h: np.ndarray | None = None
    hwp: HWP | None = None
    pair_behind_h: np.ndarray | None = None
    behind_terms: tuple = ()

    @cached_property
    def pair_hits(self) -> np.ndarray | None:
        """Each pair's hits N_i on the sky, (pairs, npix), or None (made on first use)."""
        return self._on_sky(self.observed_pair_hits)

    @cached_property
    def pair_h(self) -> np.ndarray | None:
        """Each pair's h_{n,i} on the sky, (pairs, N_MAX + 1, npix), or None (made on first use)."""
        return self._on_sky(self.observed_pair_h)

    def _on_sky(self, values):
        if values is None:
            return None
        out = np.zeros((*values.shape[:-1], self.combined.hits.size), dtype=values.dtype)
        out[..., self.observed] = values
        return out

    def behind(self, n: int, m: int, offset: str | None = None) -> np.ndarray:
        """Each pair's moment (n, m, offset) behind the plate, (pairs, npix) (:func:`moments_behind`)."""
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


#: bytes a pair's sums take per observed pixel: N_MAX + 1 complex sums and its hits
PAIR_PIXEL_BYTES = 16 * (N_MAX + 1) + 8
#: the sample rate [Hz] at which :func:`observed_pixels` follows the boresight: a sample every
#: half degree at 1 deg/s, within a pixel of :data:`~boresight.moments.observed.FOOTPRINT_NSIDE`
FOOTPRINT_RATE_HZ = 2.0


def pair_blocks(
    n_pairs: int, nside: int, *, per_pair: bool = False, observed: int | None = None
) -> list[range]:
    """The blocks of pairs :func:`characterise_focalplane` streams the schedule for: all pairs at
    once when their maps are kept, else as many as :data:`PAIR_BLOCK_BYTES` holds on ``observed``
    pixels (default the whole sky; :func:`observed_pixels` estimates them)."""
    pixels = 12 * nside**2 if observed is None else max(1, observed)
    size = (
        n_pairs
        if per_pair
        else max(1, min(n_pairs, PAIR_BLOCK_BYTES // (pixels * PAIR_PIXEL_BYTES)))
    )
    return [range(a, min(a + size, n_pairs)) for a in range(0, n_pairs, size)]


def observed_pixels(schedule: Schedule, focalplane: FocalPlane, nside: int) -> int:
    """An estimate, made before the scan is streamed, of how many pixels at ``nside`` the pairs
    of ``focalplane`` observe: the boresight's track at :data:`FOOTPRINT_RATE_HZ` binned at
    :data:`~boresight.moments.observed.FOOTPRINT_NSIDE` (at most ``nside``), widened by the
    furthest a pair can sit from the boresight at any angle (its distance from the rotation
    centre and the centre's; :func:`~boresight.moments.observed.observed_estimate`). Boresight repeats follow
    the same tracks and are walked once."""
    coarse = min(nside, FOOTPRINT_NSIDE)
    thin = replace(
        schedule,
        sample_rate_hz=min(schedule.sample_rate_hz, FOOTPRINT_RATE_HZ),
        repeat_boresight_deg=schedule.repeat_boresight_deg[:1],
    )
    seen = np.zeros(12 * coarse**2, dtype=bool)
    for _, _, args in ces_chunks(thin):
        pix = ces_hits(*args, coarse, 1, thin.turnarounds == "exclude")[0]
        seen[pix[pix >= 0]] = True
    xi0, eta0 = focalplane.rotation_centre_deg  # a pair circles the centre as the boresight turns
    apart = np.hypot(focalplane.xi_deg - xi0, focalplane.eta_deg - eta0)
    reach = float(np.max(apart, initial=0.0)) + float(np.hypot(xi0, eta0))
    return observed_estimate(np.flatnonzero(seen), coarse, nside, reach)


#: samples of the schedule one task streams at most, its CESs whole: a season splits into groups
#: of CESs that run as tasks of their own (fixed by the schedule, so the sums' rounding is too)
GROUP_SAMPLES = 1 << 22


def time_groups(schedule: Schedule, samples: int | None = None) -> list[tuple[range, int]]:
    """The schedule's CESs in observing order (:func:`~boresight.pointing.ces_chunks`' places)
    cut into consecutive groups of at least ``samples`` samples (default
    :data:`GROUP_SAMPLES`; the last may hold fewer): each group's places and its samples."""
    samples = GROUP_SAMPLES if samples is None else samples
    per = [int(c.duration_s * schedule.sample_rate_hz) for c in schedule.ces]
    per *= len(schedule.repeat_boresight_deg)
    groups, first, count = [], 0, 0
    for place, n in enumerate(per):
        count += n
        if count >= samples or place == len(per) - 1:
            groups.append((range(first, place + 1), count))
            first, count = place + 1, 0
    return groups


def _task_stats(schedule, pairs, nside, tolerance_deg, chunk_samples, ces, update=None):
    """One block of pairs over one group of CESs (``ces``, places in observing order), ``pairs``
    = (their ``vectors`` (m, 6) at angle 0, their angles (m,) [rad], the HWP or None, the
    rotation centre [deg], the observed pixels expected). Every sum lives on the pixels the
    group observes (:class:`~boresight.moments.observed.Slots`), none on the sky; returned in
    RING order of those pixels: ``observed``, the pairs' combined sums, hits and angle bitmaps
    (``acc``, as :class:`Accumulator` holds them) and each pair's sums and hits. Behind ``hwp``,
    of the pairs' reflected angles. An independent task (:mod:`boresight._util.tasks`)."""
    exclude = schedule.turnarounds == "exclude"
    centred, gammas, hwp, centre, expected = pairs
    npix, m = 12 * nside**2, centred.shape[0]
    nbins = Accumulator.bins(tolerance_deg)
    slots = Slots(npix)
    capacity = min(npix, expected)
    acc_sums = np.zeros((capacity, N_MAX + 1), dtype=np.complex128)
    acc_hits = np.zeros(capacity, dtype=np.int64)
    occupancy = np.zeros((capacity, Accumulator.words(nbins)), dtype=np.uint64)
    sums = np.zeros((m, capacity, N_MAX + 1), dtype=np.complex128)
    hits = np.zeros((m, capacity), dtype=np.int64)
    nparts = numba.get_num_threads()
    none = np.zeros(0)
    for repeat, index, args in ces_chunks(schedule, max(1, chunk_samples // m), ces=ces):
        chi = (
            none
            if hwp is None
            else chunk_angles(hwp, schedule, repeat, index, first=args[0], n=args[1])
        )
        vectors = off_centre(centred, centre, ces_angle_deg(schedule, repeat, index))
        pix, c, s, b = ces_hits_pairs(*args, nside, nbins, exclude, vectors, chi, gammas)
        interrupts.check()
        rows = slots.index(pix)
        acc_sums = grow_rows(acc_sums, slots.n, axis=0)
        acc_hits = grow_rows(acc_hits, slots.n, axis=0)
        occupancy = grow_rows(occupancy, slots.n, axis=0)
        sums, hits = grow_rows(sums, slots.n, axis=1), grow_rows(hits, slots.n, axis=1)
        bounds = pixel_ranges(pix.ravel(), npix, nparts)
        bin_pairs(pix, rows, c, s, b, acc_sums, acc_hits, occupancy, sums, hits, bounds)
        if update is not None:
            update(args[1] * m)
    order = np.argsort(slots.pixels)  # the observed pixels in RING order
    _in_order(sums, hits, order)
    return {  # the pairs' sums and hits whole (their first n rows): no copy of the largest arrays
        "observed": slots.pixels[order],
        "acc": (acc_sums[order], acc_hits[order], occupancy[order]),
        "sums": sums,
        "hits": hits,
    }


@njit(parallel=True)
def _in_order(sums, hits, order):
    """Each pair's first ``order.size`` rows of sums (m, rows, N_MAX + 1) and hits (m, rows) put
    in ``order``, in place."""
    for d in numba.prange(sums.shape[0]):
        rows, counts = sums[d][order], hits[d][order]
        sums[d, : order.size] = rows
        hits[d, : order.size] = counts


@njit(parallel=True)
def _pair_sums(sums, hits, n, per_pair):
    """From each pair's sums and hits on the ``n`` observed pixels (the first n rows of
    (m, rows, N_MAX + 1) and (m, rows)), in RING order, those pixels' sum_i N_i^2
    ``|h_{n,i}|^2`` (N_MAX + 1, n) and each pair's sum over them of N_i ``|h_{n,i}|^2``
    (m, N_MAX + 1); with ``per_pair`` the sums become h_n,i, in place."""
    m, terms = sums.shape[0], sums.shape[2]
    sum_sq = np.zeros((terms, n))
    weights = np.zeros((m, terms))
    for j in numba.prange(n):  # a pixel's pairs in pair order
        for d in range(m):
            for t in range(terms):
                z = sums[d, j, t]
                sum_sq[t, j] += z.real * z.real + z.imag * z.imag
    for d in numba.prange(m):  # a pair's pixels in RING order
        for j in range(n):
            scale = 1.0 / max(hits[d, j], 1)
            for t in range(terms):
                z = sums[d, j, t]
                weights[d, t] += (z.real * z.real + z.imag * z.imag) * scale
                if per_pair:
                    sums[d, j, t] = z * scale
    return sum_sq, weights


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
    worker_threads: int | None = None,
    progress: bool = False,
) -> FocalPlaneStats:
    """Statistics of a schedule seen by every pair of a focal plane, each from its own place
    (:func:`boresight.pointing.detector_pointing`, fused into the binning).

    Behind a HWP each pair's moments are those of its reflected angle
    (:func:`boresight.instrument.hwp.reflected`): the angle at which a bare pair sees the sky as it does, so
    that :mod:`boresight.predict.focalplane` predicts what it carries through the HWP
    (:data:`boresight.instrument.hwp.THROUGH_HWP`).

    Pairs are streamed in blocks (:func:`pair_blocks`), so memory holds one block's maps, not one
    per pair, and the schedule in groups of CESs (:func:`time_groups`), each block over each
    group an independent task, run in this process or on Dask (:mod:`boresight._util.tasks`);
    every task's sums live on the pixels it observes, and they add in (block, group) order as
    they arrive, so the result is the same wherever they run and the process holds one block's
    sums and the tasks in flight.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    focalplane : boresight.instrument.focalplane.FocalPlane
    nside : int
    tolerance_deg : float
    chunk_samples : int
        Detector-samples per chunk.
    per_pair : bool
        Keep each pair's hits and h_n.
    hwp : boresight.instrument.hwp.HWP, optional
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
    worker_threads : int, optional
        Numba threads in each local worker (default: its share of the cores).
    progress : bool

    Returns
    -------
    FocalPlaneStats
    """
    from tqdm import tqdm

    vectors = focalplane.vectors()
    npix = 12 * nside**2
    expected = observed_pixels(schedule, focalplane, nside)
    blocks = pair_blocks(focalplane.n_pairs, nside, per_pair=per_pair, observed=expected)
    groups = time_groups(schedule)
    total = schedule.n_samples * focalplane.n_pairs
    # on the pixels observed so far: the pairs' combined sums, hits and bitmaps; sum_i N_i^2
    # |h_{n,i}|^2 of the blocks finished; the current block's pairs' sums and hits
    combined = Union(axes=(0, 0, 0), joins=(False, False, True))
    sum_sq = Union(axes=(1,))
    weights = np.zeros((focalplane.n_pairs, N_MAX + 1))
    kept = {}  # with per_pair there is one block, whose maps are kept as they are
    order = [(b, g) for b in range(len(blocks)) for g in range(len(groups))]
    pending, merged, block = {}, [0], [Union(axes=(1, 1))]
    with tqdm(total=total, unit="sample", unit_scale=True, disable=not progress) as bar:
        serial = scheduler == "serial"

        def finish(i, result):
            pending[i] = result
            if not serial:
                bar.update(groups[order[i][1]][1] * len(blocks[order[i][0]]))
            while merged[0] in pending:  # in (block, group) order: the sums' rounding is fixed
                part = pending.pop(merged[0])
                b, g = order[merged[0]]
                combined.add(part["observed"], *part["acc"])
                block[0].add(part["observed"], part["sums"], part["hits"])
                del part
                if g == len(groups) - 1:  # the block's last group: its pairs' sums are whole
                    done, block[0] = block[0], Union(axes=(1, 1))
                    (sums, hits), n = done.arrays, done.pixels.size
                    squares, weights[blocks[b].start : blocks[b].stop] = _pair_sums(
                        sums, hits, n, per_pair
                    )
                    sum_sq.add(done.pixels, squares)
                    if per_pair:
                        kept.update(
                            observed=done.pixels,
                            observed_pair_hits=hits[:, :n],
                            observed_pair_h=np.swapaxes(sums[:, :n], 1, 2),
                        )
                    del done, sums, hits
                merged[0] += 1

        gammas = np.radians(focalplane.gamma_deg)
        arguments = [
            (
                schedule,
                (
                    np.ascontiguousarray(vectors[blocks[b].start : blocks[b].stop]),
                    np.ascontiguousarray(gammas[blocks[b].start : blocks[b].stop]),
                    hwp,
                    focalplane.rotation_centre_deg,
                    expected,
                ),
                nside,
                tolerance_deg,
                chunk_samples,
                groups[g][0],
                bar.update if serial else None,
            )
            for b, g in order
        ]
        tasks.run(
            _task_stats,
            arguments,
            finish,
            scheduler=scheduler,
            workers=workers,
            window=2 * workers,
            threads=worker_threads,
        )
    terms = ()  # the moments behind the plate: T's, the pointing's and the beams', each once
    if per_pair and hwp is not None and hwp.present:
        wanted = (POINTING_BEHIND_TERMS if pointing else ()) + (BEAM_BEHIND_TERMS if beams else ())
        wanted += IP_BEHIND_TERMS if ip else ()
        terms = tuple(dict.fromkeys(T_BEHIND_TERMS + wanted))
    behind = (
        moments_behind(schedule, focalplane, hwp, nside, terms=terms, chunk_samples=chunk_samples)
        if terms
        else None
    )
    sky_sq = np.zeros((N_MAX + 1, npix))
    sky_sq[:, sum_sq.pixels] = sum_sq.arrays[0]
    rows = np.flatnonzero(combined.arrays[1] > 0)
    return FocalPlaneStats(
        combined=stats_of_rows(
            npix, combined.pixels[rows], rows, combined.arrays, tolerance_deg=tolerance_deg
        ),
        sum_sq=sky_sq,
        focalplane=focalplane,
        pair_weights=weights,
        **kept,
        hwp=hwp,
        pair_behind_h=behind,
        behind_terms=terms,
    )
