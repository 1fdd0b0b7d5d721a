"""``boresight compare-scans``: the residual B-mode of a real CES schedule beside its synthetic twin
(paper section 3.1), one pass and with the schedule's boresight repeats."""

from __future__ import annotations

import argparse
import logging
from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from .._util import io, provenance
from ..jobs import resources
from ..jobs.compare_scans import FIRST_BIN_ELL, SYSTEMATICS, compare_scans
from ..outputs import plots
from ..schedule import load_schedule
from ..sky import SkyConfig, make_sky
from ..validation import ConfigError
from . import _common

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane
    from ..schedule import ScanMotion

log = logging.getLogger(__name__)

NAME = "compare-scans"
HELP = "residual B-modes of a CES schedule and its twin"
MIN_NSIDE = 8  #: the lowest Nside whose lmax = 2 Nside reaches past it


def run(
    schedule_path: str,
    out_dir: str,
    *,
    nside: int = 128,
    systematic: str = "gain",
    fwhm_arcmin: float = 30.0,
    seed: int = 1,
    tolerance_deg: float = 1.0,
    force: bool = False,
    motion: ScanMotion | None = None,
    frame: str | None = None,
    turnarounds: str | None = None,
    focalplane: FocalPlane | None = None,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """The residual B-mode of a real schedule beside its synthetic twin.

    Writes scan_maps.fits (crossings, N_phi, R, ``|h_1..4|^2``), scan_stats.csv (survey means of
    the real scan and the twin), compare.csv, compare.png/pdf and manifest.json.

    Parameters
    ----------
    schedule_path, out_dir : str
    nside : int
    systematic : {"gain", "pointing"}
        The paper's differential gain or pointing
        (:data:`boresight.jobs.compare_scans.SYSTEMATICS`).
    fwhm_arcmin : float
        The sky's beam.
    seed : int
        The sky's and the twin's.
    tolerance_deg : float
        Crossing angles closer than this count as one in N_phi.
    force : bool
    motion : boresight.schedule.ScanMotion, optional
        For a TOAST schedule: scan rate, acceleration and sample rate.
    frame, turnarounds : str, optional
        Replace the schedule file's (:class:`boresight.schedule.Schedule`).
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        The real scans seen by every pair of this focal plane from its own place, binned into one
        map; the twin takes (N_phi, R) of all its pairs' crossings together, on the paper's Q
        and U pairs at the axis, and the paper's per-pair values go to its pairs by their angles
        (:func:`boresight.jobs.compare_scans.on_focalplane`). Default: the paper's pairs on the
        boresight.
    checks : boresight.jobs.resources.Checks
        The up-front memory and time checks to make.

    Returns
    -------
    list of dict
        The binned residuals of the four scans.
    """
    if systematic not in SYSTEMATICS:
        raise ConfigError(f"--systematic {systematic!r}; allowed: {tuple(SYSTEMATICS)}")
    schedule = load_schedule(schedule_path, motion, frame=frame, turnarounds=turnarounds)
    sky_config = _sky_config(nside, fwhm_arcmin, seed)
    inputs = [schedule_path, *(focalplane.files if focalplane is not None else [])]
    io.check_output_dir(out_dir, force, inputs)
    pairs = 0 if focalplane is None else focalplane.n_pairs  # the real scans' pairs, pointed
    estimate = resources.schedule_estimate(
        "compare-scans", schedule, nside, tod_runs=4, pointed_pairs=pairs
    )
    resources.require(estimate, checks)
    timer = provenance.Timer(log)
    sky = make_sky(sky_config)
    result = compare_scans(
        schedule, sky, systematic, timer=timer, tolerance_deg=tolerance_deg, seed=seed,
        focalplane=focalplane,
    )  # fmt: skip
    options = dict(nside=nside, systematic=systematic, fwhm_arcmin=fwhm_arcmin)
    options.update(tolerance_deg=tolerance_deg, seed=seed, focalplane=focalplane)
    with io.staged_dir(out_dir, force, inputs) as stage:
        _write(result, stage, schedule, systematic)
        io.write_json(
            stage / "manifest.json", _manifest(schedule_path, schedule, options, timer, estimate)
        )
    return result.rows


def _manifest(schedule_path, schedule, options, timer, estimate):
    """The run's manifest: its inputs and options, seeds, stages and estimate."""
    focalplane, seed = options.pop("focalplane"), options.pop("seed")
    return provenance.manifest(
        {
            "schedule": schedule_path,
            "frame": schedule.frame,
            "turnarounds": schedule.turnarounds,
            **options,
            "focalplane": None if focalplane is None else focalplane.source,
        },
        {"sky": seed, "twin": seed},
        timer.stages,
        estimate.as_dict(),
    )


def _sky_config(nside, fwhm_arcmin, seed):
    """The sky's config, refused where lmax = 2 Nside does not reach the first band."""
    try:
        sky_config = SkyConfig(nside=nside, lmax=2 * nside, fwhm_arcmin=fwhm_arcmin, seed=seed)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--nside / --fwhm-arcmin: {err}") from None
    if 2 * nside <= FIRST_BIN_ELL:  # before the simulations, not at the bands after them
        raise ConfigError(
            f"--nside {nside}: the bands start at ell = {FIRST_BIN_ELL}, beyond lmax = 2 Nside = "
            f"{2 * nside}; give --nside {MIN_NSIDE} or more"
        )
    return sky_config


def _write(result, stage, schedule, systematic):
    """scan_maps.fits, scan_stats.csv, compare.csv and the figure into ``stage``."""
    stats, obs, rows = result.stats, result.observed, result.rows
    io.write_maps(
        stage / "scan_maps.fits",
        [stats.hits, stats.n_distinct, stats.range_rad]
        + [np.where(obs, np.abs(stats.h[n]) ** 2, hp.UNSEEN) for n in range(1, 5)],
        [
            "CROSSINGS",
            "N_PHI",
            "RANGE_RAD",
            "ABS_H1_SQ",
            "ABS_H2_SQ",
            "ABS_H3_SQ",
            "ABS_H4_SQ",
        ],
        ["", "", "rad", "", "", "", ""],
        frame=schedule.frame,
    )
    io.write_csv(stage / "scan_stats.csv", result.table, list(result.table[0]))
    io.write_csv(stage / "compare.csv", rows, list(rows[0]))
    plots.compare_figure(rows, systematic, stage / "compare")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("schedule", help="schedule file (TOML, CSV or TOAST)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--force", action="store_true", help="replace an earlier output")
    parser.add_argument("--nside", type=int, default=128, help="HEALPix Nside (lmax = 2 Nside)")
    parser.add_argument("--systematic", choices=tuple(SYSTEMATICS), default="gain")
    parser.add_argument("--fwhm-arcmin", type=float, default=30.0, help="the sky's beam")
    _common.focalplane_flag(parser)
    _common.motion_flags(parser)
    _common.pointing_flags(parser)


def main(args: argparse.Namespace) -> int:
    run(
        args.schedule,
        args.out,
        nside=args.nside,
        systematic=args.systematic,
        fwhm_arcmin=args.fwhm_arcmin,
        force=args.force,
        motion=_common.motion(args),
        focalplane=_common.focalplane(args),
        checks=_common.checks(args),
        **_common.pointing(args),
    )
    return 0
