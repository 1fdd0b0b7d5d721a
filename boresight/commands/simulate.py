"""``boresight simulate``: a study simulated with and without its systematics, its residual
pseudo-C_BB with the h_n prediction, FITS maps, tables and figures."""

from __future__ import annotations

import argparse
import logging

import healpy as hp
import numpy as np

from .. import spectra
from .._util import io, precompile, provenance
from ..config import Study, load_study
from ..jobs import residual, resources
from ..outputs import plots
from ..validation import require_finite
from . import _common

log = logging.getLogger(__name__)

NAME = "simulate"
HELP = "simulate a study from a TOML config"
#: the header comments of the maps' FITS files
MAP_COMMENTS = [
    "I is the input sky's I where Q, U are valid: pair differences do not",
    "measure I. HITS: hits x rotations; RCOND: 2x2 reciprocal condition.",
]


def run(
    study: Study,
    out_dir: str,
    *,
    force: bool = False,
    progress: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """Simulate a study with and without its systematics and predict its residual.

    Writes FITS maps (I, Q, U, HITS, RCOND), spectra.csv (per multipole: the residual, its parts,
    the prediction and the pseudo-spectra of the maps with the systematic), bands.csv (the same
    band columns as a reproduction's results.csv), figures and manifest.json.

    Parameters
    ----------
    study : boresight.config.Study
    out_dir : str
    force : bool
        Replace an earlier output of boresight's.
    progress : bool
        Show progress bars.
    checks : boresight.jobs.resources.Checks
        The up-front memory and time checks to make.

    Returns
    -------
    list of dict
        The per-multipole rows of spectra.csv.
    """
    io.check_output_dir(out_dir, force, study.inputs)
    estimate = resources.study_estimate("simulate", study)
    resources.require(estimate, checks)
    timer = provenance.Timer(log)
    lmax, nthreads = study.output.lmax, study.run.nthreads
    kernels = precompile.kernels_for("study", study.run.backend, study.systematics.has_pointing)
    precompile.precompile(kernels, nthreads, timer)
    with timer("simulate and predict"):
        job, sky, mask = residual.from_study(study, keep_maps=True, progress=progress)
        ref, sim = job.maps
    with timer("spectra"):
        columns = job.columns()
        i_map = np.where(sim.valid, sky.maps[0], 0.0)
        maps = np.array([i_map, *sim.qu])
        pseudo = spectra.pseudo_spectra(
            maps, mask, lmax, nthreads=nthreads, analysis=study.run.analysis
        )
    require_finite("the residual spectrum", job.total)
    require_finite("the pseudo-spectra", pseudo)
    columns.update({f"pseudo_{n}": pseudo[i] for i, n in enumerate(spectra.ORDER)})
    rows = [
        {"ell": ell, **{k: np.nan if v is None else v[ell] for k, v in columns.items()}}
        for ell in range(lmax + 1)
    ]
    bands = residual.band_rows(study.output.edges(), job.columns())
    with io.staged_dir(out_dir, force, study.inputs) as stage:
        if study.output.maps:
            _write_maps(stage, sky, sim, ref)
        io.write_csv(stage / "spectra.csv", rows, ["ell", *columns])
        io.write_csv(stage / "bands.csv", bands, list(bands[0]))
        plots.spectrum_figure(bands, stage / "residual")
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                study.raw,
                {"sky": study.sky.seed, "scan": study.scan.seed},
                timer.stages,
                estimate.as_dict(),
            ),
        )
    return rows


def _write_maps(stage, sky, sim, ref):
    """The maps with and without the systematics, and a figure of their spurious Q and U."""
    for name, m in (
        ("maps_systematics.fits", sim),
        ("maps_reference.fits", ref),
    ):
        io.write_maps(
            stage / name,
            [
                np.where(m.valid, sky.maps[0], hp.UNSEEN),
                m.q,
                m.u,
                m.hits,
                m.rcond,
            ],
            ["I", "Q", "U", "HITS", "RCOND"],
            ["uK", "uK", "uK", "", ""],
            comments=MAP_COMMENTS,
        )
    both = sim.valid & ref.valid
    spurious = [np.where(both, a - b, hp.UNSEEN) for a, b in ((sim.q, ref.q), (sim.u, ref.u))]
    plots.map_figure(spurious, ["Q spurious", "U spurious"], stage / "maps_spurious.png")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="a study file (TOML)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--force", action="store_true", help="replace an earlier output")


def main(args: argparse.Namespace) -> int:
    run(
        load_study(args.config),
        args.out,
        force=args.force,
        progress=_common.progress(args),
        checks=_common.checks(args),
    )
    return 0
