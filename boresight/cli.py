"""The ``boresight`` command line: one subcommand per module of :mod:`boresight.commands`.

Exit codes: 0 success, 1 a claim of ``reproduce`` not reproduced, 2 bad input (a
:class:`boresight.validation.BoresightError`: config, arguments, schedule, output directory,
memory or time), 3 a bug in boresight (its traceback is printed), 130 interrupted (Ctrl-C), 143
terminated (SIGTERM). Nothing is written when the input is bad, and an interrupted job leaves no
output behind (a sweep keeps its finished points, a design its best schedule).
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import sys
import traceback

from ._util import interrupts

log = logging.getLogger("boresight")

BAD_INPUT, BUG = 2, 3  #: exit codes
FULL = (errno.ENOSPC, errno.EDQUOT)  #: a full disk or quota: the machine's state, not a bug


def parser() -> argparse.ArgumentParser:
    """The ``boresight`` parser: ``-q``, ``-v``, ``--no-memory-check`` and ``--yes`` before or
    after the subcommand, ``--version``, and each command's own flags."""
    from . import __version__, commands

    p = _Parser(
        prog="boresight",
        description=DESCRIPTION,
        epilog=EXIT_CODES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action="version", version=f"boresight {__version__}")
    _common_flags(p, default=False)
    # the same flags after the subcommand: unset there, they leave the main parser's value
    common = argparse.ArgumentParser(add_help=False)
    _common_flags(common, default=argparse.SUPPRESS)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in commands.ALL:
        parser_ = sub.add_parser(command.NAME, parents=[common], help=command.HELP)
        command.add_arguments(parser_)
        parser_.set_defaults(main=command.main)
    return p


#: what ``boresight --help`` says first, in plain text (the module's docstring is reST)
DESCRIPTION = (
    "How much false B-mode do a CMB telescope's pair-differencing systematics leave, and how much\n"
    "of it does rotating the instrument about its boresight remove? One subcommand per job;\n"
    "'boresight COMMAND --help' lists its flags."
)
EXIT_CODES = (
    "exit codes: 0 success, 1 a claim of 'reproduce' not reproduced, 2 bad input (nothing is\n"
    "written), 3 a bug in boresight (with its traceback), 130 interrupted, 143 terminated."
)


class _Parser(argparse.ArgumentParser):
    """argparse's parser, whose errors are one line naming the flag and where help is, not the
    whole usage (17 lines for a command with many flags)."""

    def error(self, message):
        self.exit(BAD_INPUT, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _common_flags(p, default):
    g = p.add_argument_group("every command")
    g.add_argument("-q", "--quiet", action="store_true", default=default, help="only warnings")
    g.add_argument("-v", "--verbose", action="store_true", default=default, help="debug output")
    g.add_argument(
        "--no-memory-check",
        action="store_true",
        default=default,
        help="run even when the memory estimate exceeds this machine's memory",
    )
    g.add_argument(
        "--yes",
        action="store_true",
        default=default,
        help="run even when the run is estimated to take over an hour",
    )


def configure_logging(*, quiet: bool = False, verbose: bool = False) -> None:
    """boresight's own lines at INFO (WARNING with ``quiet``, DEBUG with ``verbose``); other
    libraries' (healpy's graticule spacing, numba, dask) only from WARNING up.

    Parameters
    ----------
    quiet, verbose : bool
    """
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    log.setLevel(logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO)


def main(argv: list[str] | None = None) -> int:
    """The ``boresight`` command.

    Ctrl-C and SIGTERM are noted from the first line on, before numba and the rest of boresight
    are imported, and acted on between chunks of work (:mod:`boresight._util.interrupts`).

    Parameters
    ----------
    argv : list of str, optional
        Default: sys.argv[1:].

    Returns
    -------
    int
        The exit code (see the module's docstring).
    """

    # the command line draws files, never windows (a library leaves a notebook's backend alone)
    os.environ.setdefault("MPLBACKEND", "Agg")
    with interrupts.handled():
        done = False
        try:
            from .validation import BoresightError

            args = parser().parse_args(argv)
            configure_logging(quiet=args.quiet, verbose=args.verbose)
            interrupts.check()
            code = args.main(args)
            done = True
            interrupts.check()  # a signal after the job's last check
            return code
        except KeyboardInterrupt as err:  # Interrupted, or a library's own KeyboardInterrupt
            stop = err if isinstance(err, interrupts.Interrupted) else interrupts.Interrupted()
            kept = stop.kept or (
                "it came after the outputs were complete" if done else "nothing was written"
            )
            print(f"boresight: {stop.verb}; {kept}", file=sys.stderr)
            return stop.exit_code
        except BoresightError as err:
            print(f"boresight: error: {err}", file=sys.stderr)
            return BAD_INPUT
        except Exception as err:  # a full disk is the machine's state; anything else a bug
            if isinstance(err, OSError) and err.errno in FULL:
                where = f" writing {err.filename}" if err.filename else ""
                print(
                    f"boresight: error: {err.strerror}{where}; nothing was written (an earlier "
                    "output is kept): free some space, or give --out on another disk",
                    file=sys.stderr,
                )
                return BAD_INPUT
            traceback.print_exc()
            print(
                "boresight: internal error: this is a bug in boresight, not in your input; "
                "please report it with the traceback above",
                file=sys.stderr,
            )
            return BUG


if __name__ == "__main__":
    sys.exit(main())
