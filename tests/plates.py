"""What the half-wave plate's tests share: schedules, skies and the TOD leak of a systematic
behind a plate."""

from helpers import T0

from boresight.schedule import CES, Schedule, Site


def minute_schedule(starts, repeats=(0.0,)):
    """One-minute CESs turning around for 2 s at each end of their 10 deg throws."""
    ces = tuple(CES(T0 + s, 60.0, 50.0, 180.0, 10.0, turnaround_s=2.0) for s in starts)
    return Schedule(ces, Site(-22.958, -67.787, 5200.0), 2.0, repeat_boresight_deg=repeats)


def wide_schedule(repeats):
    """One 10-minute CES over a 60 deg throw, its set repeated ``repeats`` times."""
    ces = (CES(T0, 600.0, 50.0, 180.0, 60.0, turnaround_s=2.0),)
    return Schedule(ces, Site(-22.958, -67.787, 5200.0), 2.0, repeat_boresight_deg=(0.0,) * repeats)
