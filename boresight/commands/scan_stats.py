"""``boresight scan-stats``: the h_n, hit, N_phi and R maps of a study's synthetic scan or of a real
schedule, their survey means, in boresight's layout or SO/SMARTIES's."""

from __future__ import annotations

import argparse
import dataclasses
import logging
from typing import TYPE_CHECKING

import numpy as np

from .. import engine, masks
from .. import moments as scanstats
from .._util import io, precompile, provenance, tasks
from ..config import Study, as_dict, load_study
from ..instrument.hwp import check_sampling
from ..jobs import resources
from ..moments.focalplane import time_groups
from ..outputs import hn_maps
from ..outputs.hn_maps import FORMATS, Layout, ScanMaps
from ..schedule import is_schedule, load_schedule
from ..sky import SkyConfig
from ..validation import ConfigError
from . import _common

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane
    from ..instrument.hwp import HWP
    from ..schedule import ScanMotion

log = logging.getLogger(__name__)

NAME = "scan-stats"
HELP = "h_n, hit, N_phi and R maps of a study or a schedule"


def run(
    study: Study,
    out_dir: str,
    *,
    force: bool = False,
    n_max: int = 4,
    layout: Layout = Layout(),
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """Write the h_n, hit, N_phi and R maps of a study's synthetic scan, and their survey means.

    Parameters
    ----------
    study : boresight.config.Study
    out_dir : str
    force : bool
    n_max : int
        Highest moment written.
    layout : Layout
    checks : boresight.jobs.resources.Checks
        The up-front memory and time checks to make.

    Returns
    -------
    list of dict
        n, mean_abs_h2, mean_re, mean_im for n = 1..n_max, in the layout's convention.
    """
    io.check_output_dir(out_dir, force, study.inputs)
    estimate = resources.study_estimate("scan-stats", study)
    resources.require(estimate, checks)
    nside = study.sky.nside
    obs = masks.from_config(study.mask, nside) > 0
    h, crossings = engine.scan_moments(study.scan, nside, pixels=obs, nthreads=study.run.nthreads)
    n_phi, r, _ = study.scan.per_pixel(np.arange(12 * nside**2), 12 * nside**2)
    maps = ScanMaps(h, obs, crossings, n_phi, r)
    return hn_maps.write(
        out_dir,
        maps,
        n_max=n_max,
        inputs=study.inputs,
        force=force,
        layout=layout,
        config=as_dict(study),
        estimate=estimate,
    )


def run_schedule(
    schedule_path: str,
    out_dir: str,
    *,
    nside: int = 128,
    motion: ScanMotion | None = None,
    force: bool = False,
    tolerance_deg: float = 1.0,
    layout: Layout = Layout(),
    frame: str | None = None,
    turnarounds: str | None = None,
    focalplane: FocalPlane | None = None,
    per_detector: bool = False,
    hwp: HWP | None = None,
    scheduler: str | None = "serial",
    workers: int = 2,
    progress: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """:func:`run` for a CES schedule file (boresight's TOML or CSV, or TOAST's); the files of
    each layout, with a focal plane, per detector and behind a plate, are
    :func:`boresight.outputs.hn_maps.write`'s.

    Parameters
    ----------
    schedule_path, out_dir : str
    nside : int
    motion : boresight.schedule.ScanMotion, optional
        For a TOAST schedule: scan rate, acceleration and sample rate.
    force : bool
    tolerance_deg : float
        Crossing angles closer than this count as one in N_phi.
    layout : boresight.outputs.hn_maps.Layout
    frame, turnarounds : str, optional
        Replace the schedule file's (:class:`boresight.schedule.Schedule`).
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        Every pair pointed from its own place (default: every pair on the boresight).
    per_detector : bool
        Each detector's maps as sotodlib's ``Hn`` writes them (SO layout, a focal plane).
    hwp : boresight.instrument.hwp.HWP, optional
        Also the moments h_{n,m} behind it (:data:`boresight.moments.HWP_TERMS`).
    scheduler : str, optional
        Where a focal plane's blocks of pairs run: "serial", None (a local Dask cluster of
        ``workers`` processes) or a Dask scheduler's address.
    workers : int
    progress : bool
    checks : boresight.jobs.resources.Checks

    Returns
    -------
    list of dict
        As :func:`run`.
    """
    layout.check_schedule_outputs(focalplane=focalplane, per_detector=per_detector, hwp=hwp)
    schedule = load_schedule(schedule_path, motion, frame=frame, turnarounds=turnarounds)
    check_sampling(hwp, schedule.sample_rate_hz)  # before the work, not in its first chunk
    layout.check_frame(schedule.frame)
    _check_nside(nside)
    io.check_output_dir(out_dir, force, [schedule_path])
    estimate = _estimate(schedule, nside, focalplane=focalplane, per_detector=per_detector, hwp=hwp)
    resources.require(estimate, checks)
    timer = provenance.Timer(log)
    job = "schedule-stats" if focalplane is None else "focalplane-stats"
    precompile.precompile(precompile.kernels_for(job), timer=timer)
    with timer("characterise the schedule"):
        stats, planes = _characterise(
            schedule, nside, tolerance_deg, focalplane=focalplane, per_pair=per_detector,
            scheduler=scheduler, workers=workers, progress=progress,
        )  # fmt: skip
    plate_moments = _plate_moments(schedule, hwp, nside, focalplane, timer, progress)
    config = _config(schedule_path, schedule, nside, tolerance_deg, focalplane, hwp)
    inputs = [schedule_path, *(focalplane.files if focalplane is not None else [])]
    maps = ScanMaps(stats.h, stats.observed, stats.hits, stats.n_distinct, stats.range_rad)
    return hn_maps.write(
        out_dir, maps, n_max=scanstats.N_MAX, inputs=inputs, force=force, layout=layout,
        config=config, estimate=estimate, planes=planes, hwp_moments=plate_moments,
    )  # fmt: skip


def _check_nside(nside):
    """Refuse an Nside the maps cannot have, before any work."""
    try:
        SkyConfig(nside=nside, lmax=2 * nside)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--nside: {err}") from None


def _plate_moments(schedule, hwp, nside, focalplane, timer, progress):
    """The plate's moments as ``make(each)`` for the writer (None without a plate)."""
    if hwp is None or not hwp.present:
        return None

    def make(each):
        with timer("the HWP's moments"):
            return scanstats.hwp_moments(
                schedule, hwp, nside, focalplane=focalplane, each=each, progress=progress
            )

    return make


def _config(schedule_path, schedule, nside, tolerance_deg, focalplane, hwp):
    """The manifest's config of a schedule's run."""
    config = {
        "schedule": schedule_path,
        "nside": nside,
        "frame": schedule.frame,
        "turnarounds": schedule.turnarounds,
        "tolerance_deg": tolerance_deg,
    }
    if focalplane is not None:
        config["focalplane"] = focalplane.source
    if hwp is not None and hwp.present:
        config["hwp"] = dataclasses.asdict(hwp)
    config["observing_s"] = schedule.n_samples / schedule.sample_rate_hz
    config["sample_rate_hz"] = schedule.sample_rate_hz
    return config


def _estimate(schedule, nside, *, focalplane, per_detector, hwp):
    """The run's memory and time estimate: the pairs pointed, the per-pair maps held at once
    (with ``per_detector`` every pair's; twice over several groups of CESs), the plate's
    moments."""
    pairs = 0 if focalplane is None else focalplane.n_pairs
    observed = scanstats.observed_pixels(schedule, focalplane, nside) if pairs else None
    blocks = (
        scanstats.pair_blocks(pairs, nside, per_pair=per_detector, observed=observed)
        if pairs
        else []
    )
    estimate = resources.schedule_estimate(
        "schedule-stats",
        schedule,
        nside,
        pointed_pairs=pairs,
        # a block's sums (with per_detector: every pair's); over several groups of CESs, those
        # merged so far beside the next group's
        pair_maps=max((len(b) for b in blocks), default=0)
        * (2 if len(time_groups(schedule)) > 1 else 1),
        observed_pixels=observed,
        hwp_terms=len(scanstats.HWP_TERMS) if hwp is not None and hwp.present else 0,
    )
    return estimate


def _characterise(
    schedule, nside, tolerance_deg, *, focalplane, per_pair, scheduler, workers, progress
):
    """The schedule's ScanStats, and with a focal plane its FocalPlaneStats (else None)."""
    if focalplane is None:
        return scanstats.characterise_schedule(
            schedule, nside, tolerance_deg, progress=progress
        ), None
    planes = scanstats.characterise_focalplane(
        schedule,
        focalplane,
        nside,
        tolerance_deg,
        per_pair=per_pair,
        scheduler=scheduler,
        workers=workers,
        progress=progress,
    )
    return planes.combined, planes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="a study file, or a schedule (TOML, CSV or TOAST)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--force", action="store_true", help="replace an earlier output")
    parser.add_argument("--nside", type=int, default=128, help="map resolution of a schedule")
    parser.add_argument(
        "--format",
        choices=FORMATS,
        default="boresight",
        help="h_n maps as hn_maps.fits, as SO/SMARTIES {prefix}_cos_{n}/_sin_{n}.fits in "
        "TOAST's psi convention (odd h_n change sign), or as litebird_sim's "
        "h_maps_det_boresight.h5 (groups 'n,m'; Galactic maps only)",
    )
    parser.add_argument("--prefix", default="hn", help="file name prefix of --format so")
    parser.add_argument(
        "--partial",
        action="store_true",
        help="write every FITS map as a HEALPix partial map of the observed pixels (healpy "
        "reads it back with UNSEEN elsewhere; SMARTIES, which expects 0 there, then needs a mask "
        "within the hits map's pixels)",
    )
    _common.focalplane_flag(parser)
    parser.add_argument(
        "--scheduler",
        default="serial",
        help="with --focalplane: run its blocks of pairs on Dask, 'local' for a local cluster or "
        "a scheduler's address (default: serial, in this process)",
    )
    parser.add_argument("--workers", type=int, default=2, help="local cluster worker processes")
    parser.add_argument(
        "--per-detector",
        action="store_true",
        help="with --focalplane and --format so: each detector's maps, as sotodlib's Hn writes",
    )
    _common.hwp_flags(parser)
    _common.motion_flags(parser)
    _common.pointing_flags(parser)


def main(args: argparse.Namespace) -> int:
    layout = Layout(format=args.format, prefix=args.prefix, partial=args.partial)
    if is_schedule(args.config):
        rows = run_schedule(
            args.config,
            args.out,
            nside=args.nside,
            motion=_common.motion(args),
            force=args.force,
            layout=layout,
            focalplane=_common.focalplane(args),
            per_detector=args.per_detector,
            hwp=_common.hwp(args),
            scheduler=tasks.check_scheduler(None if args.scheduler == "local" else args.scheduler),
            workers=args.workers,
            progress=_common.progress(args),
            checks=_common.checks(args),
            **_common.pointing(args),
        )
    else:
        if args.focalplane or args.per_detector or args.hwp != "none" or args.format == "litebird":
            raise ConfigError(
                "--focalplane, --per-detector, --hwp and --format litebird need a schedule, "
                "not a study"
            )
        rows = run(
            load_study(args.config),
            args.out,
            force=args.force,
            layout=layout,
            checks=_common.checks(args),
        )
    for row in rows:
        log.info("n=%d  <|h_n|^2> = %.4g", row["n"], row["mean_abs_h2"])
    return 0
