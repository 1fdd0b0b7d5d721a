"""``boresight compare-scans``: the residual B-mode of a real CES schedule beside its synthetic twin
(paper section 3.1), one pass and with the schedule's boresight repeats."""

from __future__ import annotations

import argparse
import logging
from dataclasses import fields, replace
from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from .. import engine, moments
from .._util import io, provenance
from ..instrument.pairs import PAPER_GAIN, PAPER_POINTING, Instrument, Systematics
from ..jobs import resources
from ..jobs.residual import band_rows, reference_from_maps, residual, simulate_maps
from ..outputs import plots
from ..schedule import load_schedule
from ..sky import SkyConfig, make_sky
from ..spectra import Footprint, log_bins
from ..validation import ConfigError, require_finite
from . import _common

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane
    from ..schedule import ScanMotion

log = logging.getLogger(__name__)

NAME = "compare-scans"
HELP = "residual B-modes of a CES schedule and its twin"
#: the systematic each choice of ``systematic`` runs
SYSTEMATICS = {"gain": PAPER_GAIN, "pointing": PAPER_POINTING}
FIRST_BIN_ELL = 10  #: the first band's lowest ell
MIN_NSIDE = 8  #: the lowest Nside whose lmax = 2 Nside reaches past it


def on_focalplane(systematics: Systematics, focalplane: FocalPlane) -> Systematics:
    """The paper's systematic on a focal plane's pairs: a value given per pair for its Q and U
    pairs (0 and 45 deg) goes to each pair by its angle, the Q pair's where cos 4 gamma > 0."""
    q_like = np.cos(4 * np.radians(focalplane.gamma_deg)) > 0
    per_pair = {}
    for f in fields(systematics):
        value = getattr(systematics, f.name)
        if isinstance(value, tuple) and len(value) == 2:
            per_pair[f.name] = tuple(float(value[0] if q else value[1]) for q in q_like)
    return replace(systematics, **per_pair)


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
        The paper's differential gain or pointing (:data:`SYSTEMATICS`).
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
        (:func:`on_focalplane`). Default: the paper's pairs on the boresight.
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
    try:
        sky_config = SkyConfig(nside=nside, lmax=2 * nside, fwhm_arcmin=fwhm_arcmin, seed=seed)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--nside / --fwhm-arcmin: {err}") from None
    if 2 * nside <= FIRST_BIN_ELL:  # before the simulations, not at the bands after them
        raise ConfigError(
            f"--nside {nside}: the bands start at ell = {FIRST_BIN_ELL}, beyond lmax = 2 Nside = "
            f"{2 * nside}; give --nside {MIN_NSIDE} or more"
        )
    inputs = [schedule_path]
    if focalplane is not None:
        inputs += focalplane.files
    io.check_output_dir(out_dir, force, inputs)
    # the real scan once and with its repeats, each with and without the systematic
    pointed = 0 if focalplane is None else focalplane.n_pairs
    estimate = resources.schedule_estimate(
        "compare-scans", schedule, nside, tod_runs=4, pointed_pairs=pointed
    )
    resources.require(estimate, checks)
    timer = provenance.Timer(log)

    def characterise(scan):
        if focalplane is None:
            return moments.characterise_schedule(scan, nside, tolerance_deg)
        return moments.characterise_focalplane(scan, focalplane, nside, tolerance_deg).combined

    with timer("characterise the schedule"):
        stats = characterise(schedule)
        # The twin takes (N_phi, R) of one pass of the CES set and repeats it at the schedule's
        # boresight angles, as the paper built its synthetic scans.
        single = characterise(schedule.single())
        twin = replace(
            single.synthetic_twin(seed=seed),
            rotations_deg=schedule.repeat_boresight_deg,
        )
        obs = stats.observed
    sky = make_sky(sky_config)
    # One pass of the CES set, and the whole schedule with its boresight repeats, each as the
    # real scan and as its twin: the paper compared the unrotated scans.
    cases = {
        "real_one_pass": schedule.single(),
        "twin_one_pass": replace(twin, rotations_deg=(0.0,)),
        "real": schedule,
        "twin": twin,
    }
    # Validity depends on the crossing angles alone, so the references fix the common mask.
    refs, focal = {}, {name: focalplane if name.startswith("real") else None for name in cases}
    for name, scan in cases.items():
        with timer(f"reference {name.replace('_', ' ')}"):
            refs[name] = simulate_maps(
                sky, scan, Instrument(), Systematics(), pixels=obs, focalplane=focal[name]
            )
    mask = obs.copy()
    for ref in refs.values():
        mask &= ref.valid
    footprint = Footprint(mask.astype(float))
    lmax = 2 * nside
    curves, chosen = {}, SYSTEMATICS[systematic]
    for name, scan in cases.items():
        with timer(f"residual {name.replace('_', ' ')}"):
            reference = reference_from_maps(refs[name], footprint, lmax)
            curves[f"residual_{name}_bb"] = residual(
                sky,
                scan,
                chosen if focal[name] is None else on_focalplane(chosen, focalplane),
                footprint,
                lmax,
                reference=reference,
                focalplane=focal[name],
            ).total
    rows = band_rows(log_bins(FIRST_BIN_ELL, lmax, 12), curves)
    require_finite("the residual spectra", list(curves.values()))
    twin_h, _ = engine.scan_moments(twin, nside, pixels=obs)
    table = [
        dict(scan="real", **stats.survey_means()),
        dict(
            scan="twin",
            pixels=int(obs.sum()),
            **{
                f"mean_abs_h{n}_sq": float(np.mean(np.abs(twin_h[n, obs]) ** 2))
                for n in range(1, 5)
            },
        ),
    ]
    with io.staged_dir(out_dir, force, inputs) as stage:
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
        io.write_csv(stage / "scan_stats.csv", table, list(table[0]))
        io.write_csv(stage / "compare.csv", rows, list(rows[0]))
        plots.compare_figure(rows, systematic, stage / "compare")
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                {
                    "schedule": schedule_path,
                    "frame": schedule.frame,
                    "turnarounds": schedule.turnarounds,
                    "nside": nside,
                    "systematic": systematic,
                    "fwhm_arcmin": fwhm_arcmin,
                    "tolerance_deg": tolerance_deg,
                    "focalplane": None if focalplane is None else focalplane.source,
                },
                {"sky": seed, "twin": seed},
                timer.stages,
                estimate.as_dict(),
            ),
        )
    return rows


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
