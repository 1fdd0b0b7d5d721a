"""``boresight suppression``: every systematic of :data:`boresight.jobs.suppression.axis.CATALOGUE` alone
through 0, 0/45, 0/90 and 0/180 deg rotation, simulated and predicted; with ``--hwp``, what that
rotation still buys behind a half-wave plate on a real schedule (:mod:`boresight.jobs.suppression.hwp`);
with ``--filter`` and/or ``--deproject``, what it buys a pipeline that filters the pair
differences, or regresses templates of T from them, before binning
(:mod:`boresight.jobs.suppression.filtered`)."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
from typing import TYPE_CHECKING

import numpy as np

from .._util import io, precompile, provenance
from ..config import OutputOptions, RunOptions, Study, check_systematics
from ..constants import ARCMIN
from ..instrument.beams import MIN_AXIS_FWHM
from ..instrument.hwp import HWP, check_sampling
from ..instrument.pairs import Instrument
from ..jobs import resources, suppression
from ..jobs.suppression import filtered as filtered_suppression
from ..jobs.suppression import hwp as hwp_suppression
from ..mitigation import Deprojection, Filtering, ces_scans
from ..mitigation.deprojection import template_alm
from ..outputs import plots
from ..schedule import load_schedule
from ..sky import SkyConfig, make_sky
from ..validation import ConfigError, require_finite
from . import _common

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane

log = logging.getLogger(__name__)

NAME = "suppression"
HELP = "every systematic alone through 0/45/90/180 deg rotation: table and figure"


def run(
    sky_config: SkyConfig,
    out_dir: str,
    *,
    survey: str = "deep",
    force: bool = False,
    progress: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """Every systematic of the catalogue alone through the paper's rotation schedules.

    Writes ``suppression.csv`` (a row per systematic and schedule: the suppression of the
    simulated and the predicted residual in three multipole bands, and the delta_r each fakes),
    ``suppression.md`` (the same, readable), ``suppression.png``/``.pdf`` and ``manifest.json``.

    Parameters
    ----------
    sky_config : boresight.sky.SkyConfig
    out_dir : str
    survey : {"deep", "wide"}
    force : bool
    progress : bool
    checks : boresight.jobs.resources.Checks
        The memory and time checks to make.

    Returns
    -------
    list of dict
        The table's rows.
    """
    if sky_config.nside < suppression.MIN_NSIDE:
        raise ConfigError(
            f"--nside = {sky_config.nside}: the suppression map's first band starts at ell = "
            f"{suppression.bands(1 << 20)[0]}, beyond lmax = 2 Nside = {2 * sky_config.nside}; "
            f"give a power of two >= {suppression.MIN_NSIDE}"
        )
    for entry in suppression.catalogue():  # every entry, before the first is simulated
        try:
            check_systematics(entry.systematics, Instrument(), (0.0, 90.0), sky_config.fwhm_arcmin)
        except ValueError as err:
            raise ConfigError(
                f"--fwhm-arcmin = {sky_config.fwhm_arcmin:g}: the {entry.name} entry "
                f"({entry.amplitude}): {err}"
            ) from None
    study = Study(sky=sky_config, output=OutputOptions(lmax=2 * sky_config.nside, lmin=2))
    estimate = suppression.estimate(study)
    resources.require(estimate, checks)
    io.check_output_dir(out_dir, force)
    timer = provenance.Timer(log)
    with timer("sky"):
        sky = make_sky(sky_config)
    with timer("simulations and predictions"):
        result = suppression.run(sky, survey, progress=progress)
    rows = suppression.table(result, sky_config.nside)
    require_finite("the simulated suppressions", [r["delta_r_sim"] for r in rows])
    with io.staged_dir(out_dir, force) as stage:
        io.write_csv(stage / "suppression.csv", rows, list(rows[0]))
        io.write_text(stage / "suppression.md", suppression.markdown(rows))
        plots.suppression_figure(result, sky_config.nside, stage / "suppression")
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                {"survey": survey, "sky": dataclasses.asdict(sky_config)},
                {"sky": sky_config.seed},
                timer.stages,
                estimate.as_dict(),
            ),
        )
    return rows


def run_hwp(
    sky_config: SkyConfig,
    schedule_path: str,
    plate: HWP,
    out_dir: str,
    *,
    focalplane: FocalPlane | None = None,
    force: bool = False,
    progress: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """What boresight rotation still buys behind a HWP, on a real schedule
    (:mod:`boresight.jobs.suppression.hwp`).

    Writes ``hwp_suppression.csv`` (a row per systematic, plate and boresight schedule: the leaked
    pseudo-C_BB in three bands, the prediction over it and the leak over the first row of its
    systematic), ``hwp_suppression.md``, ``hwp_suppression.png``/``.pdf`` and ``manifest.json``.

    Parameters
    ----------
    sky_config : boresight.sky.SkyConfig
    schedule_path : str
        A schedule file (:func:`boresight.schedule.load_schedule`): its CES set, repeated at each
        boresight schedule's angles.
    plate : boresight.instrument.hwp.HWP
        Continuous or stepped (per CES or per day).
    out_dir : str
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        The pairs, each on its own samples (default the paper's Q and U pairs on the axis).
    force, progress : bool
    checks : boresight.jobs.resources.Checks
        The memory and time checks to make.

    Returns
    -------
    list of dict
        The table's rows.
    """
    _check_hwp_sky(sky_config)
    schedule = load_schedule(schedule_path)
    hwp_suppression.check_plate(plate)
    check_sampling(plate, schedule.sample_rate_hz)
    inputs = [schedule_path, *(focalplane.files if focalplane is not None else [])]
    io.check_output_dir(out_dir, force, inputs)
    once = dataclasses.replace(schedule, repeat_boresight_deg=(0.0,))
    estimate = resources.schedule_estimate(
        "hwp-suppression",
        once,
        sky_config.nside,
        lmax=sky_config.lmax,
        n_pairs=2 if focalplane is None else focalplane.n_pairs,
        tod_runs=hwp_suppression.tod_runs(),
    )
    resources.require(estimate, checks)
    timer = provenance.Timer(log)
    kernels = precompile.kernels_for("validation", pointing=True)  # before the stages: Ctrl-C
    precompile.precompile(kernels + precompile.kernels_for("focalplane-stats"), timer=timer)
    with timer("sky"):
        sky = make_sky(sky_config)
    with timer("simulations and predictions"):
        result = hwp_suppression.run(schedule, sky, plate, focalplane=focalplane, progress=progress)
    with io.staged_dir(out_dir, force, inputs) as stage:
        io.write_csv(stage / "hwp_suppression.csv", result.rows, list(result.rows[0]))
        io.write_text(stage / "hwp_suppression.md", hwp_suppression.markdown(result.rows))
        plots.hwp_suppression_figure(result, stage / "hwp_suppression")
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                {
                    "schedule": schedule_path,
                    "hwp": dataclasses.asdict(plate),
                    "sky": dataclasses.asdict(sky_config),
                    "focalplane": None if focalplane is None else focalplane.names,
                },
                {"sky": sky_config.seed},
                timer.stages,
                estimate.as_dict(),
            ),
        )
    return result.rows


def run_filtered(
    sky_config: SkyConfig,
    schedule_path: str,
    filtering: Filtering,
    out_dir: str,
    *,
    focalplane: FocalPlane | None = None,
    scattered: bool = False,
    depth_uk_arcmin: float = filtered_suppression.DEPTH_UK_ARCMIN,
    force: bool = False,
    progress: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """What boresight rotation buys a pipeline that filters (and/or deprojects) before binning, on
    a real schedule (:mod:`boresight.jobs.suppression.filtered`); a deprojection of T's
    derivatives evaluates the sky exactly. Writes ``filtered_suppression.csv``/``.md``/``.png``,
    the filter's transfer function (``transfer.csv``/``.npz``/``.png``), ``sky_kept.csv`` and
    ``manifest.json``.

    Parameters
    ----------
    sky_config : boresight.sky.SkyConfig
    schedule_path : str
        A schedule file (:func:`boresight.schedule.load_schedule`): its CES set, repeated at each
        boresight schedule's angles.
    filtering : boresight.mitigation.Filtering
    out_dir : str
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        The pairs, each on its own samples (default: the paper's pairs on the axis).
    scattered : bool
        The systematics drawn per pair (:data:`boresight.jobs.suppression.filtered.SCATTERED`: a
        gain and a pointing offset scattered over the pairs) in place of the paper's four
        (:data:`~boresight.jobs.suppression.filtered.CASES`).
    depth_uk_arcmin : float
        The survey's white polarisation depth [muK arcmin] over the footprint's sky fraction:
        each row's delta_r is read against its pipeline's sigma(r).
    force, progress : bool
    checks : boresight.jobs.resources.Checks

    Returns
    -------
    list of dict
        The table's rows.
    """
    cases = filtered_suppression.SCATTERED if scattered else filtered_suppression.CASES
    options = dict(focalplane=focalplane, cases=cases, depth_uk_arcmin=depth_uk_arcmin)
    schedule, inputs, estimate = _filtered_inputs(sky_config, schedule_path, filtering, **options)
    io.check_output_dir(out_dir, force, inputs)
    resources.require(estimate, checks)
    timer = provenance.Timer(log)
    kernels = precompile.kernels_for("validation", pointing=True)  # before the stages: Ctrl-C
    precompile.precompile(kernels, timer=timer)
    with timer("sky"):
        sky = make_sky(sky_config)
    exact = filtering.deprojection.derivatives > 0  # T's derivatives follow only an exact sky
    run_options = RunOptions(evaluation="exact") if exact else RunOptions()
    with timer("simulations"):
        result = filtered_suppression.run(
            schedule, sky, filtering, run_options=run_options, progress=progress, **options
        )
    config = {
        "schedule": schedule_path,
        "filter": str(filtering),
        "deprojection_template": filtering.deprojection.template_map,
        "evaluation": run_options.evaluation,
        "sky": dataclasses.asdict(sky_config),
        "focalplane": None if focalplane is None else focalplane.names,
        "systematics": {case.name: case.amplitude for case in cases},
        "noise": dataclasses.asdict(result.noise),
    }
    manifest = provenance.manifest(
        config, {"sky": sky_config.seed}, timer.stages, estimate.as_dict()
    )
    with io.staged_dir(out_dir, force, inputs) as stage:
        _write_filtered(stage, result, manifest)
    verdict = filtered_suppression.verdict
    print(verdict(result.rows, result.kept, noise=result.noise, transfer=result.transfer))
    return result.rows


def _filtered_inputs(sky_config, schedule_path, filtering, *, focalplane, cases, depth_uk_arcmin):
    """(the schedule, the input files, the estimate) of the filtered table, every option checked
    against the sky, the schedule and the template map before any work."""
    if not (np.isfinite(depth_uk_arcmin) and 1e-6 <= depth_uk_arcmin <= 1e6):
        raise ConfigError(f"--depth-uk-arcmin {depth_uk_arcmin:g}: give a depth in [1e-6, 1e6]")
    if sky_config.nside < hwp_suppression.MIN_NSIDE:
        raise ConfigError(
            f"--nside = {sky_config.nside}: the table's bands start at ell = 30; give a power of "
            f"two >= {hwp_suppression.MIN_NSIDE}"
        )
    schedule = load_schedule(schedule_path)
    try:
        ces_scans(filtering, schedule)
    except ValueError as err:
        raise ConfigError(f"--filter {filtering}: {err}") from None
    inputs = [schedule_path, *(focalplane.files if focalplane is not None else [])]
    template = filtering.deprojection.template_map
    if template is not None:  # the map against the sky and the frame, before any work
        try:
            template_alm(
                template, nside=sky_config.nside, lmax=sky_config.lmax, frame=schedule.frame
            )
        except ValueError as err:
            raise ConfigError(f"--deproject-template: {err}") from None
        inputs.append(template)
    estimate = resources.schedule_estimate(
        "deprojected-suppression" if filtering.deprojection.derivatives else "filtered-suppression",
        dataclasses.replace(schedule, repeat_boresight_deg=(0.0,)),
        sky_config.nside,
        lmax=sky_config.lmax,
        n_pairs=2 if focalplane is None else focalplane.n_pairs,
        tod_runs=filtered_suppression.tod_runs(
            cases=cases, deprojects=bool(filtering.deprojection)
        ),
    )
    return schedule, inputs, estimate


def _write_filtered(stage, result, manifest):
    """Write ``filtered_suppression.csv`` (a row per systematic, pipeline and boresight schedule:
    the leaked pseudo-C_BB in three bands, over the same schedule's raw leak, that over the
    filter's F_BB and over its own pipeline's unrotated leak), ``filtered_suppression.md``,
    ``filtered_suppression.png``/``.pdf``, the filter's transfer function (``transfer.csv``, a row
    per band and pair of fields; ``transfer.npz``, its matrix T[to, from, band], error, edges and
    field pairs; ``transfer.png``/``.pdf``), ``sky_kept.csv`` (per pipeline and boresight
    schedule, the sky's own pseudo-C_EE and C_BB per band over the raw pipeline's; for a pipeline
    that only deprojects, beside them the share the spin rule predicts) and
    ``manifest.json`` into ``stage``."""
    io.write_csv(stage / "filtered_suppression.csv", result.rows, list(result.rows[0]))
    io.write_text(stage / "filtered_suppression.md", filtered_suppression.markdown(result.rows))
    io.write_csv(stage / "sky_kept.csv", result.kept, list(result.kept[0]))
    plots.filtered_suppression_figure(result, stage / "filtered_suppression")
    transfer = result.transfer
    io.write_csv(stage / "transfer.csv", transfer.rows(), list(transfer.rows()[0]))
    io.write_npz(
        stage / "transfer.npz",
        edges=transfer.edges,
        matrix=transfer.matrix,
        error=transfer.error,
        field_pairs=np.array(transfer.fields),
        n_sims=transfer.n_sims,
    )
    plots.transfer_figure(transfer, stage / "transfer")
    io.write_json(stage / "manifest.json", manifest)


def _check_hwp_sky(sky_config):
    """Refuse a sky the HWP table's bands or beams cannot take, before any work."""
    if sky_config.nside < hwp_suppression.MIN_NSIDE:
        raise ConfigError(
            f"--nside = {sky_config.nside}: the HWP table's bands start at ell = 30; give a power "
            f"of two >= {hwp_suppression.MIN_NSIDE}"
        )
    hwp_suppression.check_resolution(sky_config.nside, sky_config.fwhm_arcmin)


#: the flags of the plate's own cases: flag -> (its HWP field, its values, its help)
PLATE_FLAGS = {
    "--hwp-ip": ("ip", None, "the plate's IP epsilon (1e-3)"),
    "--hwp-angle-offset-deg": ("angle_offset_deg", None, "the plate's angle offset [deg] (0.1)"),
    "--hwp-angle-jitter-deg": (
        "angle_jitter_deg",
        None,
        "the rms of the plate's angle jitter per sample [deg] (0.5)",
    ),
    "--hwp-synchronous-muk": (
        "synchronous_muk",
        2,
        "the plate's synchronous signal at 2 and 4 chi, A_2 A_4 [muK] (1 1)",
    ),
}


def _dest(flag):
    return flag[2:].replace("-", "_")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--force", action="store_true", help="replace an earlier output")
    parser.add_argument(
        "--nside",
        type=int,
        default=256,
        help="HEALPix Nside: the spectra to lmax = 2 Nside, the sky to 3 Nside - 1 (with --hwp "
        "to 2 Nside, as its bench)",
    )
    parser.add_argument("--survey", choices=("deep", "wide"), default="deep")
    parser.add_argument(
        "--fwhm-arcmin",
        type=float,
        default=None,
        help="the sky's beam [arcmin] (30; with --hwp 60, as its bench: its predictions need a "
        "beam of 3 pixels)",
    )
    parser.add_argument("--seed", type=int, default=0, help="the sky's seed")
    _common.hwp_flags(parser)
    for flag, (_, nargs, what) in PLATE_FLAGS.items():
        parser.add_argument(flag, type=float, nargs=nargs, default=None, help=f"with --hwp: {what}")
    parser.add_argument(
        "--schedule",
        help="with --hwp or --filter: the schedule file whose CES set the table repeats "
        "(required there)",
    )
    parser.add_argument(
        "--filter",
        help="what the pipeline filters before binning, e.g. p3+ground: p<order> a polynomial "
        "per throw, ground[<order>] or groundbin<deg> a ground template per CES, -split per scan "
        "direction (boresight.mitigation.Filtering); with --schedule, not with --hwp",
    )
    parser.add_argument(
        "--deproject",
        help="templates of T the pipeline regresses from each pair difference per CES, after "
        "any --filter, e.g. gain,pointing: gain, pointing (x and y), width, ellipticity (plus "
        "and cross), or bk for all six (boresight.mitigation.Deprojection); with --schedule, "
        "not with --hwp; pointing, width and ellipticity evaluate the sky exactly; /<hours>h "
        "regresses per block of that many hours of CESs (bk/10h)",
    )
    parser.add_argument(
        "--deproject-template",
        help="with --deproject: a HEALPix FITS map of T (of the sky's Nside, in the schedule's "
        "frame) to build the templates from, a Planck-like map with its own noise and beam "
        "(default: the simulated sky's own T)",
    )
    parser.add_argument(
        "--depth-uk-arcmin",
        type=float,
        default=None,
        help="with --filter or --deproject: the survey's white polarisation depth [muK arcmin] "
        f"over the footprint, which each delta_r is read against "
        f"({filtered_suppression.DEPTH_UK_ARCMIN:g})",
    )
    _common.focalplane_flag(parser, "; with --hwp or --filter only")
    parser.add_argument(
        "--scattered",
        action="store_true",
        help="with --filter or --deproject: a gain {mean 0, rms 0.01} and a pointing offset "
        "{mean 0.1, rms 0.05} arcmin in directions {mean 0, rms 90} deg drawn per pair, in place "
        "of the paper's four systematics (a focal plane's own, with --focalplane)",
    )


def _filtering(args, plate):
    """The pipeline of ``--filter`` and ``--deproject`` (and its template map), refused with
    what does not go with it, before any work."""
    flag = "--filter" if args.filter is not None else "--deproject"
    if plate is not None:
        raise ConfigError(
            f"{flag} and --hwp: give one of them (a filter behind a plate is to come)"
        )
    given = [f for f in PLATE_FLAGS if getattr(args, _dest(f)) is not None]
    if given:
        raise ConfigError(
            f"{', '.join(given)} with {flag}: the filtered table runs without a plate"
        )
    if args.schedule is None:
        raise ConfigError(f"{flag}: give --schedule, the schedule file the table repeats")
    try:
        filtering = Filtering.parse(args.filter or "none")
    except ValueError as err:
        raise ConfigError(f"--filter: {err}") from None
    if args.deproject is not None:
        try:
            deprojection = Deprojection.parse(args.deproject)
        except ValueError as err:
            raise ConfigError(f"--deproject: {err}") from None
        if filtering.deprojection and deprojection:
            raise ConfigError("--filter deproject(...) and --deproject: give one of them")
        filtering = dataclasses.replace(
            filtering, deprojection=filtering.deprojection or deprojection
        )
    if args.deproject_template is not None:
        if not filtering.deprojection:
            raise ConfigError("--deproject-template: give --deproject too (what to fit)")
        if not os.path.isfile(args.deproject_template):
            raise ConfigError(f"--deproject-template {args.deproject_template}: no such file")
        deprojection = dataclasses.replace(
            filtering.deprojection, template_map=args.deproject_template
        )
        filtering = dataclasses.replace(filtering, deprojection=deprojection)
    if not filtering:
        raise ConfigError(
            f"{flag} none: give a filter (e.g. p3+ground) or templates (e.g. gain,pointing)"
        )
    return filtering


def main(args: argparse.Namespace) -> int:
    plate = _common.hwp(args)
    narrowest = MIN_AXIS_FWHM / ARCMIN  # the beam entries need a sky beam they can analyse
    if args.fwhm_arcmin is not None and not args.fwhm_arcmin >= narrowest:
        raise ConfigError(
            f"--fwhm-arcmin {args.fwhm_arcmin:g}: the table's beam entries act on the sky's beam; "
            f"give at least {narrowest:.2f} arcmin"
        )
    cleaning = args.filter is not None or args.deproject is not None
    on_schedule = plate is not None or cleaning  # the tables of a real schedule
    if args.depth_uk_arcmin is not None and not cleaning:
        raise ConfigError("--depth-uk-arcmin: with --filter or --deproject only")
    if args.scattered and not cleaning:
        raise ConfigError("--scattered: with --filter or --deproject only")
    try:
        sky_config = SkyConfig(
            nside=args.nside,
            lmax=2 * args.nside if on_schedule else 3 * args.nside - 1,
            fwhm_arcmin=(60.0 if on_schedule else 30.0)
            if args.fwhm_arcmin is None
            else args.fwhm_arcmin,
            seed=args.seed,
        )
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--nside / --fwhm-arcmin / --seed: {err}") from None
    if cleaning:
        filtering = _filtering(args, plate)
        depth = args.depth_uk_arcmin
        run_filtered(
            sky_config,
            args.schedule,
            filtering,
            args.out,
            focalplane=_common.focalplane(args),
            scattered=args.scattered,
            depth_uk_arcmin=filtered_suppression.DEPTH_UK_ARCMIN if depth is None else depth,
            force=args.force,
            progress=_common.progress(args),
            checks=_common.checks(args),
        )
        return 0
    if plate is not None:
        if args.schedule is None:
            raise ConfigError("--hwp: give --schedule, the schedule file the HWP table repeats")
        for flag, (field, _, _) in PLATE_FLAGS.items():
            value = getattr(args, _dest(flag))
            if value is not None:
                plate = dataclasses.replace(plate, **{field: value})
        run_hwp(
            sky_config,
            args.schedule,
            plate,
            args.out,
            focalplane=_common.focalplane(args),
            force=args.force,
            progress=_common.progress(args),
            checks=_common.checks(args),
        )
        return 0
    flags = ("--schedule", "--focalplane", *PLATE_FLAGS)
    given = [f for f in flags if getattr(args, _dest(f)) is not None]
    if given:
        also = (
            " (--schedule and --focalplane go with --filter and --deproject too)" if given else ""
        )
        raise ConfigError(f"{', '.join(given)} belong to the HWP table: give --hwp too{also}")
    run(
        sky_config,
        args.out,
        survey=args.survey,
        force=args.force,
        progress=_common.progress(args),
        checks=_common.checks(args),
    )
    return 0
