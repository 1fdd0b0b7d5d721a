"""``boresight scan-stats``: the h_n, hit, N_phi and R maps of a study's synthetic scan or of a real
schedule, their survey means, in boresight's layout or SO/SMARTIES's."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import healpy as hp
import numpy as np

from .. import engine, masks
from .. import moments as scanstats
from .._util import interrupts, io, precompile, provenance, tasks
from ..config import Study, as_dict, load_study
from ..instrument.hwp import check_sampling
from ..jobs import resources
from ..outputs import litebird as litebird_maps
from ..outputs import plots
from ..outputs import so as so_maps
from ..schedule import is_schedule, load_schedule
from ..sky import SkyConfig
from ..validation import ConfigError, require_finite
from . import _common

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane
    from ..instrument.hwp import HWP
    from ..schedule import ScanMotion

log = logging.getLogger(__name__)

NAME = "scan-stats"
HELP = "h_n, hit, N_phi and R maps of a study or a schedule"
FORMATS = ("boresight", "so", "litebird")
#: the header COMMENT of boresight-layout h_n maps
BORESIGHT_CONVENTION = "h_n = RE + i IM of <exp(i n psi)>, psi in boresight's convention"
#: the header COMMENT of the HWP's moments
HWP_CONVENTION = "h_n,m = RE_n_m + i IM_n_m of <exp(i(n psi + m chi))>; M = minus"


@dataclass(frozen=True)
class Layout:
    """How the h_n maps are written.

    Parameters
    ----------
    format : {"boresight", "so", "litebird"}
        One FITS table ``hn_maps.fits`` (RE_H1.., IM_H1..) in boresight's psi convention, the
        SO/SMARTIES files of :mod:`boresight.outputs.so` (``{prefix}_cos_{n}.fits``...) in TOAST's,
        or litebird_sim's HDF5 file of :mod:`boresight.outputs.litebird` in boresight's.
    prefix : str
        File name prefix of the SO layout: letters, digits, '_', '-' and '.'.
    """

    format: str = "boresight"
    prefix: str = "hn"

    def __post_init__(self):
        if self.format not in FORMATS:
            raise ConfigError(f"--format {self.format!r}; allowed: {FORMATS}")
        if not self.prefix or not all(c.isalnum() or c in "_-." for c in self.prefix):
            raise ConfigError(f"--prefix {self.prefix!r} must be letters, digits, '_', '-' or '.'")
        self.check_names([self.prefix])

    def check_names(self, prefixes) -> None:
        """Refuse file-name prefixes (the layout's, or one per detector) whose files' names would
        exceed what a file system takes."""
        for prefix in prefixes:
            longest = len(os.fsencode(f"{prefix}_cos_4.fits"))
            if longest > io.MAX_NAME_BYTES:
                what = (
                    f"is {len(self.prefix)} characters"
                    if prefix == self.prefix
                    else (f"with the detector name {prefix[len(self.prefix) + 1 :]!r}")
                )
                raise ConfigError(
                    f"--prefix {what}: its files' names would be {longest} bytes, at most "
                    f"{io.MAX_NAME_BYTES} are allowed"
                )

    @property
    def convention(self) -> str:
        """The psi convention of every output: TOAST/SO's in the SO layout, else boresight's."""
        return "toast" if self.format == "so" else "boresight"


class ScanMaps(NamedTuple):
    """What scan-stats writes of a scan, RING maps (npix,).

    h : numpy.ndarray, complex128, shape (n_max + 1, npix)
        h_n in boresight's convention, 0 where unobserved.
    observed : numpy.ndarray of bool
    crossings : numpy.ndarray
        Samples (or hits x rotations) per pixel.
    n_phi, range_rad : numpy.ndarray
        Distinct crossing angles and their range [rad].
    """

    h: np.ndarray
    observed: np.ndarray
    crossings: np.ndarray
    n_phi: np.ndarray
    range_rad: np.ndarray


def run(
    study: Study,
    out_dir: str,
    *,
    force: bool = False,
    n_max: int = 4,
    layout: Layout = Layout(),
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """Write the h_n, hit, N_phi and R maps of a study's synthetic scan, and their survey means.

    Parameters
    ----------
    study : boresight.config.Study
    out_dir : str
    force : bool
    n_max : int
        Highest moment written.
    layout : Layout
    checks : boresight.jobs.resources.Checks
        The up-front memory and time checks to make.

    Returns
    -------
    list of dict
        n, mean_abs_h2, mean_re, mean_im for n = 1..n_max, in the layout's convention.
    """
    io.check_output_dir(out_dir, force, study.inputs)
    estimate = resources.study_estimate("scan-stats", study)
    resources.require(estimate, checks)
    nside = study.sky.nside
    obs = masks.from_config(study.mask, nside) > 0
    h, crossings = engine.scan_moments(study.scan, nside, pixels=obs, nthreads=study.run.nthreads)
    n_phi, r, _ = study.scan.per_pixel(np.arange(12 * nside**2), 12 * nside**2)
    maps = ScanMaps(h, obs, crossings, n_phi, r)
    return _write(out_dir, maps, n_max, study.inputs, force, layout, as_dict(study), estimate)


def run_schedule(
    schedule_path: str,
    out_dir: str,
    *,
    nside: int = 128,
    motion: ScanMotion | None = None,
    force: bool = False,
    tolerance_deg: float = 1.0,
    layout: Layout = Layout(),
    frame: str | None = None,
    turnarounds: str | None = None,
    focalplane: FocalPlane | None = None,
    per_detector: bool = False,
    hwp: HWP | None = None,
    scheduler: str | None = "serial",
    workers: int = 2,
    progress: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """:func:`run` for a CES schedule file (boresight's TOML or CSV, or TOAST's).

    With a focal plane every pair is pointed from its own place; the h_n maps are then the focal
    plane's combination (all pairs' samples binned together), ``hn_scatter.fits`` holds the
    scattered weights sum_i N_i^2 ``|h_{n,i}|^2`` / N^2, and ``pairs.csv`` and ``pairs.png`` each
    pair's hit-weighted <``|h_n|^2``> (against its distance from the boresight). ``per_detector`` (SO layout) also writes sotodlib's per-detector files
    ``{prefix}_{det}_cos_{n}.fits``, ``_sin_{n}`` and ``_hits``, with psi as sotodlib's ``Hn``
    computes it (TOAST's psi less the detector's polarisation angle).

    Parameters
    ----------
    schedule_path, out_dir : str
    nside : int
    motion : boresight.schedule.ScanMotion, optional
        For a TOAST schedule: scan rate, acceleration and sample rate.
    force : bool
    tolerance_deg : float
        Crossing angles closer than this count as one in N_phi.
    layout : Layout
    frame, turnarounds : str, optional
        The sky frame of the maps and what the turnarounds' samples do
        (:class:`boresight.schedule.Schedule`; default: the file's).
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        Default: every pair on the boresight.
    per_detector : bool
        Write each detector's maps (SO layout, with a focal plane).
    hwp : boresight.instrument.hwp.HWP, optional
        Also the moments h_{n,m} of the boresight's psi and the HWP's angle
        (:data:`boresight.moments.HWP_TERMS`): ``hwp_moments.fits`` (RE_n_m, IM_n_m, with M for
        a minus sign: RE_2_M4 is Re h_{2,-4}), or litebird_sim's file in its layout. With a
        focal plane, of each pair's own psi: the combination in ``hwp_moments.fits`` (or
        litebird_sim's ``h_maps_det_focalplane.h5``), and in litebird_sim's layout a file per
        detector, its pair's.
    scheduler : str, optional
        Where a focal plane's blocks of pairs run: "serial" (this process), None (a local Dask
        cluster of ``workers`` processes) or a Dask scheduler's address.
    workers : int
    progress : bool
        Show a progress bar over the schedule's samples.
    checks : boresight.jobs.resources.Checks

    Returns
    -------
    list of dict
        As :func:`run`.
    """
    if per_detector and (focalplane is None or layout.format != "so"):
        raise ConfigError("--per-detector needs --focalplane and --format so")
    lite_files = hwp is not None and hwp.present and layout.format == "litebird"
    if per_detector or (lite_files and focalplane is not None):
        names = [det for pair in focalplane.detectors for det in pair]
        for det in names:
            if not all(c.isalnum() or c in "_-." for c in det) or det in (
                "boresight",
                "focalplane",
            ):
                raise ConfigError(
                    f"detector {det!r} of {focalplane.source} cannot name a file of its own: "
                    "letters, digits, '_', '-' and '.' only, and not 'boresight' or 'focalplane'"
                )
        if per_detector:
            layout.check_names(f"{layout.prefix}_{det}" for det in names)
    if hwp is not None and hwp.present and layout.format == "so":
        raise ConfigError(
            "--hwp: the HWP's moments are in boresight's or litebird_sim's layout: leave out "
            "--format so"
        )
    schedule = load_schedule(schedule_path, motion, frame=frame, turnarounds=turnarounds)
    check_sampling(hwp, schedule.sample_rate_hz)  # before the work, not in its first chunk
    if layout.format == "litebird":
        litebird_maps.check_frame(schedule.frame)
    try:
        SkyConfig(nside=nside, lmax=2 * nside)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"--nside: {err}") from None
    io.check_output_dir(out_dir, force, [schedule_path])
    pairs = 0 if focalplane is None else focalplane.n_pairs
    blocks = scanstats.pair_blocks(pairs, nside, per_pair=per_detector) if pairs else []
    estimate = resources.schedule_estimate(
        "schedule-stats",
        schedule,
        nside,
        pointed_pairs=pairs,
        pair_maps=max((len(b) for b in blocks), default=0),  # with per_detector: every pair
        hwp_terms=len(scanstats.HWP_TERMS) if hwp is not None and hwp.present else 0,
    )
    resources.require(estimate, checks)
    timer = provenance.Timer(log)
    job = "schedule-stats" if focalplane is None else "focalplane-stats"
    precompile.precompile(precompile.kernels_for(job), timer=timer)
    config = {
        "schedule": schedule_path,
        "nside": nside,
        "frame": schedule.frame,
        "turnarounds": schedule.turnarounds,
        "tolerance_deg": tolerance_deg,
    }
    inputs = [schedule_path]
    with timer("characterise the schedule"):
        if focalplane is None:
            stats = scanstats.characterise_schedule(
                schedule, nside, tolerance_deg, progress=progress
            )
            planes = None
        else:
            planes = scanstats.characterise_focalplane(
                schedule,
                focalplane,
                nside,
                tolerance_deg,
                per_pair=per_detector,
                scheduler=scheduler,
                workers=workers,
                progress=progress,
            )
            stats = planes.combined
            config["focalplane"] = focalplane.source
            inputs += focalplane.files
    moments = None
    if hwp is not None and hwp.present:

        def moments(each):
            with timer("the HWP's moments"):
                return scanstats.hwp_moments(
                    schedule, hwp, nside, focalplane=focalplane, each=each, progress=progress
                )

        config["hwp"] = dataclasses.asdict(hwp)
    config["observing_s"] = schedule.n_samples / schedule.sample_rate_hz
    config["sample_rate_hz"] = schedule.sample_rate_hz
    maps = ScanMaps(stats.h, stats.observed, stats.hits, stats.n_distinct, stats.range_rad)
    return _write(
        out_dir,
        maps,
        scanstats.N_MAX,
        inputs,
        force,
        layout,
        config,
        estimate,
        planes=planes,
        hwp_moments=moments,
    )


def _write_focalplane(stage, planes, layout, frame):
    """The scattered weights, each pair's means and, where kept, each detector's SO maps."""
    scattered = planes.scattered()
    observed = planes.combined.hits > 0
    io.write_maps(
        stage / "hn_scatter.fits",
        [np.where(observed, scattered[n], hp.UNSEEN) for n in range(scanstats.N_MAX + 1)],
        [f"SCATTER_H{n}" for n in range(scanstats.N_MAX + 1)],
        [""] * (scanstats.N_MAX + 1),
        comments=["sum over pairs of N_i^2 |h_n,i|^2 / N^2 (n = 0: sum N_i^2 / N^2)"],
        frame=frame,
    )
    rows = planes.pair_means()
    io.write_csv(stage / "pairs.csv", rows, list(rows[0]))
    plots.pairs_figure(rows, stage / "pairs")
    if planes.pair_h is None:
        return
    plane = planes.focalplane
    n = np.arange(scanstats.N_MAX + 1)[:, None]
    for i, pair in enumerate(plane.detectors):
        interrupts.check()  # hundreds of files: Ctrl-C stops between them
        for det, offset in zip(pair, np.radians(plane.hn_offset_deg[i])):
            h = planes.pair_h[i] * np.exp(1j * n * offset)  # sotodlib's Hn psi: + gamma - pol
            so_maps.write(stage, f"{layout.prefix}_{det}", h, planes.pair_hits[i], frame=frame)


def _hwp_columns(hits, moments):
    """hwp_moments.fits' maps and names: RE_n_m and IM_n_m, M for a minus sign."""
    observed = hits > 0
    maps, names = [], []
    for part, f in (("RE", np.real), ("IM", np.imag)):
        for (n, m), h in moments.items():
            maps.append(np.where(observed, f(h), hp.UNSEEN))
            names.append(f"{part}_{n}_{m}".replace("-", "M"))
    return maps, names


def _write(
    out_dir, maps, n_max, inputs, force, layout, config, estimate, *, planes=None, hwp_moments=None
):
    """The survey means, the h_n maps in the layout, the scan maps, a figure and the manifest. In
    the SO layout every output, hn_summary.csv included, is in TOAST/SO's psi convention (odd h_n
    change sign); the manifest's ``psi_convention`` says which. ``hwp_moments``, if given, makes
    the HWP's moments as ``hwp_moments(each)`` (:func:`boresight.moments.hwp_moments`): in
    litebird_sim's layout with a focal plane, ``each`` writes every detector's file as its pair's
    are made."""
    h, obs = maps.h, maps.observed
    frame = config.get("frame", "icrs")
    turn = so_maps.to_so if layout.format == "so" else (lambda hn, n: hn)
    rows = [
        dict(
            n=n,
            mean_abs_h2=float(np.mean(np.abs(h[n][obs]) ** 2)),
            mean_re=float(np.mean(turn(h[n][obs], n).real)),
            mean_im=float(np.mean(turn(h[n][obs], n).imag)),
        )
        for n in range(1, n_max + 1)
    ]
    require_finite("the h_n summary", [list(row.values()) for row in rows])
    with io.staged_dir(out_dir, force, inputs) as stage:
        if layout.format == "litebird":
            lite = dict(
                frame=frame,
                duration_s=config["observing_s"],
                sample_rate_hz=config["sample_rate_hz"],
            )
        if hwp_moments is not None:
            each = None
            if layout.format == "litebird" and planes is not None:

                def each(i, hits, h):
                    interrupts.check()
                    for det in planes.focalplane.detectors[i]:
                        litebird_maps.write(stage, det, hits, h, **lite)

            hwp_moments = hwp_moments(each)
        if layout.format == "litebird":
            hits, moments = hwp_moments or (
                maps.crossings,
                {(n, 0): h[n] for n in range(1, n_max + 1)},
            )
            name = "boresight" if planes is None else "focalplane"
            litebird_maps.write(stage, name, hits, moments, **lite)
        elif layout.format == "so":
            so_maps.write(
                stage,
                layout.prefix,
                h,
                maps.crossings,
                n_values=range(1, n_max + 1),
                frame=frame,
            )
        else:
            parts = [("RE", np.real), ("IM", np.imag)]
            io.write_maps(
                stage / "hn_maps.fits",
                [np.where(obs, f(h[n]), hp.UNSEEN) for _, f in parts for n in range(1, n_max + 1)],
                [f"{p}_H{n}" for p, _ in parts for n in range(1, n_max + 1)],
                [""] * (2 * n_max),
                comments=[BORESIGHT_CONVENTION],
                frame=frame,
            )
        if hwp_moments is not None and layout.format == "boresight":
            columns, names = _hwp_columns(*hwp_moments)
            io.write_maps(
                stage / "hwp_moments.fits",
                columns,
                names,
                [""] * len(names),
                comments=[HWP_CONVENTION],
                frame=frame,
            )
        io.write_maps(
            stage / "scan_maps.fits",
            [
                maps.crossings,
                np.where(obs, maps.n_phi, 0),
                np.where(obs, maps.range_rad, 0),
            ],
            ["CROSSINGS", "N_PHI", "RANGE_RAD"],
            ["", "", "rad"],
            frame=frame,
        )
        io.write_csv(stage / "hn_summary.csv", rows, list(rows[0]))
        if planes is not None:
            _write_focalplane(stage, planes, layout, frame)
        plots.map_figure(
            [np.where(obs, np.abs(h[n]) ** 2, hp.UNSEEN) for n in (1, 2)],
            ["|h_1|^2", "|h_2|^2"],
            stage / "hn_maps.png",
            unit="",
        )
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                {**config, "frame": frame, "psi_convention": layout.convention},
                {},
                {},
                estimate.as_dict(),
            ),
        )
    return rows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="a study file, or a schedule (TOML, CSV or TOAST)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--force", action="store_true", help="replace an earlier output")
    parser.add_argument("--nside", type=int, default=128, help="map resolution of a schedule")
    parser.add_argument(
        "--format",
        choices=FORMATS,
        default="boresight",
        help="h_n maps as hn_maps.fits, as SO/SMARTIES {prefix}_cos_{n}/_sin_{n}.fits in "
        "TOAST's psi convention (odd h_n change sign), or as litebird_sim's "
        "h_maps_det_boresight.h5 (groups 'n,m'; Galactic maps only)",
    )
    parser.add_argument("--prefix", default="hn", help="file name prefix of --format so")
    _common.focalplane_flag(parser)
    parser.add_argument(
        "--scheduler",
        default="serial",
        help="with --focalplane: run its blocks of pairs on Dask, 'local' for a local cluster or "
        "a scheduler's address (default: serial, in this process)",
    )
    parser.add_argument("--workers", type=int, default=2, help="local cluster worker processes")
    parser.add_argument(
        "--per-detector",
        action="store_true",
        help="with --focalplane and --format so: each detector's maps, as sotodlib's Hn writes",
    )
    _common.hwp_flags(parser)
    _common.motion_flags(parser)
    _common.pointing_flags(parser)


def main(args: argparse.Namespace) -> int:
    layout = Layout(args.format, args.prefix)
    if is_schedule(args.config):
        rows = run_schedule(
            args.config,
            args.out,
            nside=args.nside,
            motion=_common.motion(args),
            force=args.force,
            layout=layout,
            focalplane=_common.focalplane(args),
            per_detector=args.per_detector,
            hwp=_common.hwp(args),
            scheduler=tasks.check_scheduler(None if args.scheduler == "local" else args.scheduler),
            workers=args.workers,
            progress=_common.progress(args),
            checks=_common.checks(args),
            **_common.pointing(args),
        )
    else:
        if args.focalplane or args.per_detector or args.hwp != "none" or args.format == "litebird":
            raise ConfigError(
                "--focalplane, --per-detector, --hwp and --format litebird need a schedule, "
                "not a study"
            )
        rows = run(
            load_study(args.config),
            args.out,
            force=args.force,
            layout=layout,
            checks=_common.checks(args),
        )
    for row in rows:
        log.info("n=%d  <|h_n|^2> = %.4g", row["n"], row["mean_abs_h2"])
    return 0
