"""Mitigation: what a pipeline does to the time-ordered data before binning.

The stage between the simulated pair differences and the map-maker: filters (a Legendre
polynomial per throw or half-scan, :mod:`~boresight.mitigation.polyfilter`; an azimuth template
per CES, :mod:`~boresight.mitigation.groundfilter`) and, to come, template deprojection, each a
file of this package. A filter acts on a leak exactly as on the sky, since the leak enters the
pair difference as signal does. Neither is in the engine's streams yet: each is a function of
one detector's samples, tested equal to TOAST's operator on TOAST's own simulation.
"""

from .filtering import CesScan, Filtering, ces_scans
from .groundfilter import azimuth_phase, ground_filter, ground_templates
from .polyfilter import legendre_templates, poly_filter

__all__ = [
    "CesScan",
    "Filtering",
    "ces_scans",
    "azimuth_phase",
    "ground_filter",
    "ground_templates",
    "legendre_templates",
    "poly_filter",
]
