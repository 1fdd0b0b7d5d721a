"""What TOD deprojection leaves and what it costs, predicted, against TOD skies.

:func:`template_error_check`: what a template map's error leaves. T-only Gaussian skies are scanned through the engine with a systematic, and each pair
difference is deprojected per block (:class:`boresight.mitigation.Deprojection`) with templates
read from a noisy template map: the sky itself (or at another beam) plus white noise of a given
share of the sky's rms, written as a FITS map as a user's Planck-like map would be. The mean of
the skies' leak pseudo-C_BB, band by band, is set against the exact expectation of the schedule's
own h_n (:func:`boresight.predict.expected_residual`, with the samples' offsets in their pixels)
whose C_ell^TT is replaced by the residual field's
(:func:`boresight.predict.template_error.template_error`).

:func:`template_cost_check`: what the templates take of the sky's E. CAMB skies (T, E and B
correlated) are scanned without a systematic, binned from the raw pair differences and from the
deprojected ones (templates read from the sky itself); the skies' mean pseudo-C_EE deprojected
over raw, band by band, is set against the definite share a spin-2 template takes
(:func:`boresight.predict.template_cost.template_cost`) through the footprint's mask coupling.
"""

from __future__ import annotations

import dataclasses
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import healpy as hp
import numpy as np
from tqdm import tqdm

from .. import harmonics, spectra
from .. import moments as scanstats
from ..config import RunOptions
from ..cosmology import load_spectra
from ..coupling import mask_coupling
from ..instrument.pairs import Instrument, Systematics
from ..mitigation import Deprojection, Filtering
from ..predict import delta_r, expected_residual, tensor_template
from ..predict.template_cost import template_cost
from ..predict.template_error import deprojected_theory, template_error
from ..predict.windows import pixel_window
from ..sky import SkyConfig, make_sky
from .residual import residual, simulate_maps
from .suppression.hwp import RCOND_FOOTPRINT, bands

if TYPE_CHECKING:
    from ..schedule import Schedule

#: the sky's spectra a T-only sky needs: its polarised spectra zeroed (a gain's h_0 term would
#: otherwise leak the theory's P, which the skies do not have)
POLARISED = ("ee", "te", "bb_lens", "ee_tensor", "te_tensor", "bb_tensor")


@dataclass(frozen=True)
class TemplateCheck:
    """The deprojected leak of ``n_skies`` TOD skies and its prediction, per band.

    Attributes
    ----------
    edges : numpy.ndarray
        The bands' edges (``edges[i] <= ell < edges[i + 1]``).
    mean, error : numpy.ndarray
        The skies' mean leak pseudo-C_BB per band and the error of that mean.
    predicted : numpy.ndarray
        The closed form's pseudo-C_BB per band.
    kappa : float
        The fit's share of the template's error (:attr:`TemplateError.kappa`).
    """

    edges: np.ndarray
    mean: np.ndarray
    error: np.ndarray
    predicted: np.ndarray
    kappa: float

    @property
    def ratio(self) -> np.ndarray:
        """The prediction over the skies' mean, per band."""
        return self.predicted / self.mean


def template_error_check(
    schedule: Schedule,
    systematics: Systematics,
    templates: tuple[str, ...],
    *,
    nside: int,
    noise: float,
    n_skies: int,
    template_fwhm_arcmin: float | None = None,
    fwhm_arcmin: float = 60.0,
    band_width: int = 20,
    ell_min: int = 40,
    seed: int = 10,
    progress: bool = False,
) -> TemplateCheck:
    """Deprojected TOD skies against the template error's prediction.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
        The CESs, evaluated exactly at every sample.
    systematics : boresight.instrument.pairs.Systematics
        The systematic the skies leak (a gain or a pointing offset).
    templates : tuple of str
        The template sets fitted per block (``("gain",)`` or ``("pointing",)``).
    nside, n_skies : int
        The maps' resolution (lmax = 2 nside) and the number of skies.
    noise : float
        The template map's white noise over the first sky's rms.
    template_fwhm_arcmin : float, optional
        The template map's beam; the sky's own (``fwhm_arcmin``) by default.
    band_width, ell_min : int
        Bands of ``band_width`` from ``ell_min`` to 2 nside.
    seed : int
        The first sky's seed (sky i has ``seed + i``; the noise its own generator).
    progress : bool
        A progress bar over the skies, with its ETA.
    """
    if templates not in (("gain",), ("pointing",)):
        raise ValueError(f"templates {templates}: the check fits ('gain',) or ('pointing',)")
    if n_skies < 2 or noise <= 0:
        raise ValueError(f"n_skies {n_skies}, noise {noise}: at least 2 skies, noise above 0")
    if 2 * nside <= ell_min:
        raise ValueError(f"nside {nside}: its bands start at ell_min {ell_min}, above 2 nside")
    lmax = 2 * nside
    run = RunOptions(evaluation="exact")
    config = SkyConfig(nside=nside, lmax=lmax, fwhm_arcmin=fwhm_arcmin, seed=1)
    first = make_sky(config).without_polarisation()
    raw = simulate_maps(first, schedule, Instrument(), Systematics(), run=run)
    mask = (raw.rcond > 0.05).astype(float)
    footprint = spectra.as_footprint(mask)
    edges = np.append(np.arange(ell_min, lmax, band_width), lmax + 1)
    sigma = noise * np.std(first.maps[0])
    rng = np.random.default_rng(3)
    measured = []
    with tempfile.TemporaryDirectory() as directory:
        for i in tqdm(range(n_skies), desc="template error skies", disable=not progress):
            config = dataclasses.replace(config, seed=seed + i)
            sky = make_sky(config).without_polarisation()
            template = sky.maps[0]
            if template_fwhm_arcmin is not None:
                at = dataclasses.replace(config, fwhm_arcmin=template_fwhm_arcmin)
                template = make_sky(at).maps[0]
            path = Path(directory) / f"template_{i}.fits"
            noisy = template + sigma * rng.normal(size=template.size)
            hp.write_map(path, noisy, extra_header=[("COORDSYS", "C")], dtype=np.float64)
            deprojection = Deprojection(templates, template_map=str(path))
            job = residual(
                sky,
                schedule,
                systematics,
                footprint,
                lmax,
                run=run,
                filtering=Filtering(deprojection=deprojection),
            )
            measured.append(spectra.bin_spectrum(job.auto, edges)[1])
    theory = load_spectra()
    theory = dataclasses.replace(theory, **dict.fromkeys(POLARISED, np.zeros_like(theory.tt)))
    left = template_error(
        theory.tt,
        lmax=lmax,
        fwhm_arcmin=fwhm_arcmin,
        template_fwhm_arcmin=template_fwhm_arcmin,
        noise_cl=sigma**2 * 4 * np.pi / (12 * nside**2),
        derivatives=0 if templates == ("gain",) else 1,
    )
    # the exact expectation of the schedule's own h_n, the samples' offsets in their pixels too:
    # the noise's gradient is blue, and its leak reads the pixel scale
    stats = scanstats.characterise_schedule(schedule, nside)
    predicted = expected_residual(
        stats.h,
        mask,
        systematics,
        deprojected_theory(theory, left, fwhm_arcmin=fwhm_arcmin),
        fwhm_arcmin,
        lmax=lmax,
        hits=stats.hits,
        evaluation="exact",
        offsets=scanstats.centroid_moments(schedule, nside),
    ).leaked
    measured = np.array(measured)
    return TemplateCheck(
        edges=edges,
        mean=measured.mean(axis=0),
        error=measured.std(axis=0, ddof=1) / np.sqrt(n_skies),
        predicted=spectra.bin_spectrum(predicted, edges)[1],
        kappa=float(left.kappa),
    )


@dataclass(frozen=True)
class CostCheck:
    """What deprojection keeps of the sky's E and B, per band: TOD skies and the prediction.

    Attributes
    ----------
    edges : numpy.ndarray
        The bands' edges (``edges[i] <= ell < edges[i + 1]``).
    ee_kept, bb_kept : numpy.ndarray
        The skies' mean pseudo-C_EE (C_BB) deprojected over their mean raw one, per band.
    ee_error, bb_error : numpy.ndarray
        Their errors: the spread of each sky's own ratio over sqrt(n_skies).
    ee_predicted, bb_predicted : numpy.ndarray
        The predicted pseudo-C_EE and pseudo-C_BB kept: the definite share of E a spin-2
        template takes, read through the footprint's mask, which leaks E into the pseudo-C_BB
        (1 without a spin-2 template).
    correlation : float
        The spin-2 template's zero-lag correlation with the sky's P (0 without one).
    delta_r, delta_r_error : float
        The r the deprojected maps' pseudo-C_BB fakes over the raw maps' (unpurified: the E the
        mask leaks into B), the skies' mean and its error.
    delta_r_predicted : float
        The same from the E the spin-2 template takes (:meth:`TemplateCost.pseudo_bb_taken`).
    """

    edges: np.ndarray
    ee_kept: np.ndarray
    ee_error: np.ndarray
    bb_kept: np.ndarray
    bb_error: np.ndarray
    ee_predicted: np.ndarray
    bb_predicted: np.ndarray
    correlation: float
    delta_r: float
    delta_r_error: float
    delta_r_predicted: float


def template_cost_check(
    schedule: Schedule,
    deprojection: Deprojection,
    *,
    nside: int,
    n_skies: int,
    fwhm_arcmin: float = 60.0,
    edges: np.ndarray | None = None,
    seed: int = 10,
    progress: bool = False,
) -> CostCheck:
    """CAMB skies through the raw and the deprojected pipeline against the predicted cost.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
        The CESs, evaluated exactly at every sample, the paper's Q and U pairs on the boresight.
    deprojection : boresight.mitigation.Deprojection
        The template sets and their blocks, read from each sky itself (not a template map).
    nside, n_skies : int
        The maps' resolution (lmax = 2 nside) and the number of skies.
    fwhm_arcmin : float
        The sky's beam.
    edges : numpy.ndarray, optional
        The bands (default :func:`boresight.jobs.suppression.hwp.bands`' for ``nside``).
    seed : int
        The first sky's seed (sky i has ``seed + i``).
    progress : bool
        A progress bar over the skies, with its ETA.
    """
    if n_skies < 2:
        raise ValueError(f"n_skies {n_skies}: at least 2 skies")
    if not deprojection or deprojection.template_map is not None:
        raise ValueError(
            f"deprojection {deprojection}: the cost check fits templates of the sky itself"
        )
    lmax = 2 * nside
    edges = bands(nside) if edges is None else np.asarray(edges)
    if np.any(np.diff(edges) <= 0) or edges[-1] > lmax + 1:
        raise ValueError(
            f"bands {edges.tolist()}: increasing edges to at most 2 nside + 1 (the default bands "
            "need nside >= 32)"
        )
    run = RunOptions(evaluation="exact")
    config = SkyConfig(nside=nside, lmax=lmax, fwhm_arcmin=fwhm_arcmin, seed=seed)
    footprint, power, bb = None, {"raw": [], "deprojected": []}, {"raw": [], "deprojected": []}
    for i in tqdm(range(n_skies), desc="template cost skies", disable=not progress):
        sky = make_sky(dataclasses.replace(config, seed=seed + i))
        for name, filtering in (
            ("raw", Filtering()),
            ("deprojected", Filtering(deprojection=deprojection)),
        ):
            maps = simulate_maps(
                sky, schedule, Instrument(), Systematics(), run=run, filtering=filtering
            )
            if footprint is None:  # the raw maps' footprint, shared by every sky
                mask = (maps.rcond > RCOND_FOOTPRINT).astype(float)
                footprint = spectra.as_footprint(mask)
            alm = footprint.alm(maps.qu_at(footprint.pixels), lmax, 2)
            cls = [harmonics.alm2cl(a) for a in alm]
            power[name].append([spectra.bin_spectrum(cl, edges)[1] for cl in cls])
            bb[name].append(cls[1])
    raw, dep = (np.array(power[k]) for k in ("raw", "deprojected"))  # (skies, E/B, bands)
    kept = dep.mean(axis=0) / raw.mean(axis=0)
    error = np.std(dep / raw, axis=0, ddof=1) / np.sqrt(n_skies)
    theory = load_spectra()
    cost = template_cost(
        theory, lmax=lmax, fwhm_arcmin=fwhm_arcmin, templates=deprojection.templates
    )
    coupling = mask_coupling(mask, lmax)
    ee_predicted, bb_predicted = cost.pseudo_kept(coupling, edges)
    template = tensor_template(coupling, theory, fwhm_arcmin, nside)
    faked = [delta_r(d - r, template) for d, r in zip(bb["deprojected"], bb["raw"])]
    taken = cost.pseudo_bb_taken(coupling, pixel_window(nside, lmax))
    return CostCheck(
        edges=edges,
        ee_kept=kept[0],
        ee_error=error[0],
        bb_kept=kept[1],
        bb_error=error[1],
        ee_predicted=ee_predicted,
        bb_predicted=bb_predicted,
        correlation=cost.correlation,
        delta_r=float(np.mean(faked)),
        delta_r_error=float(np.std(faked, ddof=1) / np.sqrt(n_skies)),
        delta_r_predicted=delta_r(taken, template),
    )
