"""Schedule files: boresight's TOML (everything) and CSV (one CES per row), TOAST's (read and
written by :mod:`boresight.schedule.toast`) and SO's SAT master schedule
(:mod:`boresight.schedule.master`), each recognised by its content."""

from __future__ import annotations

import csv
import json
import os
from dataclasses import replace
from typing import TYPE_CHECKING

from .._util import io
from .._util.io import toml_text, tomllib
from ..validation import ScheduleError
from . import master, toast
from .model import CES, CES_LIMITS, CES_METADATA, CES_REQUIRED, Schedule, Site

if TYPE_CHECKING:
    from .toast import ScanMotion


def load_schedule(
    path: str,
    motion: ScanMotion | None = None,
    *,
    frame: str | None = None,
    turnarounds: str | None = None,
) -> Schedule:
    """Read a schedule file: boresight's TOML or CSV, any TOAST schedule, or SO's SAT master
    schedule.

    TOML: optional [site], sample_rate_hz, dut1_s, repeat_boresight_deg and [[ces]] tables of CES
    fields. CSV: a header naming CES fields and one CES per row. Unknown keys or columns are errors.
    A TOAST schedule (text of any version, or ECSV; see :mod:`boresight.schedule.toast`) is
    recognised by its content, whatever its name; so is a master schedule (15 ``|``-separated
    columns, :mod:`boresight.schedule.master`).

    Parameters
    ----------
    path : str or os.PathLike
    motion : boresight.toast.ScanMotion, optional
        Scan rate, acceleration and sample rate of a TOAST schedule, which its file leaves out
        (default: ``SimGround``'s, at 20 Hz); of a master schedule, its sample rate.
        boresight's own formats hold their own.
    frame, turnarounds : str, optional
        Replace the file's (:class:`Schedule`); a TOML schedule may give its own, the others
        take the defaults.

    Returns
    -------
    Schedule

    Raises
    ------
    ScheduleError
        Naming the file, the row (CSV line or [[ces]] number) and the key.
    """
    path = str(path)
    if not os.path.isfile(path):
        raise ScheduleError(f"schedule not found (or not a file): {path}")
    if master.is_master_schedule(path):
        rate = (motion or toast.ScanMotion()).sample_rate_hz
        schedule = master.read(path, sample_rate_hz=rate)
    elif toast.is_toast_schedule(path):
        schedule = toast.read(path, motion or toast.ScanMotion())
    else:
        try:
            schedule = Schedule(_csv_rows(path)) if path.endswith(".csv") else _toml_schedule(path)
        except ScheduleError:
            raise
        except (ValueError, TypeError) as err:
            raise ScheduleError(f"schedule {path}: {err}") from None
    given = {k: v for k, v in (("frame", frame), ("turnarounds", turnarounds)) if v is not None}
    try:
        return replace(schedule, **given)
    except ValueError as err:
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
    if master.is_master_schedule(path) or toast.is_toast_schedule(path):
        return True
    if str(path).endswith(".csv"):
        return True
    try:
        return "ces" in toml_text(path)
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


SCHEDULE_KEYS = (
    "site",
    "ces",
    "sample_rate_hz",
    "dut1_s",
    "repeat_boresight_deg",
    "frame",
    "turnarounds",
)


def _toml_schedule(path):
    try:
        raw = toml_text(path)
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
        raw.get("frame", "icrs"),
        raw.get("turnarounds", "include"),
    )


def schedule_format(path: str) -> str:
    """The format of a schedule file: "so-master", "toast", "csv" or "toml"."""
    if master.is_master_schedule(path):
        return "so-master"
    if toast.is_toast_schedule(path):
        return "toast"
    return "csv" if str(path).endswith(".csv") else "toml"


def write_schedule(schedule: Schedule, path: str, fmt: str) -> None:
    """Write a schedule in one of the formats :func:`load_schedule` reads, atomically.

    Parameters
    ----------
    schedule : Schedule
    path : str
    fmt : {"toml", "csv", "toast", "so-master"}
        TOML keeps everything but the idle blocks and CES labels of a master schedule; CSV holds
        the CESs only (the default site and sample rate), with the repeats as rows; TOAST as
        :func:`boresight.schedule.toast.write`; SO's master schedule as
        :func:`boresight.schedule.master.write`.
    """
    if fmt == "so-master":
        master.write(schedule, path)
        return
    if fmt == "toast":
        toast.write(schedule, path)
        return
    keys = list(CES_LIMITS) + list(CES_METADATA)
    if fmt == "csv":
        rows = [{k: getattr(c, k) for k in keys} for c in schedule.expanded()]
        io.write_csv(path, rows, keys)
        return
    if fmt != "toml":
        raise ValueError(f"schedule format must be toml, csv, toast or so-master, got {fmt!r}")
    s = schedule.site

    def value(v):
        return json.dumps(v) if isinstance(v, str) else repr(v)

    lines = [
        f"sample_rate_hz = {schedule.sample_rate_hz!r}",
        f"dut1_s = {schedule.dut1_s!r}",
        f"repeat_boresight_deg = {list(schedule.repeat_boresight_deg)!r}",
        f"frame = {value(schedule.frame)}",
        f"turnarounds = {value(schedule.turnarounds)}",
        "",
        "[site]",
        *(f"{k} = {value(getattr(s, k))}" for k in ("lat_deg", "lon_deg", "alt_m", "name")),
        f"telescope = {value(s.telescope)}",
    ]
    for c in schedule.ces:
        lines += ["", "[[ces]]", *(f"{k} = {value(getattr(c, k))}" for k in keys)]
    io.write_text(path, "\n".join(lines) + "\n")
