"""The one job every command runs: the residual B-mode that a systematic leaves in a scan's maps.

sky + scan + instrument + systematics + mask + run options -> simulate with and without the
systematic -> residual pseudo-C_BB (its cross part 2 Re<B, dB> and its leaked power <dB, dB>) ->
h_n prediction (C_ell level, and optionally map level) -> one :class:`Residual`. ``reproduce`` runs
it per experiment and rotation angle, ``simulate`` once, ``sweep`` once per point and
``compare-scans`` once per scan, and :func:`band_rows` makes every table from its result.

The spherical-harmonic transforms go through a :class:`boresight.jobs.transforms.Transforms` queue,
inline or overlapping the next job's simulation; either way the numbers are the same bits.
"""

from __future__ import annotations

import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from .. import engine, harmonics, predict, spectra
from .._util import interrupts
from ..config import RunOptions, Study
from ..cosmology import load_spectra
from ..coupling import Coupling, mask_coupling
from ..evaluation import ENGINE_METHODS
from ..instrument.focalplane import FocalPlane
from ..instrument.hwp import HWP
from ..instrument.pairs import Instrument, Systematics
from ..mapmaking import Maps
from ..masks import from_config
from ..mitigation import Filtering
from ..moments import Moments, compute_moments
from ..scan import SyntheticScan
from ..schedule import Schedule
from ..sky import Sky
from .transforms import Transforms

N_MAX = predict.N_MAX


@dataclass(frozen=True)
class Reference:
    """The no-systematic side of a residual.

    Parameters
    ----------
    qu : numpy.ndarray, shape (2, nobs), optional
        Q, U [muK] of the reference maps on the mask's observed pixels (``flatnonzero(mask)``),
        0 where invalid; None for the zero reference.
    b_alm : concurrent.futures.Future, optional
        Of the B alm (nalm,) of the masked reference maps.

    Notes
    -----
    ``Reference.zero()`` is the empty reference: the residual is then the systematic's own spectrum
    (the paper's Q = U = 0 check), and the cross part is 0.
    """

    qu: np.ndarray = None
    b_alm: Future = None

    @classmethod
    def zero(cls):
        return cls()


@dataclass
class Residual:
    """A residual job's result: unbinned spectra (lmax + 1,) [muK^2] from ell = 0.

    Parameters
    ----------
    parts : concurrent.futures.Future
        Of (cross, auto): 2 Re<B, dB> and <dB, dB>, resolved on first use of :attr:`cross`,
        :attr:`auto` or :attr:`total` (C_BB(sys) - C_BB(no sys)).
    predicted_cl : numpy.ndarray, optional
        The h_n prediction of the residual pseudo-C_BB (None when not predicted).
    predicted_map_parts : concurrent.futures.Future, optional
        Of the (cross, auto) of the predicted spurious map; :attr:`predicted_map` is their sum.
    h_power : dict
        ``<|h_n|^2>`` over the observed pixels, n = 1..4 (with a prediction).
    maps : tuple of boresight.mapmaking.Maps, optional
        (reference, with systematic), when kept; the reference is None when it was shared.
    stages : dict
        Seconds spent simulating and predicting.
    zero_qu : Residual, optional
        The same hits over the sky with Q = U = 0, against no reference (the systematic's own
        spectrum: the paper's check that the residual comes from the polarised sky), when asked
        for.
    """

    parts: Future
    predicted_cl: np.ndarray = None
    predicted_map_parts: Future = None
    h_power: dict = field(default_factory=dict)
    maps: tuple = None
    stages: dict = field(default_factory=dict)
    zero_qu: Residual = None

    @property
    def cross(self):
        return interrupts.result(self.parts)[0]

    @property
    def auto(self):
        return interrupts.result(self.parts)[1]

    @property
    def total(self):
        return self.cross + self.auto

    @property
    def predicted_map(self):
        parts = self.predicted_map_parts
        return None if parts is None else sum(interrupts.result(parts))

    #: the band-table columns (results.csv, bands.csv, sweep tables) and the spectrum each bins:
    #: a new column is one entry here
    COLUMNS: ClassVar[dict] = {
        "residual_bb": "total",
        "residual_auto_bb": "auto",
        "residual_cross_bb": "cross",
        "predicted_bb": "predicted_cl",
    }

    def columns(self):
        """The unbinned spectra of the band tables.

        Returns
        -------
        dict
            Column name (:attr:`COLUMNS`) -> (lmax + 1,) array [muK^2], or None where not computed.
        """
        return {name: getattr(self, spectrum) for name, spectrum in self.COLUMNS.items()}


def simulate_maps(
    sky: Sky,
    scan: SyntheticScan | Schedule,
    instrument: Instrument,
    systematics: Systematics,
    *,
    pixels: np.ndarray | None = None,
    run: RunOptions = RunOptions(),
    leak_template: np.ndarray | None = None,
    focalplane: FocalPlane | None = None,
    filtering: Filtering = Filtering(),
    hwp: HWP | None = None,
    mapmaker: str = "pairs",
    evaluation: str | None = None,
    progress: bool = False,
) -> Maps:
    """Maps of a synthetic or a real scan.

    Parameters
    ----------
    sky : boresight.sky.Sky
    scan : boresight.scan.SyntheticScan or boresight.schedule.Schedule
        A real schedule's sample stream covers its own pixels (``pixels`` is then unused).
    instrument : boresight.instrument.pairs.Instrument
    systematics : boresight.instrument.pairs.Systematics
    pixels : numpy.ndarray, optional
        Pixels a synthetic scan observes: a boolean map (npix,) or increasing RING indices (the
        engine then keeps them without a copy); default: all.
    run : boresight.config.RunOptions
    leak_template : numpy.ndarray, optional
        (npix,) template of the additive leak [muK].
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        A real schedule seen by every pair of this focal plane from its own place
        (:func:`boresight.engine.simulate_focalplane`), in place of ``instrument``'s pairs on the
        boresight.
    filtering : boresight.mitigation.Filtering
        What the pipeline filters before binning (:func:`boresight.engine.simulate_schedule`,
        :func:`boresight.engine.simulate_focalplane`): a real schedule's only.
    hwp : boresight.instrument.hwp.HWP, optional
        A half-wave plate in front of ``focalplane``'s pairs
        (:func:`boresight.engine.simulate_focalplane`).
    mapmaker : str
        How a real schedule's samples become maps (:data:`boresight.mapmaking.MAPMAKERS`):
        ``"detectors"`` gives I too, each detector's TOD filtered alike where ``filtering``
        filters.
    evaluation : {"interp", "exact", "pixel"}, optional
        How the TOD reads the sky, default ``run.evaluation``; ``"pixel"`` (the engine's alone:
        no prediction reads it) takes each map's value in the sample's pixel, as TOAST's
        ``ScanHealpixMap`` and an observation matrix do.
    progress : bool

    Returns
    -------
    boresight.mapmaking.Maps
    """
    maps, _ = _simulate(
        sky,
        scan,
        instrument,
        systematics,
        pixels,
        run,
        leak_template,
        progress,
        zero_qu=False,
        focalplane=focalplane,
        filtering=filtering,
        hwp=hwp,
        mapmaker=mapmaker,
        evaluation=evaluation,
    )
    return maps


def _simulate(
    sky,
    scan,
    instrument,
    systematics,
    pixels,
    run,
    leak_template,
    progress,
    zero_qu,
    focalplane,
    filtering=Filtering(),
    hwp=None,
    mapmaker="pairs",
    evaluation=None,
):
    """(maps, the maps of Q = U = 0 from the same hits with ``zero_qu``, else None)."""
    if evaluation is not None and evaluation not in ENGINE_METHODS:
        raise ValueError(f"evaluation = {evaluation!r}; allowed: {ENGINE_METHODS}")
    on_samples = dict(
        evaluation=run.evaluation if evaluation is None else evaluation,
        leak_template=leak_template,
        nthreads=run.nthreads,
        backend=run.backend,
        rcond_min=run.rcond_min,
        mapmaker=mapmaker,
    )
    if mapmaker != "pairs" and not isinstance(scan, Schedule):
        raise ValueError(
            f"mapmaker {mapmaker!r} takes a real schedule's samples, not a synthetic scan"
        )
    if filtering and not isinstance(scan, Schedule):
        raise ValueError(
            f"filtering ({filtering}) acts per throw and per CES: it needs a real schedule, and a "
            "synthetic scan has neither"
        )
    if hwp is not None and focalplane is None:
        raise ValueError("a half-wave plate here goes in front of a focal plane's pairs")
    if focalplane is not None:
        if not isinstance(scan, Schedule):
            raise ValueError(
                "a focal plane needs a real schedule: a synthetic scan has no pointing"
            )
        maps = engine.simulate_focalplane(
            sky,
            scan,
            focalplane,
            systematics,
            filtering=filtering,
            hwp=hwp,
            progress=progress,
            **on_samples,
        )
        return maps, None
    if isinstance(scan, Schedule):
        maps = engine.simulate_schedule(
            sky, scan, instrument, systematics, filtering=filtering, progress=progress, **on_samples
        )
        return maps, None
    options = dict(pixels=pixels, leak_template=leak_template, progress=progress)
    if zero_qu:
        return engine.simulate_with_zero_qu(
            sky, scan, instrument, systematics, **options, **run.engine_kwargs()
        )
    maps = engine.simulate(sky, scan, instrument, systematics, **options, **run.engine_kwargs())
    return maps, None


def n_max_for(systematics: Systematics) -> int:
    """The highest h_n a prediction of these systematics uses: the beams' reach h_6
    (:data:`boresight.predict.BEAM_N_MAX`), the others h_4, an added systematic its own n.

    Parameters
    ----------
    systematics : boresight.instrument.pairs.Systematics

    Returns
    -------
    int
    """
    n_max = predict.BEAM_N_MAX if systematics.has_beams else N_MAX
    return max([n_max] + [abs(one.n) for one in systematics.added_on])


def _masked_b(qu, footprint, lmax, run, overwrite=True):
    """B alm of (2, nobs) Q, U on the footprint's pixels, masked in place unless ``overwrite`` is
    False (the reference's maps, which later jobs read)."""
    eb = footprint.alm(
        qu, lmax, 2, nthreads=run.nthreads, analysis=run.analysis, overwrite=overwrite
    )
    return eb[1].copy()  # not a view that keeps E alive with the reference


def simulate_reference(
    sky: Sky,
    scan: SyntheticScan | Schedule,
    mask: np.ndarray | spectra.Footprint,
    lmax: int,
    *,
    instrument: Instrument = Instrument(),
    run: RunOptions = RunOptions(),
    focalplane: FocalPlane | None = None,
    filtering: Filtering = Filtering(),
    hwp: HWP | None = None,
    transforms: Transforms | None = None,
    progress: bool = False,
) -> tuple[Reference, Maps]:
    """Simulate a scan without a systematic.

    Parameters
    ----------
    sky, scan, instrument, run, focalplane, filtering, hwp, progress
        As in :func:`residual`.
    mask : numpy.ndarray, shape (npix,), or boresight.spectra.Footprint
        Weights in [0, 1]; pixels with weight > 0 are simulated.
    lmax : int
    transforms : Transforms, optional
        Where the B alm is computed (default: inline).

    Returns
    -------
    reference : Reference
    maps : boresight.mapmaking.Maps
    """
    footprint = spectra.as_footprint(mask)
    maps = simulate_maps(
        sky,
        scan,
        instrument,
        Systematics(),
        pixels=footprint.pixels,
        run=run,
        focalplane=focalplane,
        filtering=filtering,
        hwp=hwp,
        progress=progress,
    )
    return reference_from_maps(maps, footprint, lmax, run=run, transforms=transforms), maps


def reference_from_maps(
    maps: Maps,
    mask: np.ndarray | spectra.Footprint,
    lmax: int,
    *,
    run: RunOptions = RunOptions(),
    transforms: Transforms | None = None,
) -> Reference:
    """The :class:`Reference` of simulated no-systematic maps.

    Parameters
    ----------
    maps : boresight.mapmaking.Maps
    mask : numpy.ndarray, shape (npix,), or boresight.spectra.Footprint
        The mask, or its footprint when already built.
    lmax : int
    run : boresight.config.RunOptions
    transforms : Transforms, optional

    Returns
    -------
    Reference
        Their Q, U on the observed pixels and a Future of the B alm of the masked maps.
    """
    transforms = Transforms() if transforms is None else transforms
    footprint = spectra.as_footprint(mask)
    qu = maps.qu_at(footprint.pixels)
    return Reference(qu, transforms.submit(_masked_b, qu, footprint, lmax, run, False))


def _parts(d_qu, ref, footprint, lmax, run):
    """(cross, auto) from the difference map (2, nobs) on the footprint's pixels, which the job
    owns; the cross part is 0 against a zero reference."""
    if ref.qu is None:
        auto = harmonics.alm2cl(_masked_b(d_qu, footprint, lmax, run))
        return np.zeros_like(auto), auto
    b_ref = ref.b_alm.result()
    return spectra.difference_bb_parts(
        d_qu,
        b_ref,
        footprint,
        lmax,
        nthreads=run.nthreads,
        analysis=run.analysis,
        overwrite=True,
    )


def _as_qu(p):
    """(2, n) Q, U of P = Q + i U (n,) complex128, as a view of its memory: a copy would be alive
    beside it at the peak of the Nside-2048 reproduction (0.3 GB)."""
    return p.view(np.float64).reshape(p.size, 2).T


def _difference_parts(sim_qu, ref, footprint, lmax, run):
    if ref.qu is not None:
        sim_qu -= ref.qu  # in place: the job owns its maps
    return _parts(sim_qu, ref, footprint, lmax, run)


def residual(
    sky: Sky,
    scan: SyntheticScan | Schedule,
    systematics: Systematics,
    mask: np.ndarray | spectra.Footprint,
    lmax: int,
    *,
    instrument: Instrument = Instrument(),
    run: RunOptions = RunOptions(),
    reference: Reference | None = None,
    prediction: predict.Prediction | None = None,
    predict_map: bool = False,
    moments: Moments | None = None,
    leak_template: np.ndarray | None = None,
    focalplane: FocalPlane | None = None,
    filtering: Filtering = Filtering(),
    hwp: HWP | None = None,
    transforms: Transforms | None = None,
    keep_maps: bool = False,
    zero_qu: bool = False,
    progress: bool = False,
) -> Residual:
    """Simulate ``scan`` over ``sky`` with ``systematics`` and return its :class:`Residual`.

    Parameters
    ----------
    sky : boresight.sky.Sky
    scan : boresight.scan.SyntheticScan or boresight.schedule.Schedule
    systematics : boresight.instrument.pairs.Systematics
    mask : numpy.ndarray, shape (npix,), or boresight.spectra.Footprint
        Weights in [0, 1] (RING); pixels with weight > 0 are simulated. Jobs on one mask share
        its footprint when given one (:func:`boresight.spectra.as_footprint`).
    lmax : int
        Band limit of the spectra.
    instrument : boresight.instrument.pairs.Instrument
    run : RunOptions
        Evaluation, backend, chunking and threads of the engine.
    reference : Reference, optional
        The no-systematic side, when shared by several jobs (the same sky and scan positions);
        simulated here by default. ``Reference.zero()`` measures the systematic's own spectrum.
    prediction : boresight.predict.Prediction, optional
        Predict the residual from h_n; the C_ell level where :func:`boresight.predict.supports`
        the instrument and its repeats.
    predict_map : bool
        Also transform the predicted spurious map (the map-level check); always with an added
        systematic (:mod:`boresight.instrument.added`), which only the map level predicts.
    moments : Moments, optional
        The moments of a synthetic ``scan``'s one repeat (:func:`compute_moments`), when several jobs
        share them (the same scan at other rotations); ``scan``'s rotations replace theirs.
    leak_template : numpy.ndarray, optional
        Template map of the additive leak (default: the sky's I).
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        Simulate a real schedule with every pair of this focal plane, each from its own place
        (:func:`simulate_maps`). Its residual is predicted by
        :func:`boresight.predict.focalplane.expected_residual`, not here: no ``prediction``.
    filtering : boresight.mitigation.Filtering
        What the pipeline filters before binning, on a real schedule's pairs on the boresight or
        on ``focalplane`` (:func:`simulate_maps`), the reference's as the systematic's. Its
        leak is not predicted yet: no ``prediction`` with a filter.
    hwp : boresight.instrument.hwp.HWP, optional
        A half-wave plate in front of ``focalplane``'s pairs, the reference's as the
        systematic's; predicted by :mod:`boresight.predict.focalplane` and
        :mod:`boresight.predict.hwp`, not here.
    transforms : Transforms, optional
        Where the transforms run (default: inline).
    keep_maps : bool
        Keep (reference, systematic) Maps in the result.
    zero_qu : bool
        Also :attr:`Residual.zero_qu`, from the same hits (a synthetic scan's, without detector
        beams): the numbers of this job over ``sky.without_polarisation()`` against
        ``Reference.zero()``, without a second simulation.
    progress : bool
        Show a progress bar.

    Returns
    -------
    Residual
    """
    if zero_qu and isinstance(scan, Schedule):
        raise ValueError("zero_qu needs a synthetic scan; simulate sky.without_polarisation()")
    if focalplane is not None and (prediction is not None or predict_map):
        raise ValueError(
            "a focal plane's residual is predicted by predict.focalplane.expected_residual"
        )
    if filtering and (prediction is not None or predict_map):
        raise ValueError(f"a filtered leak ({filtering}) is not predicted yet: no prediction")
    transforms = Transforms() if transforms is None else transforms
    stages, t0 = {}, time.perf_counter()
    footprint = spectra.as_footprint(mask)
    pixels = footprint.pixels
    ref_maps = None
    if reference is None:
        reference, ref_maps = simulate_reference(
            sky,
            scan,
            footprint,
            lmax,
            instrument=instrument,
            run=run,
            focalplane=focalplane,
            filtering=filtering,
            hwp=hwp,
            transforms=transforms,
            progress=progress,
        )
    # the last map-level check of a prediction (Prediction.last_map_check) predicts first: the
    # T gradient it reads (0.3 GB on the wide mask at Nside 2048) then goes before the simulated
    # maps exist; the others predict after simulating, to make the gradient as late as they can
    first = (
        prediction is not None
        and (predict_map or systematics.added)
        and systematics.has_pointing
        and prediction.last_map_check
    )

    def predicted():  # (h power, C_ell prediction, the map level's future or None), timed
        start = time.perf_counter()
        mom = _job_moments(scan, sky.nside, pixels, run, systematics, moments)
        power, cl = _predicted_cl(
            sky, scan, mom, systematics, instrument, footprint, prediction, run
        )
        map_parts = None
        if predict_map or systematics.added:
            dp = _predicted_map(
                sky, mom, systematics, instrument, prediction, leak_template, pixels, run
            )
            map_parts = transforms.submit(_parts, _as_qu(dp), reference, footprint, lmax, run)
            del dp  # the job owns it
        stages["predict"] = time.perf_counter() - start
        return power, cl, map_parts

    ahead = predicted() if first else None
    sim, sim_qu0 = _simulate(
        sky,
        scan,
        instrument,
        systematics,
        pixels,
        run,
        leak_template,
        progress,
        zero_qu,
        focalplane,
        filtering,
        hwp,
    )
    # the maps' own Q, U go to the queue, and the maps are let go before a full queue makes the
    # submit wait: at the Nside-2048 peak copies waited beside their maps (1.1 GB)
    qu = sim.qu_at(pixels) if keep_maps else sim.take_qu(pixels)
    qu0 = None if sim_qu0 is None else sim_qu0.take_qu(pixels)
    maps = (ref_maps, sim) if keep_maps else None  # kept in the result only when asked for
    del sim, sim_qu0
    parts = transforms.submit(_difference_parts, qu, reference, footprint, lmax, run)
    del qu  # the job owns it
    stages["simulate"] = time.perf_counter() - t0 - stages.get("predict", 0.0)
    result = Residual(parts, maps=maps, stages=stages)
    if zero_qu:
        result.zero_qu = Residual(
            transforms.submit(_difference_parts, qu0, Reference.zero(), footprint, lmax, run)
        )
    del qu0
    if prediction is None:
        return result
    result.h_power, result.predicted_cl, result.predicted_map_parts = (
        ahead if first else predicted()
    )
    return result


def _predicted_cl(sky, scan, moments, systematics, instrument, footprint, prediction, run):
    """(<|h_n|^2> n = 1..4 of the rotated scan, the C_ell prediction or None where it has none)."""
    power = {n: float(moments.rotated_power(n)) for n in range(1, N_MAX + 1)}
    # an added systematic's term is the map level's alone (boresight.instrument.added)
    if not predict.supports(instrument, moments.rotations_deg) or systematics.added:
        return power, None
    return power, predict.residual_pseudo_bb(
        moments.h,
        footprint,
        prediction,
        systematics,
        instrument=instrument,
        rotations_deg=moments.rotations_deg,
        crossings=moments.crossings,
        # the hits' spread over their pixels, and the maps read by interpolation there
        in_pixel=getattr(scan, "in_pixel", "random"),
        interpolated=run.evaluation == "interp",
        sky=sky if prediction.field_cl is not None else None,
        analysis=run.analysis,
    )


def _job_moments(scan, nside, pixels, run, systematics, moments):
    """A job's :class:`Moments`: the shared ones at ``scan``'s rotations, or its own."""
    n_max = n_max_for(systematics)
    if moments is None or isinstance(scan, Schedule):
        return compute_moments(
            scan, nside, pixels, n_max=n_max, nthreads=run.nthreads, backend=run.backend
        )
    if moments.h.shape[0] <= n_max:
        raise ValueError(f"moments hold h_n to {moments.h.shape[0] - 1}; these need {n_max}")
    return moments._replace(rotations_deg=tuple(scan.rotations_deg))


def _predicted_map(sky, moments, systematics, instrument, prediction, template, pixels, run):
    """The h_n prediction of the spurious P on ``pixels`` (:func:`boresight.predict.delta_p`)."""
    gradient = prediction.gradient(sky, pixels, run.nthreads) if systematics.has_pointing else None
    return predict.delta_p(
        sky,
        moments.h,
        systematics,
        instrument,
        template=template,
        nthreads=run.nthreads,
        rotations_deg=moments.rotations_deg,
        pixels=pixels,
        gradient=gradient,
    )


def study_prediction(
    study: Study, sky: Sky, mask: np.ndarray, couplings: Coupling | None = None
) -> predict.Prediction:
    """The :class:`boresight.predict.Prediction` of a study's residual.

    Parameters
    ----------
    study : boresight.config.Study
    sky : boresight.sky.Sky
    mask : numpy.ndarray, shape (npix,)
    couplings : boresight.coupling.Coupling, optional
        Reuse this coupling of the mask (default: computed here).

    Returns
    -------
    boresight.predict.Prediction
        With the sky's own spectra inside the mask.
    """
    lmax, nthreads = study.output.lmax, study.run.nthreads
    if couplings is None:
        couplings = mask_coupling(mask, lmax, nthreads, band=study.sky.lmax)
    field_cl = predict.local_cl(
        sky,
        mask,
        lmax,
        nthreads=nthreads,
        beams=study.systematics.has_beams,
        analysis=study.run.analysis,
    )
    return predict.Prediction(load_spectra(), couplings, study.sky.fwhm_arcmin, field_cl)


def from_study(
    study: Study,
    *,
    mask: np.ndarray | None = None,
    couplings: Coupling | None = None,
    keep_maps: bool = False,
    progress: bool = False,
) -> tuple[Residual, Sky, np.ndarray]:
    """Run the residual job a study describes.

    Parameters
    ----------
    study : boresight.config.Study
    mask : numpy.ndarray, shape (npix,), optional
        The study's mask, when already made.
    couplings : boresight.coupling.Coupling, optional
        Its coupling at output.lmax, when already made.
    keep_maps : bool
        Keep (reference, with systematic) maps in the result.
    progress : bool

    Returns
    -------
    job : Residual
        With its prediction where the instrument allows.
    sky : boresight.sky.Sky
    mask : numpy.ndarray, shape (npix,)
    """
    mask = from_config(study.mask, study.sky.nside) if mask is None else mask
    sky = study.load_sky()
    prediction = study_prediction(study, sky, mask, couplings)
    job = residual(
        sky,
        study.scan,
        study.systematics,
        mask,
        study.output.lmax,
        instrument=study.instrument,
        run=study.run,
        prediction=prediction,
        leak_template=study.load_leak_template(),
        keep_maps=keep_maps,
        progress=progress,
    )
    return job, sky, mask


def band_rows(edges: np.ndarray, columns: dict, **fixed) -> list[dict]:
    """The one table builder: one row per band of every unbinned spectrum.

    Parameters
    ----------
    edges : array_like of int
        Band edges; band i is edges[i] <= ell < edges[i + 1].
    columns : dict
        Column name -> unbinned spectrum (lmax + 1,) [muK^2], or None for a NaN column.
    **fixed
        Values repeated in every row (experiment, angle, delta_r, ...).

    Returns
    -------
    list of dict
        ``fixed``, ell_lo, ell_hi (inclusive) and the band mean of each column.
    """
    edges = np.asarray(edges)
    nan = np.full(edges.size - 1, np.nan)
    binned = {
        name: nan if cl is None else spectra.bin_spectrum(cl, edges)[1]
        for name, cl in columns.items()
    }
    return [
        dict(
            **fixed,
            ell_lo=int(lo),
            ell_hi=int(hi) - 1,
            **{name: values[i] for name, values in binned.items()},
        )
        for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:]))
    ]
