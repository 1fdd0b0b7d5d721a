"""Mitigation: what a pipeline does to the time-ordered data before binning.

The stage between the simulated pair differences and the map-maker: filters (a Legendre
polynomial per throw or half-scan, :mod:`~boresight.mitigation.polyfilter`; an azimuth template
per CES, :mod:`~boresight.mitigation.groundfilter`) and template deprojection
(:mod:`~boresight.mitigation.deprojection`, BICEP/Keck's templates of T regressed per CES), each a
file of this package; :mod:`~boresight.mitigation.filtering` says which filters a pipeline runs.
A filter acts on a leak exactly as on the sky, since the leak enters the pair difference as
signal does. The engine applies them CES by CES (``engine.simulate_schedule``,
``engine.simulate_focalplane``).
"""

from .deprojection import Deprojection
from .filtering import CesScan, Filtering, ces_scans
from .groundfilter import azimuth_phase, ground_filter, ground_templates
from .polyfilter import legendre_templates, poly_filter

__all__ = [
    "CesScan",
    "Deprojection",
    "Filtering",
    "ces_scans",
    "azimuth_phase",
    "ground_filter",
    "ground_templates",
    "legendre_templates",
    "poly_filter",
]
