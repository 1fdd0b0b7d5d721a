"""h_n maps of a scan in a layout chosen by name: boresight's ``hn_maps.fits``, the SO/SMARTIES files
of :mod:`boresight.outputs.so` or litebird_sim's HDF5 file of :mod:`boresight.outputs.litebird`
(:data:`WRITERS`), with the scan's crossing maps, its survey means, a figure and the manifest
(:func:`write`)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import NamedTuple

import healpy as hp
import numpy as np

from .._util import interrupts, io, provenance
from ..constants import N_MAX
from ..validation import ConfigError, require_finite
from . import litebird, plots, so

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
    partial : bool
        Every FITS map a HEALPix partial map of the observed pixels (a PIXEL column beside the
        values: healpy.read_map fills the rest with UNSEEN), not the whole sky.
    """

    format: str = "boresight"
    prefix: str = "hn"
    partial: bool = False

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

    def check_schedule_outputs(self, *, focalplane, per_detector, hwp) -> None:
        """Refuse what this layout cannot hold of a schedule's outputs: per-detector files but in
        the SO layout with a focal plane, a plate's moments in the SO layout, and detector names
        that cannot name files of their own."""
        if per_detector and (focalplane is None or self.format != "so"):
            raise ConfigError("--per-detector needs --focalplane and --format so")
        lite_files = hwp is not None and hwp.present and self.format == "litebird"
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
                self.check_names(f"{self.prefix}_{det}" for det in names)
        if hwp is not None and hwp.present and self.format == "so":
            raise ConfigError(
                "--hwp: the HWP's moments are in boresight's or litebird_sim's layout: leave out "
                "--format so"
            )

    def check_frame(self, frame: str) -> None:
        """Refuse a frame the layout's files cannot name (litebird_sim's: Galactic or Ecliptic)."""
        if self.format == "litebird":
            litebird.check_frame(frame)

    def observed(self, observed: np.ndarray) -> np.ndarray | None:
        """The pixels a FITS map of this layout is written on: ``observed`` for partial maps,
        else None (the whole sky)."""
        return observed if self.partial else None

    @property
    def files_per_pair(self) -> bool:
        """Whether a plate's moments of each pair of a focal plane get files of their own
        (litebird_sim's layout, a file per detector)."""
        return self.format == "litebird"

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


def _boresight(stage, maps, n_max, frame, layout, plate, lite):
    """hn_maps.fits (RE_H1.., IM_H1..) and with a plate hwp_moments.fits."""
    obs, h = maps.observed, maps.h
    parts = [("RE", np.real), ("IM", np.imag)]
    io.write_maps(
        stage / "hn_maps.fits",
        [np.where(obs, f(h[n]), hp.UNSEEN) for _, f in parts for n in range(1, n_max + 1)],
        [f"{p}_H{n}" for p, _ in parts for n in range(1, n_max + 1)],
        [""] * (2 * n_max),
        comments=[BORESIGHT_CONVENTION],
        frame=frame,
        observed=layout.observed(obs),
    )
    if plate is not None:
        columns, names = _hwp_columns(*plate)
        io.write_maps(
            stage / "hwp_moments.fits",
            columns,
            names,
            [""] * len(names),
            comments=[HWP_CONVENTION],
            frame=frame,
            observed=layout.observed(plate[0] > 0),
        )


def _so(stage, maps, n_max, frame, layout, plate, lite):
    """The SO/SMARTIES files ``{prefix}_cos_{n}.fits``... (a plate is refused up front)."""
    so.write(
        stage, layout.prefix, maps.h, maps.crossings, n_values=range(1, n_max + 1), frame=frame,
        partial=layout.partial,
    )  # fmt: skip


def _litebird(stage, maps, n_max, frame, layout, plate, lite):
    """litebird_sim's h_maps_det_{boresight,focalplane}.h5: the plate's h_{n,m}, or h_{n,0}."""
    hits, moments = plate or (maps.crossings, {(n, 0): maps.h[n] for n in range(1, n_max + 1)})
    litebird.write(stage, lite.pop("name"), hits, moments, **lite)


#: the h_n maps' writer of each layout
WRITERS = {"boresight": _boresight, "so": _so, "litebird": _litebird}


def write_focalplane(stage, planes, layout, frame):
    """The scattered weights, each pair's means and, where kept, each detector's SO maps."""
    scattered = planes.scattered()
    observed = planes.combined.hits > 0
    io.write_maps(
        stage / "hn_scatter.fits",
        [np.where(observed, scattered[n], hp.UNSEEN) for n in range(N_MAX + 1)],
        [f"SCATTER_H{n}" for n in range(N_MAX + 1)],
        [""] * (N_MAX + 1),
        comments=["sum over pairs of N_i^2 |h_n,i|^2 / N^2 (n = 0: sum N_i^2 / N^2)"],
        frame=frame,
        observed=layout.observed(observed),
    )
    rows = planes.pair_means()
    io.write_csv(stage / "pairs.csv", rows, list(rows[0]))
    plots.pairs_figure(rows, stage / "pairs")
    if planes.observed_pair_h is None:
        return
    plane = planes.focalplane
    n = np.arange(N_MAX + 1)[:, None]
    npix = planes.combined.hits.size
    for i, pair in enumerate(plane.detectors):
        interrupts.check()  # hundreds of files: Ctrl-C stops between them
        hits = np.zeros(npix, dtype=np.int64)  # one detector's maps on the sky at a time
        hits[planes.observed] = planes.observed_pair_hits[i]
        for det, offset in zip(pair, np.radians(plane.hn_offset_deg[i])):
            h = np.zeros((N_MAX + 1, npix), dtype=np.complex128)
            h[:, planes.observed] = planes.observed_pair_h[i] * np.exp(1j * n * offset)  # Hn's psi
            so.write(stage, f"{layout.prefix}_{det}", h, hits, frame=frame, partial=layout.partial)


def _hwp_columns(hits, moments):
    """hwp_moments.fits' maps and names: RE_n_m and IM_n_m, M for a minus sign."""
    observed = hits > 0
    maps, names = [], []
    for part, f in (("RE", np.real), ("IM", np.imag)):
        for (n, m), h in moments.items():
            maps.append(np.where(observed, f(h), hp.UNSEEN))
            names.append(f"{part}_{n}_{m}".replace("-", "M"))
    return maps, names


def write(
    out_dir, maps, *, n_max, inputs, force, layout, config, estimate, planes=None, hwp_moments=None
):
    """The survey means, the h_n maps in the layout (:data:`WRITERS`), the scan maps, a figure and
    the manifest. In the SO layout every output, hn_summary.csv included, is in TOAST/SO's psi
    convention (odd h_n change sign); the manifest's ``psi_convention`` says which.
    ``hwp_moments``, if given, makes the HWP's moments as ``hwp_moments(each)``
    (:func:`boresight.moments.hwp_moments`): in litebird_sim's layout with a focal plane,
    ``each`` writes every detector's file as its pair's are made. Returns hn_summary.csv's rows.

    With a focal plane (``planes``) the h_n maps are its combination (all pairs' samples binned
    together), ``hn_scatter.fits`` holds the scattered weights sum_i N_i^2 ``|h_{n,i}|^2`` / N^2,
    and ``pairs.csv`` and ``pairs.png`` each pair's hit-weighted <``|h_n|^2``> (against its
    distance from the boresight); with each pair's maps kept, the SO layout also has sotodlib's
    per-detector files ``{prefix}_{det}_cos_{n}.fits``, ``_sin_{n}`` and ``_hits``, with psi as
    sotodlib's ``Hn`` computes it (TOAST's psi less the detector's polarisation angle). Behind a
    plate: ``hwp_moments.fits`` (RE_n_m, IM_n_m, with M for a minus sign: RE_2_M4 is Re
    h_{2,-4}), or litebird_sim's file in its layout; with a focal plane, of each pair's own psi,
    the combination (litebird_sim's ``h_maps_det_focalplane.h5``) and in litebird_sim's layout a
    file per detector, its pair's.
    """
    h, obs = maps.h, maps.observed
    frame = config.get("frame", "icrs")
    turn = so.to_so if layout.convention == "toast" else (lambda hn, n: hn)
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
    lite = dict(
        name="boresight" if planes is None else "focalplane",
        frame=frame,
        duration_s=config.get("observing_s"),
        sample_rate_hz=config.get("sample_rate_hz"),
    )
    with io.staged_dir(out_dir, force, inputs) as stage:
        plate = None
        if hwp_moments is not None:
            plate = hwp_moments(_per_pair(layout, stage, planes, lite))
        WRITERS[layout.format](stage, maps, n_max, frame, layout, plate, dict(lite))
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
            observed=layout.observed(obs),
        )
        io.write_csv(stage / "hn_summary.csv", rows, list(rows[0]))
        if planes is not None:
            write_focalplane(stage, planes, layout, frame)
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


def _per_pair(layout, stage, planes, lite):
    """What the plate's moments do with each pair's as they are made: in litebird_sim's layout
    with a focal plane, write every detector's file; else nothing (None)."""
    if not layout.files_per_pair or planes is None:
        return None
    options = {k: v for k, v in lite.items() if k != "name"}

    def each(i, hits, h):
        interrupts.check()
        for det in planes.focalplane.detectors[i]:
            litebird.write(stage, det, hits, h, **options)

    return each
