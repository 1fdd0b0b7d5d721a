"""The transfer function of a filtering pipeline: what a filter does to each polarised bandpower.

A pair-differencing pipeline maps Q and U alone, so its transfer function is the polarised block
of SOOPERCOOL's 9x9 one. A pure-E and a pure-B sky of one Gaussian draw (C_ell = (ell + 10)^-2
[muK^2] before the sky's beam, :func:`pure_skies`) are simulated on a schedule, binned from the
raw pair differences and from the filtered ones; the masked pseudo-C_ell of every pair of the two
maps' fields (EE, EB, BE, BB) for every pair of pure skies ((E, E), (E, B), (B, E), (B, B)) are
binned into bandpowers. The transfer matrix T_b of band b is SOOPERCOOL's
(``coupling_utils.get_transfer_with_error``): the least-squares solution of C_filtered = C_raw
T_b over the pure pairs, with C the (pure pair, field pair) matrix of mean bandpowers; its error
is the spread over the realisations of the same solution for each realisation's filtered
bandpowers. ``T[i, j, b]`` is field pair j's share of field pair i's filtered power
(SOOPERCOOL's ``"{j}_to_{i}"``): ``T[BB, BB]`` is the F_ell^BB most people quote, ``T[BB, EE]``
the E-to-B leakage the filter makes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import harmonics, spectra
from .._util import interrupts
from ..config import RunOptions
from ..instrument.pairs import Instrument, Systematics
from ..mitigation import Filtering
from ..sky import Sky, gaussian_alm, sky_of_alm
from .residual import simulate_maps

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane
    from ..schedule import Schedule

#: the fields of a pair of polarised maps, in SOOPERCOOL's order of its 9 (T dropped)
FIELD_PAIRS = ("EE", "EB", "BE", "BB")
#: the pure skies (each pair of them, crossed too, makes a row of the transfer's least squares)
PURE = ("E", "B")
#: the same with T: SOOPERCOOL's 9 fields and pure skies, for the detectors' map-maker
PURE_TEB = ("T", "E", "B")
FIELD_PAIRS_TEB = tuple(a + b for a in PURE_TEB for b in PURE_TEB)
#: the pure skies' spectrum before the beam: C_ell = (ell + ELL_0)^-2 [muK^2]
ELL_0 = 10.0


@dataclass(frozen=True)
class Transfer:
    """A filter's polarised transfer matrix per band.

    Parameters
    ----------
    edges : numpy.ndarray of int
        The bands' edges [lo, hi).
    matrix, error : numpy.ndarray, shape (F, F, n_bands)
        T[i, j, b], field pair j into field pair i (of ``fields``), and its error.
    n_sims : int
    fields : tuple of str
        The F field pairs: :data:`FIELD_PAIRS` (the pairs' map-maker, Q and U) or
        :data:`FIELD_PAIRS_TEB` (the detectors', I too).
    """

    edges: np.ndarray
    matrix: np.ndarray
    error: np.ndarray
    n_sims: int
    fields: tuple = FIELD_PAIRS

    def entry(self, into: str, source: str) -> np.ndarray:
        """T[into, source] per band, e.g. ``entry("BB", "BB")``, F_ell^BB."""
        return self.matrix[self.fields.index(into), self.fields.index(source)]

    def entry_error(self, into: str, source: str) -> np.ndarray:
        """The error of :meth:`entry` per band."""
        return self.error[self.fields.index(into), self.fields.index(source)]

    def rows(self) -> list[dict]:
        """A row per band and entry: its band, the pair of fields from and to, value and error."""
        out = []
        for b, (lo, hi) in enumerate(zip(self.edges[:-1], self.edges[1:])):
            for i, into in enumerate(self.fields):
                for j, source in enumerate(self.fields):
                    out.append(
                        {
                            "ell_lo": int(lo),
                            "ell_hi": int(hi - 1),
                            "from": source,
                            "to": into,
                            "transfer": float(self.matrix[i, j, b]),
                            "error": float(self.error[i, j, b]),
                        }
                    )
        return out


def soopercool_transfer(
    mean_filtered: np.ndarray, mean_raw: np.ndarray, filtered: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The transfer matrix and its error from pure skies' bandpowers, SOOPERCOOL's estimator.

    Parameters
    ----------
    mean_filtered, mean_raw : numpy.ndarray, shape (n_pure_pairs, n_field_pairs, n_bands)
        Mean bandpowers over the realisations, filtered and raw.
    filtered : numpy.ndarray, shape (n_sims, n_pure_pairs, n_field_pairs, n_bands)
        Each realisation's filtered bandpowers.

    Returns
    -------
    matrix, error : numpy.ndarray, shape (n_field_pairs, n_field_pairs, n_bands)
        T[i, j, b] with C_filtered[:, i] = sum_j C_raw[:, j] T[i, j], solved by least squares
        over the pure pairs band by band; the error is the standard deviation (ddof 0, as
        SOOPERCOOL's) of the same solution for each realisation.
    """

    def solve(raw, filt):
        # band b: raw[:, :, b] X = filt[:, :, b], X (n_field, n_field); T[i, j] = X[j, i]
        out = np.empty((raw.shape[1], raw.shape[1], raw.shape[2]))
        for b in range(raw.shape[2]):
            out[:, :, b] = np.linalg.lstsq(raw[:, :, b], filt[:, :, b], rcond=None)[0].T
        return out

    matrix = solve(mean_raw, mean_filtered)
    error = np.std([solve(mean_raw, one) for one in filtered], axis=0)
    return matrix, error


#: the pure skies' temperature draw, where a pipeline deprojects, is seeded seed ^ this
TEMPERATURE_SALT = 1 << 40


def pure_skies(
    nside: int,
    *,
    lmax: int,
    fwhm_arcmin: float,
    seed: int,
    temperature: bool = False,
    pure: tuple = PURE,
) -> dict:
    """A sky of E alone and one of B alone (and with ``pure`` :data:`PURE_TEB`, one of T alone)
    with the same alm (SOOPERCOOL's: one draw of fully correlated power laws), C_ell = (ell +
    :data:`ELL_0`)^-2 before the beam, so that every pair of them, the crossed ones too, carries
    power.

    Parameters
    ----------
    nside, lmax : int
    fwhm_arcmin : float
    seed : int
    temperature : bool
        Give both skies one T of the same spectrum, drawn apart (seed ^ :data:`TEMPERATURE_SALT`)
        and so uncorrelated with their E and B: the templates a deprojecting pipeline reads
        from T, which fit the polarisation only by chance.
    pure : tuple of str
        :data:`PURE` or :data:`PURE_TEB`.

    Returns
    -------
    dict
        Each of ``pure`` -> boresight.sky.Sky.
    """
    ell = np.arange(lmax + 1)
    power = (ell + ELL_0) ** -2.0
    power[:2] = 0.0
    zero = np.zeros(lmax + 1)
    draw = gaussian_alm((power, zero, zero, zero), lmax, seed)[0]
    if temperature:
        t = gaussian_alm((power, zero, zero, zero), lmax, seed ^ TEMPERATURE_SALT)[0]
    out = {}
    for which in pure:
        alm = np.zeros((3, draw.size), dtype=np.complex128)
        alm["TEB".index(which)] = draw
        if temperature:
            alm[0] = t
        out[which] = sky_of_alm(alm, nside, fwhm_arcmin=fwhm_arcmin)
    return out


def transfer_function(
    schedule: Schedule,
    filtering: Filtering,
    footprint: np.ndarray | spectra.Footprint,
    edges: np.ndarray,
    *,
    nside: int,
    fwhm_arcmin: float = 60.0,
    n_sims: int = 8,
    seed: int = 0,
    run: RunOptions = RunOptions(),
    focalplane: FocalPlane | None = None,
    intensity: bool = False,
    evaluation: str | None = None,
) -> Transfer:
    """The filter's polarised transfer matrix on a schedule, from ``n_sims`` pairs of pure-E and
    pure-B skies through the raw and the filtered pipeline (the paper's Q and U pairs on the
    boresight, or a focal plane's pairs); with ``intensity``, SOOPERCOOL's 9x9 matrix from
    pure-T, E and B skies through the detectors' map-maker, each detector's TOD filtered. A pipeline that deprojects reads its templates from a
    T the skies share, drawn apart from their E and B (:func:`pure_skies`): what the templates
    take by chance; what they take through the sky's TE correlation is
    :func:`boresight.jobs.suppression.filtered.run`'s ``kept``.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    filtering : boresight.mitigation.Filtering
    footprint : numpy.ndarray, shape (npix,), or boresight.spectra.Footprint
        The mask the pseudo-C_ell are taken on; its pixels must be observed.
    edges : numpy.ndarray of int
        Band edges, within 2 .. 2 nside + 1.
    nside : int
    fwhm_arcmin : float
        The skies' beam.
    n_sims : int
        Realisations, >= 2 (the error's spread).
    seed : int
        Realisation i's skies are drawn from seed x 1000003 + i.
    run : boresight.config.RunOptions
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        Every pair at its own place (default the paper's pairs on the boresight).
    intensity : bool
        The T block too (:data:`FIELD_PAIRS_TEB`), from I, Q and U solved per pixel from each
        detector's own filtered samples (``mapmaker="detectors"``); a pipeline that deprojects
        regresses from the pair differences and is refused.
    evaluation : {"interp", "exact", "pixel"}, optional
        How the TOD reads the skies, default ``run.evaluation``. ``"pixel"`` reads each map's
        value in the sample's pixel, the sky a TOAST observation matrix acts on: with it F_ell^TT
        of a polynomial per throw equals the one TOAST's ``FilterBin`` observation matrix gives on
        the same skies to 0.14 % (``tests/jobs/test_transfer.py``). The interpolated TOD is
        smoother within a pixel: on the deep example's footprint at Nside 32 its F_ell^TT is the
        pixelised one's within 2 %, on the test's 110-pixel footprint 12-14 % lower.

    Returns
    -------
    Transfer
    """
    if n_sims < 2:
        raise ValueError(f"n_sims = {n_sims}: the error needs at least 2 realisations")
    if intensity and filtering.deprojection:
        raise ValueError(
            f"the T block takes each detector's TOD; deprojecting {filtering.deprojection} "
            "regresses from the pair differences"
        )
    pure, fields = (PURE_TEB, FIELD_PAIRS_TEB) if intensity else (PURE, FIELD_PAIRS)
    pure_pairs = tuple((a, b) for a in pure for b in pure)
    footprint = spectra.as_footprint(footprint)
    lmax = 2 * nside
    pipelines = {"raw": Filtering(), "filtered": filtering}
    bandpowers = {
        k: np.empty((n_sims, len(fields), len(fields), len(edges) - 1)) for k in pipelines
    }
    options = dict(run=run, filtering=None, mapmaker="detectors" if intensity else "pairs")
    options["evaluation"] = evaluation
    for i in range(n_sims):
        skies = pure_skies(
            nside,
            lmax=lmax,
            fwhm_arcmin=fwhm_arcmin,
            seed=seed * 1_000_003 + i,
            temperature=bool(filtering.deprojection),
            pure=pure,
        )
        for name, pipeline in pipelines.items():
            alm = {}
            for which, sky in skies.items():
                interrupts.check()
                options["filtering"] = pipeline
                maps = simulate_maps(
                    sky, schedule, Instrument(), Systematics(), focalplane=focalplane, **options
                )
                alm[which] = footprint.alm(maps.qu_at(footprint.pixels), lmax, 2)
                if intensity:
                    t_alm = footprint.alm(maps.i_at(footprint.pixels), lmax, 0)
                    alm[which] = np.vstack([t_alm, alm[which]])
            for p, (a, b) in enumerate(pure_pairs):
                for f, (x, y) in enumerate(fields):
                    cl = harmonics.alm2cl(alm[a][pure.index(x)], alm[b][pure.index(y)])
                    bandpowers[name][i, p, f] = spectra.bin_spectrum(cl, edges)[1]
    matrix, error = soopercool_transfer(
        bandpowers["filtered"].mean(axis=0),
        bandpowers["raw"].mean(axis=0),
        bandpowers["filtered"],
    )
    return Transfer(np.asarray(edges), matrix, error, n_sims, fields)


#: the noise Monte Carlo's uniform T [muK] and gain jitter: a jitter on detector B of a pair that
#: sees a uniform T is white noise in its pair difference (rms 0.5 x jitter x T), so the
#: engine's own stream, filters and binning carry it unchanged
NOISE_T_UK = 100.0
NOISE_JITTER = 0.01


@dataclass(frozen=True)
class NoiseTransfer:
    """What a filter keeps of a white noise's pseudo-power per band.

    Parameters
    ----------
    edges : numpy.ndarray of int
        The bands' edges [lo, hi).
    kept, error : numpy.ndarray, shape (2, n_bands)
        EE and BB: the mean over realisations of the filtered noise maps' pseudo-C_ell over the
        raw ones' (the same draws through both pipelines), and its standard error.
    n_sims : int
    """

    edges: np.ndarray
    kept: np.ndarray
    error: np.ndarray
    n_sims: int

    def entry(self, field: str) -> np.ndarray:
        """K_b of ``"EE"`` or ``"BB"``: the share of the noise's power the filter keeps."""
        return self.kept[("EE", "BB").index(field)]

    def entry_error(self, field: str) -> np.ndarray:
        """The standard error of :meth:`entry`."""
        return self.error[("EE", "BB").index(field)]


def noise_transfer(
    schedule: Schedule,
    filtering: Filtering,
    footprint: np.ndarray | spectra.Footprint,
    edges: np.ndarray,
    *,
    nside: int,
    n_sims: int = 4,
    run: RunOptions = RunOptions(),
    focalplane: FocalPlane | None = None,
) -> NoiseTransfer:
    """What a filter keeps of white detector noise, per band: ``n_sims`` realisations of white
    noise in every pair difference (a gain jitter on a uniform T, :data:`NOISE_T_UK`,
    :data:`NOISE_JITTER`; realisation i draws with seed i) through the raw and the filtered
    pipeline, the masked pseudo-C_ell^EE and BB of each, binned, filtered over raw. The same
    draw enters both pipelines, so the ratio is paired and its error small. A polynomial of
    order p per throw of n samples removes (p + 1) / n of a white noise's variance, on the
    scales along the scan where it removes the sky; on a footprint's pseudo-spectrum a band's
    white noise comes mostly from the many smaller scales the mask couples in, which the filter
    keeps, so K_b stays near 1 where F_b^BB (a red sky's, coupled in from larger scales) is
    small, and N_ell / F_b^BB (the raw noise read through the filter) is close to a
    white noise's filtered N_ell K_b / F_b^BB. A 1/f noise, whose low frequencies a filter
    removes, is not simulated.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
    filtering : boresight.mitigation.Filtering
        Filters only: templates regressed from a uniform T would be a constant, not the
        pipeline's, so a pipeline that deprojects is refused.
    footprint : numpy.ndarray, shape (npix,), or boresight.spectra.Footprint
    edges : numpy.ndarray of int
        Band edges, within 2 .. 2 nside + 1.
    nside : int
    n_sims : int
        Realisations, >= 2.
    run : boresight.config.RunOptions
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        Every pair at its own place (default the paper's pairs on the boresight).

    Returns
    -------
    NoiseTransfer
    """
    if n_sims < 2:
        raise ValueError(f"n_sims = {n_sims}: the error needs at least 2 realisations")
    if filtering.deprojection:
        raise ValueError(
            f"the noise's transfer runs filters only, not deprojecting {filtering.deprojection}"
            " (its templates of a uniform T would be a constant)"
        )
    footprint = spectra.as_footprint(footprint)
    lmax = 2 * nside
    maps = np.zeros((3, 12 * nside**2))
    maps[0] = NOISE_T_UK
    uniform = Sky.from_maps(maps, lmax=lmax)
    power = np.empty((n_sims, 2, 2, len(edges) - 1))  # realisation, raw/filtered, EE/BB, band
    for i in range(n_sims):
        noise = Systematics(dg_jitter=NOISE_JITTER, seed=i)
        for p, pipeline in enumerate((Filtering(), filtering)):
            interrupts.check()
            out = simulate_maps(
                uniform,
                schedule,
                Instrument(),
                noise,
                run=run,
                filtering=pipeline,
                focalplane=focalplane,
            )
            alm = footprint.alm(out.qu_at(footprint.pixels), lmax, 2)
            for f in range(2):
                power[i, p, f] = spectra.bin_spectrum(harmonics.alm2cl(alm[f]), edges)[1]
    ratio = power[:, 1] / power[:, 0]
    kept = power[:, 1].mean(axis=0) / power[:, 0].mean(axis=0)
    error = ratio.std(axis=0, ddof=1) / np.sqrt(n_sims)
    return NoiseTransfer(np.asarray(edges), kept, error, n_sims)
