"""``boresight export-schedule``: a schedule written for TOAST (its text format, or ECSV for
``*.ecsv``), and the SimGround call that reproduces boresight's scan from it; or, with
``--to so-master``, SO's SAT master schedule that schedlib reads."""

from __future__ import annotations

import argparse
import logging

from .._util import io
from ..schedule import load_schedule, master, toast
from . import _common

log = logging.getLogger(__name__)

NAME = "export-schedule"
HELP = "write a schedule for TOAST (and print its SimGround) or as SO's master schedule"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("schedule", help="schedule file (TOML, CSV, TOAST or SO master)")
    parser.add_argument("--out", required=True, help="the schedule file to write")
    parser.add_argument(
        "--to",
        choices=("toast", "so-master"),
        default="toast",
        help="TOAST's schedule (text, or ECSV for *.ecsv; default) or SO's SAT master schedule",
    )
    parser.add_argument("--force", action="store_true", help="replace an existing file")
    _common.motion_flags(parser)


def main(args: argparse.Namespace) -> int:
    schedule = load_schedule(args.schedule, _common.motion(args))
    io.check_output_file(args.out, args.force, [args.schedule])
    if args.to == "so-master":
        master.write(schedule, args.out)
        log.info("wrote %d master schedule rows to %s", len(master.rows(schedule)), args.out)
        return 0
    toast.write(schedule, args.out)
    log.info("wrote %d TOAST rows to %s", len(toast.rows(schedule)), args.out)
    print(toast.simground_code(schedule, args.out))
    return 0
