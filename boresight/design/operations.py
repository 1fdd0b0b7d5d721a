"""Observing time as the price of a rotation: what the telescope does between two CESs, how long
it takes, which CES loses how many minutes, and the sigma(r) that the lost time costs.

Before each CES the telescope runs SO's SAT operations in schedlib's order
(``schedlib.policies.sat``: ``setup_boresight``, ``det_setup``, ``hwp_spin_up``):

- a boresight angle that differs from the current one by more than ``angle_tolerance_deg``
  (schedlib's ``np.isclose(..., atol=1)``) stops a spinning half-wave plate (``hwp_spin_down``)
  and turns the boresight (``rotation``);
- the detectors are set up again (``det_setup``) before the first CES, and when the elevation or
  the boresight angle differs from those of the last set-up by more than the tolerances;
- a plate that is not spinning spins up (``hwp_spin_up``); one spinning the other way than the
  CES's ``hwp_dir`` stops first.

The operations start when the previous CES ends. A gap that holds them costs nothing; otherwise
they eat the next CES's start, or all of it (and then go on into the one after). A CES that starts
before the previous one ends (a schedule's boresight repeats, observed on other days) starts a new
session: its operations happen before it, without loss. schedlib's other operations (UFM relocks,
bias steps, calibration) do not depend on the angles and are not counted.

The lost fraction f of the observing time raises sigma(r): the noise power N_ell of a survey
scales as 1 / time, so sigma(r) is the Fisher sum with N_ell / (1 - f)
(:func:`boresight.noise.sigma_r`); a sigma(r) given as a number scales as (1 - f)^(-1/2), the
white-noise Knox regime. The delta_r equivalent of the lost time is sigma(r, f) - sigma(r, 0),
added to the systematic delta_r in the design's objective.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from .. import validation
from .._util.jit import njit
from ..noise import sigma_r

#: SO's SAT durations [min] (schedlib.policies.sat: HWP_SPIN_DOWN, HWP_SPIN_UP,
#: BORESIGHT_DURATION; SATPolicy.det_setup_duration)
SO_SAT = dict(hwp_spin_down_min=15.0, hwp_spin_up_min=7.0, rotation_min=1.0, det_setup_min=20.0)
PRESETS = {"so-sat": SO_SAT}
#: what each operation is called in the tables
NAMES = ("hwp spin-down", "rotation", "detector setup", "hwp spin-up")


@dataclass(frozen=True)
class Operations:
    """The ``[operations]`` table: what the telescope does between CESs, in minutes.

    Parameters
    ----------
    preset : str
        Durations to start from ("so-sat": SO's SAT, 15 + 1 + 20 + 7 = 43 minutes per rotation);
        the keys below replace them.
    hwp_spin_down_min, hwp_spin_up_min : float
        Stopping and starting the half-wave plate [min] (0 without a spinning plate).
    rotation_min : float
        Turning the boresight [min].
    det_setup_min : float
        Setting the detectors up again after a change of elevation or boresight angle [min].
    angle_tolerance_deg, elevation_tolerance_deg : float
        Changes up to these do not count (schedlib's ``atol=1``).
    """

    preset: str = "so-sat"
    hwp_spin_down_min: float | None = None
    hwp_spin_up_min: float | None = None
    rotation_min: float | None = None
    det_setup_min: float | None = None
    angle_tolerance_deg: float = 1.0
    elevation_tolerance_deg: float = 1.0

    def __post_init__(self):
        if self.preset not in PRESETS:
            raise ValueError(f"operations preset {self.preset!r}; known: {sorted(PRESETS)}")
        for key, value in PRESETS[self.preset].items():
            if getattr(self, key) is None:
                object.__setattr__(self, key, value)
            validation.number(f"operations {key}", getattr(self, key), 0.0, 1440.0)
        validation.number("operations angle_tolerance_deg", self.angle_tolerance_deg, 0.0, 180.0)
        validation.number(
            "operations elevation_tolerance_deg", self.elevation_tolerance_deg, 0.0, 90.0
        )

    @property
    def durations_s(self) -> np.ndarray:
        """Spin-down, rotation, set-up and spin-up [s]."""
        return 60.0 * np.array(
            [self.hwp_spin_down_min, self.rotation_min, self.det_setup_min, self.hwp_spin_up_min]
        )


#: the [operations] keys
OPERATIONS_KEYS = tuple(f.name for f in fields(Operations))


@dataclass(frozen=True)
class Timeline:
    """What the operations before each CES cost, for one assignment of angles.

    Parameters
    ----------
    overhead_s : numpy.ndarray, shape (n_ces,)
        The operations before each CES [s].
    lost_s : numpy.ndarray, shape (n_ces,)
        The observing time each CES loses to them [s].
    counts : numpy.ndarray, int, shape (n_ces, 4)
        How often each operation (:data:`NAMES`) runs before each CES.
    observing_s : float
        The schedule's observing time without the operations [s].
    """

    overhead_s: np.ndarray
    lost_s: np.ndarray
    counts: np.ndarray
    observing_s: float

    @property
    def lost_fraction(self) -> float:
        return float(self.lost_s.sum() / self.observing_s)


class TimePrice:
    """The delta_r equivalent of the observing time an assignment of angles loses.

    Parameters
    ----------
    rows : tuple of boresight.schedule.CES
        The CESs in observing order (a design's ``moments.rows``).
    units : list of list of int
        The CES rows of each design unit.
    operations : Operations
    noise : boresight.noise.SurveyNoise
    theory : boresight.cosmology.Spectra
    edges : numpy.ndarray
        The bands of sigma(r).
    """

    def __init__(self, rows, units, operations, noise, theory, edges):
        self.operations = operations
        self.start = np.array([c.start_unix for c in rows], dtype=float)
        self.stop = self.start + np.array([c.duration_s for c in rows], dtype=float)
        self.elevation = np.array([c.elevation_deg for c in rows], dtype=float)
        self.hwp_dir = np.array([c.hwp_dir for c in rows], dtype=np.int64)
        self.unit_of = np.empty(len(rows), dtype=np.int64)
        for u, idx in enumerate(units):
            self.unit_of[idx] = u
        self.observing_s = float(np.sum(self.stop - self.start))
        self._noise, self._theory, self._edges = noise, theory, edges
        self._sigma = {}
        self.sigma_full = self.sigma(0.0)

    def timeline(self, angles_deg: np.ndarray) -> Timeline:
        """The operations and lost time of one angle per unit."""
        angle = np.asarray(angles_deg, dtype=float)[self.unit_of]
        overhead, lost = np.zeros(angle.size), np.zeros(angle.size)
        counts = np.zeros((angle.size, 4), dtype=np.int64)
        ops = self.operations
        _timeline(
            self.start, self.stop, self.elevation, self.hwp_dir, angle, ops.durations_s,
            ops.angle_tolerance_deg, ops.elevation_tolerance_deg, overhead, lost, counts,
        )  # fmt: skip
        return Timeline(overhead, lost, counts, self.observing_s)

    def segments(self) -> list[list[int]]:
        """The units of each stretch the operations of a rotation cannot cut: runs of CESs whose
        gaps are shorter than a rotation's operations, between sessions and long gaps. One
        angle per stretch loses no observing time to rotations."""
        full = float(self.operations.durations_s.sum())
        gap = self.start[1:] - self.stop[:-1]
        cut = (gap < 0) | (gap >= full)  # a new session, or a gap that holds a rotation
        segment = np.concatenate([[0], np.cumsum(cut)])
        units, first = np.unique(self.unit_of, return_index=True)  # each unit's first row
        out = {}
        for u, row in zip(units, first):
            out.setdefault(int(segment[row]), []).append(int(u))
        return list(out.values())

    def lost_s(self, angles_deg: np.ndarray) -> float:
        """The observing time one angle per unit loses [s]."""
        return float(self.timeline(angles_deg).lost_s.sum())

    def sigma(self, lost_s: float) -> float:
        """sigma(r) with ``lost_s`` of the observing time lost (memoised: the lost times are
        sums of a few durations)."""
        key = round(float(lost_s), 6)
        if key not in self._sigma:
            kept = max(1.0 - key / self.observing_s, 1e-9)
            self._sigma[key] = sigma_r(self._noise, self._theory, self._edges, time_fraction=kept)
        return self._sigma[key]

    def value(self, angles_deg: np.ndarray) -> float:
        """sigma(r) with the lost time less sigma(r) without: the objective's time term."""
        return self.sigma(self.lost_s(angles_deg)) - self.sigma_full


def table_columns(price: TimePrice, angles_deg: np.ndarray, delta_r: float) -> dict:
    """strategies.csv's observing-time columns of one assignment.

    Returns
    -------
    dict
        The minutes of operations and of lost observing, the lost fraction, sigma(r) with the
        lost time, its delta_r equivalent and the total with the systematic delta_r.
    """
    line = price.timeline(angles_deg)
    sigma = price.sigma(float(line.lost_s.sum()))
    return dict(
        operations_min=float(line.overhead_s.sum()) / 60.0,
        lost_min=float(line.lost_s.sum()) / 60.0,
        lost_fraction=line.lost_fraction,
        sigma_r_with_lost_time=sigma,
        delta_r_lost_time=sigma - price.sigma_full,
        delta_r_total=delta_r + sigma - price.sigma_full,
    )


def timeline_rows(price: TimePrice, rows, angles_deg: np.ndarray) -> list[dict]:
    """operations.csv's rows: each CES's angle, the operations before it, the gap they had and
    the minutes it lost."""
    line = price.timeline(angles_deg)
    angle = np.asarray(angles_deg, dtype=float)[price.unit_of]
    out = []
    for i, c in enumerate(rows):
        gap = c.start_unix - price.stop[i - 1] if i else math.inf
        out.append(
            dict(
                ces=i,
                start_unix=c.start_unix,
                boresight_deg=float(angle[i]),
                elevation_deg=c.elevation_deg,
                hwp_dir=c.hwp_dir,
                operations=" + ".join(n for n, k in zip(NAMES, line.counts[i]) for _ in range(k)),
                overhead_min=line.overhead_s[i] / 60.0,
                gap_min=gap / 60.0 if gap >= 0 else math.nan,
                lost_min=line.lost_s[i] / 60.0,
            )
        )
    return out


def observed(rows, lost_s: np.ndarray, sample_rate_hz: float):
    """The CESs as the telescope observes them, for their moments: the time the operations eat
    cut from each start, a CES eaten whole kept as one sample so that the units keep their
    rows (:func:`boresight.moments.unit_moments`' ``units``).

    Parameters
    ----------
    rows : tuple of boresight.schedule.CES
    lost_s : numpy.ndarray, shape (n_ces,)
    sample_rate_hz : float

    Returns
    -------
    tuple of boresight.schedule.CES
    """
    one = 1.0 / sample_rate_hz
    return tuple(
        replace(
            c,
            start_unix=c.start_unix + min(float(lost), c.duration_s - one),
            duration_s=max(c.duration_s - float(lost), one),
        )
        for c, lost in zip(rows, lost_s)
    )


def shortened(rows, lost_s: np.ndarray):
    """The CESs with the time the operations eat cut from their starts, those eaten whole left
    out: :func:`observed`'s CESs, less its one-sample stand-ins.

    Parameters
    ----------
    rows : tuple of boresight.schedule.CES
    lost_s : numpy.ndarray, shape (n_ces,)

    Returns
    -------
    tuple of boresight.schedule.CES
    """
    kept = observed(rows, lost_s, 1.0)
    return tuple(k for k, c, lost in zip(kept, rows, lost_s) if lost < c.duration_s)


@njit
def _timeline(start, stop, el, hwp_dir, angle, durations, tol_angle, tol_el, overhead, lost,
              counts):  # fmt: skip
    """Each CES's operations (schedlib's setup_boresight, det_setup, hwp_spin_up in turn) and the
    time they eat (module docstring), into ``overhead``, ``lost`` and ``counts``."""
    down, rotation, setup, up = durations[0], durations[1], durations[2], durations[3]
    angle_now, spinning, direction, set_up = 0.0, False, -1, False
    setup_el, setup_angle = 0.0, 0.0
    free, previous_stop = -np.inf, -np.inf
    for i in range(start.size):
        t = 0.0
        if abs(angle_now - angle[i]) > tol_angle + 1e-5 * abs(angle[i]):  # np.isclose(atol=...)
            if spinning:
                t += down
                counts[i, 0] += 1
                spinning = False
            t += rotation
            counts[i, 1] += 1
            angle_now = angle[i]
        again = not set_up
        again = again or abs(setup_el - el[i]) > tol_el + 1e-5 * abs(el[i])
        again = again or abs(setup_angle - angle[i]) > tol_angle + 1e-5 * abs(angle[i])
        if again:
            t += setup
            counts[i, 2] += 1
            set_up, setup_el, setup_angle = True, el[i], angle[i]
        if spinning and direction != hwp_dir[i]:
            t += down
            counts[i, 0] += 1
            spinning = False
        if not spinning:
            t += up
            counts[i, 3] += 1
            spinning, direction = True, hwp_dir[i]
        if start[i] < previous_stop:  # a new session (a repeat observed another day)
            free = -np.inf
        ready = free + t
        overhead[i] = t
        lost[i] = min(stop[i] - start[i], max(0.0, ready - start[i]))
        free = max(stop[i], ready)
        previous_stop = stop[i]
