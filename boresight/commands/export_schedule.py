"""``boresight export-schedule``: a schedule written for TOAST (its text format, or ECSV for
``*.ecsv``), and the SimGround call that reproduces boresight's scan from it."""

from __future__ import annotations

import argparse
import logging

from .._util import io
from ..schedule import load_schedule, toast
from . import _common

log = logging.getLogger(__name__)

NAME = "export-schedule"
HELP = "write a schedule for TOAST (text, or ECSV for *.ecsv) and print its SimGround"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("schedule", help="schedule file (TOML, CSV or TOAST)")
    parser.add_argument("--out", required=True, help="the TOAST schedule file to write")
    parser.add_argument("--force", action="store_true", help="replace an existing file")
    _common.motion_flags(parser)


def main(args: argparse.Namespace) -> int:
    schedule = load_schedule(args.schedule, _common.motion(args))
    io.check_output_file(args.out, args.force, [args.schedule])
    toast.write(schedule, args.out)
    log.info("wrote %d TOAST rows to %s", len(toast.rows(schedule)), args.out)
    print(toast.simground_code(schedule, args.out))
    return 0
