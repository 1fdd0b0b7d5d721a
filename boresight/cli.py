"""Command line: `boresight reproduce | simulate | predict | scan-stats | compare-scans | sweep`.

Exit codes: 0 success, 1 a claim of `reproduce` not reproduced, 2 bad input (config, arguments,
output directory, memory), 130 interrupted (Ctrl-C), 143 terminated (SIGTERM); nothing is written
when the input is bad, and an interrupted job leaves no output behind (a sweep keeps its finished
points).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from dataclasses import replace

from . import interrupts

log = logging.getLogger("boresight")


def _parser():
    from .config import RunOptions, add_flags
    from .frames import FRAMES
    from .schedule import TURNAROUNDS
    from .sky import SkyConfig
    from .studies import LAYOUTS

    p = argparse.ArgumentParser(prog="boresight", description=__doc__.splitlines()[0])
    _common_flags(p, default=False)
    # the same flags after the subcommand: unset there, they leave the main parser's value
    common = argparse.ArgumentParser(add_help=False)
    _common_flags(common, default=argparse.SUPPRESS)
    sub = p.add_subparsers(dest="command", required=True)

    def command(name, **kwargs):
        return sub.add_parser(name, parents=[common], **kwargs)

    r = command("reproduce", help="the paper's study: figures, results.csv, report.md")
    r.add_argument("--quick", action="store_true", help="Nside 512 / lmax 1535 (minutes)")
    r.add_argument("--config", help="a study file whose [sky], [run], [output] tables apply")
    add_flags(r, SkyConfig, ("nside", "lmax", "fwhm_arcmin", "seed"), paper_defaults=True)
    add_flags(r, RunOptions)
    r.add_argument("--out", default="boresight-paper", help="output directory")
    r.add_argument("--force", action="store_true", help="overwrite an existing output directory")

    s = command("simulate", help="simulate a study from a TOML config")
    s.add_argument("config")
    s.add_argument("--out", required=True, help="output directory")
    s.add_argument("--force", action="store_true")
    ss = command("scan-stats", help="h_n, hit, N_phi and R maps of a study or a schedule")
    ss.add_argument("config", help="a study config, or a schedule (TOML, CSV or TOAST)")
    ss.add_argument("--out", required=True, help="output directory")
    ss.add_argument("--force", action="store_true")
    ss.add_argument("--nside", type=int, default=128, help="map resolution of a schedule")
    ss.add_argument(
        "--format",
        choices=LAYOUTS,
        default="boresight",
        help="h_n maps as hn_maps.fits, or as SO/SMARTIES {prefix}_cos_{n}/_sin_{n}.fits in "
        "TOAST's psi convention (odd h_n change sign)",
    )
    ss.add_argument("--prefix", default="hn", help="file name prefix of --format so")
    _motion_flags(ss)
    _pointing_flags(ss, FRAMES, TURNAROUNDS)
    sw = command("sweep", help="a grid or list of studies, locally or on a Dask cluster")
    sw.add_argument("sweep_file")
    sw.add_argument("--out", required=True, help="output directory (re-running resumes it)")
    sw.add_argument(
        "--scheduler",
        help="Dask scheduler address, or 'serial' for no Dask (default: a local cluster)",
    )
    sw.add_argument("--workers", type=int, default=2, help="local cluster worker processes")
    sw.add_argument("--force", action="store_true", help="replace a different sweep in --out")
    sw.add_argument(
        "--repair", action="store_true", help="recompute corrupt point files, keep the rest"
    )
    cs = command("compare-scans", help="residual B-modes of a CES schedule and its twin")
    cs.add_argument("schedule", help="schedule file (TOML, CSV or TOAST)")
    cs.add_argument("--out", required=True, help="output directory")
    cs.add_argument("--nside", type=int, default=128)
    cs.add_argument("--systematic", choices=("gain", "pointing"), default="gain")
    cs.add_argument("--fwhm-arcmin", type=float, default=30.0)
    cs.add_argument("--force", action="store_true")
    _motion_flags(cs)
    _pointing_flags(cs, FRAMES, TURNAROUNDS)
    ex = command(
        "export-schedule",
        help="write a schedule for TOAST (text, or ECSV for *.ecsv) and print its SimGround",
    )
    ex.add_argument("schedule", help="schedule file (TOML, CSV or TOAST)")
    ex.add_argument("out", help="the TOAST schedule file to write")
    ex.add_argument("--force", action="store_true", help="replace an existing file")
    _motion_flags(ex)
    de = command(
        "design", help="choose the boresight angles of a schedule against a systematics budget"
    )
    de.add_argument("budget", help="TOML with [systematics], [noise] and [design] tables")
    de.add_argument("schedule", help="schedule file (TOML, CSV or TOAST)")
    de.add_argument("--out", required=True, help="output directory")
    de.add_argument("--force", action="store_true")
    de.add_argument(
        "--no-validate", action="store_true", help="skip the TOD simulation of the design"
    )
    _motion_flags(de)
    _pointing_flags(de, FRAMES, TURNAROUNDS)
    su = command(
        "suppression",
        help="every systematic alone through 0/45/90/180 deg rotation: table and figure",
    )
    su.add_argument("--out", required=True, help="output directory")
    su.add_argument("--nside", type=int, default=256, help="HEALPix Nside (lmax = 2 Nside)")
    su.add_argument("--survey", choices=("deep", "wide"), default="deep")
    su.add_argument("--fwhm-arcmin", type=float, default=30.0, help="the sky's beam")
    su.add_argument("--seed", type=int, default=0, help="the sky's seed")
    su.add_argument("--force", action="store_true")
    pr = command("predict", help="analytic residual pseudo-C_BB of a config, no simulation")
    pr.add_argument("config")
    pr.add_argument("--out", help="write prediction.csv into this directory")
    pr.add_argument("--force", action="store_true")
    return p


def _common_flags(p, default):
    """-q, -v, --no-memory-check and --yes, before or after the subcommand."""
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


def _motion_flags(p):
    """Flags for what a TOAST schedule leaves out; defaults are TOAST SimGround's."""
    g = p.add_argument_group("TOAST schedules (the file does not say how the mount moves)")
    g.add_argument("--scan-rate", type=float, default=1.0, help="azimuth rate [deg/s] (1)")
    g.add_argument(
        "--rate-on",
        choices=("sky", "mount"),
        default="sky",
        help="the rate is on the sky (SimGround's fix_rate_on_sky, default) or the mount's",
    )
    g.add_argument("--scan-accel", type=float, default=1.0, help="turnaround [deg/s^2] (1)")
    g.add_argument("--sample-rate", type=float, default=20.0, help="samples per second (20)")


def _pointing_flags(p, frames, turnarounds):
    """Flags for how a schedule's samples become pointing: the sky frame and the turnarounds."""
    g = p.add_argument_group("schedule pointing")
    g.add_argument(
        "--frame",
        choices=frames,
        help="sky frame of the pointing and the maps (default: the schedule file's, else icrs)",
    )
    g.add_argument(
        "--turnarounds",
        choices=turnarounds,
        help="keep the samples of the turnarounds, or leave them out as TOAST's map-making does "
        "(default: the schedule file's, else include)",
    )


def _motion(args):
    from .schedule import ScanMotion

    return ScanMotion(args.scan_rate, args.rate_on == "sky", args.scan_accel, args.sample_rate)


def _pointing(args):
    """The --frame and --turnarounds given (None: the schedule file's)."""
    return dict(frame=args.frame, turnarounds=args.turnarounds)


def _reproduce_study(args):
    """The paper's study (:func:`paper.preset` or a --config file) with the flags applied."""
    from . import paper
    from .config import ConfigError, RunOptions, read_toml

    raw = read_toml(args.config) if args.config else {}
    study = paper.from_raw(raw, args.quick)
    sky_cfg, run = study.sky, study.run
    if args.nside is not None:
        if not 16 <= args.nside <= 8192 or args.nside & (args.nside - 1):
            raise ValueError(f"--nside must be a power of two in [16, 8192], got {args.nside}")
        lmax = min(3 * args.nside - 1, sky_cfg.lmax) if args.lmax is None else args.lmax
        sky_cfg = replace(sky_cfg, nside=args.nside, lmax=lmax)
    for name in ("lmax", "fwhm_arcmin", "seed"):
        if getattr(args, name) is not None:
            try:
                sky_cfg = replace(sky_cfg, **{name: getattr(args, name)})
            except (TypeError, ValueError) as err:
                raise ConfigError(f"--{name.replace('_', '-')}: {err}") from None
    flags = {f: getattr(args, f) for f in vars(RunOptions()) if getattr(args, f) is not None}
    try:
        run = replace(run, **flags)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--{str(err).split()[0]}: {err}") from None
    scan = replace(study.scan, seed=sky_cfg.seed) if args.seed is not None else study.scan
    given = "lmax" in raw.get("output", {})
    output = study.output if given else replace(study.output, lmax=None)  # 2 Nside of the sky
    return replace(study, sky=sky_cfg, scan=scan, run=run, output=output)


def configure_logging(quiet: bool = False, verbose: bool = False) -> None:
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
    are imported, and acted on between chunks of work (:mod:`boresight.interrupts`).

    Parameters
    ----------
    argv : list of str, optional
        Default: sys.argv[1:].

    Returns
    -------
    int
        The exit code: 0 success, 1 a claim not reproduced, 2 bad input, 130 Ctrl-C, 143 SIGTERM.
    """
    # the command line draws files, never windows (a library leaves a notebook's backend alone)
    os.environ.setdefault("MPLBACKEND", "Agg")
    with interrupts.handled():
        args, done = None, False
        try:
            args = _parser().parse_args(argv)
            configure_logging(args.quiet, args.verbose)
            progress = sys.stderr.isatty() and not args.quiet
            interrupts.check()
            from .resources import Checks

            checks = Checks(memory=not args.no_memory_check, time=not args.yes)
            code = _run(args, progress, checks)
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
        except (OSError, ValueError, TypeError) as err:
            print(f"boresight: error: {err}", file=sys.stderr)
            return 2


def _run(args, progress, checks):
    """Run the parsed command; returns the exit code."""
    from . import studies
    from .config import load_study
    from .schedule import is_schedule
    from .sky import SkyConfig

    if args.command == "reproduce":
        claims = studies.reproduce(
            args.out, _reproduce_study(args), args.force, log.info, progress, checks
        )
        bad = [c for c in claims if not c.reproduced]
        log.info(
            "%d of %d claims reproduced; see %s/report.md",
            len(claims) - len(bad),
            len(claims),
            args.out,
        )
        return 1 if bad else 0
    if args.command == "sweep":
        from . import plots, sweep

        rows = sweep.run_sweep(
            args.sweep_file,
            args.out,
            args.scheduler,
            args.workers,
            args.force,
            log.info,
            progress,
            args.repair,
            checks,
        )
        plots.continuum_figure(rows, f"{args.out}/suppression")
        log.info("%d rows in %s/results.csv", len(rows), args.out)
        return 0
    if args.command == "compare-scans":
        studies.compare_scans(
            args.schedule,
            args.out,
            args.nside,
            args.systematic,
            args.fwhm_arcmin,
            force=args.force,
            log=log.info,
            checks=checks,
            motion=_motion(args),
            **_pointing(args),
        )
        return 0
    if args.command == "design":
        result = studies.design_schedule(
            args.budget,
            args.schedule,
            args.out,
            args.force,
            _motion(args),
            not args.no_validate,
            log.info,
            progress,
            **_pointing(args),
            checks=checks,
        )
        for row in result["strategies"]:
            log.info(
                "%-14s delta_r = %.3g  (%.3g sigma(r))",
                row["strategy"],
                row["delta_r"],
                row["delta_r_over_sigma_r"],
            )
        return 0
    if args.command == "suppression":
        sky_cfg = SkyConfig(
            nside=args.nside, lmax=3 * args.nside - 1, fwhm_arcmin=args.fwhm_arcmin, seed=args.seed
        )
        studies.suppression_map(
            sky_cfg, args.survey, args.out, args.force, log.info, progress, checks
        )
        return 0
    if args.command == "export-schedule":
        from . import io
        from .schedule import load_schedule, toast

        schedule = load_schedule(args.schedule, _motion(args))
        io.check_output_file(args.out, args.force, [args.schedule])
        toast.write(schedule, args.out)
        log.info("wrote %d TOAST rows to %s", len(toast.rows(schedule)), args.out)
        print(toast.simground_code(schedule, args.out))
        return 0
    if args.command == "scan-stats":
        opts = dict(log=log.info, checks=checks, layout=args.format, prefix=args.prefix)
        if is_schedule(args.config):
            motion = _motion(args)
            rows = studies.schedule_stats(
                args.config,
                args.out,
                args.nside,
                motion,
                args.force,
                **opts,
                **_pointing(args),
                progress=progress,
            )
        else:
            rows = studies.scan_stats(load_study(args.config), args.out, args.force, **opts)
        for row in rows:
            log.info("n=%d  <|h_n|^2> = %.4g", row["n"], row["mean_abs_h2"])
        return 0
    study = load_study(args.config)
    if args.command == "simulate":
        studies.simulate(study, args.out, args.force, log.info, progress, checks)
    else:
        rows = studies.predict_study(study, args.out, args.force, log.info, checks)
        if not args.out:
            print("ell,predicted_bb")
            for row in rows:
                print(f"{row['ell']},{row['predicted_bb']:.6e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
