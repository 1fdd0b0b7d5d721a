"""Real telescope schedules: the model (:mod:`~boresight.schedule.model`: sites, CESs, boresight
repeats), boresight's TOML and CSV files (:mod:`~boresight.schedule.files`) and TOAST's text and
ECSV files (:mod:`~boresight.schedule.toast`), SO's SAT master schedule
(:mod:`~boresight.schedule.master`). :mod:`boresight.pointing` turns a schedule into
pointing."""

from ..validation import ScheduleError
from .files import is_schedule, load_schedule, schedule_format, write_schedule
from .model import (
    ATACAMA,
    CES,
    CES_LIMITS,
    CES_METADATA,
    CES_REQUIRED,
    TURNAROUNDS,
    Idle,
    Schedule,
    Site,
)
from .toast import ScanMotion

__all__ = [
    "ATACAMA",
    "CES",
    "CES_LIMITS",
    "CES_METADATA",
    "CES_REQUIRED",
    "Idle",
    "TURNAROUNDS",
    "ScanMotion",
    "Schedule",
    "ScheduleError",
    "Site",
    "is_schedule",
    "load_schedule",
    "schedule_format",
    "write_schedule",
]
