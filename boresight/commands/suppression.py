"""``boresight suppression``: every systematic of :data:`boresight.suppression.CATALOGUE` alone
through 0, 0/45, 0/90 and 0/180 deg rotation, simulated and predicted."""

from __future__ import annotations

import argparse
import dataclasses
import logging

from .. import io, plots, provenance, resources, suppression
from ..config import OutputOptions, Study, check_systematics
from ..instrument import Instrument
from ..sky import SkyConfig, make_sky
from ..validation import ConfigError, require_finite
from . import _common

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
    checks : boresight.resources.Checks
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
    for entry in suppression.CATALOGUE:  # every entry, before the first is simulated
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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--force", action="store_true", help="replace an earlier output")
    parser.add_argument("--nside", type=int, default=256, help="HEALPix Nside (lmax = 2 Nside)")
    parser.add_argument("--survey", choices=("deep", "wide"), default="deep")
    parser.add_argument("--fwhm-arcmin", type=float, default=30.0, help="the sky's beam")
    parser.add_argument("--seed", type=int, default=0, help="the sky's seed")


def main(args: argparse.Namespace) -> int:
    try:
        sky_config = SkyConfig(
            nside=args.nside,
            lmax=3 * args.nside - 1,
            fwhm_arcmin=args.fwhm_arcmin,
            seed=args.seed,
        )
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--nside / --fwhm-arcmin / --seed: {err}") from None
    run(
        sky_config,
        args.out,
        survey=args.survey,
        force=args.force,
        progress=_common.progress(args),
        checks=_common.checks(args),
    )
    return 0
