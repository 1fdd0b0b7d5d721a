"""``boresight reproduce``: the paper's study, its figures, results.csv, report.md with a computed
verdict for each claim, and manifest.json."""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import replace

from .. import masks
from .._util import io, provenance
from ..config import RunOptions, Study, add_flags, as_dict, read_toml
from ..jobs import paper, resources
from ..outputs import plots, report
from ..sky import SkyConfig
from ..validation import ConfigError
from . import _common

log = logging.getLogger(__name__)

NAME = "reproduce"
HELP = "the paper's study: figures, results.csv, report.md"
#: the figures of the paper: (experiment, rotation angles, file stem)
FIGURES = (
    ("pointing_wide", [None, 180.0], "fig1_pointing_wide"),
    ("gain_deep", [None, 90.0], "fig2_gain_deep"),
    ("pointing_wide", [None, 180.0, 179.0, 160.0], "fig3_pointing_angles"),
    ("gain_deep", [None, 90.0, 89.0, 70.0], "fig4_gain_angles"),
)


def run(
    out_dir: str,
    study: Study | None = None,
    *,
    force: bool = False,
    progress: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list:
    """Run the paper's study and write figures, results.csv, report.md and manifest.json.

    Parameters
    ----------
    out_dir : str
    study : boresight.config.Study, optional
        :func:`boresight.jobs.paper.preset` (the default, its quick resolution) or
        :func:`boresight.jobs.paper.from_raw`.
    force : bool
        Replace an earlier output of boresight's.
    progress : bool
        Show progress bars.
    checks : boresight.jobs.resources.Checks
        The up-front memory and time checks to make.

    Returns
    -------
    list of boresight.outputs.report.Claim
        With computed verdicts.
    """
    study = paper.preset(quick=True) if study is None else study
    io.check_output_dir(out_dir, force, study.inputs)
    estimate = resources.study_estimate("reproduce", study)
    resources.require(estimate, checks)
    results, stages = paper.run_study(study, progress=progress)
    rows = paper.tidy_rows(results, study)
    claims = report.evaluate_claims(results, rows, study)
    with io.staged_dir(out_dir, force, study.inputs) as stage:
        t0 = time.perf_counter()
        for name, angles, stem in FIGURES:
            res = results[name]
            table = paper.band_table(res, rows, study)
            plots.residual_figure(res, table, study, stage / stem, angles=angles)
        fig_nside = min(study.sky.nside, 256)
        for survey, title, stem in (
            ("wide", "SO-like wide (LAT) footprint", "fig5_wide_mask"),
            ("deep", "SO-like deep (SAT) footprint", "fig6_deep_mask"),
        ):
            plots.footprint_figure(masks.survey_mask(survey, fig_nside), title, stage / stem)
        io.write_csv(stage / "results.csv", rows, paper.CSV_COLUMNS)
        stages["outputs"] = round(time.perf_counter() - t0, 3)
        io.write_text(stage / "report.md", report.report_markdown(claims, study, stages))
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                as_dict(study),
                {"sky": study.sky.seed, "scan": study.scan.seed},
                stages,
                estimate.as_dict(),
            ),
        )
    return claims


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="Nside 512 / lmax 1535 (minutes)")
    parser.add_argument("--config", help="a study file whose [sky], [run], [output] tables apply")
    add_flags(parser, SkyConfig, ("nside", "lmax", "fwhm_arcmin", "seed"), paper_defaults=True)
    add_flags(parser, RunOptions)
    parser.add_argument("--out", default="boresight-paper", help="output directory")
    parser.add_argument(
        "--force", action="store_true", help="overwrite an existing output directory"
    )


def study_of(args: argparse.Namespace) -> Study:
    """The paper's study (:func:`jobs.paper.preset` or a --config file) with the flags applied."""
    raw = read_toml(args.config) if args.config else {}
    study = paper.from_raw(raw, args.quick)
    sky_cfg, run_options = study.sky, study.run
    if args.nside is not None:
        if not 16 <= args.nside <= 8192 or args.nside & (args.nside - 1):
            raise ConfigError(f"--nside must be a power of two in [16, 8192], got {args.nside}")
        lmax = min(3 * args.nside - 1, sky_cfg.lmax) if args.lmax is None else args.lmax
        sky_cfg = _sky_flag(sky_cfg, "nside", nside=args.nside, lmax=lmax)
    for name in ("lmax", "fwhm_arcmin", "seed"):
        if getattr(args, name) is not None:
            sky_cfg = _sky_flag(sky_cfg, name, **{name: getattr(args, name)})
    flags = {f: getattr(args, f) for f in vars(RunOptions()) if getattr(args, f) is not None}
    try:
        run_options = replace(run_options, **flags)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--{str(err).split()[0]}: {err}") from None
    scan = replace(study.scan, seed=sky_cfg.seed) if args.seed is not None else study.scan
    given = "lmax" in raw.get("output", {})
    output = study.output if given else replace(study.output, lmax=None)  # 2 Nside of the sky
    try:
        return replace(study, sky=sky_cfg, scan=scan, run=run_options, output=output)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--nside / --lmax: {err}") from None


def _sky_flag(sky_cfg, flag, **fields):
    try:
        return replace(sky_cfg, **fields)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--{flag.replace('_', '-')}: {err}") from None


def main(args: argparse.Namespace) -> int:
    claims = run(
        args.out,
        study_of(args),
        force=args.force,
        progress=_common.progress(args),
        checks=_common.checks(args),
    )
    bad = [c for c in claims if not c.reproduced]
    log.info(
        "%d of %d claims reproduced; see %s/report.md",
        len(claims) - len(bad),
        len(claims),
        args.out,
    )
    return 1 if bad else 0
