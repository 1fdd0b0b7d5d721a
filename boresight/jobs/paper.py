"""The paper's study as a preset of the one residual job: wide survey + pointing and deep survey +
gain, with and without partial boresight rotation, the analytic predictions, the reference curves
and the Q = U = 0 check.

A reproduction is a :class:`boresight.config.Study` (sky, run and output sections; :func:`preset`
gives the paper's and the quick resolution) run through :func:`boresight.jobs.residual.residual` once
per experiment and rotation angle. Every spectrum is binned once, by :func:`band_table`, and
results.csv, the report's claims and the figures read that table. The pseudo-spectra (most of the
time at lmax 4000) are transformed on a background thread while the next rotation angle is
simulated and predicted; the stage times in the manifest are the main thread's.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from .. import predict
from .._util import precompile, provenance
from ..config import ConfigError, OutputOptions, RunOptions, Study, build_section, check_types
from ..cosmology import load_spectra
from ..coupling import mask_coupling
from ..instrument.pairs import PAPER_GAIN, PAPER_POINTING, Systematics
from ..masks import SURVEY_FSKY, fsky, survey_mask, survey_span
from ..moments import compute_moments
from ..scan import SyntheticScan, paper_scan
from ..sky import SkyConfig, make_sky
from ..spectra import Footprint
from .residual import Residual, band_rows, n_max_for, residual, simulate_reference
from .transforms import Transforms

if TYPE_CHECKING:
    from collections.abc import Sequence

log = logging.getLogger(__name__)
#: a job waiting in the transforms' queue holds its Q, U on the observed pixels: two may wait
#: while each is at most this many bytes, else one (0.3 GB a job at Nside 2048 on the wide mask)
QUEUE_BYTES = 2**28


@dataclass(frozen=True)
class Experiment:
    """One of the paper's two experiments.

    Parameters
    ----------
    name : str
    survey : {"deep", "wide"}
    systematics : boresight.instrument.pairs.Systematics
    ideal_deg : float
        The rotation that cancels the systematic's h_n [deg].
    angles_deg : tuple of float
        The rotations simulated [deg].
    reference : {"a_lens", "r"}
        The reference curves: lensing B (r = 0), or tensor B (lensing removed).
    reference_values : tuple of float
    """

    name: str
    survey: str
    systematics: Systematics
    ideal_deg: float
    angles_deg: tuple
    reference: str  #: "a_lens" (lensing B, r = 0) or "r" (tensor B, lensing removed)
    reference_values: tuple


EXPERIMENTS = (
    Experiment(
        "pointing_wide",
        "wide",
        PAPER_POINTING,
        180.0,
        (180.0, 179.0, 160.0),
        "a_lens",
        (0.001, 0.05, 1.0),
    ),
    Experiment("gain_deep", "deep", PAPER_GAIN, 90.0, (90.0, 89.0, 70.0), "r", (0.001, 0.01, 0.1)),
)


def preset(quick: bool = False, run: RunOptions | None = None, **sky_fields) -> Study:
    """The paper's study.

    Nside 2048, lmax 4000, a 7 arcmin beam and seed 1, or with ``quick`` Nside 512 and lmax 1535
    (minutes on a laptop). Bands: 14 from ell = 20 to min(lmax, 2 Nside); the scan seed is the
    sky's.

    Parameters
    ----------
    quick : bool
    run : boresight.config.RunOptions, optional
    **sky_fields
        Overrides of the :class:`boresight.sky.SkyConfig` fields.

    Returns
    -------
    boresight.config.Study
    """
    nside, lmax = (512, 1535) if quick else (2048, 4000)
    sky_cfg = SkyConfig(
        **{"nside": nside, "lmax": lmax, "fwhm_arcmin": 7.0, "seed": 1, **sky_fields}
    )
    return Study(sky_cfg, SyntheticScan(seed=sky_cfg.seed), run=run or RunOptions())


#: sections a reproduction takes from a study file; the experiments fix the rest
REPRODUCE_SECTIONS = ("sky", "scan", "run", "output")


def from_raw(raw: dict, quick: bool = False) -> Study:
    """The paper's study with a study file's [sky], [run], [output] tables (and scan.seed) applied.

    What ``boresight reproduce --config FILE`` runs.

    Parameters
    ----------
    raw : dict
        Parsed TOML.
    quick : bool
        Start from the quick preset.

    Returns
    -------
    boresight.config.Study

    Raises
    ------
    boresight.config.ConfigError
        A table the experiments set ([systematics], [mask], ...), or a bad value.
    """
    check_types(raw)
    fixed = sorted(set(raw) - set(REPRODUCE_SECTIONS))
    scan_keys = sorted(set(raw.get("scan", {})) - {"seed"})
    if fixed or scan_keys:
        raise ConfigError(
            f"reproduce runs the paper's experiments, which set {fixed or scan_keys}; "
            f"a reproduction takes only {REPRODUCE_SECTIONS} (scan: seed only)"
        )
    base = preset(quick)
    sky_cfg = build_section("sky", SkyConfig, {**vars(base.sky), **raw.get("sky", {})})
    seed = raw.get("scan", {}).get("seed", sky_cfg.seed)
    run = build_section("run", RunOptions, raw.get("run", {}))
    output = build_section("output", OutputOptions, raw.get("output", {}))
    try:
        return Study(sky_cfg, SyntheticScan(seed=seed), run=run, output=output, raw=raw)
    except (ValueError, TypeError) as err:
        raise ConfigError(f"[output] {err}") from None


@dataclass
class ExperimentResult:
    """One experiment's residual jobs.

    Parameters
    ----------
    experiment : Experiment
    fsky : float
    residuals : dict
        Rotation angle (None: no rotation) -> :class:`boresight.jobs.residual.Residual`.
    zero_qu_residuals : dict
        The same with Q = U = 0 input, at no and the ideal rotation.
    references : dict
        Reference value -> pseudo-C_BB [muK^2].
    """

    experiment: Experiment
    fsky: float
    residuals: dict = field(default_factory=dict)  #: residual.Residual per angle
    zero_qu_residuals: dict = field(default_factory=dict)  #: Q = U = 0 input, no / ideal angle
    references: dict = field(default_factory=dict)  #: pseudo-C_ell BB per reference value

    def residual(self, angle):
        """C_BB(sys) - C_BB(no sys) [muK^2], (lmax + 1,)."""
        return self.residuals[angle].total

    @property
    def cross(self):
        return {a: r.cross for a, r in self.residuals.items()}

    @property
    def auto(self):
        return {a: r.auto for a, r in self.residuals.items()}

    @property
    def predicted_cl(self):
        return {a: r.predicted_cl for a, r in self.residuals.items()}

    @property
    def predicted_map(self):
        return {a: r.predicted_map for a, r in self.residuals.items() if r.predicted_map_parts}

    @property
    def zero_qu(self):
        return {a: r.auto for a, r in self.zero_qu_residuals.items()}


def run_study(
    study: Study = preset(),
    experiments: Sequence[Experiment] = EXPERIMENTS,
    *,
    progress: bool = False,
) -> tuple[dict, dict]:
    """Run the paper's study.

    Parameters
    ----------
    study : boresight.config.Study
    experiments : sequence of Experiment
    progress : bool

    Returns
    -------
    results : dict
        Experiment name -> :class:`ExperimentResult`.
    stages : dict
        Main-thread seconds per stage.
    """
    timer = provenance.Timer(log)
    pointing = any(exp.systematics.has_pointing for exp in experiments)
    kernels = precompile.kernels_for("study", study.run.backend, pointing)
    precompile.precompile(kernels, study.run.nthreads, timer)
    theory = load_spectra()
    with timer("sky"):
        sky = make_sky(study.sky, theory, study.run.nthreads)
        # the experiments read the maps on their surveys' rings alone: the other rings' pages are
        # let go (62 % of the sky kept, 0.43 GiB less at Nside 2048; the numbers' bits unchanged)
        sky = sky.kept_on(*survey_span([exp.survey for exp in experiments], study.sky.nside))
    results = {}
    # one queue for every experiment: the next one starts while the last transforms run
    with Transforms(background=True, depth=queue_depth(study, experiments)) as transforms:
        for exp in experiments:
            results[exp.name] = _run_experiment(
                exp, study, sky, theory, timer, progress, transforms
            )
        with timer("transforms still running"):
            transforms.wait()
    return results, timer.stages


def queue_depth(study: Study, experiments: Sequence[Experiment] = EXPERIMENTS) -> int:
    """How many transforms may wait at a time: 2 while a job's maps (Q and U, float64, on the
    largest survey's observed pixels) take at most :data:`QUEUE_BYTES`, else 1. Either way the
    numbers are the same bits (:class:`boresight.jobs.transforms.Transforms`).

    Parameters
    ----------
    study : boresight.config.Study
    experiments : sequence of Experiment

    Returns
    -------
    int
    """
    largest = max(SURVEY_FSKY[exp.survey] for exp in experiments)
    job = 2 * 8 * 12 * study.sky.nside**2 * largest
    return 2 if job <= QUEUE_BYTES else 1


def _run_experiment(exp, study, sky, theory, timer, progress, transforms):
    lmax, run, seed = study.output.lmax, study.run, study.scan.seed
    fwhm, nside = study.sky.fwhm_arcmin, study.sky.nside
    with timer(f"{exp.name}: mask and coupling"):
        mask = survey_mask(exp.survey, nside)
        local = transforms.submit(
            partial(
                predict.local_cl,
                nthreads=run.nthreads,
                beams=False,
                analysis=run.analysis,
            ),
            sky,
            mask,
            lmax,
        )
        couplings = mask_coupling(mask, lmax, run.nthreads, band=study.sky.lmax)
    res = ExperimentResult(exp, fsky(mask))
    key = "r" if exp.reference == "r" else "a_lens"
    for value in exp.reference_values:
        res.references[value] = predict.reference_bb(couplings, theory, fwhm, nside, **{key: value})
    angles = (None,) + exp.angles_deg
    # the map-level and Q = U = 0 checks need no other angle than none and the ideal one; the
    # T gradient of the map level goes once the last of them has read it (0.3 GB at Nside 2048)
    checked = [angle in (None, exp.ideal_deg) for angle in angles]
    prediction = predict.Prediction(
        theory, couplings, fwhm, field_cl=local, map_checks=sum(checked)
    )
    job = dict(run=run, transforms=transforms, progress=progress)
    footprint = Footprint(mask)  # the observed pixels, shared by every job
    del mask  # the footprint's pixels and weights are all the jobs read (0.4 GB at Nside 2048)
    with timer(f"{exp.name}: reference (no systematic)"):
        reference = simulate_reference(  # its maps are not kept (0.6 GiB at Nside 2048)
            sky, paper_scan(exp.survey, seed=seed), footprint, lmax, **job
        )[0]
    label = {
        angle: "no rotation" if angle is None else f"rotation {angle:g} deg" for angle in angles
    }
    with timer(f"{exp.name}: scan moments"):  # one repeat's: the same at every angle
        moments = compute_moments(
            paper_scan(exp.survey, seed=seed),
            nside,
            footprint.pixels,
            n_max=n_max_for(exp.systematics),
            nthreads=run.nthreads,
            backend=run.backend,
        )
    for angle, ideal in zip(angles, checked):
        with timer(f"{exp.name}: {label[angle]}"):
            res.residuals[angle] = residual(
                sky,
                paper_scan(exp.survey, angle, seed=seed),
                exp.systematics,
                footprint,
                lmax,
                **job,
                reference=reference,
                moments=moments,
                prediction=prediction,
                predict_map=ideal,
                zero_qu=ideal,
            )
        if ideal:
            res.zero_qu_residuals[angle] = res.residuals[angle].zero_qu
    return res


@dataclass(frozen=True)
class BandTable:
    """An experiment's spectra binned once; the CSV, the report's claims and the figures read it.

    Parameters
    ----------
    centres : numpy.ndarray, shape (nbands,)
    columns : dict
        (angle, column) -> band values, the results.csv columns.
    references : dict
        Reference value -> band values.
    """

    centres: np.ndarray
    columns: dict  #: (angle, column) -> band values
    references: dict  #: reference value -> band values

    def values(
        self, angle: float | None, column: str, lo: float = 0, hi: float = np.inf
    ) -> np.ndarray:
        """Band values of a column at an angle, for bands whose centre lies in [lo, hi].

        Parameters
        ----------
        angle : float or None
        column : str
        lo, hi : float

        Returns
        -------
        numpy.ndarray
        """
        keep = (self.centres >= lo) & (self.centres <= hi)
        return self.columns[angle, column][keep]

    def reference(self, value: float, lo: float = 0, hi: float = np.inf) -> np.ndarray:
        """Band values of a reference curve, for bands whose centre lies in [lo, hi].

        Parameters
        ----------
        value : float
        lo, hi : float

        Returns
        -------
        numpy.ndarray
        """
        keep = (self.centres >= lo) & (self.centres <= hi)
        return self.references[value][keep]


def experiment_rows(res: ExperimentResult, study: Study) -> list[dict]:
    """The results.csv rows of one experiment.

    Parameters
    ----------
    res : ExperimentResult
    study : boresight.config.Study

    Returns
    -------
    list of dict
        One per (rotation angle, ell band), with the columns of :data:`CSV_COLUMNS`.
    """
    edges = study.output.edges()
    rows = []
    for angle, job in res.residuals.items():
        rows += band_rows(
            edges,
            {**job.columns(), "predicted_map_bb": job.predicted_map},
            experiment=res.experiment.name,
            pbr_angle_deg="" if angle is None else angle,
        )
    base = {r["ell_lo"]: r["residual_bb"] for r in rows if r["pbr_angle_deg"] == ""}
    for r in rows:
        total = r["residual_bb"]
        r["reduction"] = base[r["ell_lo"]] / total if total != 0 else np.inf
        r.update(
            nside=study.sky.nside,
            lmax=study.sky.lmax,
            seed=study.sky.seed,
            evaluation=study.run.evaluation,
        )
    return rows


def band_table(res: ExperimentResult, rows: list[dict], study: Study) -> BandTable:
    """The :class:`BandTable` of one experiment from its results.csv rows.

    Parameters
    ----------
    res : ExperimentResult
    rows : list of dict
        :func:`tidy_rows`.
    study : boresight.config.Study

    Returns
    -------
    BandTable
    """
    mine = [r for r in rows if r["experiment"] == res.experiment.name]
    angles = [None if r["pbr_angle_deg"] == "" else r["pbr_angle_deg"] for r in mine]
    first = [r for r, a in zip(mine, angles) if a is None]
    centres = np.array([0.5 * (r["ell_lo"] + r["ell_hi"]) for r in first])
    columns = {}
    for r, a in zip(mine, angles):
        for name in CSV_COLUMNS[4:-4]:
            columns.setdefault((a, name), []).append(r[name])
    references = {
        value: band_rows(study.output.edges(), {"c": cl}) for value, cl in res.references.items()
    }
    return BandTable(
        centres,
        {k: np.array(v) for k, v in columns.items()},
        {value: np.array([r["c"] for r in rows_]) for value, rows_ in references.items()},
    )


def tidy_rows(results: dict, study: Study) -> list[dict]:
    """The rows of results.csv.

    Parameters
    ----------
    results : dict
        From :func:`run_study`.
    study : boresight.config.Study

    Returns
    -------
    list of dict
        One per (experiment, rotation angle, ell band).
    """
    return [row for res in results.values() for row in experiment_rows(res, study)]


#: the columns of results.csv
CSV_COLUMNS = (
    "experiment",
    "pbr_angle_deg",
    "ell_lo",
    "ell_hi",
    *Residual.COLUMNS,
    "predicted_map_bb",
    "reduction",
    "nside",
    "lmax",
    "seed",
    "evaluation",
)
