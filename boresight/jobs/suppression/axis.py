"""The suppression map: which pair-differencing systematics boresight rotation cures, and how much.

Each systematic of :data:`CATALOGUE` runs alone, at a stated amplitude, through the rotation
schedules of :data:`ANGLES` on one synthetic survey. For every (systematic, schedule) the
simulated and the predicted leaked power of the residual pseudo-C_BB (<dB, dB>, without the
cross term with the sky's own B, which is one realisation's scatter) are binned in three multipole
bands, divided by the unrotated residual (the suppression), and turned into the bias on r they fake
(:func:`boresight.predict.delta_r`). Rotation cures a term coupled to h_n with n > 0 by
``|<exp(i n alpha_k)>|^2``; terms of h_0 (a polarisation-angle error, a non-orthogonality) and the
white gain jitter (which only averages down with more samples) it cannot touch.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ... import predict, spectra
from ..._util import interrupts
from ...config import RunOptions
from ...cosmology import load_spectra
from ...coupling import mask_coupling
from ...instrument.added import REGISTRY
from ...instrument.pairs import PAPER_GAIN, PAPER_POINTING, Instrument, Systematics
from ...masks import SURVEY_FSKY, survey_mask
from ...moments import compute_moments
from ...predict.terms import couples_through
from ...scan import paper_scan
from .. import resources
from ..residual import residual, simulate_reference
from ..transforms import Transforms

if TYPE_CHECKING:
    from ...config import Study
    from ...sky import Sky
    from ..resources import Estimate

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Entry:
    """One systematic of the suppression map.

    Parameters
    ----------
    name : str
    amplitude : str
        The amplitude, in words for the table.
    coupling : str
        The spin moments it couples through.
    systematics : Systematics
        With a single-entry ``dg_repeat`` that alternates in sign over the repeats.
    """

    name: str
    amplitude: str
    coupling: str
    systematics: Systematics

    def for_repeats(self, n_repeats: int) -> Systematics:
        """The systematics of a schedule of n repeats: gain drift alternates +d, -d, ..."""
        drift = float(self.systematics.dg_repeat)
        values = tuple(drift * (-1) ** k for k in range(n_repeats))
        return replace(self.systematics, dg_repeat=values)


#: each systematic alone at a stated amplitude, on the paper's Q and U pairs
CATALOGUE = (
    Entry("gain", "dg = +-0.01", "h_2 T, h_4 P*", PAPER_GAIN),
    Entry("pointing", "rho = 0.1 arcmin", "h_1, h_3 grad T", PAPER_POINTING),
    Entry("leak", "leak = 0.01, 0.005", "h_2 T", Systematics(leak=(0.01, 0.005))),
    Entry("angle", "delta = 0.5 deg", "h_0 P", Systematics(pol_angle_deg=0.5)),
    Entry(
        "non-orthogonality",
        "eps = 1, -1 deg",
        "h_0 P (efficiency)",
        Systematics(nonortho_deg=(1, -1)),
    ),
    Entry("gain drift", "dg_repeat = +-0.001", "h_2 T per repeat", Systematics(dg_repeat=0.001)),
    Entry("gain jitter", "sigma = 0.01 per sample", "white", Systematics(dg_jitter=0.01)),
    Entry("beam width", "FWHM_B + 0.3 arcmin", "h_2 nabla^2 T", Systematics(dfwhm_b_arcmin=0.3)),
    Entry("ellipticity", "e_B = 0.01", "h_0, h_4 eth^2 T", Systematics(ellipticity_b=0.01)),
)
ANGLES = (None, 45.0, 90.0, 180.0)  #: the second repeat of each schedule [deg], None: no rotation


def catalogue() -> tuple[Entry, ...]:
    """:data:`CATALOGUE`, then each added systematic (:mod:`boresight.instrument.added`) at its
    own amplitude, in the order they were registered."""
    added = (
        Entry(
            one.key,
            one.words,
            couples_through(one.key),
            Systematics(added={one.key: one.amplitude}),
        )
        for one in REGISTRY.values()
    )
    return CATALOGUE + tuple(added)


MIN_NSIDE = 16  #: the lowest Nside whose 2 Nside reaches past the first band's start, 30


def bands(nside: int) -> np.ndarray:
    """The multipole bands [30, 100), [100, 300), [300, 2 nside] (edges), those below 2 nside."""
    return np.array([e for e in (30, 100, 300) if e < 2 * nside] + [2 * nside + 1])


@dataclass
class Result:
    """The suppression map's spectra.

    Parameters
    ----------
    simulated, predicted : dict
        (systematic, schedule index) -> leaked power <dB, dB> of the residual pseudo-C_BB
        (lmax + 1,) [muK^2]; predicted is None where the C_ell-level prediction does not apply.
    template : numpy.ndarray
        Pseudo-C_BB of tensors at r = 1 (:func:`boresight.predict.tensor_template`).
    lensing : numpy.ndarray
        Pseudo-C_BB of lensing (A_lens = 1).
    """

    simulated: dict
    predicted: dict
    template: np.ndarray
    lensing: np.ndarray


def estimate(study: Study) -> Estimate:
    """The memory and time of :func:`run` on a study's sky: its arrays, the largest beam entry's
    grid and cubes (one entry's simulation at a time), and every entry's samples.

    Parameters
    ----------
    study : boresight.config.Study
        The sky and the bands.

    Returns
    -------
    boresight.jobs.resources.Estimate
    """

    base = resources.study_estimate("suppression", study)
    beams = max(
        resources.beam_bytes(e.systematics, Instrument(), study.sky.fwhm_arcmin, study.sky.lmax)
        for e in catalogue()
    )
    scan = paper_scan("deep")
    pixels = 12.0 * study.sky.nside**2 * SURVEY_FSKY["wide"]  # the larger survey
    runs = len(catalogue()) * len(ANGLES) * 2  # each entry and schedule, with its reference
    samples = runs * pixels * scan.n_phi * 2 * 2 * 2  # hits x repeats x pairs x detectors
    return replace(
        base,
        parts={**base.parts, "beams": beams},
        seconds=samples / resources.SAMPLE_RATES["synthetic"],
        samples=samples,
    )


def run(
    sky: Sky,
    survey: str = "deep",
    *,
    run_options: RunOptions = RunOptions(),
    progress: bool = False,
) -> Result:
    """Simulate and predict every systematic of :func:`catalogue` through :data:`ANGLES`.

    The prediction is the C_ell level's, or the predicted map's where only the map level
    predicts a systematic (an added one).

    Parameters
    ----------
    sky : boresight.sky.Sky
    survey : {"deep", "wide"}
        The paper's synthetic survey and mask.
    run_options : boresight.config.RunOptions
    progress : bool

    Returns
    -------
    Result
    """
    theory = load_spectra()
    nside, lmax = sky.nside, 2 * sky.nside
    mask = survey_mask(survey, nside)
    couplings = mask_coupling(mask, lmax, run_options.nthreads, band=sky.lmax)
    local = predict.local_cl(
        sky,
        mask,
        lmax,
        nthreads=run_options.nthreads,
        beams=True,
        analysis=run_options.analysis,
    )
    prediction = predict.Prediction(theory, couplings, sky.fwhm_arcmin, local, leaked=True)
    simulated, predicted = {}, {}
    with Transforms(background=True) as transforms:
        ref, _ = simulate_reference(
            sky, paper_scan(survey), mask, lmax, run=run_options, transforms=transforms
        )
        # one repeat's moments, the same under every schedule, to the beams' h_6
        moments = compute_moments(
            paper_scan(survey),
            nside,
            mask > 0,
            n_max=predict.BEAM_N_MAX,
            nthreads=run_options.nthreads,
            backend=run_options.backend,
        )
        for entry in catalogue():
            for i, angle in enumerate(ANGLES):
                scan = paper_scan(survey, angle)
                log.info("%s: rotations %s deg", entry.name, _schedule(scan))
                job = residual(
                    sky,
                    scan,
                    entry.for_repeats(len(scan.rotations_deg)),
                    mask,
                    lmax,
                    run=run_options,
                    reference=ref,
                    prediction=prediction,
                    moments=moments,
                    transforms=transforms,
                    progress=progress,
                )
                simulated[entry.name, i] = job
                predicted[entry.name, i] = _predicted(job)
        transforms.wait()
    simulated = {key: job.auto for key, job in simulated.items()}
    template = predict.tensor_template(couplings, theory, sky.fwhm_arcmin, nside)
    lensing = predict.reference_bb(couplings, theory, sky.fwhm_arcmin, nside, a_lens=1.0)
    return Result(simulated, predicted, template, lensing)


def table(result: Result, nside: int) -> list[dict]:
    """One row per (systematic, schedule): band suppressions and delta_r.

    The suppression of a band is the unrotated leaked power over the rotated one (larger is
    better; 1 means rotation does nothing), simulated and predicted; delta_r is that of the
    leaked power.

    Parameters
    ----------
    result : Result
    nside : int

    Returns
    -------
    list of dict
    """
    edges = bands(nside)
    rows = []
    for entry in catalogue():
        base_sim = spectra.bin_spectrum(result.simulated[entry.name, 0], edges)[1]
        base_pred = _binned(result.predicted[entry.name, 0], edges)
        for i, angle in enumerate(ANGLES):
            sim = spectra.bin_spectrum(result.simulated[entry.name, i], edges)[1]
            pred = _binned(result.predicted[entry.name, i], edges)
            row = dict(
                systematic=entry.name,
                amplitude=entry.amplitude,
                couples_through=entry.coupling,
                rotations_deg=_schedule(paper_scan("deep", angle)),
            )
            for b, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
                tag = f"ell_{lo}_{hi - 1}"
                row[f"suppression_sim_{tag}"] = base_sim[b] / sim[b]
                row[f"suppression_pred_{tag}"] = base_pred[b] / pred[b]
            row["delta_r_sim"] = predict.delta_r(result.simulated[entry.name, i], result.template)
            pred_cl = result.predicted[entry.name, i]
            row["delta_r_pred"] = (
                np.nan if pred_cl is None else predict.delta_r(pred_cl, result.template)
            )
            rows.append(row)
    return rows


def markdown(rows: list[dict]) -> str:
    """The table as Markdown: suppression simulated (predicted) per band, and delta_r.

    Parameters
    ----------
    rows : list of dict
        :func:`table`.

    Returns
    -------
    str
    """
    band_names = [k[len("suppression_sim_") :] for k in rows[0] if k.startswith("suppression_sim_")]
    head = ["systematic", "amplitude", "couples through", "rotation [deg]"]
    head += [f"suppression {b.replace('ell_', 'ell ').replace('_', '-')}" for b in band_names]
    head += ["delta_r sim (pred)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["systematic"], r["amplitude"], r["couples_through"], r["rotations_deg"]]
        cells += [
            f"{_g(r[f'suppression_sim_{b}'])} ({_g(r[f'suppression_pred_{b}'])})"
            for b in band_names
        ]
        cells.append(f"{r['delta_r_sim']:.2g} ({r['delta_r_pred']:.2g})")
        lines.append("| " + " | ".join(cells) + " |")
    note = (
        "\nSuppression: the unrotated leaked power <dB, dB> of the residual pseudo-C_BB over the "
        "rotated one in each band, simulated (predicted); 1 means rotation does nothing, "
        "'cancels' a cancellation to rounding. delta_r: the bias on r the leaked power fakes "
        "over 30 <= ell <= 300.\n"
    )
    return "\n".join(lines) + "\n" + note


CANCELS = 1e10  #: a suppression above this is a cancellation to rounding


def _g(x):
    if not np.isfinite(x):
        return "-"
    return "cancels" if x > CANCELS else f"{x:.3g}"


def _schedule(scan):
    return "/".join(f"{a:g}" for a in scan.rotations_deg)


def _predicted(job):
    """A job's predicted leaked power: the C_ell level's, else the predicted map's <dB, dB>."""
    if job.predicted_cl is not None or job.predicted_map_parts is None:
        return job.predicted_cl
    return interrupts.result(job.predicted_map_parts)[1]


def _binned(cl, edges):
    if cl is None:
        return np.full(edges.size - 1, np.nan)
    return spectra.bin_spectrum(cl, edges)[1]
