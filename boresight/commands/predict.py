"""``boresight predict``: the analytic residual pseudo-C_BB of a study, without a simulation."""

from __future__ import annotations

import argparse
import logging

from .. import masks
from .._util import io, provenance
from ..config import Study, load_study
from ..cosmology import load_spectra
from ..coupling import mask_coupling
from ..jobs import resources
from ..jobs.residual import n_max_for
from ..moments import compute_moments
from ..predict import Prediction, residual_pseudo_bb
from ..validation import ConfigError, require_finite
from . import _common

log = logging.getLogger(__name__)

NAME = "predict"
HELP = "analytic residual pseudo-C_BB of a config, no simulation"


def run(
    study: Study,
    out_dir: str | None = None,
    *,
    force: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """The analytic prediction of a study's residual pseudo-C_BB, from the theory spectra.

    Parameters
    ----------
    study : boresight.config.Study
        Its sky must be the theory's (no sky.maps).
    out_dir : str, optional
        Write prediction.csv and manifest.json there.
    force : bool
    checks : boresight.jobs.resources.Checks
        The up-front memory and time checks to make.

    Returns
    -------
    list of dict
        ell, predicted_bb [muK^2] for ell = 0..output.lmax.
    """
    if study.sky_maps is not None:
        raise ConfigError("predict uses the theory spectra; remove sky.maps from the config")
    if out_dir is not None:
        io.check_output_dir(out_dir, force, study.inputs)
    estimate = resources.study_estimate("predict", study)
    resources.require(estimate, checks)
    nside, lmax = study.sky.nside, study.output.lmax
    mask = masks.from_config(study.mask, nside)
    n_max = n_max_for(study.systematics)
    moments = compute_moments(
        study.scan,
        nside,
        mask > 0,
        n_max=n_max,
        nthreads=study.run.nthreads,
        backend=study.run.backend,
    )
    couplings = mask_coupling(mask, lmax, study.run.nthreads, band=study.sky.lmax)
    pred = residual_pseudo_bb(
        moments.h,
        mask,
        Prediction(load_spectra(), couplings, study.sky.fwhm_arcmin),
        study.systematics,
        instrument=study.instrument,
        rotations_deg=moments.rotations_deg,
        crossings=moments.crossings,
    )
    require_finite("the predicted spectrum", pred)
    rows = [dict(ell=ell, predicted_bb=pred[ell]) for ell in range(lmax + 1)]
    if out_dir is not None:
        with io.staged_dir(out_dir, force, study.inputs) as stage:
            io.write_csv(stage / "prediction.csv", rows, ["ell", "predicted_bb"])
            io.write_json(
                stage / "manifest.json",
                provenance.manifest(study.raw, {"scan": study.scan.seed}, {}, estimate.as_dict()),
            )
    return rows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="a study file (TOML)")
    parser.add_argument("--out", help="write prediction.csv there (default: print it)")
    parser.add_argument("--force", action="store_true", help="replace an earlier output")


def main(args: argparse.Namespace) -> int:
    rows = run(load_study(args.config), args.out, force=args.force, checks=_common.checks(args))
    if not args.out:
        print("ell,predicted_bb")
        for row in rows:
            print(f"{row['ell']},{row['predicted_bb']:.6e}")
    return 0
