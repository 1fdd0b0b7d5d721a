"""What a pipeline filters before binning, as data: a :class:`Filtering` and what it does to one
CES's pair differences.

A CES of a schedule (:class:`boresight.schedule.CES`) is filtered in two steps, as two TOAST
operators in a row: the polynomial per throw (:func:`~boresight.mitigation.polyfilter.poly_filter`),
then the ground template per CES (:func:`~boresight.mitigation.groundfilter.ground_filter`). Each
throw is TOAST's: a scan and half of each turnaround beside it, so that throws meet at the
turnarounds' middles, where the mount reverses. The turnarounds' samples are left out of every fit
(TOAST's ``turnarounds_invalid``) and filtered with the rest. The scan's direction is the throw's:
even throws go towards larger azimuth (the schedule's first leg), odd ones back.

Written as text (the CLI's ``--filter``), a filtering is its parts joined by ``+``: ``p3`` a
polynomial of order 3 per throw; ``ground`` (order 5, TOAST's default) or ``ground3`` a Legendre
template in azimuth; ``groundbin0.5`` azimuth bins of 0.5 deg; a ground part ending in ``-split``
has a template per scan direction; ``deproject(gain,pointing)`` the templates of T regressed per
CES after the filters (:mod:`~boresight.mitigation.deprojection`; ``deproject(bk)`` all of
BICEP/Keck's). ``none`` is no filtering.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..constants import DEG
from ..pointing import ces_samples
from ..validation import integer, number
from .deprojection import Deprojection
from .groundfilter import ground_filter
from .polyfilter import poly_filter

#: the ground filter's trend: Legendre orders 1 .. this in time, fitted with it and kept (TOAST's
#: GroundFilter default)
TREND_ORDER = 5

#: the ground template's Legendre order written as ``ground`` alone (TOAST's default)
GROUND_ORDER = 5

_PART = re.compile(r"^(?:p(\d+)|ground(\d+)?|groundbin([0-9.]+))(-split)?$")
_DEPROJECT = re.compile(r"deproject\(([^)]*)\)")


@dataclass(frozen=True)
class Filtering:
    """The filters a pipeline applies to each pair difference before binning.

    Parameters
    ----------
    poly_order : int, optional
        A Legendre polynomial of this order per throw (BICEP/Keck: 3); None for none.
    ground_order : int, optional
        A Legendre template of this order in azimuth per CES; None for none.
    ground_bin_deg : float, optional
        Or azimuth bins of this width [deg] (not with ``ground_order``).
    ground_split : bool
        A ground template per scan direction.
    deprojection : boresight.mitigation.Deprojection
        Templates of T regressed from each pair difference per CES, after the filters.
    """

    poly_order: int | None = None
    ground_order: int | None = None
    ground_bin_deg: float | None = None
    ground_split: bool = False
    deprojection: Deprojection = Deprojection()

    def __post_init__(self):
        if self.poly_order is not None:
            integer("filter poly_order", self.poly_order, 0, 64)
        if self.ground_order is not None:
            integer("filter ground_order", self.ground_order, 0, 64)
        if self.ground_bin_deg is not None:
            width = number("filter ground_bin_deg", self.ground_bin_deg, 0.0, 360.0)
            if width <= 0:
                raise ValueError("filter ground_bin_deg must be > 0")
            if self.ground_order is not None:
                raise ValueError(
                    "filter: a ground template is Legendre (ground_order) or binned "
                    "(ground_bin_deg), not both"
                )
        if self.ground_split and not self.has_ground:
            raise ValueError("filter ground_split needs a ground template")

    @property
    def has_ground(self) -> bool:
        return self.ground_order is not None or self.ground_bin_deg is not None

    @property
    def filters(self) -> bool:
        """Whether it filters (a polynomial or a ground template), deprojection aside."""
        return self.poly_order is not None or self.has_ground

    def __bool__(self) -> bool:
        return self.filters or bool(self.deprojection)

    @classmethod
    def parse(cls, text: str) -> Filtering:
        """A filtering from its text (the module's docstring), e.g. ``"p3+ground-split"``."""
        text = text.strip().lower()
        options = {}
        deprojections = _DEPROJECT.findall(text)
        if len(deprojections) > 1:
            raise ValueError(f"filter {text!r}: two deproject parts")
        if deprojections:
            options["deprojection"] = Deprojection.parse(deprojections[0])
            text = "+".join(p for p in _DEPROJECT.sub("", text).split("+") if p.strip())
        if text in ("", "none"):
            return cls(**options)
        for part in text.split("+"):
            match = _PART.match(part.strip())
            if match is None:
                raise ValueError(
                    f"filter part {part!r}: write p<order>, ground, ground<order>, "
                    "groundbin<deg>, a ground part with -split, deproject(<templates>), joined "
                    "by '+' (e.g. p3+ground+deproject(gain,pointing))"
                )
            poly, order, width, split = match.groups()
            key = "poly_order" if poly is not None else "ground"
            if key in options:
                raise ValueError(f"filter {text!r}: two {key.split('_')[0]} parts")
            if poly is not None:
                if split:
                    raise ValueError(f"filter part {part!r}: only a ground part splits")
                options["poly_order"] = int(poly)
            else:
                options["ground"] = (order, width, bool(split))
        ground = options.pop("ground", None)
        if ground is not None:
            order, width, split = ground
            if width is not None:
                options["ground_bin_deg"] = float(width)
            else:
                options["ground_order"] = GROUND_ORDER if order is None else int(order)
            options["ground_split"] = split
        return cls(**options)

    def __str__(self) -> str:
        parts = []
        if self.poly_order is not None:
            parts.append(f"p{self.poly_order}")
        if self.ground_order is not None:
            parts.append(f"ground{self.ground_order}")
        if self.ground_bin_deg is not None:
            parts.append(f"groundbin{self.ground_bin_deg:g}")
        if self.ground_split:
            parts[-1] += "-split"
        if self.deprojection:
            parts.append(f"deproject({self.deprojection})")
        return "+".join(parts) or "none"

    def apply(self, signal: np.ndarray, ces_scan: CesScan) -> np.ndarray:
        """One CES's streams filtered: the polynomial per throw, then the ground template (the
        deprojection, which needs the templates, is the engine's next step).

        Parameters
        ----------
        signal : numpy.ndarray, shape (n,) or (n_signals, n)
            The CES's pair differences, every sample of it in time order.
        ces_scan : CesScan

        Returns
        -------
        numpy.ndarray
            A new array shaped as ``signal``.
        """
        out = np.array(signal, dtype=np.float64, copy=True)
        if self.poly_order is not None:
            out = poly_filter(
                out, order=self.poly_order, intervals=ces_scan.throws, flags=ces_scan.turning
            )
        if self.has_ground:
            direction = ces_scan.direction
            out = ground_filter(
                out,
                az=ces_scan.az,
                filter_order=self.ground_order,
                bin_width_rad=None if self.ground_bin_deg is None else self.ground_bin_deg * DEG,
                trend_order=TREND_ORDER,
                split=(direction, ~direction) if self.ground_split else None,
                flags=ces_scan.turning,
            )
        return out


@dataclass(frozen=True)
class CesScan:
    """What a filter needs of one CES's samples: their azimuth, throws and turnarounds.

    Parameters
    ----------
    az : numpy.ndarray, shape (n,)
        Boresight azimuth [rad].
    turning : numpy.ndarray of bool, shape (n,)
        The turnarounds' samples.
    throws : numpy.ndarray of int, shape (n_throws, 2)
        Each throw's samples, [first, last) (TOAST's throws: they meet mid-turnaround).
    direction : numpy.ndarray of bool, shape (n,)
        True on the throws that go towards larger azimuth.
    """

    az: np.ndarray
    turning: np.ndarray
    throws: np.ndarray
    direction: np.ndarray

    @classmethod
    def of(cls, ces, schedule) -> CesScan:
        """The CES's samples as :func:`boresight.pointing.ces_samples` gives them.

        Parameters
        ----------
        ces : boresight.schedule.CES
        schedule : boresight.schedule.Schedule
            Its sample rate.

        Raises
        ------
        ValueError
            A CES that does not scan (no throw).
        """
        leg, rate = ces.az_throw_deg / ces.speed_deg_s, schedule.sample_rate_hz
        if ces.az_throw_deg <= 0 or leg * rate < 1:
            raise ValueError(
                f"CES {ces.name!r} does not scan (throw {ces.az_throw_deg} deg over "
                f"{leg:.3g} s at {rate} Hz): nothing to filter per throw or in azimuth"
            )
        t, az, _, turning = ces_samples(ces, schedule)
        period = leg + ces.turnaround_s
        index = np.floor((t - ces.start_unix + 0.5 * ces.turnaround_s) / period).astype(np.int64)
        starts = np.flatnonzero(np.diff(index, prepend=index[0] - 1))
        ends = np.append(starts[1:], index.size)
        return cls(az, turning, np.stack([starts, ends], axis=1), index % 2 == 0)

    def check(self, filtering: Filtering) -> None:
        """Refuse a filter this CES cannot take: a polynomial with more terms than a throw has
        samples to fit, azimuth bins wider than the throw, more templates to deproject than the
        CES has samples off its turnarounds.

        Raises
        ------
        ValueError
        """
        fitted = [int(np.count_nonzero(~self.turning[a:b])) for a, b in self.throws[:-1]] or [
            int(np.count_nonzero(~self.turning))
        ]
        if filtering.poly_order is not None and filtering.poly_order + 1 > min(fitted):
            raise ValueError(
                f"filter poly_order {filtering.poly_order} needs {filtering.poly_order + 1} "
                f"samples per throw; a throw of this schedule has {min(fitted)} off the turnarounds"
            )
        n_templates, scanning = filtering.deprojection.n_templates, int(np.sum(~self.turning))
        if n_templates and scanning <= n_templates:
            raise ValueError(
                f"deprojection ({filtering.deprojection}) fits {n_templates} "
                f"template{'s' if n_templates > 1 else ''} per CES; a CES of this schedule has "
                f"{scanning} samples off its turnarounds"
            )
        if filtering.ground_bin_deg is not None:
            width = float(np.ptp(self.az)) / DEG
            if filtering.ground_bin_deg > width:
                raise ValueError(
                    f"filter ground_bin_deg {filtering.ground_bin_deg} is wider than the scan's "
                    f"{width:.3g} deg of azimuth"
                )


def ces_scans(filtering: Filtering, schedule) -> list[CesScan]:
    """Each CES's :class:`CesScan`, checked against ``filtering`` (:meth:`CesScan.check`): what
    a filtered simulation of ``schedule`` needs, refused before any work.

    Parameters
    ----------
    filtering : Filtering
    schedule : boresight.schedule.Schedule

    Returns
    -------
    list of CesScan
        In the order of ``schedule.ces``.

    Raises
    ------
    ValueError
        A CES that does not scan, or cannot take the filter.
    """
    scans = [CesScan.of(ces, schedule) for ces in schedule.ces]
    for scan in scans:
        scan.check(filtering)
    return scans
