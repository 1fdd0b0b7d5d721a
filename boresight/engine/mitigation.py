"""What a pipeline does to each CES's pair differences before binning, in the engine: the
filters, then the templates regressed per block (:mod:`boresight.mitigation`), for
:func:`boresight.engine.axis.simulate_schedule` and :func:`boresight.engine.focalplane.
simulate_focalplane`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .. import harmonics

# CPU only (not of the contract): the 3x3 maps, and the pair differences a filter acts on
from ..kernels.cpu import bin_detectors, bin_differences
from ..kernels.pixels import ang2pix_array
from ..mitigation import ces_scans
from ..mitigation.deprojection import template_alm

#: the map-makers a cleaned stream bins into: the pair differences' (Q, U), or each detector's
#: own samples' (I, Q, U), every detector's TOD filtered alike (a pipeline's T transfer)
CLEANED_MAPMAKERS = ("pairs", "detectors")


class Cleaning:
    """What a pipeline does to each CES's pair differences before binning: its filters, then its
    templates (filtered as the data are) regressed per block of CESs and subtracted.

    A block's cleaned parts are held until its last CES (one CES by default), then regressed and
    binned: memory is one block's samples, whatever the schedule's length."""

    def __init__(self, filtering, sky, frame):
        self.filtering, self.deprojection = filtering, filtering.deprojection
        self.alm = None  # the templates' T: the sky's own, or a template map's
        if self.deprojection.template_map is not None:
            self.alm = template_alm(
                self.deprojection.template_map,
                nside=sky.nside,
                lmax=harmonics.alm_lmax(sky.alm.shape[-1]),
                frame=frame,
            )

    def check(self, schedule, *, backend, mapmaker, evaluation, hwp=None):
        """Refuse, before any work, what the pipeline cannot run; every CES against the filters
        (its :class:`~boresight.mitigation.CesScan` kept for :meth:`blocks`)."""
        if backend != "cpu" or mapmaker not in CLEANED_MAPMAKERS or hwp is not None:
            raise ValueError(
                f"filtering ({self.filtering}) runs on the CPU backend with the pairs' or the "
                f"detectors' map-maker and no plate, not backend {backend!r}, mapmaker "
                f"{mapmaker!r}" + ("" if hwp is None else ", a HWP")
            )
        if self.deprojection and mapmaker != "pairs":
            raise ValueError(
                f"deprojecting {self.deprojection} regresses its templates from the pair "
                f"differences: the pairs' map-maker, not {mapmaker!r}"
            )
        self.detectors = mapmaker == "detectors"
        if self.deprojection.derivatives and evaluation != "exact":
            raise ValueError(
                f"deprojecting {self.deprojection} fits derivatives of T, which the TOD follows "
                f"only with evaluation 'exact', not {evaluation!r} (interpolated or pixelised "
                "maps differ from their derivatives)"
            )
        self.scans = ces_scans(self.filtering, schedule)

    def blocks(self, schedule):
        """(its name, [(a schedule of one CES of one repeat, its CesScan), ...]) per block of the
        deprojection (:meth:`boresight.mitigation.Deprojection.blocks`), in observing order,
        after :meth:`check`."""
        scans = self.scans
        for repeat in schedule.repeat_boresight_deg:
            for name, members in self.deprojection.blocks(schedule.ces):
                one = [
                    (
                        replace(
                            schedule,
                            ces=(schedule.ces[i],),
                            repeat_boresight_deg=(repeat,),
                            turnarounds="include",
                        ),
                        scans[i],
                    )
                    for i in members
                ]
                yield f"{name} at boresight {repeat:g} deg", one

    def part(self, d, binner, theta, phi, psi, *, scan, schedule, nside):
        """One CES's pair differences d (M, H) of one pointing stream (or, for the detectors'
        map-maker, both detectors' samples, (2M, H)), filtered, with what its block's regression
        and binning need."""
        if self.filtering.filters:
            d = self.filtering.apply(d, scan)
        templates = None
        if self.deprojection:
            templates = binner.templates(self.deprojection, theta, phi, psi, alm=self.alm)
            if self.filtering.filters:
                templates = self.filtering.apply(templates, scan)
        keep = np.ones(d.shape[1], bool) if schedule.turnarounds == "include" else ~scan.turning
        pix = ang2pix_array(nside, theta[keep], phi[keep])
        return d, templates, ~scan.turning, keep, pix

    def bin_block(self, parts, c_s, normal, block):
        """A block's parts (:meth:`part`) and their weights (c, s) regressed together and binned
        into ``normal`` (a block of one CES without a copy)."""

        def joined(items, axis):
            return items[0] if len(items) == 1 else np.concatenate(items, axis=axis)

        d = joined([p[0] for p in parts], 1)
        if self.deprojection:
            templates = joined([p[1] for p in parts], -1)
            fit = joined([p[2] for p in parts], 0)
            d = self.deprojection.apply(d, templates, fit, block=block)
        keep = joined([p[3] for p in parts], 0)
        pix = joined([p[4] for p in parts], 0)
        c, s = (joined([x[k] for x in c_s], 1) for k in (0, 1))
        if self.detectors:  # d holds detector A's samples of every pair, then B's
            a, b = np.split(d[:, keep], 2)
            bin_detectors(pix, c[:, keep], s[:, keep], a, b, normal)
        else:
            bin_differences(pix, c[:, keep], s[:, keep], d[:, keep], normal)
