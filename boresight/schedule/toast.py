"""TOAST ground schedules in and out, without importing toast.

``toast_ground_schedule`` writes a plain-text schedule: a ``#``-commented header line, a site line
(site, telescope, latitude [deg], longitude [deg], altitude [m]), then one row per CES sub-scan.
TOAST's own reader (``toast.schedule.GroundSchedule.read``) tells four text versions apart by
their field count, fields separated by ``|`` or, where a line has none, by white space:

======= ====== ==========================================================================
version fields row
======= ====== ==========================================================================
4       9      start, stop, rotation, name, az min, az max, el, pass, sub (``|``-separated)
3       11     as 4, with the dates and times as separate whitespace fields
2       22     start, stop, MJD start, MJD stop, rotation, name, az min, az max, el, rising
               or setting, Sun and Moon positions (8), Moon phase, pass, sub, fraction
1       24     as 2, with the dates and times as separate whitespace fields
======= ====== ==========================================================================

A fifth form is an ECSV table (columns ``start_time, stop_time, boresight_angle, name, azmin,
azmax, el, scan_index, subscan_index``, site in its metadata), read here with astropy.

Times are UTC; angles are degrees. Rotation is the boresight angle, which boresight's CES
``boresight_deg`` takes unchanged: a TOAST rotation of +45 deg turns the crossing angle by
+45 deg in both codes. Their crossing angles differ by a constant: boresight's psi is TOAST's
psi + 180 deg, so odd h_n change sign between the two and even ones agree (``docs/conventions.md``).

The file leaves out how the mount moves. :class:`ScanMotion` supplies it, with TOAST's
``SimGround`` defaults: 1 deg/s azimuth rate on the sky (``fix_rate_on_sky``), so the mount turns
at 1 / cos(el) deg/s, and 1 deg/s^2 acceleration, so each turnaround takes 2 v / a seconds.
Each CES starts at az min moving towards az max and turns around outside the range, as
``SimGround`` does (``toast.ops.sim_ground_utils.simulate_ces_scan`` without random phase).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np

from .. import validation
from .._util.io import atomic_path, tomllib, write_text
from ..validation import ScheduleError
from .model import CES, CES_LIMITS, Schedule, Site

#: field count of a text row -> (version, whether dates and times are split into two fields)
TEXT_VERSIONS = {9: (4, False), 11: (3, True), 22: (2, False), 24: (1, True)}
#: the ECSV columns TOAST writes and reads
ECSV_COLUMNS = (
    "start_time",
    "stop_time",
    "boresight_angle",
    "name",
    "azmin",
    "azmax",
    "el",
    "scan_index",
    "subscan_index",
)
_DATE = "%Y-%m-%d %H:%M:%S"


@dataclass(frozen=True)
class ScanMotion:
    """How the mount moves, which TOAST schedule files leave out; defaults are ``SimGround``'s.

    Parameters
    ----------
    rate_deg_s : float
        Azimuth scan rate [deg/s], > 0 (``SimGround.scan_rate_az``).
    rate_on_sky : bool
        The rate is on the sky, so the mount turns at rate / cos(el) (``fix_rate_on_sky``);
        False: the rate is the mount's.
    accel_deg_s2 : float
        Mount azimuth acceleration in the turnarounds [deg/s^2], > 0 (``scan_accel_az``).
    sample_rate_hz : float
        Samples per second (TOAST takes it from the focal plane; boresight's default is 20 Hz).
    """

    rate_deg_s: float = 1.0
    rate_on_sky: bool = True
    accel_deg_s2: float = 1.0
    sample_rate_hz: float = 20.0

    def __post_init__(self):
        validation.number("scan rate [deg/s]", self.rate_deg_s, 1e-6, 100.0)
        validation.number("scan acceleration [deg/s^2]", self.accel_deg_s2, 1e-6, 1e3)
        validation.number("sample rate [Hz]", self.sample_rate_hz, 1e-3, 1e4)
        if not isinstance(self.rate_on_sky, bool):
            raise TypeError(f"rate_on_sky must be True or False, got {self.rate_on_sky!r}")

    def mount_speed(self, elevation_deg: float) -> float:
        """Mount azimuth speed [deg/s] at an elevation [deg]."""
        if self.rate_on_sky:
            return self.rate_deg_s / math.cos(math.radians(elevation_deg))
        return self.rate_deg_s

    def turnaround_s(self, elevation_deg: float) -> float:
        """Time to reverse from +v to -v at constant deceleration [s]: 2 v / a."""
        return 2 * self.mount_speed(elevation_deg) / self.accel_deg_s2


def file_text(path: str | os.PathLike) -> str | None:
    """A text file's content, a UTF-8 byte-order mark dropped; None if it cannot be read."""
    try:
        with open(path, encoding="utf-8-sig") as f:
            return f.read()
    except (OSError, UnicodeDecodeError):
        return None


def is_toast_schedule(path: str | os.PathLike) -> bool:
    """Whether a file is a TOAST schedule, from its content: ECSV; or text that is not TOML (a
    study or a boresight schedule, whose comments may say anything), is not named ``*.toml`` or
    ``*.csv``, and starts with a comment line or a site line (site, telescope, three numbers). A
    broken TOAST file is then read as one, so that its error names the line.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    bool
    """
    text = file_text(path)
    if text is None:
        return False
    if text.startswith("# %ECSV"):
        return True
    try:
        tomllib.loads(text)
        return False
    except tomllib.TOMLDecodeError:
        pass
    if str(path).lower().endswith((".toml", ".csv")) or not text.strip():
        return False
    if text.startswith("#"):
        return True
    first = next(line for line in text.splitlines() if line.strip())
    fields = _fields(first)
    try:
        return len(fields) == 5 and all(np.isfinite([float(x) for x in fields[2:]]))
    except ValueError:
        return False


def _fields(line):
    """A text line's fields as TOAST splits them: at ``|``, else at white space."""
    return [x.strip() for x in line.split("|")] if "|" in line else line.split()


def read(path: str | os.PathLike, motion: ScanMotion = ScanMotion()) -> Schedule:
    """Read a TOAST ground schedule of any version (text 1-4 or ECSV).

    Parameters
    ----------
    path : str or os.PathLike
    motion : ScanMotion
        Scan rate, acceleration and sample rate, which the file does not hold.

    Returns
    -------
    boresight.schedule.Schedule
        One CES per row, in file order, with the patch name, pass and sub-pass as metadata and
        the site's and telescope's names on its site.

    Raises
    ------
    boresight.schedule.ScheduleError
        Naming the file and line.
    """
    path = str(path)
    if not os.path.isfile(path):
        raise ScheduleError(f"schedule not found (or not a file): {path}")
    text = file_text(path)
    if text is None:
        raise ScheduleError(f"TOAST schedule {path} is not readable UTF-8 text")
    ecsv = text.startswith("# %ECSV")
    site, rows = _read_ecsv(path) if ecsv else _parse_text(text.splitlines(), path)
    if not rows:
        raise ScheduleError(f"TOAST schedule {path} has no CES rows")
    ces = []
    for where, fields in rows:
        try:
            ces.append(_ces(motion, **fields))
        except (ValueError, TypeError) as err:
            raise ScheduleError(f"{where}: {err}") from None
    return Schedule(tuple(ces), site, motion.sample_rate_hz)


def _parse_text(lines, path):
    """The site and ``(where, fields)`` of each row of a text schedule's lines, read as TOAST's
    reader does (comments and lines holding "SPECIAL" skipped)."""
    site, rows, version = None, [], None
    for number, line in enumerate(lines, start=1):
        if line.startswith("#") or not line.strip() or "SPECIAL" in line:
            continue
        where = f"TOAST schedule {path}, line {number}"
        fields = _fields(line)
        if site is None:
            site = _site(fields, where)
            continue
        if len(fields) not in TEXT_VERSIONS:
            raise ScheduleError(f"{where}: {len(fields)} fields; TOAST rows have 9, 11, 22 or 24")
        if version not in (None, TEXT_VERSIONS[len(fields)]):
            raise ScheduleError(f"{where}: {len(fields)} fields, unlike the rows before it")
        version = TEXT_VERSIONS[len(fields)]
        if version[1]:  # dates and times as separate fields
            fields = [f"{fields[0]} {fields[1]}", f"{fields[2]} {fields[3]}", *fields[4:]]
        if version[0] <= 2:  # drop MJDs; keep rotation..el; pass and sub before the fraction
            fields = [*fields[:2], *fields[4:9], fields[-3], fields[-2]]
        rows.append((where, _row(fields, where)))
    if site is None:
        raise ScheduleError(f"TOAST schedule {path} has no site line")
    return site, rows


def _site(fields, where):
    if len(fields) != 5:
        hint = (
            "; 15 fields is SO's master schedule, which load_schedule reads"
            if len(fields) == 15
            else ""
        )
        raise ScheduleError(
            f"{where}: the site line needs 5 fields (site, telescope, latitude, longitude, "
            f"altitude), got {len(fields)}{hint}"
        )
    try:
        lat, lon, alt = (float(x) for x in fields[2:])
        return Site(lat, lon, alt, fields[0], fields[1])
    except (ValueError, TypeError) as err:
        raise ScheduleError(f"{where}: {err}") from None


def _row(fields, where):
    """The fields of one version-4-shaped row: start, stop, rotation, name, az min, az max, el,
    pass, sub."""
    start, stop, rotation, name, azmin, azmax, el, scan, subscan = fields
    try:
        return dict(
            start=_utc(start),
            stop=_utc(stop),
            rotation=float(rotation),
            name=name,
            azmin=float(azmin),
            azmax=float(azmax),
            el=float(el),
            scan_index=_index("pass", scan),
            subscan_index=_index("sub-pass", subscan),
        )
    except ValueError as err:
        raise ScheduleError(f"{where}: {err}") from None


def _index(what, value):
    """A pass or sub-pass number: an integer, never a fraction cut short."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"the {what} {value} is not an integer") from None
    if not number.is_integer() or number < 0:
        raise ValueError(f"the {what} {value} is not an integer >= 0")
    return int(number)


def _utc(text):
    """Seconds since 1970 of a UTC date and time (ISO 8601; a time without a zone is UTC)."""
    when = datetime.fromisoformat(text.strip())
    if when.tzinfo is None:
        when = when.replace(tzinfo=timezone.utc)
    return when.timestamp()


def _read_ecsv(path):
    from astropy import units as u
    from astropy.table import Table

    try:
        table = Table.read(path, format="ascii.ecsv")
    except Exception as err:  # astropy raises many kinds for a malformed table
        raise ScheduleError(f"TOAST schedule {path} is not a readable ECSV table: {err}") from None
    missing = [c for c in ECSV_COLUMNS if c not in table.colnames]
    if missing:
        raise ScheduleError(f"TOAST schedule {path}: missing ECSV columns {missing}")

    def value(where, quantity, unit):
        try:
            return u.Quantity(quantity, unit).to_value(unit)
        except (TypeError, ValueError) as err:  # UnitConversionError is a ValueError
            raise ScheduleError(f"TOAST schedule {path}, {where}: {err}; it needs {unit}") from None

    meta = table.meta
    position = {
        key: float(value(f"metadata {key}", meta.get(key, 0.0), unit))
        for key, unit in (("site_lat", u.deg), ("site_lon", u.deg), ("site_alt", u.m))
    }
    try:
        site = Site(
            position["site_lat"],
            position["site_lon"],
            position["site_alt"],
            str(meta.get("site_name", "site")),
            str(meta.get("telescope_name", "telescope")),
        )
    except (ValueError, TypeError) as err:
        raise ScheduleError(f"TOAST schedule {path}, metadata: {err}") from None
    angles = {
        c: value(f"column {c}", table[c].quantity, u.deg)
        for c in ("boresight_angle", "azmin", "azmax", "el")
    }
    rows = []
    for i, row in enumerate(table):
        fields = [
            str(row["start_time"]),
            str(row["stop_time"]),
            angles["boresight_angle"][i],
            str(row["name"]),
            angles["azmin"][i],
            angles["azmax"][i],
            angles["el"][i],
            row["scan_index"],
            row["subscan_index"],
        ]
        where = f"TOAST schedule {path}, row {i + 1}"
        rows.append((where, _row(fields, where)))
    return site, rows


def _ces(motion, start, stop, rotation, name, azmin, azmax, el, scan_index, subscan_index):
    """A CES from a TOAST row: the azimuth range wraps upwards past 360 deg as in TOAST."""
    validation.number("el", el, 0.0, 90.0)
    if not 0 < el < 90:
        raise ValueError(f"el = {el} must lie in (0, 90) deg")
    for key, value in (("azmin", azmin), ("azmax", azmax), ("rotation", rotation)):
        validation.number(key, value)
    speed, limit = motion.mount_speed(el), CES_LIMITS["speed_deg_s"][1]
    if speed > limit:
        how = "on the sky" if motion.rate_on_sky else "of the mount"
        raise ValueError(
            f"el = {el:g} deg: the scan rate {motion.rate_deg_s:g} deg/s {how} turns the mount at "
            f"{speed:.4g} deg/s (rate / cos el), above {limit:g} deg/s; lower --scan-rate or give "
            "it as the mount's (--rate-on mount)"
        )
    if azmax < azmin:
        azmax += 360.0
    return CES(
        start_unix=start,
        duration_s=stop - start,
        elevation_deg=el,
        az_centre_deg=0.5 * (azmin + azmax),
        az_throw_deg=azmax - azmin,
        speed_deg_s=motion.mount_speed(el),
        boresight_deg=rotation,
        turnaround_s=motion.turnaround_s(el),
        name=name,
        scan_index=scan_index,
        subscan_index=subscan_index,
    )


def rows(schedule: Schedule) -> list[dict]:
    """One TOAST row per CES and boresight repeat, the repeats as explicit rows.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule

    Returns
    -------
    list of dict
        start, stop [datetime, UTC], rotation, azmin, azmax, el [deg], name, scan_index,
        subscan_index; in observing order (the CES set once per repeat angle).

    Notes
    -----
    ``SimGround`` names each observation's session ``name-pass-subpass`` and, when a session
    repeats the one before, re-uses its pointing: every row would then be simulated as the first.
    So where two rows share (name, scan_index, subscan_index), as every CES of a boresight TOML
    or CSV schedule does ("ces", 0, 0) and as a repeat does its CES, each row's pass becomes its
    place in observing order, 0, 1, 2, ... (the sub-passes kept); labels that are already unique
    are written as they are.
    """
    expanded = schedule.expanded()
    labels = [(c.name, c.scan_index, c.subscan_index) for c in expanded]
    unique = len(set(labels)) == len(labels)
    return [
        dict(
            start=datetime.fromtimestamp(c.start_unix, timezone.utc),
            stop=datetime.fromtimestamp(c.start_unix + c.duration_s, timezone.utc),
            rotation=c.boresight_deg,
            name=c.name,
            azmin=c.az_centre_deg - 0.5 * c.az_throw_deg,
            azmax=c.az_centre_deg + 0.5 * c.az_throw_deg,
            el=c.elevation_deg,
            scan_index=c.scan_index if unique else i,
            subscan_index=c.subscan_index,
        )
        for i, c in enumerate(expanded)
    ]


def _time(when):
    """TOAST's date format, with microseconds only where the time has them."""
    return when.strftime(_DATE + (".%f" if when.microsecond else ""))


def text(schedule: Schedule) -> str:
    """A schedule in TOAST's newest text format (version 4, ``|``-separated).

    Parameters
    ----------
    schedule : boresight.schedule.Schedule

    Returns
    -------
    str
        The file's text; angles to 1e-8 deg, times to the microsecond.

    Raises
    ------
    boresight.schedule.ScheduleError
        A name TOAST's readers would not read back (:func:`check_names`).
    """
    check_names(schedule)
    s = schedule.site
    lines = [
        "# Site | Telescope | Latitude [deg] | Longitude [deg] | Elevation [m]",
        f"{s.name} | {s.telescope} | {s.lat_deg:.8f} | {s.lon_deg:.8f} | {s.alt_m:.3f}",
        "# Start time UTC | Stop time UTC | Rotation | Patch name | Az min. | Az max. | Elev. | "
        "Pass | Sub",
    ]
    for r in rows(schedule):
        lines.append(
            f"{_time(r['start'])} | {_time(r['stop'])} | {r['rotation']:.8f} | {r['name']} | "
            f"{r['azmin']:.8f} | {r['azmax']:.8f} | {r['el']:.8f} | {r['scan_index']} | "
            f"{r['subscan_index']}"
        )
    return "\n".join(lines) + "\n"


def check_names(schedule: Schedule) -> None:
    """Refuse the names a TOAST text schedule cannot carry: TOAST's reader skips every line that
    holds "SPECIAL" (a row, or the site line, after which it reads the first row as the site) and
    strips the spaces around each field.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule

    Raises
    ------
    boresight.schedule.ScheduleError
        Naming the site, the telescope or the CES (by its row in observing order).
    """
    s = schedule.site
    names = [("the site name", s.name), ("the telescope name", s.telescope)]
    names += [(f"CES row {i + 1}'s name", c.name) for i, c in enumerate(schedule.expanded())]
    for what, name in names:
        if "SPECIAL" in name:
            raise ScheduleError(
                f"{what} {name!r} holds 'SPECIAL': TOAST's schedule readers skip every line "
                "that does; rename it (or write ECSV, *.ecsv)"
            )
        if name != name.strip():
            raise ScheduleError(
                f"{what} {name!r} starts or ends with spaces, which TOAST's readers drop"
            )


def write(schedule: Schedule, path: str | os.PathLike) -> None:
    """Write a schedule for TOAST: ECSV where the name ends in ``.ecsv``, else version-4 text.

    The file is complete or absent: it is written under a temporary name and renamed.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    path : str or os.PathLike
    """

    if not str(path).lower().endswith(".ecsv"):
        write_text(path, text(schedule))
        return
    from astropy import units as u
    from astropy.table import QTable

    table = QTable()
    data = rows(schedule)
    for column in ECSV_COLUMNS:
        key = {"start_time": "start", "stop_time": "stop", "boresight_angle": "rotation"}.get(
            column, column
        )
        values = [r[key] for r in data]
        if column in ("start_time", "stop_time"):
            values = [v.isoformat() for v in values]
        angle = column in ("boresight_angle", "azmin", "azmax", "el")
        table[column] = np.asarray(values) * u.deg if angle else values
    s = schedule.site
    table.meta.update(
        site_name=s.name,
        telescope_name=s.telescope,
        site_lat=s.lat_deg * u.deg,
        site_lon=s.lon_deg * u.deg,
        site_alt=s.alt_m * u.m,
    )
    with atomic_path(path) as tmp:
        table.write(tmp, format="ascii.ecsv", overwrite=True)


def simground_settings(schedule: Schedule) -> tuple[dict, list[str]]:
    """The ``SimGround`` settings that move the mount as the schedule's CESs do.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule

    Returns
    -------
    settings : dict
        ``scan_rate_az`` [deg/s], ``fix_rate_on_sky``, ``scan_accel_az`` [deg/s^2] and the focal
        plane's ``sample_rate`` [Hz].
    notes : list of str
        What a single ``SimGround`` cannot reproduce (CESs at different rates, instantaneous
        turnarounds); empty when it reproduces the scan exactly.
    """
    ces = schedule.ces
    sky = [c.speed_deg_s * math.cos(math.radians(c.elevation_deg)) for c in ces]
    notes = []
    if _same(sky):
        settings = dict(scan_rate_az=sky[0], fix_rate_on_sky=True)
    else:
        settings = dict(scan_rate_az=ces[0].speed_deg_s, fix_rate_on_sky=False)
        if not _same([c.speed_deg_s for c in ces]):
            notes.append(
                "the CESs scan at different rates, on the sky and on the mount; SimGround has "
                "one rate (the first CES's is given)"
            )
    accel = [2 * c.speed_deg_s / c.turnaround_s for c in ces if c.turnaround_s > 0]
    if len(accel) < len(ces):
        notes.append(
            "some CESs reverse instantly (turnaround_s = 0); SimGround always decelerates, "
            "taking 2 v / a per turnaround"
        )
    if accel and not _same(accel):
        notes.append("the CESs turn around at different accelerations (the first is given)")
    settings["scan_accel_az"] = accel[0] if accel else 1.0
    settings["sample_rate"] = schedule.sample_rate_hz
    return settings, notes


def _same(values, rtol=1e-9):
    return max(values) - min(values) <= rtol * max(abs(v) for v in values)


def simground_code(schedule: Schedule, schedule_file: str) -> str:
    """Python lines that simulate the schedule's scan with TOAST, for the user to paste.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    schedule_file : str
        The TOAST schedule written for it.

    Returns
    -------
    str
    """
    settings, notes = simground_settings(schedule)
    lines = [f"# {note}" for note in notes] + [
        f"# focal plane sample_rate = {settings['sample_rate']:g} * u.Hz",
        "schedule = toast.schedule.GroundSchedule()",
        f"schedule.read({schedule_file!r})",
        "sim_ground = toast.ops.SimGround(",
        "    schedule=schedule,",
        f"    scan_rate_az={settings['scan_rate_az']!r} * u.degree / u.second,",
        f"    fix_rate_on_sky={settings['fix_rate_on_sky']},",
        f"    scan_accel_az={settings['scan_accel_az']!r} * u.degree / u.second**2,",
        "    randomize_phase=False,",
        "    track_azimuth=False,",
        ")",
    ]
    return "\n".join(lines)
