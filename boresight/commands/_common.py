"""What the commands share: the checks a user may skip, the progress bar's switch, and the flags
of schedule files, focal planes and half-wave plates."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from ..frames import FRAMES
from ..instrument.focalplane import load_focalplane
from ..instrument.hwp import HWP, MODES, STEPS
from ..jobs.resources import Checks
from ..schedule import TURNAROUNDS, ScanMotion
from ..validation import ConfigError


def checks(args: argparse.Namespace) -> Checks:
    """The up-front checks the flags leave on: memory (--no-memory-check), time (--yes)."""
    return Checks(memory=not args.no_memory_check, time=not args.yes)


def progress(args: argparse.Namespace) -> bool:
    """Whether to show progress bars: on a terminal, without -q."""
    return sys.stderr.isatty() and not args.quiet


def motion_flags(parser: argparse.ArgumentParser) -> None:
    """Flags for what a TOAST schedule leaves out; defaults are TOAST SimGround's."""
    g = parser.add_argument_group("TOAST schedules (the file does not say how the mount moves)")
    g.add_argument("--scan-rate", type=float, default=1.0, help="azimuth rate [deg/s] (1)")
    g.add_argument(
        "--rate-on",
        choices=("sky", "mount"),
        default="sky",
        help="the rate is on the sky (SimGround's fix_rate_on_sky, default) or the mount's",
    )
    g.add_argument("--scan-accel", type=float, default=1.0, help="turnaround [deg/s^2] (1)")
    g.add_argument("--sample-rate", type=float, default=20.0, help="samples per second (20)")


def motion(args: argparse.Namespace):
    """The :class:`boresight.schedule.ScanMotion` of the motion flags."""

    try:
        return ScanMotion(args.scan_rate, args.rate_on == "sky", args.scan_accel, args.sample_rate)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--scan-rate, --scan-accel or --sample-rate: {err}") from None


def pointing_flags(parser: argparse.ArgumentParser) -> None:
    """Flags for how a schedule's samples become pointing: the sky frame and the turnarounds."""

    g = parser.add_argument_group("schedule pointing")
    g.add_argument(
        "--frame",
        choices=FRAMES,
        help="sky frame of the pointing and the maps (default: the schedule file's, else icrs)",
    )
    g.add_argument(
        "--turnarounds",
        choices=TURNAROUNDS,
        help="keep the samples of the turnarounds, or leave them out as TOAST's map-making does "
        "(default: the schedule file's, else include)",
    )


def pointing(args: argparse.Namespace) -> dict:
    """The --frame and --turnarounds given (None: the schedule file's)."""
    return dict(frame=args.frame, turnarounds=args.turnarounds)


def focalplane_flag(parser: argparse.ArgumentParser, replaces: str = "") -> None:
    """``--focalplane``: point every pair of a schedule from its place in a focal plane."""
    parser.add_argument(
        "--focalplane",
        help="point every pair from its place: TOAST's focal-plane HDF5, a CSV/TOML table "
        "(name, xi_deg, eta_deg, gamma_deg, pol_angle_deg), 'hexagon:N:WIDTH_DEG' or 'axis' "
        f"(the paper's pairs on the boresight, the default){replaces}",
    )
    parser.add_argument(
        "--rotation-centre",
        metavar="XI0,ETA0",
        help="where in the focal plane the boresight rotation turns about [deg] (sotodlib's "
        "sat_v1 fp_rot_xi0, fp_rot_eta0; default 0,0, its centre)",
    )


def focalplane(args: argparse.Namespace):
    """The :class:`boresight.instrument.focalplane.FocalPlane` of --focalplane (turning about
    --rotation-centre), or None."""
    centre = getattr(args, "rotation_centre", None)
    if not args.focalplane:
        if centre:
            raise ConfigError("--rotation-centre needs --focalplane: it moves the pairs off it")
        return None
    focal = load_focalplane(args.focalplane)
    if centre:
        try:
            xi0, eta0 = (float(x) for x in centre.split(","))
        except ValueError:
            raise ConfigError(f"--rotation-centre {centre!r}: give XI0,ETA0 in degrees") from None
        focal = dataclasses.replace(focal, rotation_centre_deg=(xi0, eta0))
    return focal


def hwp_flags(parser: argparse.ArgumentParser) -> None:
    """Flags of a half-wave plate (:class:`boresight.instrument.hwp.HWP`)."""
    g = parser.add_argument_group("half-wave plate")
    g.add_argument("--hwp", choices=MODES, default="none", help="a HWP (default: none)")
    g.add_argument(
        "--hwp-frequency", type=float, default=2.0, help="a continuous HWP's rotations per second"
    )
    g.add_argument(
        "--hwp-phase-deg", type=float, default=0.0, help="its angle at unix time 0 [deg]"
    )
    g.add_argument(
        "--hwp-angles",
        default="0,22.5,45,67.5",
        help="a stepped HWP's angles in turn, comma-separated [deg]",
    )
    g.add_argument(
        "--hwp-step", choices=STEPS, default="ces", help="when a stepped HWP steps (default: ces)"
    )


def hwp(args: argparse.Namespace):
    """The :class:`boresight.instrument.hwp.HWP` of the HWP flags, or None without one."""
    if args.hwp == "none":
        return None
    try:
        angles = tuple(float(a) for a in args.hwp_angles.split(","))
    except ValueError:
        raise ConfigError(f"--hwp-angles {args.hwp_angles!r}: comma-separated numbers") from None
    return HWP(args.hwp, args.hwp_frequency, args.hwp_phase_deg, angles, args.hwp_step)
