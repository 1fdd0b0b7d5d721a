"""Real ground scans: constant-elevation scans (CES) from a site, with a boresight schedule.

Each CES sweeps the azimuth between centre - throw / 2 and centre + throw / 2 at constant speed,
reversing at each end in ``turnaround_s`` at constant deceleration (overshooting by
speed * turnaround / 4), at fixed elevation and boresight angle. The Earth turns between and
during CESs. Pointing is a rotation from the horizon frame to equatorial coordinates of date
(CIRS, from the Earth Rotation Angle with UT1 = UTC + dut1). It ignores polar motion, refraction
and diurnal aberration (each below 0.5 arcsec). Coordinates of date differ from ICRS by
precession-nutation, about 0.35 deg in 2026: irrelevant for crossing-angle statistics and noted in
FITS outputs.

The crossing angle psi of a sample is the orientation on the sky of the focal plane's "up" axis
(towards the zenith at zero boresight rotation), measured from e_theta towards e_phi like the
synthetic scans' psi, plus the boresight angle: psi = pi - q + boresight, with q the parallactic
angle (position angle of the zenith, east of north).
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numba
import numpy as np

from . import validation
from .config import ConfigError, tomllib
from .constants import DEG

if TYPE_CHECKING:
    from collections.abc import Iterator

    from .toast_schedule import ScanMotion


UNIX_EPOCH_JD = 2440587.5
#: Simons Observatory site, Cerro Toco, Atacama (deg, deg, m)
ATACAMA = (-22.958, -67.787, 5200.0)


@dataclass(frozen=True)
class Site:
    """An observatory position.

    Parameters
    ----------
    lat_deg : float
        Geodetic latitude [deg], in [-90, 90].
    lon_deg : float
        East longitude [deg].
    alt_m : float
        Altitude [m].
    name, telescope : str
        Labels kept from and written to TOAST schedules (no ``|`` or line breaks).
    """

    lat_deg: float = ATACAMA[0]
    lon_deg: float = ATACAMA[1]
    alt_m: float = ATACAMA[2]
    name: str = "site"
    telescope: str = "telescope"

    def __post_init__(self):
        validation.number("lat_deg", self.lat_deg, -90.0, 90.0)
        validation.number("lon_deg", self.lon_deg, -180.0, 360.0)
        validation.number("alt_m", self.alt_m, -500.0, 1e5)
        validation.label("site name", self.name)
        validation.label("telescope", self.telescope)


@dataclass(frozen=True)
class CES:
    """One constant-elevation scan; every field finite and within :data:`CES_LIMITS`.

    Parameters
    ----------
    start_unix : float
        Start [UTC seconds since 1970].
    duration_s : float
        Length [s], > 0.
    elevation_deg : float
        Elevation [deg], in (0, 90).
    az_centre_deg, az_throw_deg : float
        Centre and full width of the azimuth sweep [deg].
    speed_deg_s : float
        Azimuth speed of the mount [deg/s], > 0.
    boresight_deg : float
        Boresight rotation of this CES [deg].
    turnaround_s : float
        Time to reverse at each end, at constant deceleration [s].
    name : str
        Patch name (TOAST's), kept as metadata.
    scan_index, subscan_index : int
        TOAST's pass and sub-pass of the patch, kept as metadata.
    """

    start_unix: float
    duration_s: float
    elevation_deg: float
    az_centre_deg: float
    az_throw_deg: float
    speed_deg_s: float = 1.0
    boresight_deg: float = 0.0
    turnaround_s: float = 0.0  #: time to reverse at each end, at constant deceleration
    name: str = "ces"
    scan_index: int = 0
    subscan_index: int = 0

    def __post_init__(self):
        for name, (lo, hi) in CES_LIMITS.items():
            validation.number(f"CES {name}", getattr(self, name), lo, hi)
        validation.label("CES name", self.name)
        validation.integer("CES scan_index", self.scan_index, 0)
        validation.integer("CES subscan_index", self.subscan_index, 0)
        if not 0 < self.elevation_deg < 90:
            raise ValueError(f"CES elevation_deg = {self.elevation_deg} must lie in (0, 90)")
        if self.duration_s <= 0 or self.speed_deg_s <= 0:
            raise ValueError("CES duration_s and speed_deg_s must be > 0")


#: allowed range of every CES field: start between 1970 and 2100, speeds and times of real mounts
CES_LIMITS = {
    "start_unix": (0.0, 4.1e9),
    "duration_s": (0.0, 1e7),
    "elevation_deg": (0.0, 90.0),
    "az_centre_deg": (-720.0, 720.0),
    "az_throw_deg": (0.0, 360.0),
    "speed_deg_s": (0.0, 100.0),
    "boresight_deg": (-3600.0, 3600.0),
    "turnaround_s": (0.0, 3600.0),
}
#: the CES fields a schedule must give (the others have defaults)
CES_REQUIRED = ("start_unix", "duration_s", "elevation_deg", "az_centre_deg", "az_throw_deg")
#: the CES labels a schedule may give (TOAST's patch name, pass and sub-pass)
CES_METADATA = ("name", "scan_index", "subscan_index")


@dataclass(frozen=True)
class Schedule:
    """A site, a set of CESs and the sample rate.

    Parameters
    ----------
    ces : tuple of CES
    site : Site
    sample_rate_hz : float
    dut1_s : float
        UT1 - UTC [s], in [-1, 1].
    repeat_boresight_deg : tuple of float
        The CES set is observed once per angle [deg] (identical sky tracks).
    """

    ces: tuple
    site: Site = Site()
    sample_rate_hz: float = 20.0
    dut1_s: float = 0.0  #: UT1 - UTC [s]
    repeat_boresight_deg: tuple = (0.0,)  #: the CES set is observed once per angle [deg]

    def __post_init__(self):
        if not self.ces or not all(isinstance(c, CES) for c in self.ces):
            raise ValueError("a schedule needs at least one CES")
        validation.number("sample_rate_hz", self.sample_rate_hz, 1e-3, 1e4)
        validation.number("dut1_s", self.dut1_s, -1.0, 1.0)
        rep = validation.numbers_array(
            "repeat_boresight_deg", self.repeat_boresight_deg, -3600.0, 3600.0
        )
        if rep.ndim != 1 or rep.size == 0:
            raise ValueError("repeat_boresight_deg needs at least one angle")
        object.__setattr__(self, "repeat_boresight_deg", tuple(float(a) for a in rep))

    @property
    def n_samples(self):
        per_set = sum(int(c.duration_s * self.sample_rate_hz) for c in self.ces)
        return per_set * len(self.repeat_boresight_deg)

    def repeated(self, boresight_deg):
        """This CES set observed once per boresight angle in the list (identical sky tracks)."""
        return replace(self, repeat_boresight_deg=tuple(boresight_deg))

    def single(self):
        """The CES set observed once, without the boresight repeats."""
        return replace(self, repeat_boresight_deg=(0.0,))

    def expanded(self):
        """The CESs in observing order, each boresight repeat as CESs of their own.

        Returns
        -------
        tuple of CES
            The CES set once per repeat angle, ``boresight_deg`` = its own + the repeat's.
        """
        return tuple(
            replace(c, boresight_deg=c.boresight_deg + rep)
            for rep in self.repeat_boresight_deg
            for c in self.ces
        )


class ScheduleError(ConfigError):
    """A schedule file that cannot be read, with the file, row and key in the message."""


def load_schedule(path: str, motion: ScanMotion | None = None) -> Schedule:
    """Read a schedule file: boresight's TOML or CSV, or any TOAST schedule.

    TOML: optional [site], sample_rate_hz, dut1_s, repeat_boresight_deg and [[ces]] tables of CES
    fields. CSV: a header naming CES fields and one CES per row. Unknown keys or columns are errors.
    A TOAST schedule (text of any version, or ECSV; see :mod:`boresight.toast_schedule`) is
    recognised by its content, whatever its name.

    Parameters
    ----------
    path : str or os.PathLike
    motion : boresight.toast_schedule.ScanMotion, optional
        Scan rate, acceleration and sample rate of a TOAST schedule, which its file leaves out
        (default: ``SimGround``'s, at 20 Hz). boresight's own formats hold their own.

    Returns
    -------
    Schedule

    Raises
    ------
    ScheduleError
        Naming the file, the row (CSV line or [[ces]] number) and the key.
    """
    from . import toast_schedule

    path = str(path)
    if not os.path.isfile(path):
        raise ScheduleError(f"schedule not found (or not a file): {path}")
    if toast_schedule.is_toast_schedule(path):
        return toast_schedule.read(path, motion or toast_schedule.ScanMotion())
    try:
        if path.endswith(".csv"):
            return Schedule(_csv_rows(path))
        return _toml_schedule(path)
    except ScheduleError:
        raise
    except (ValueError, TypeError) as err:
        raise ScheduleError(f"schedule {path}: {err}") from None


def is_schedule(path: str) -> bool:
    """Whether a file is a schedule (TOAST's, CSV, or TOML with [[ces]]) rather than a study.

    Parameters
    ----------
    path : str

    Returns
    -------
    bool
    """
    from . import toast_schedule

    if toast_schedule.is_toast_schedule(path) or str(path).endswith(".csv"):
        return True
    try:
        with open(path, "rb") as f:
            return "ces" in tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return False


def _ces(fields, where):
    """A CES from a dict of fields, with ``where`` (file and row) in every error."""
    unknown = sorted(set(fields) - set(CES_LIMITS) - set(CES_METADATA))
    missing = [k for k in CES_REQUIRED if k not in fields]
    if unknown or missing:
        raise ScheduleError(
            f"{where}: unknown keys {unknown}, missing keys {missing}; CES keys: "
            f"{list(CES_LIMITS) + list(CES_METADATA)}"
        )
    try:
        return CES(**fields)
    except (ValueError, TypeError) as err:
        raise ScheduleError(f"{where}: {err}") from None


def _csv_rows(path):
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        rows = []
        for i, row in enumerate(reader, start=2):
            where = f"schedule {path}, line {i}"
            if None in row or None in row.values():
                raise ScheduleError(
                    f"{where}: the row has a different number of values than the header"
                )
            fields = {}
            for key, text in row.items():
                try:
                    fields[key] = (
                        text if key == "name" else (int if key in CES_METADATA else float)(text)
                    )
                except ValueError:
                    raise ScheduleError(f"{where}: {key} = {text!r} is not a number") from None
            rows.append(_ces(fields, where))
    if not rows:
        raise ScheduleError(f"schedule {path} has no CES rows")
    return tuple(rows)


SCHEDULE_KEYS = ("site", "ces", "sample_rate_hz", "dut1_s", "repeat_boresight_deg")


def _toml_schedule(path):
    with open(path, "rb") as f:
        try:
            raw = tomllib.load(f)
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
            raise ScheduleError(f"schedule {path} is not valid TOML: {err}") from None
    unknown = sorted(set(raw) - set(SCHEDULE_KEYS))
    if unknown:
        raise ScheduleError(
            f"schedule {path}: unknown keys {unknown}; allowed: {list(SCHEDULE_KEYS)}"
        )
    site, ces = raw.get("site", {}), raw.get("ces", [])
    if not isinstance(site, dict) or not isinstance(ces, list):
        raise ScheduleError(f"schedule {path}: [site] must be a table and [[ces]] a list of tables")
    bad_site = sorted(set(site) - {"lat_deg", "lon_deg", "alt_m", "name", "telescope"})
    if bad_site:
        raise ScheduleError(f"schedule {path}: unknown [site] keys {bad_site}")
    if not all(isinstance(c, dict) for c in ces):
        raise ScheduleError(f"schedule {path}: every [[ces]] must be a table")
    repeat = raw.get("repeat_boresight_deg", [0.0])
    if not isinstance(repeat, list):
        raise ScheduleError(f"schedule {path}: repeat_boresight_deg must be a list of angles")
    return Schedule(
        tuple(_ces(c, f"schedule {path}, [[ces]] number {i + 1}") for i, c in enumerate(ces)),
        Site(**site),
        raw.get("sample_rate_hz", 20.0),
        raw.get("dut1_s", 0.0),
        tuple(repeat),
    )


def schedule_format(path: str) -> str:
    """The format of a schedule file: "toast", "csv" or "toml"."""
    from . import toast_schedule

    if toast_schedule.is_toast_schedule(path):
        return "toast"
    return "csv" if str(path).endswith(".csv") else "toml"


def write_schedule(schedule: Schedule, path: str, fmt: str) -> None:
    """Write a schedule in one of the formats :func:`load_schedule` reads, atomically.

    Parameters
    ----------
    schedule : Schedule
    path : str
    fmt : {"toml", "csv", "toast"}
        TOML keeps everything; CSV holds the CESs only (the default site and sample rate), with
        the repeats as rows; TOAST as :func:`boresight.toast_schedule.write`.
    """
    from . import io, toast_schedule

    if fmt == "toast":
        toast_schedule.write(schedule, path)
        return
    keys = list(CES_LIMITS) + list(CES_METADATA)
    if fmt == "csv":
        rows = [{k: getattr(c, k) for k in keys} for c in schedule.expanded()]
        io.write_csv(path, rows, keys)
        return
    if fmt != "toml":
        raise ValueError(f"schedule format must be toml, csv or toast, got {fmt!r}")
    s = schedule.site

    def value(v):
        return json.dumps(v) if isinstance(v, str) else repr(v)

    lines = [
        f"sample_rate_hz = {schedule.sample_rate_hz!r}",
        f"dut1_s = {schedule.dut1_s!r}",
        f"repeat_boresight_deg = {list(schedule.repeat_boresight_deg)!r}",
        "",
        "[site]",
        *(f"{k} = {value(getattr(s, k))}" for k in ("lat_deg", "lon_deg", "alt_m", "name")),
        f"telescope = {value(s.telescope)}",
    ]
    for c in schedule.ces:
        lines += ["", "[[ces]]", *(f"{k} = {value(getattr(c, k))}" for k in keys)]
    io.write_text(path, "\n".join(lines) + "\n")


@numba.njit(inline="always")
def earth_rotation_angle(jd_ut1):
    """Earth Rotation Angle (IERS 2003), not reduced to [0, 2 pi).

    Parameters
    ----------
    jd_ut1 : float
        UT1 Julian date.

    Returns
    -------
    float
        [rad].
    """
    return (
        2 * np.pi * ((jd_ut1 % 1.0) + 0.7790572732640 + 0.00273781191135448 * (jd_ut1 - 2451545.0))
    )


@numba.njit(inline="always")
def horizon_terms(az, se, ce, sl, cl):
    """The rotation from horizon to equatorial coordinates of one direction.

    Parameters
    ----------
    az : float
        Azimuth east of north [rad].
    se, ce : float
        sin and cos of the elevation.
    sl, cl : float
        sin and cos of the latitude.

    Returns
    -------
    sd, y, x : float
        sin(dec), cos(dec) sin(H) and cos(dec) cos(H), H the hour angle.
    """
    sa, ca = np.sin(az), np.cos(az)
    sd = min(1.0, max(-1.0, sl * se + cl * ce * ca))
    return sd, -sa * ce, cl * se - sl * ce * ca


@numba.njit(inline="always")
def parallactic_terms(sd, x, y, tl):
    """The atan2 arguments of the parallactic angle.

    Parameters
    ----------
    sd, x, y : float
        From :func:`horizon_terms`.
    tl : float
        tan(latitude).

    Returns
    -------
    y, X : float
        q = atan2(y, X), X = cos(dec)^2 tan(lat) - sin(dec) x.
    """
    return y, tl * (x * x + y * y) - sd * x


@numba.njit(inline="always")
def _to_equatorial(az, se, ce, local_era, sl, cl, tl):
    """One sample: (theta, phi, q) from azimuth, sin/cos elevation, local ERA and latitude.

    sin H and cos H come from the hour angle's own atan2 arguments (their norm is cos(dec)).
    """
    sd, y, x = horizon_terms(az, se, ce, sl, cl)
    ha = np.arctan2(y, x)
    qy, qx = parallactic_terms(sd, x, y, tl)
    q = np.arctan2(qy, qx) if x * x + y * y > 0 else 0.0
    return np.arccos(sd), (local_era - ha) % (2 * np.pi), q


@numba.njit(parallel=True, cache=True)
def horizon_to_equatorial(az, el, local_era, lat):
    """Horizon to equatorial coordinates of date, with the parallactic angle.

    Parameters
    ----------
    az, el : numpy.ndarray, shape (n,)
        Azimuth east of north and elevation [rad].
    local_era : numpy.ndarray, shape (n,)
        Local Earth rotation angle [rad].
    lat : float
        Latitude [rad].

    Returns
    -------
    theta, phi, q : numpy.ndarray, shape (n,)
        Colatitude, right ascension of date and parallactic angle (east of north) [rad].
    """
    n = az.size
    theta = np.empty(n)
    phi = np.empty(n)
    q = np.empty(n)
    sl, cl, tl = np.sin(lat), np.cos(lat), np.tan(lat)
    for k in numba.prange(n):
        theta[k], phi[k], q[k] = _to_equatorial(
            az[k], np.sin(el[k]), np.cos(el[k]), local_era[k], sl, cl, tl
        )
    return theta, phi, q


@numba.njit(inline="always")
def _scan_offset(t, throw, speed, turnaround):
    """Azimuth offset from the CES centre [rad] at time t [s] (throw [rad], speed [rad/s])."""
    leg = throw / speed
    u = t % (2 * (leg + turnaround))
    if u < leg:
        return -0.5 * throw + speed * u
    u -= leg
    if u < turnaround:
        return 0.5 * throw + speed * u - speed * u * u / turnaround
    u -= turnaround
    if u < leg:
        return 0.5 * throw - speed * u
    u -= leg
    return -0.5 * throw - speed * u + speed * u * u / turnaround


@numba.njit(cache=True)
def _scan_offsets(t, throw, speed, turnaround):
    out = np.empty(t.size)
    for i in range(t.size):
        out[i] = _scan_offset(t[i], throw, speed, turnaround)
    return out


def ces_samples(ces, schedule, start=0, stop=None):
    """Times and horizon pointing of samples of a CES.

    Parameters
    ----------
    ces : CES
    schedule : Schedule
        Its sample rate.
    start, stop : int
        Sample range (default: the whole CES).

    Returns
    -------
    t : numpy.ndarray
        [unix s].
    az, el : numpy.ndarray
        [rad].
    """
    n = int(ces.duration_s * schedule.sample_rate_hz)
    stop = n if stop is None else min(stop, n)
    t = np.arange(start, stop) / schedule.sample_rate_hz
    az = ces.az_centre_deg * DEG + _scan_offsets(
        t, max(ces.az_throw_deg, 1e-12) * DEG, ces.speed_deg_s * DEG, ces.turnaround_s
    )
    return ces.start_unix + t, az, np.full(t.size, ces.elevation_deg * DEG)


@numba.njit(inline="always")
def azimuth_and_local_era(t, start_unix, az_centre, throw, speed, turnaround, jd_offset, lon):
    """Azimuth and local Earth rotation angle t seconds into a CES.

    Parameters
    ----------
    t, start_unix : float
        [s].
    az_centre, throw, speed : float
        [rad], [rad], [rad/s].
    turnaround : float
        [s].
    jd_offset : float
        UT1 Julian date of the Unix epoch.
    lon : float
        East longitude [rad].

    Returns
    -------
    az, local_era : float
        [rad].
    """
    az = az_centre + _scan_offset(t, max(throw, 1e-300), speed, turnaround)
    return az, earth_rotation_angle((start_unix + t) / 86400.0 + jd_offset) + lon


@numba.njit(parallel=True, cache=True)
def _ces_pointing(
    k0,
    n,
    start_unix,
    rate,
    az_centre,
    throw,
    speed,
    turnaround,
    el,
    jd_offset,
    lon,
    lat,
    psi_offset,
):
    """Fused :func:`ces_samples`, :func:`earth_rotation_angle` and :func:`horizon_to_equatorial`.

    Angles in rad (throw, speed in rad and rad/s); returns theta, phi, psi of samples k0..k0+n-1.
    """
    theta = np.empty(n)
    phi = np.empty(n)
    psi = np.empty(n)
    sl, cl, tl = np.sin(lat), np.cos(lat), np.tan(lat)
    se, ce = np.sin(el), np.cos(el)
    for i in numba.prange(n):
        az, local_era = azimuth_and_local_era(
            (k0 + i) / rate, start_unix, az_centre, throw, speed, turnaround, jd_offset, lon
        )
        theta[i], phi[i], q = _to_equatorial(az, se, ce, local_era, sl, cl, tl)
        psi[i] = np.pi - q + psi_offset
    return theta, phi, psi


def chunk_arguments(schedule, chunk_samples=1 << 20):
    """Kernel arguments of every chunk of a schedule, in observing order: the CES set in time order,
    once per boresight repeat. Parameters as :func:`pointing`.

    Yields
    ------
    tuple
        (first sample, samples: int; start [unix s], rate [Hz], azimuth centre, throw [rad], speed
        [rad/s], turnaround [s], elevation [rad], UT1 Julian date offset, longitude, latitude [rad],
        boresight angle [rad]: float, also where the file gave an integer, since numba compiles a
        kernel anew for each combination of types).
    """
    lat, lon = schedule.site.lat_deg * DEG, schedule.site.lon_deg * DEG
    jd_offset = UNIX_EPOCH_JD + schedule.dut1_s / 86400.0
    for repeat in schedule.repeat_boresight_deg:
        for c in schedule.ces:
            n = int(c.duration_s * schedule.sample_rate_hz)
            scalars = (
                c.start_unix,
                schedule.sample_rate_hz,
                c.az_centre_deg * DEG,
                c.az_throw_deg * DEG,
                c.speed_deg_s * DEG,
                c.turnaround_s,
                c.elevation_deg * DEG,
                jd_offset,
                lon,
                lat,
                (c.boresight_deg + repeat) * DEG,
            )
            for s in range(0, n, chunk_samples):
                yield (s, min(chunk_samples, n - s), *map(float, scalars))


def pointing(schedule: Schedule, chunk_samples: int = 1 << 20) -> Iterator[tuple]:
    """The pointing of a whole schedule, chunk by chunk.

    Parameters
    ----------
    schedule : Schedule
    chunk_samples : int

    Yields
    ------
    theta, phi, psi : numpy.ndarray, shape (<= chunk_samples,)
        Colatitude, right ascension of date and crossing angle [rad]; the CES set in time order,
        once per boresight repeat.
    """
    for args in chunk_arguments(schedule, chunk_samples):
        yield _ces_pointing(*args)
