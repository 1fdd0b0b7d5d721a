"""A design's units: the spin sums of each unit of a schedule's CESs, which a boresight angle
per unit turns into h_n.

A schedule's CESs are grouped into units (each CES, each UTC day, or each TOAST pass) and every
unit gets one boresight angle. On the axis a unit's hits contribute, per observed pixel p,

    S_n,u(p) = sum over its samples of exp(i n psi0),

with psi0 the crossing angle at boresight angle 0; at angle a_u they contribute
S_n,u exp(i n a_u). So the h_n of any assignment is

    h_n(p) = sum_u S_n,u(p) exp(i n a_u) / hits(p),

and the hits do not depend on the angles (:class:`UnitMoments`). Off the axis a pair's hits
move when the boresight turns, so a unit's sums are built once per allowed angle, per pair
(:class:`UnitSums`). The design's objectives (:mod:`boresight.design`) read both.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from datetime import datetime, timezone
from typing import TYPE_CHECKING

import numpy as np

from .._util import interrupts
from .._util.jit import njit
from ..constants import DEG, N_MAX
from ..instrument.hwp import HWP, chunk_angles
from ..pointing import chunk_arguments, pointing
from ..schedule import Schedule
from .axis import ces_hits
from .focalplane import characterise_focalplane
from .offsets import sample_offsets

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..instrument.focalplane import FocalPlane

#: how a design groups a schedule's CESs into units: each CES, each UTC day, each TOAST pass
GROUPS = ("ces", "day", "pass")


def units_of(rows: tuple, group: str) -> list[list[int]]:
    """The CES rows of each unit, in time order of the units' first CES.

    Parameters
    ----------
    rows : tuple of boresight.schedule.CES
    group : {"ces", "day", "pass"}

    Returns
    -------
    list of list of int
    """
    if group not in GROUPS:
        raise ValueError(f"group must be one of {GROUPS}, got {group!r}")
    keys = {}
    for i, c in enumerate(rows):
        if group == "ces":
            key = i
        elif group == "day":
            key = datetime.fromtimestamp(c.start_unix, timezone.utc).date()
        else:
            key = (c.name, c.scan_index)
        keys.setdefault(key, []).append(i)
    return sorted(keys.values(), key=lambda idx: min(rows[i].start_unix for i in idx))


@dataclass
class UnitMoments:
    """Every unit's spin sums over the observed pixels, at boresight angle 0.

    Parameters
    ----------
    nside : int
    pixels : numpy.ndarray, int64, shape (n_obs,)
        RING indices of the observed pixels.
    hits : numpy.ndarray, float64, shape (n_obs,)
        Samples per observed pixel (all units).
    offsets : numpy.ndarray, int64, shape (n_units + 1,)
        Unit u's entries are offsets[u]:offsets[u + 1].
    index : numpy.ndarray, int64, shape (n_entries,)
        Observed-pixel index of each entry.
    sums : numpy.ndarray, complex128, shape (N_MAX, n_entries)
        S_n of each entry, n = 1..N_MAX.
    units : list of list of int
        The CES rows of each unit.
    rows : tuple of boresight.schedule.CES
    centroids : numpy.ndarray, complex128, shape (2, N_MAX + 1, n_entries), optional
        sum exp(i n psi) delta and sum exp(i n psi) conj(delta) of each entry, n = 0..N_MAX,
        delta the samples' offsets from their pixel centres
        (:func:`boresight.moments.sample_offsets`): the unit's share of
        :func:`boresight.moments.centroid_moments` times the hits.
    """

    nside: int
    pixels: np.ndarray
    hits: np.ndarray
    offsets: np.ndarray
    index: np.ndarray
    sums: np.ndarray
    units: list
    rows: tuple
    centroids: np.ndarray | None = None

    @property
    def n_units(self):
        return len(self.units)

    def h(self, angles_deg: np.ndarray) -> np.ndarray:
        """h_n on the observed pixels for one angle per unit.

        Parameters
        ----------
        angles_deg : numpy.ndarray, shape (n_units,)

        Returns
        -------
        numpy.ndarray, complex128, shape (N_MAX + 1, n_obs)
            h_0 = 1 and h_1..h_N_MAX.
        """
        a = np.asarray(angles_deg, dtype=float) * DEG
        phases = np.exp(1j * np.arange(1, N_MAX + 1)[None, :] * a[:, None])  # (n_units, N_MAX)
        out = np.zeros((N_MAX + 1, self.pixels.size), dtype=np.complex128)
        _rotate_and_sum(self.offsets, self.index, self.sums, phases, out)
        out[1:] /= self.hits
        out[0] = 1.0
        return out

    @property
    def mask(self) -> np.ndarray:
        """The observed pixels as a full-sky RING mask of ones (npix,)."""
        return self.full_sky(np.ones(self.pixels.size))

    def full_sky(self, h_obs: np.ndarray) -> np.ndarray:
        """Observed-pixel maps as full-sky RING maps, 0 elsewhere."""
        out = np.zeros(h_obs.shape[:-1] + (12 * self.nside**2,), dtype=h_obs.dtype)
        out[..., self.pixels] = h_obs
        return out

    def stepped_plate(self, hwp: HWP, steps_deg: np.ndarray) -> HWP:
        """A stepped HWP at one angle per unit (a design's ``steps_deg``), CES by CES of
        :meth:`schedule`'s CESs."""
        per_ces = np.zeros(len(self.rows))
        for u, idx in enumerate(self.units):
            per_ces[idx] = steps_deg[u]
        return replace(hwp, mode="stepped", angles_deg=tuple(per_ces), step="ces")

    def schedule(self, schedule: Schedule, angles_deg: np.ndarray) -> Schedule:
        """The schedule with every CES at its unit's angle, repeats as CESs of their own."""
        rows = list(self.rows)
        for u, idx in enumerate(self.units):
            for i in idx:
                rows[i] = replace(rows[i], boresight_deg=float(angles_deg[u]))
        return replace(schedule, ces=tuple(rows), repeat_boresight_deg=(0.0,))


@njit
def _rotate_and_sum(offsets, index, sums, phases, out):
    """out[n, pixel] += S_n of each entry times exp(i n a) of its unit (n = 1..N_MAX)."""
    for u in range(offsets.size - 1):
        for e in range(offsets[u], offsets[u + 1]):
            p = index[e]
            for n in range(sums.shape[0]):
                out[n + 1, p] += sums[n, e] * phases[u, n]


def unit_moments(
    schedule: Schedule,
    nside: int,
    group: str = "ces",
    chunk_samples: int = 1 << 20,
    *,
    hwp: HWP | None = None,
    centroids: bool = False,
    units: list | None = None,
) -> UnitMoments:
    """Build every unit's spin sums once, with the fused pointing of ``scanstats``.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    nside : int
    group : {"ces", "day", "pass"}
    chunk_samples : int
    hwp : boresight.instrument.hwp.HWP, optional
        A continuous HWP: the sums are of the pairs' reflected angle psi + 2 chi
        (:func:`boresight.instrument.hwp.reflected`, gamma 0), chi at each sample's time. The focal plane
        carries the plate, so a boresight angle a still turns them by exp(i n a).
    centroids : bool
        Also the sums of the samples' offsets from their pixel centres
        (:attr:`UnitMoments.centroids`; on the axis a boresight angle moves no sample, so they
        turn by exp(i n a) too), for a sky read exactly at each sample.
    units : list of list of int, optional
        The CES rows of each unit (default :func:`units_of` the schedule's rows by ``group``):
        another schedule's units, its CESs shortened.

    Returns
    -------
    UnitMoments
    """
    if hwp is not None and not hwp.spinning:
        raise ValueError("unit_moments turns the angles by a continuous HWP's only")
    rows = schedule.expanded()
    units = units_of(rows, group) if units is None else units
    per_unit = []
    for idx in units:
        pix, e1, deltas = [], [], []
        for i in idx:
            one = replace(schedule, ces=(replace(rows[i], boresight_deg=0.0),)).single()
            exclude = schedule.turnarounds == "exclude"
            for args in chunk_arguments(one, chunk_samples):
                interrupts.check()
                p, c, s, _ = ces_hits(*args, nside, 1, exclude)
                kept = p >= 0
                turn = c + 1j * s
                if hwp is not None:
                    turn = turn * np.exp(
                        2j * chunk_angles(hwp, one, 0, 0, first=args[0], n=args[1])
                    )
                pix.append(p[kept])
                e1.append(turn[kept])
            if centroids:  # the same samples in the same order, turnarounds left out alike
                for theta, phi, _ in pointing(one, chunk_samples):
                    deltas.append(sample_offsets(theta, phi, nside)[1])
        pix, e1 = np.concatenate(pix), np.concatenate(e1)
        upix, inverse = np.unique(pix, return_inverse=True)
        sums = _bin_powers(inverse, upix.size, e1, np.ones_like(e1), 1)
        cent = None
        if centroids:
            delta = np.concatenate(deltas)
            cent = np.array(
                [_bin_powers(inverse, upix.size, e1, d, 0) for d in (delta, np.conj(delta))]
            )
        per_unit.append((upix, np.bincount(inverse, minlength=upix.size), sums, cent))
    pixels = np.unique(np.concatenate([u[0] for u in per_unit]))
    index = np.concatenate([np.searchsorted(pixels, u[0]) for u in per_unit])
    hits = np.bincount(index, np.concatenate([u[1] for u in per_unit]), pixels.size)
    offsets = np.concatenate([[0], np.cumsum([u[0].size for u in per_unit])])
    sums = np.concatenate([u[2] for u in per_unit], axis=1)
    cent = np.concatenate([u[3] for u in per_unit], axis=2) if centroids else None
    return UnitMoments(nside, pixels, hits, offsets, index, sums, units, rows, cent)


def _bin_powers(inverse, size, e1, value, first):
    """Each entry's sum of value e1^n over its samples, n = first..N_MAX: (N_MAX + 1 - first,
    size)."""
    power = value
    for _ in range(first):
        power = power * e1
    out = np.empty((N_MAX + 1 - first, size), dtype=np.complex128)
    for n in range(out.shape[0]):
        out[n] = np.bincount(inverse, power.real, size) + 1j * np.bincount(
            inverse, power.imag, size
        )
        power = power * e1
    return out


@dataclass
class UnitSums:
    """Every unit's per-pair spin sums at every allowed angle.

    Parameters
    ----------
    nside : int
    allowed_deg : numpy.ndarray, shape (K,)
    pixels : list of list of numpy.ndarray
        [u][k]: the RING pixels unit u's pairs see at allowed angle k.
    sums : list of list of numpy.ndarray
        [u][k]: S_n,i (pairs, N_MAX + 1, pixels) complex, n = 0 the pair's hits.
    focalplane : boresight.instrument.focalplane.FocalPlane
    """

    nside: int
    allowed_deg: np.ndarray
    pixels: list
    sums: list
    focalplane: FocalPlane

    @property
    def unit_count(self) -> int:
        return len(self.sums)

    def choices(self, angles_deg: np.ndarray) -> np.ndarray:
        """Each unit's index among the allowed angles (n_units,)."""
        return allowed_index(self.allowed_deg, angles_deg)


def allowed_index(allowed, angles_deg):
    """The index among ``allowed`` of each angle."""
    angles = np.asarray(angles_deg, dtype=float)
    index = np.argmin(np.abs(angles[:, None] - allowed[None, :]), axis=1)
    if np.any(allowed[index] != angles):
        raise ValueError("every unit's angle must be one of the allowed angles")
    return index


def unit_sums(
    moments: UnitMoments,
    schedule: Schedule,
    focal: FocalPlane,
    allowed_deg: tuple,
    *,
    progress: Callable | None = None,
) -> UnitSums:
    """Scan every unit at every allowed angle with every pair on its own samples.

    Parameters
    ----------
    moments : UnitMoments
        The units (their CES rows) and the Nside.
    schedule : boresight.schedule.Schedule
    focal : boresight.instrument.focalplane.FocalPlane
    allowed_deg : tuple of float
    progress : callable, optional
        Called with 1 after each unit and angle.

    Returns
    -------
    UnitSums
    """
    allowed = np.asarray(allowed_deg, dtype=float)
    pixels, sums = [], []
    for idx in moments.units:
        pixels.append([])
        sums.append([])
        for a in allowed:
            interrupts.check()
            rows = tuple(replace(moments.rows[i], boresight_deg=float(a)) for i in idx)
            one = replace(schedule, ces=rows, repeat_boresight_deg=(0.0,))
            stats = characterise_focalplane(one, focal, moments.nside, per_pair=True)
            seen = stats.observed
            hits = stats.observed_pair_hits.astype(float)
            s = stats.observed_pair_h * hits[:, None, :]
            s[:, 0] = hits
            pixels[-1].append(seen)
            sums[-1].append(s)
            if progress is not None:
                progress(1)
    return UnitSums(moments.nside, allowed, pixels, sums, focal)
