"""SO's SAT master schedule in and out: the file ``schedlib`` reads
(``schedlib.instrument.parse_sequence_from_toast_sat``, simonsobs/scheduler).

``#`` starts a comment anywhere on a line (pandas' ``comment="#"``); every other non-blank line is
one block of 15 ``|``-separated columns::

    start_utc | stop_utc | hwp_dir | rotation | az_min | az_max | el | speed | accel | priority |
    type | pass | sub | uid | patch

Times are UTC; angles degrees. ``rotation`` is the boresight angle, as TOAST's and as boresight's
CES ``boresight_deg`` (``docs/conventions.md``). schedlib scans each block from ``az_min`` through
``|az_max - az_min|`` at ``speed`` [deg/s] turning with ``accel`` [deg/s^2]; boresight's CES takes
them as its azimuth range, its mount speed and a turnaround of 2 speed / accel. ``hwp_dir`` 1 spins
the half-wave plate forward (schedlib: counter-clockwise, positive frequency), 0 reversed.
A block of ``type`` "None" is a time without observation (schedlib's ``NoObsBlock``): kept as
:class:`~boresight.schedule.model.Idle` and written back as read. ``priority``, ``type`` and
``uid`` ride on each CES as labels, verbatim. The file has no site line: the site is SO's
(:data:`~boresight.schedule.model.ATACAMA`).
"""

from __future__ import annotations

import math
import os
from datetime import datetime, timezone

from .._util.io import tomllib, write_text
from ..validation import ScheduleError
from .model import CES, Idle, Schedule, Site
from .toast import file_text

#: the master schedule's columns, in schedlib's order
COLUMNS = (
    "start_utc",
    "stop_utc",
    "hwp_dir",
    "rotation",
    "az_min",
    "az_max",
    "el",
    "speed",
    "accel",
    "priority",
    "type",
    "pass",
    "sub",
    "uid",
    "patch",
)
#: the labels a CES carries from and to the file, verbatim
LABELS = ("priority", "type", "uid")
#: schedlib's type of a block without observation
IDLE_TYPE = "None"
#: the labels written for a CES that has none (a schedule read from another format)
DEFAULT_LABELS = {"priority": "1", "type": "cmb"}


def _data_lines(text):
    """(line number, fields) of each data line: comments cut at ``#``, blank lines skipped."""
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0]
        if line.strip():
            yield number, [x.strip() for x in line.split("|")]


def is_master_schedule(path: str | os.PathLike) -> bool:
    """Whether a file is an SO master schedule: not TOML, and its first data line has 15
    ``|``-separated columns (TOAST's rows have 9, 11, 22 or 24, its site line 5).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    bool
    """
    text = file_text(path)
    if text is None or str(path).lower().endswith((".toml", ".csv", ".ecsv")):
        return False
    try:
        tomllib.loads(text)
        return False
    except tomllib.TOMLDecodeError:
        pass
    first = next(_data_lines(text), None)
    return first is not None and len(first[1]) == len(COLUMNS)


def read(path: str | os.PathLike, *, sample_rate_hz: float = 20.0) -> Schedule:
    """Read an SO SAT master schedule.

    Parameters
    ----------
    path : str or os.PathLike
    sample_rate_hz : float
        Samples per second, which the file does not hold.

    Returns
    -------
    boresight.schedule.Schedule
        One CES per observing block in file order, its blocks without observation as ``idle``,
        at SO's site.

    Raises
    ------
    boresight.schedule.ScheduleError
        Naming the file, the line and the column: a wrong column count, a value that is not a
        number, an unknown ``hwp_dir``, ``az_max`` below ``az_min``, a block that ends before it
        starts, blocks out of time order or overlapping.
    """
    path = str(path)
    text = file_text(path) if os.path.isfile(path) else None
    if text is None:
        raise ScheduleError(f"master schedule {path}: not found or not readable UTF-8 text")
    ces, idle, previous = [], [], None
    for number, fields in _data_lines(text):
        where = f"master schedule {path}, line {number}"
        if len(fields) != len(COLUMNS):
            raise ScheduleError(
                f"{where}: {len(fields)} columns; a master schedule row has {len(COLUMNS)}: "
                + " | ".join(COLUMNS)
            )
        row = dict(zip(COLUMNS, fields))
        start, stop = (_time(where, row, key) for key in ("start_utc", "stop_utc"))
        if stop <= start:
            raise ScheduleError(f"{where}: stop_utc {row['stop_utc']} is not after start_utc")
        if previous is not None and start < previous[0]:
            raise ScheduleError(
                f"{where}: start_utc {row['start_utc']} is before the stop_utc of line "
                f"{previous[1]}; blocks must be in time order and must not overlap"
            )
        previous = (stop, number)
        if row["type"] == IDLE_TYPE:
            idle.append(Idle(start, stop, tuple(row.items())))
            continue
        ces.append(_ces(where, row, start, stop))
    if not ces:
        raise ScheduleError(f"master schedule {path} has no observing blocks")
    try:
        return Schedule(
            tuple(ces), Site(name="atacama", telescope="sat"), sample_rate_hz, idle=tuple(idle)
        )
    except ValueError as err:
        raise ScheduleError(f"master schedule {path}: {err}") from None


def _time(where, row, key):
    try:
        when = datetime.fromisoformat(row[key])
    except ValueError:
        raise ScheduleError(
            f"{where}, column {key}: {row[key]!r} is not a UTC date and time"
        ) from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=timezone.utc)
    return when.timestamp()


def _number(where, row, key):
    try:
        value = float(row[key])
    except ValueError:
        raise ScheduleError(f"{where}, column {key}: {row[key]!r} is not a number") from None
    if not math.isfinite(value):
        raise ScheduleError(f"{where}, column {key}: {row[key]!r} is not finite")
    return value


def _index(where, row, key):
    value = _number(where, row, key)
    if not value.is_integer() or value < 0:
        raise ScheduleError(f"{where}, column {key}: {row[key]!r} is not an integer >= 0")
    return int(value)


def _ces(where, row, start, stop):
    """A CES of one observing row."""
    hwp = _number(where, row, "hwp_dir")
    if hwp not in (0.0, 1.0):
        raise ScheduleError(
            f"{where}, column hwp_dir: {row['hwp_dir']!r}; 1 (forward) or 0 (reversed)"
        )
    az_min, az_max, speed, accel = (
        _number(where, row, k) for k in ("az_min", "az_max", "speed", "accel")
    )
    if az_max < az_min:
        raise ScheduleError(
            f"{where}, column az_max: {row['az_max']} is below az_min {row['az_min']}; schedlib "
            "scans from az_min through |az_max - az_min|: give az_max above az_min (past 360)"
        )
    if accel <= 0 or speed <= 0:
        raise ScheduleError(f"{where}, columns speed and accel: both must be > 0")
    for key in ("uid", "type", "patch"):
        _check_label(where, key, row[key])
    try:
        return CES(
            start_unix=start,
            duration_s=stop - start,
            elevation_deg=_number(where, row, "el"),
            az_centre_deg=0.5 * (az_min + az_max),
            az_throw_deg=az_max - az_min,
            speed_deg_s=speed,
            boresight_deg=_number(where, row, "rotation"),
            turnaround_s=2.0 * speed / accel,
            name=row["patch"],
            scan_index=_index(where, row, "pass"),
            subscan_index=_index(where, row, "sub"),
            hwp_dir=int(hwp),
            labels=tuple((k, row[k]) for k in LABELS),
        )
    except ValueError as err:
        raise ScheduleError(f"{where}: {err}") from None


def _check_label(where, key, value):
    """schedlib strips ``uid``, ``type`` and ``patch`` as text: a number there breaks its
    reader (pandas reads it as one), and ``|`` or ``#`` would break the row."""
    try:
        float(value)
        numeric = True
    except ValueError:
        numeric = False
    if numeric or not value or "|" in value or "#" in value or "\n" in value:
        raise ScheduleError(
            f"{where}, column {key}: {value!r}; schedlib reads it as text: it must be non-empty, "
            "not a number, and hold no '|' or '#'"
        )


def _utc(seconds):
    when = datetime.fromtimestamp(seconds, timezone.utc)
    return when.strftime("%Y-%m-%d %H:%M:%S" + (".%f" if when.microsecond else ""))


def _g(value):
    """A number as written: 10 significant digits, the file's own text when it had fewer."""
    return f"{value:.10g}"


def rows(schedule: Schedule) -> list[dict]:
    """The master schedule's rows of a schedule: its CESs in observing order, with its idle
    blocks, sorted by start.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule

    Returns
    -------
    list of dict
        Each row's 15 columns as text.

    Raises
    ------
    boresight.schedule.ScheduleError
        Rows that overlap in time (a schedule with boresight repeats, whose repeats share their
        CESs' times), a CES without turnaround time (schedlib needs an acceleration), a label
        schedlib cannot read.
    """
    out = []
    for i, c in enumerate(schedule.expanded()):
        where = f"CES row {i + 1} (start {_utc(c.start_unix)})"
        if c.turnaround_s <= 0:
            raise ScheduleError(
                f"{where}: turnaround_s = 0; schedlib turns the mount with a finite acceleration: "
                "give the CES its turnaround time"
            )
        labels = {**DEFAULT_LABELS, "uid": f"boresight-{i:06d}", **dict(c.labels)}
        for key in ("uid", "type"):
            _check_label(where, key, labels[key])
        _check_label(where, "patch", c.name)
        row = dict(
            start_utc=_utc(c.start_unix),
            stop_utc=_utc(c.start_unix + c.duration_s),
            hwp_dir=str(c.hwp_dir),
            rotation=_g(c.boresight_deg),
            az_min=_g(c.az_centre_deg - 0.5 * c.az_throw_deg),
            az_max=_g(c.az_centre_deg + 0.5 * c.az_throw_deg),
            el=_g(c.elevation_deg),
            speed=_g(c.speed_deg_s),
            accel=_g(2.0 * c.speed_deg_s / c.turnaround_s),
            priority=labels["priority"],
            type=labels["type"],
            **{"pass": str(c.scan_index)},
            sub=str(c.subscan_index),
            uid=labels["uid"],
            patch=c.name,
        )
        out.append((c.start_unix, c.start_unix + c.duration_s, row))
    out += [(b.start_unix, b.stop_unix, dict(b.fields)) for b in schedule.idle]
    out.sort(key=lambda r: r[0])
    for (_, stop, before), (start, _, after) in zip(out, out[1:]):
        if start < stop:
            raise ScheduleError(
                f"the blocks starting {before['start_utc']} and {after['start_utc']} overlap; a "
                "master schedule lists each block once at its own time (a schedule with "
                "repeat_boresight_deg repeats its CESs' times: give each repeat its own CESs)"
            )
    return [r for _, _, r in out]


def text(schedule: Schedule) -> str:
    """A schedule as an SO SAT master schedule's text.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule

    Returns
    -------
    str
    """
    lines = [
        "# SO SAT master schedule (schedlib.instrument.parse_sequence_from_toast_sat), from boresight",
        "# times UTC; angles deg; rotation = boresight angle (TOAST's); hwp_dir 1 forward, 0 reversed",
        "# " + " | ".join(COLUMNS),
    ]
    lines += [" | ".join(r[k] for k in COLUMNS) for r in rows(schedule)]
    return "\n".join(lines) + "\n"


def write(schedule: Schedule, path: str | os.PathLike) -> None:
    """Write a schedule as an SO SAT master schedule, atomically.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    path : str or os.PathLike
    """
    write_text(path, text(schedule))
