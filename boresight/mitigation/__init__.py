"""Mitigation: what a pipeline does to the time-ordered data before binning.

The stage between the simulated pair differences and the map-maker: filters (a Legendre
polynomial per throw or half-scan, :mod:`~boresight.mitigation.polyfilter`) and, to come, the
ground template and template deprojection, each a file of this package with its prediction in
:mod:`boresight.predict`. A filter acts on a leak exactly as on the sky, since the leak enters
the pair difference as signal does.
"""

from .polyfilter import legendre_templates, poly_filter

__all__ = ["legendre_templates", "poly_filter"]
