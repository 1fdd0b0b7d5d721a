"""The simulation engine: sky -> scan -> detectors and systematics -> pair differences -> maps.

One concept per file: :mod:`~boresight.engine.binner` (the hot loop a chunk of hits goes
through, and the maps solved from its sums), :mod:`~boresight.engine.axis` (pairs on the
boresight: synthetic scans, sample streams, schedules filtered before binning, and the scan's
h_n), :mod:`~boresight.engine.focalplane` (a focal plane's pairs, each on its own samples,
behind a plate or filtered) and :mod:`~boresight.engine.mitigation` (the filters and templates
applied CES by CES before binning).
"""

from .axis import scan_moments, simulate, simulate_samples, simulate_schedule, simulate_with_zero_qu
from .binner import DEFAULT_CHUNK_PIXELS, check_samples
from .focalplane import simulate_focalplane

__all__ = [
    "DEFAULT_CHUNK_PIXELS",
    "check_samples",
    "scan_moments",
    "simulate",
    "simulate_focalplane",
    "simulate_samples",
    "simulate_schedule",
    "simulate_with_zero_qu",
]
