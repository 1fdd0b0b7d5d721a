"""What a job will need, memory and time, estimated from its inputs before anything is allocated.

The memory estimate is this process's resident size when the job is checked (Python, numpy, numba,
healpy and ducc0 already loaded) plus what the job allocates at its peak:

* its full-sky and observed-pixel arrays, per HEALPix pixel (:data:`BYTES_PER_PIXEL`, measured
  peaks of each command at Nside 64-512, ``bench/bench_memory.py``);
* the sky's alm;
* one chunk of a synthetic scan's hits: per hit its position and angle, and the sky fields at
  detector A and at detector B of every pair and rotation;
* detector beams: the largest Gauss-Legendre grid of a beam's harmonic analysis, and one
  convolution cube per distinct beam, kept for the whole simulation (:func:`beam_bytes`).

A job whose estimate exceeds the machine's memory (the smaller of physical memory and a cgroup
limit) is refused with the estimate, unless the user passes ``--no-memory-check``. The time
estimate counts the job's detector samples at this machine class's rates (:data:`SAMPLE_RATES`);
a job estimated to take longer than :data:`TIME_LIMIT_S` is refused unless the user passes
``--yes``, and one longer than a minute says its estimate. ``tests/jobs/test_resources.py`` checks the
memory estimate against the measured peak of every command within a factor of 1.5.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..constants import ARCMIN
from ..engine import DEFAULT_CHUNK_PIXELS
from ..instrument import beams
from ..instrument.pairs import Instrument
from ..masks import SURVEY_FSKY
from ..predict import BEAM_N_MAX
from ..validation import MemoryLimitError, TimeLimitError

_log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from ..config import Study
    from ..instrument.pairs import Instrument, Systematics
    from ..schedule import Schedule

GIB = 2.0**30
#: peak bytes per HEALPix pixel of each job, over what it holds per alm, per hit and per beam:
#: fitted to the measured peaks of bench/bench_memory.py at Nside 64-512 (2-core machine)
BYTES_PER_PIXEL = {
    "simulate": 200.0,
    # the sky's maps on the surveys' rings, h_n in complex64, the jobs' maps on the observed
    # pixels and one queued transform: 105 B a pixel at Nside 2048 (5.53 GiB: the estimate is
    # 1.39x), more at 256-512 where the transforms' work space weighs more (0.96-1.02x there;
    # bench/bench_memory.py and bench_reproduce.py)
    "reproduce": 150.0,
    "predict": 40.0,
    "scan-stats": 220.0,
    "schedule-stats": 240.0,
    "compare-scans": 320.0,
    "design": 280.0,
    "suppression": 380.0,
    # the HWP table: 53 maps of moments per pair behind the plate, and the sky at every sample
    # (4.6 GB at Nside 256, 17 GB at 512 on the deep example)
    "hwp-suppression": 5400.0,
    # the filtered table: the compare-scans maps and spectra, and one CES's samples at a time
    "filtered-suppression": 320.0,
    # the same table deprojecting T's derivatives: the sky evaluated exactly at every sample
    "deprojected-suppression": 320.0,
}
#: bytes per pixel of each h_{n,m} of scan-stats --hwp: its sums, the moments and their maps
#: (1.27 kB a pixel for the 23 default terms, measured at Nside 256 and 512)
HWP_TERM_BYTES = 56.0
COMMANDS = {
    "schedule-stats": "scan-stats",
    "hwp-suppression": "suppression --hwp",
    "filtered-suppression": "suppression --filter",
    "deprojected-suppression": "suppression --deproject",
}  #: the command of a job whose name differs
SKY_JOBS = {
    "simulate",
    "reproduce",
    "compare-scans",
    "design",
    "suppression",
    "hwp-suppression",
    "filtered-suppression",
    "deprojected-suppression",
}  #: make a sky
ALM_BYTES = 48.0  #: the sky's T, E, B alm, complex128
#: a process with every stage of boresight imported (what some jobs import only after their
#: check) [bytes]
WORKING_SET_BYTES = 0.22 * GIB
#: what a job loads after its check on top (the numba kernels of its stages, matplotlib's fonts)
LATE_IMPORTS_BYTES = 0.06 * GIB
#: detector samples per second on the 2-core machine class, the jobs' other stages included: a
#: synthetic scan's, a real schedule's pointing and binning (scan-stats), its TOD
#: (simulate_samples, per pair), the design's per-unit moments (bench/bench_memory.py prints
#: the estimated and the measured seconds of each command)
SAMPLE_RATES = {
    "synthetic": 5.0e7,
    "pointing": 1.5e7,
    "tod": 1.6e7,
    "moments": 8.0e6,
    "exact tod": 1.3e6,  # the sky synthesised at each sample (the HWP table), pair-samples/s
    # a schedule's pair differences raw and filtered by turns, with the table's spectra (the
    # filtered table: 2.8e6 raw, 1.8e6 filtered pair-samples/s on the deep example at Nside 32)
    "filtered tod": 2.0e6,
    # a focal plane's pairs, each pointed from its own place and binned: 4.2e6 pair-samples/s
    # between 1,027 and 3,367 pairs of a hexagon (10^4 pairs ran 3.5x the pointing's 1.5e7)
    "pair pointing": 4.0e6,
}
#: the rate of a job's TOD simulations where it is not :data:`SAMPLE_RATES`' "tod"
JOB_RATES = {
    "hwp-suppression": "exact tod",
    "filtered-suppression": "filtered tod",
    # the deep example's bk table at Nside 128: 1.5e6 pair-samples/s with its spectra
    "deprojected-suppression": "exact tod",
}
#: seconds per HEALPix pixel of a job's map-level work (the HWP table's predictions: 120 s +
#: 5e-4 s per pixel fits its runs on the deep example at Nside 64-512 on 2 cores)
PIXEL_SECONDS = {"hwp-suppression": 5.0e-4}
TIME_LIMIT_S = 3600.0  #: longest estimated run that needs no --yes
TIME_NOTICE_S = 60.0  #: longest estimated run that is not announced
#: bytes per point of a beam's analysis grid: colatitude and azimuth meshes, the beam, its
#: polarised part and the stack ducc0 analyses
GRID_BYTES_PER_POINT = 72.0


@dataclass(frozen=True)
class Checks:
    """Which up-front checks a job makes: memory (off with ``--no-memory-check``) and the time
    limit (off with ``--yes``)."""

    memory: bool = True
    time: bool = True


@dataclass(frozen=True)
class Estimate:
    """A job's estimated peak memory and run time.

    Parameters
    ----------
    job : str
    parts : dict
        Bytes of each part at the peak: "process" (this process when checked), "arrays",
        "alm", "chunk", "beams", "late imports".
    seconds : float
        Estimated run time.
    samples : float
        The detector samples behind ``seconds``.
    """

    job: str
    parts: dict = field(default_factory=dict)
    seconds: float = 0.0
    samples: float = 0.0

    @property
    def bytes(self) -> float:
        return float(sum(self.parts.values()))

    def as_dict(self) -> dict:
        """For manifests: GiB of the total and of each part, and the seconds."""
        return {
            "memory_gib": round(self.bytes / GIB, 4),
            "parts_gib": {k: round(v / GIB, 4) for k, v in self.parts.items()},
            "seconds": round(self.seconds, 1),
        }


def resident_bytes() -> float:
    """This process's resident memory now [bytes] (Linux /proc, else its peak so far)."""
    try:
        with open("/proc/self/statm") as f:
            return float(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0


def available_bytes() -> float:
    """The memory a job may use.

    Returns
    -------
    float
        Physical memory, or the cgroup (container) limit where that is smaller [bytes].
    """
    total = float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    for limit_file in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(limit_file).read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            total = min(total, float(text))
    return total


def _n_alm(lmax):
    return (lmax + 1.0) * (lmax + 2.0) / 2.0


def _common(job, nside, lmax):
    return {
        "process": max(resident_bytes(), WORKING_SET_BYTES),
        "late imports": LATE_IMPORTS_BYTES,
        "arrays": BYTES_PER_PIXEL[job] * 12.0 * nside**2,
        "alm": ALM_BYTES * _n_alm(lmax) if job in SKY_JOBS else 0.0,
    }


def beam_bytes(
    systematics: Systematics,
    instrument: Instrument,
    fwhm_arcmin: float,
    lmax: int,
    *,
    cubes: bool = True,
) -> float:
    """Memory of detector beams at its peak: the largest beam's analysis grid, plus with
    ``cubes`` one convolution cube per distinct beam (the engine keeps them all).

    The cube of a beam is ducc0's (2 kmax + 1) x Ntheta x Nphi doubles, kmax its moments above
    the tolerance (:func:`boresight.instrument.beams.truncate`): its analysis, which the run would do
    first, is done here where the grid fits (it is cached), so the estimate is the plan's own.

    Parameters
    ----------
    systematics : boresight.instrument.pairs.Systematics
    instrument : boresight.instrument.pairs.Instrument
    fwhm_arcmin : float
        The sky's beam.
    lmax : int
        The sky's band limit.
    cubes : bool
        The simulation's cubes (a prediction has none).

    Returns
    -------
    float
        [bytes]; 0 without beam systematics.
    """
    if not systematics.has_beams:
        return 0.0
    import ducc0

    nominal = fwhm_arcmin * ARCMIN
    distinct = {b for pair in beams.pair_beams(systematics.per_pair(instrument.n_pairs), nominal)
                for b in pair if b != beams.Beam(nominal)}  # fmt: skip
    # the convolution analyses every moment, the prediction's filters those to h_6 (k <= 8)
    kmax = beams.KMAX_LIMIT if cubes else BEAM_N_MAX + 2
    grids = {b: beams.grid_points(b, lmax, kmax) * GRID_BYTES_PER_POINT for b in distinct}
    grid = max(grids.values(), default=0.0)
    if not cubes or grid > available_bytes():
        return grid
    total = 0.0
    for b in distinct:
        kmax = beams.cube_moments(b, nominal, lmax)
        plan = ducc0.totalconvolve.ConvolverPlan(
            lmax, kmax, sigma=beams.CUBE_OVERSAMPLING, epsilon=beams.CONVOLUTION_EPSILON
        )
        total += 8.0 * plan.Npsi() * plan.Ntheta() * plan.Nphi()
    return grid + total


def _survey_fraction(study):
    """The share of the sky a study's scan observes (its mask's), for the chunks of hits."""

    return SURVEY_FSKY.get(study.mask.survey, 1.0) if study.mask.file is None else 1.0


def study_estimate(job: str, study: Study) -> Estimate:
    """The estimate of a study's job: ``simulate``, ``predict``, ``scan-stats``, ``reproduce``.

    Parameters
    ----------
    job : str
        A key of :data:`BYTES_PER_PIXEL`.
    study : boresight.config.Study

    Returns
    -------
    Estimate
    """

    nside, lmax = study.sky.nside, max(study.sky.lmax, study.output.lmax)
    parts = _common(job, nside, lmax)
    n_phi = float(np.max(study.scan.n_phi))
    rotations, pairs = len(study.scan.rotations_deg), study.instrument.n_pairs
    simulates = job in ("simulate", "reproduce")
    if simulates:
        chunk = study.run.chunk_pixels or DEFAULT_CHUNK_PIXELS[study.run.backend]
        hits = min(float(chunk), 12.0 * nside**2) * n_phi
        parts["chunk"] = hits * 8.0 * (6.0 + 3.0 * rotations * pairs)
    parts["beams"] = beam_bytes(
        study.systematics, study.instrument, study.sky.fwhm_arcmin, study.sky.lmax, cubes=simulates
    )
    samples = 0.0
    if simulates:  # both detectors of every pair, at every hit and rotation, twice (reference)
        observed = 12.0 * nside**2 * _survey_fraction(study)
        samples = 2 * observed * float(np.mean(study.scan.n_phi)) * rotations * pairs * 2
        if job == "reproduce":
            samples *= 7  # the paper's two experiments: 4 + 3 angles and their references
    return Estimate(job, parts, samples / SAMPLE_RATES["synthetic"], samples)


def schedule_estimate(
    job: str,
    schedule: Schedule,
    nside: int,
    *,
    lmax: int | None = None,
    n_pairs: int = 2,
    tod_runs: int = 0,
    systematics: Systematics | None = None,
    instrument: Instrument | None = None,
    fwhm_arcmin: float = 0.0,
    pointed_pairs: int = 0,
    pair_maps: int = 0,
    observed_pixels: int | None = None,
    design_units: int = 0,
    design_channels: int = 4,
    design_band: int | None = None,
    hwp_terms: int = 0,
) -> Estimate:
    """The estimate of a schedule's job: ``schedule-stats``, ``compare-scans``, ``design``.

    Parameters
    ----------
    job : str
        A key of :data:`BYTES_PER_PIXEL`.
    schedule : boresight.schedule.Schedule
    nside : int
    lmax : int, optional
        The sky's band limit, if the job makes one (default 2 Nside).
    n_pairs : int
        Pairs of the TOD simulations.
    tod_runs : int
        TOD simulations of the whole schedule (with and without the systematic each count).
    systematics, instrument, fwhm_arcmin
        The TOD simulations' beams, if any.
    pointed_pairs : int
        Pairs of a focal plane pointed each from its own place (0: the boresight alone).
    pair_maps : int
        Per-pair maps held at once (:func:`boresight.moments.pair_blocks`).
    observed_pixels : int, optional
        The pixels those maps are held on (:func:`boresight.moments.observed_pixels`; default
        the whole sky).
    hwp_terms : int
        The h_{n,m} a schedule's statistics behind a HWP make (:data:`HWP_TERM_BYTES` a pixel
        each).
    design_units : int
        The units a design assigns angles to: its exact objective holds each unit's (E, B) alm
        of up to ``design_channels`` channels to ``design_band`` (default 4 to 2 lmax,
        :class:`boresight.design.exact.ExactObjective`; a filtering pipeline's one per sky and
        moment to lmax, :class:`boresight.design.filtered.FilteredObjective`).
    design_channels : int
    design_band : int, optional

    Returns
    -------
    Estimate
    """

    lmax = 2 * nside if lmax is None else lmax
    parts = _common(job, nside, lmax)
    parts["chunk"] = 8.0 * 6.0 * min(float(schedule.n_samples), 2.0**20)
    if systematics is not None and tod_runs:
        parts["beams"] = beam_bytes(
            systematics, instrument or Instrument(), fwhm_arcmin, lmax, cubes=True
        )
    if hwp_terms:
        parts["hwp moments"] = HWP_TERM_BYTES * hwp_terms * 12.0 * nside**2
    if design_units:
        band = 2 * lmax if design_band is None else design_band
        parts["unit alm"] = 16.0 * design_units * design_channels * 2 * _n_alm(band)
    if pair_maps:
        observed = 12.0 * nside**2 if observed_pixels is None else float(observed_pixels)
        # sums (5 complex) and hits per pair on the observed pixels, and the pixels' slot table
        parts["pair maps"] = 88.0 * observed * pair_maps + 4.0 * 12 * nside**2
        parts["chunk"] *= 28.0 / 48.0  # pixel, cos, sin, angle bin per pair-sample
    samples = float(schedule.n_samples)
    if pointed_pairs:
        seconds = samples * pointed_pairs / SAMPLE_RATES["pair pointing"]
    else:
        seconds = samples / SAMPLE_RATES["pointing"]
    if job == "design":
        seconds += samples / SAMPLE_RATES["moments"]
    rate = SAMPLE_RATES[JOB_RATES.get(job, "tod")]
    seconds += tod_runs * samples * n_pairs / rate + PIXEL_SECONDS.get(job, 0.0) * 12 * nside**2
    return Estimate(job, parts, seconds, samples * max(1, tod_runs * n_pairs))


def _duration(seconds):
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def require(estimate: Estimate, checks: Checks = Checks()) -> None:
    """Refuse a job whose estimate exceeds the machine's memory or :data:`TIME_LIMIT_S`.

    Parameters
    ----------
    estimate : Estimate
    checks : Checks
        Which of the two to make.

    Notes
    -----
    An estimate over :data:`TIME_NOTICE_S` is logged at INFO.

    Raises
    ------
    MemoryLimitError
        With the estimate and the machine's memory in GiB.
    TimeLimitError
        With the estimated duration and the samples behind it.
    """
    have = available_bytes()
    if checks.memory and estimate.bytes > have:
        big = max(estimate.parts, key=estimate.parts.get)
        raise MemoryLimitError(
            f"{COMMANDS.get(estimate.job, estimate.job)} needs about {estimate.bytes / GIB:.1f} GiB ({big}: "
            f"{estimate.parts[big] / GIB:.1f} GiB) but this machine has {have / GIB:.1f} GiB; "
            "lower the Nside, lmax, n_phi or the beams, or pass --no-memory-check"
        )
    if checks.time and estimate.seconds > TIME_LIMIT_S:
        raise TimeLimitError(
            f"{COMMANDS.get(estimate.job, estimate.job)} would take about {_duration(estimate.seconds)} on this machine "
            f"({estimate.samples:.3g} detector samples); pass --yes to run it"
        )
    if estimate.seconds > TIME_NOTICE_S:
        _log.info("estimated run time: about %s", _duration(estimate.seconds))
