"""Per-pair statistics of a focal plane's scan: every pair's samples binned together as the
map-maker combines them, the pairs' own hits and h_n, and blocks of pairs streamed here or on
Dask.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba
import numpy as np

from .._util import interrupts, tasks
from ..constants import N_MAX
from ..instrument.focalplane import off_centre
from ..instrument.hwp import chunk_angles
from ..pointing import ces_angle_deg, ces_chunks
from .axis import Accumulator, ScanStats, bin_pairs, ces_hits_pairs, pixel_ranges
from .hwp import (
    BEAM_BEHIND_TERMS,
    IP_BEHIND_TERMS,
    POINTING_BEHIND_TERMS,
    T_BEHIND_TERMS,
    moments_behind,
)

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
    pair_hits : numpy.ndarray, int64, shape (pairs, npix), or None
        Each pair's hits N_i, where asked.
    pair_h : numpy.ndarray, complex128, shape (pairs, N_MAX + 1, npix), or None
        Each pair's h_{n,i}, where asked.
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
    pair_hits: np.ndarray | None = None
    pair_h: np.ndarray | None = None
    hwp: HWP | None = None
    pair_behind_h: np.ndarray | None = None
    behind_terms: tuple = ()

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


def pair_blocks(n_pairs: int, nside: int, *, per_pair: bool = False) -> list[range]:
    """The blocks of pairs :func:`characterise_focalplane` streams the schedule for: all pairs at
    once when their maps are kept, else as many as :data:`PAIR_BLOCK_BYTES` holds."""
    per = 12 * nside**2 * (16 * (N_MAX + 1) + 8)
    size = n_pairs if per_pair else max(1, min(n_pairs, PAIR_BLOCK_BYTES // per))
    return [range(a, min(a + size, n_pairs)) for a in range(0, n_pairs, size)]


def _block_stats(schedule, pairs, nside, tolerance_deg, chunk_samples, per_pair, update=None):
    """One block of pairs, ``pairs`` = (their ``vectors`` (m, 6) at angle 0, their angles (m,)
    [rad], the HWP or None, the rotation centre [deg]), over the whole
    schedule: its combined sums (an :class:`Accumulator`), its share of ``sum_sq`` and its
    pairs' weights, and where asked its pairs' hits and h_n; behind ``hwp``, of the pairs'
    reflected angles. An independent task (:mod:`boresight._util.tasks`)."""
    exclude = schedule.turnarounds == "exclude"
    centred, gammas, hwp, centre = pairs
    npix, m = 12 * nside**2, centred.shape[0]
    acc = Accumulator(nside, tolerance_deg)
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
        vectors = off_centre(centred, centre, ces_angle_deg(schedule, repeat, index))
        pix, c, s, b = ces_hits_pairs(*args, nside, acc.nbins, exclude, vectors, chi, gammas)
        interrupts.check()
        bounds = pixel_ranges(pix.ravel(), npix, nparts)
        bin_pairs(pix, c, s, b, acc.sums, acc.hits, acc.occupancy, sums, hits, bounds)
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
    (:func:`boresight.instrument.hwp.reflected`): the angle at which a bare pair sees the sky as it does, so
    that :mod:`boresight.predict.focalplane` predicts what it carries through the HWP
    (:data:`boresight.instrument.hwp.THROUGH_HWP`).

    Pairs are streamed in blocks (:func:`pair_blocks`), so memory holds one block's maps, not one
    per pair. The blocks are independent tasks, run in this process or on Dask
    (:mod:`boresight._util.tasks`); their sums add in block order, so the result is the same wherever
    they run.

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
    combined = Accumulator(nside, tolerance_deg)
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
                    focalplane.rotation_centre_deg,
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
        moments_behind(schedule, focalplane, hwp, nside, terms=terms, chunk_samples=chunk_samples)
        if terms
        else None
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
