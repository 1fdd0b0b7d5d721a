"""``boresight sweep``: a grid or list of studies (:mod:`boresight.jobs.sweep`), locally or on a Dask
cluster, resumable, with its results table and the suppression continuum figure."""

from __future__ import annotations

import argparse
import logging

from .._util import tasks
from ..jobs import sweep
from ..outputs import plots
from . import _common

log = logging.getLogger(__name__)

NAME = "sweep"
HELP = "a grid or list of studies, locally or on a Dask cluster"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("sweep_file", help="a sweep file (TOML: a base study and its [sweep])")
    parser.add_argument("--out", required=True, help="output directory (re-running resumes it)")
    parser.add_argument(
        "--scheduler",
        help="Dask scheduler address, or 'serial' for no Dask (default: a local cluster)",
    )
    parser.add_argument("--workers", type=int, default=2, help="local cluster worker processes")
    parser.add_argument("--force", action="store_true", help="replace a different sweep in --out")
    parser.add_argument(
        "--repair",
        action="store_true",
        help="recompute corrupt point files, keep the rest",
    )


def main(args: argparse.Namespace) -> int:
    rows = sweep.run_sweep(
        args.sweep_file,
        args.out,
        scheduler=tasks.check_scheduler(args.scheduler),
        workers=args.workers,
        force=args.force,
        progress=_common.progress(args),
        repair=args.repair,
        checks=_common.checks(args),
    )
    plots.continuum_figure(rows, f"{args.out}/suppression")
    log.info("%d rows in %s/results.csv", len(rows), args.out)
    return 0
