"""What the mount allows: boresight angles allowed per elevation range (and per patch), and a
most number of changes of angle per day. The design's search never leaves them
(:func:`boresight.design.exact.search`); each one's cost in the objective is measured by
searching without it (:func:`boresight.design.job.design`).

A CES is bound by every rule whose elevation range [lo, hi) holds its elevation and whose patch,
where the rule names one, is its name; a unit (a CES, a day, a pass) by the rules of all its
CESs. A change is a change of angle by more than the operations' tolerance (1 deg, schedlib's)
between consecutive CESs of one session (a schedule's boresight repeats are sessions of their
own), counted on the UTC day the later CES starts.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np

from .. import validation


@dataclass(frozen=True)
class AngleRule:
    """Boresight angles allowed in an elevation range.

    Parameters
    ----------
    elevation_deg : tuple of float
        [lo, hi) [deg].
    angles_deg : tuple of float
        The angles a CES there may take [deg].
    patch : str, optional
        Only the CESs of this patch (TOAST's and SO's patch name, the CES ``name``).
    """

    elevation_deg: tuple
    angles_deg: tuple
    patch: str | None = None

    def __post_init__(self):
        el = validation.numbers_array("constraint elevation_deg", self.elevation_deg, 0.0, 90.0)
        if el.shape != (2,) or el[1] <= el[0]:
            raise ValueError(
                f"constraint elevation_deg = {list(self.elevation_deg)}: give [lo, hi], lo < hi"
            )
        angles = validation.numbers_array("constraint angles_deg", self.angles_deg, -3600, 3600)
        if angles.ndim != 1 or angles.size == 0:
            raise ValueError("constraint angles_deg must list at least one angle")
        object.__setattr__(self, "elevation_deg", tuple(float(x) for x in el))
        object.__setattr__(self, "angles_deg", tuple(float(a) for a in angles))
        if self.patch is not None:
            validation.label("constraint patch", self.patch)

    def applies(self, ces) -> bool:
        lo, hi = self.elevation_deg
        return lo <= ces.elevation_deg < hi and self.patch in (None, ces.name)

    def __str__(self):
        angles = ", ".join(f"{a:g}" for a in self.angles_deg)
        where = f" of patch {self.patch}" if self.patch is not None else ""
        lo, hi = self.elevation_deg
        return f"angles {{{angles}}} deg at elevation [{lo:g}, {hi:g}) deg{where}"


@dataclass(frozen=True)
class Constraints:
    """The ``[constraints]`` table.

    Parameters
    ----------
    angles : tuple of AngleRule
        ``[[constraints.angles]]``.
    max_changes_per_day : int, optional
        The most changes of angle a UTC day may hold.
    """

    angles: tuple = ()
    max_changes_per_day: int | None = None

    def __post_init__(self):
        if self.max_changes_per_day is not None:
            validation.integer("max_changes_per_day", self.max_changes_per_day, 0)

    @property
    def names(self) -> list[str]:
        """Each constraint, as the table of their costs names it."""
        out = [str(rule) for rule in self.angles]
        if self.max_changes_per_day is not None:
            out.append(f"at most {self.max_changes_per_day} changes per day")
        return out

    def without(self, k: int) -> Constraints:
        """These constraints less the k-th of :attr:`names`."""
        if k < len(self.angles):
            return Constraints(self.angles[:k] + self.angles[k + 1 :], self.max_changes_per_day)
        return Constraints(self.angles, None)


class Feasibility:
    """Constraints bound to a schedule's units: which angles each unit may take, and whether an
    assignment keeps the most changes per day.

    Parameters
    ----------
    constraints : Constraints
    rows : tuple of boresight.schedule.CES
        The CESs in observing order.
    units : list of list of int
        The CES rows of each unit.
    tolerance_deg : float
        Changes up to this do not count.
    """

    def __init__(self, constraints, rows, units, tolerance_deg=1.0):
        self.constraints = constraints
        self.tolerance = float(tolerance_deg)
        self.allowed = []  # per unit: a set of angles, or None for any
        for u, idx in enumerate(units):
            allowed = None
            for rule in constraints.angles:
                if any(rule.applies(rows[i]) for i in idx):
                    here = set(rule.angles_deg)
                    allowed = here if allowed is None else allowed & here
            if allowed is not None and not allowed:
                raise ValueError(
                    f"design unit {u} (first CES at elevation {rows[idx[0]].elevation_deg:g} "
                    "deg) is bound by constraints that allow no common angle"
                )
            self.allowed.append(allowed)
        self.unit_of = np.empty(len(rows), dtype=np.int64)
        for u, idx in enumerate(units):
            self.unit_of[idx] = u
        start = np.array([c.start_unix for c in rows])
        stop = start + np.array([c.duration_s for c in rows])
        # consecutive rows of one session: the later starts after the earlier ends
        self.same_session = start[1:] >= stop[:-1]
        days = [datetime.fromtimestamp(t, timezone.utc).date() for t in start[1:]]
        session = np.concatenate([[0], np.cumsum(~self.same_session)])[1:]
        keys = {}
        self.day = np.array([keys.setdefault((s, d), len(keys)) for s, d in zip(session, days)])
        self.n_days = len(keys)

    def unit_ok(self, u: int, angle: float) -> bool:
        """Whether unit u may take the angle."""
        return self.allowed[u] is None or float(angle) in self.allowed[u]

    def changes_per_day(self, angles_deg: np.ndarray) -> np.ndarray:
        """Changes of angle on each (session, UTC day)."""
        angle = np.asarray(angles_deg, dtype=float)[self.unit_of]
        moved = (np.abs(np.diff(angle)) > self.tolerance) & self.same_session
        return np.bincount(self.day[moved], minlength=self.n_days)

    def days_ok(self, angles_deg: np.ndarray) -> bool:
        """Whether every day keeps the most changes (the search's check of a move, whose moved
        units' angles :meth:`unit_ok` checks)."""
        most = self.constraints.max_changes_per_day
        if most is None or not self.day.size:
            return True
        return bool(self.changes_per_day(angles_deg).max(initial=0) <= most)

    def violations(self, angles_deg: np.ndarray) -> int:
        """Units at an angle their rules do not allow, and days over the most changes."""
        bad = sum(not self.unit_ok(u, a) for u, a in enumerate(angles_deg))
        most = self.constraints.max_changes_per_day
        if most is not None and self.day.size:
            bad += int(np.sum(self.changes_per_day(angles_deg) > most))
        return int(bad)

    def ok(self, angles_deg: np.ndarray) -> bool:
        return self.violations(angles_deg) == 0

    def greedy(self, allowed_deg: tuple) -> np.ndarray:
        """A start that keeps the rules: each unit at the previous unit's angle where allowed,
        else at its first allowed angle (in ``allowed_deg``' order)."""
        out, now = np.empty(len(self.allowed)), float(allowed_deg[0])
        for u in range(out.size):
            if not self.unit_ok(u, now):
                now = next(float(a) for a in allowed_deg if self.unit_ok(u, a))
            out[u] = now
        return out

    def check_allowed(self, allowed_deg: tuple) -> None:
        """Every unit has an angle among the design's allowed ones."""
        for u, here in enumerate(self.allowed):
            if here is not None and not here & {float(a) for a in allowed_deg}:
                raise ValueError(
                    f"design unit {u}: its constraints allow {sorted(here)} deg, none of the "
                    f"design's angles_deg {list(allowed_deg)}"
                )
