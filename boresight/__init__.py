"""boresight: differential-systematic B-modes and partial boresight rotation for CMB scans.

The pipeline, one module per stage: cosmology -> sky -> scan -> instrument -> engine (tod_cpu /
tod_gpu kernels) -> mapmaking -> masks -> spectra / coupling -> predict -> paper / report -> plots
-> studies / cli.
"""

__version__ = "0.1.0"

from .engine import scan_moments, simulate  # noqa: E402
from .instrument import PAPER_GAIN, PAPER_POINTING, Instrument, Systematics  # noqa: E402
from .scan import SyntheticScan, paper_scan  # noqa: E402
from .sky import Sky, SkyConfig, make_sky  # noqa: E402

__all__ = [
    "simulate",
    "scan_moments",
    "Instrument",
    "Systematics",
    "PAPER_GAIN",
    "PAPER_POINTING",
    "SyntheticScan",
    "paper_scan",
    "Sky",
    "SkyConfig",
    "make_sky",
]
