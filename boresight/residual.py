"""The one job every command runs: the residual B-mode that a systematic leaves in a scan's maps.

sky + scan + instrument + systematics + mask + run options -> simulate with and without the
systematic -> residual pseudo-C_BB (its cross part 2 Re<B, dB> and its leaked power <dB, dB>) ->
h_n prediction (C_ell level, and optionally map level) -> one :class:`Residual`. ``reproduce`` runs
it per experiment and rotation angle, ``simulate`` once, ``sweep`` once per point and
``compare-scans`` once per scan, and :func:`band_rows` makes every table from its result.

The spherical-harmonic transforms, most of the time at high lmax, go through a
:class:`Transforms` queue: inline by default, or on one background thread so that they overlap the
simulation of the next job (ducc0 releases the GIL and uses every core). Either way the numbers are
the same bits.
"""

from __future__ import annotations

import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar, NamedTuple

import numpy as np

from . import engine, harmonics, interrupts, pointing, predict, scanstats, spectra
from .schedule import Schedule
from .config import RunOptions
from .instrument import Instrument, Systematics
from .mapmaking import Maps
from .scan import SyntheticScan

if TYPE_CHECKING:
    from .config import Study
    from .coupling import Coupling
    from .sky import Sky


N_MAX = predict.N_MAX


class Transforms:
    """A queue of spherical-harmonic jobs: inline, or in order on one background thread.

    Parameters
    ----------
    background : bool
        Run jobs on a background thread (ducc0 releases the GIL and uses every core), so they
        overlap the main thread's simulations; else run each at once.
    depth : int
        At most this many background jobs wait at a time (each holds full-sky maps).

    Notes
    -----
    Jobs must not call numba's parallel kernels, which run on the main thread (numba's threading
    layer is not re-entrant). Use as a context manager; :meth:`wait` re-raises a job's error.
    """

    def __init__(self, background=False, depth=2):
        self._pool = (
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="boresight-transforms")
            if background
            else None
        )
        self._queued = deque()
        self._all = []
        self.depth = depth

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=exc[0] is not None)

    def submit(self, fn, *args):
        """Run or queue ``fn(*args)``.

        Returns
        -------
        concurrent.futures.Future
            Of ``fn``'s result (already done when inline).
        """
        if self._pool is None:
            future = Future()
            future.set_result(fn(*args))
            return future
        while len(self._queued) >= self.depth:
            interrupts.result(self._queued.popleft())
        future = self._pool.submit(fn, *args)
        self._queued.append(future)
        self._all.append(future)
        return future

    def wait(self):
        """Wait for every job; re-raises the first job's exception."""
        for future in self._all:
            interrupts.result(future)


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


@dataclass(frozen=True)
class Prediction:
    """What the h_n prediction of a residual needs.

    Parameters
    ----------
    theory : boresight.cosmology.Spectra
        Lensed LCDM and tensor spectra [muK^2].
    couplings : boresight.coupling.Coupling
        The mask's coupling at the job's lmax, from the sky's band limit (its ``band``).
    fwhm_arcmin : float
        The sky's Gaussian beam [arcmin].
    field_cl : boresight.predict.FieldSpectra or Future, optional
        Spectra [muK^2] of the sky inside the mask (:func:`boresight.predict.local_cl`),
        which removes the patch's sample variance from the comparison; default: the theory.
    leaked : bool
        Predict the leaked power (:attr:`Residual.auto`) rather than the whole residual.
    """

    theory: object
    couplings: object
    fwhm_arcmin: float
    field_cl: object = None
    leaked: bool = False
    _held: dict = field(default_factory=dict, repr=False, compare=False)

    def gradient(self, sky: Sky, pixels: np.ndarray, nthreads: int = 0) -> np.ndarray:
        """The sky's dT/dtheta, dT/dphi / sin(theta) at ``pixels``, (2, n), kept for the next
        job's map-level prediction on the same sky and pixels (the jobs of one mask share both).
        """
        held = self._held.get("gradient")
        if held is None or held[0] is not sky or held[1] is not pixels:
            grad = harmonics.alm2map_gradient(sky.alm[0], sky.nside, nthreads, pixels)
            held = self._held["gradient"] = (sky, pixels, grad)
        return held[2]

    def release(self):
        """Drop what :meth:`gradient` keeps (0.3 GB on the wide mask at Nside 2048) once no
        other job will check its map."""
        self._held.clear()


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


def simulate(
    sky: Sky,
    scan: SyntheticScan | Schedule,
    instrument: Instrument,
    systematics: Systematics,
    pixels: np.ndarray,
    run: RunOptions = RunOptions(),
    leak_template: np.ndarray | None = None,
    progress: bool = False,
    zero_qu: bool = False,
) -> Maps | tuple[Maps, Maps]:
    """Maps of a synthetic or a real scan.

    Parameters
    ----------
    sky : boresight.sky.Sky
    scan : boresight.scan.SyntheticScan or boresight.schedule.Schedule
        A real schedule's sample stream covers its own pixels (``pixels`` is then unused).
    instrument : boresight.instrument.Instrument
    systematics : boresight.instrument.Systematics
    pixels : numpy.ndarray
        Pixels a synthetic scan observes: a boolean map (npix,) or increasing RING indices (the
        engine then keeps them without a copy).
    run : boresight.config.RunOptions
    leak_template : numpy.ndarray, optional
        (npix,) template of the additive leak [muK].
    progress : bool
    zero_qu : bool
        Also the maps with the sky's Q = U = 0, from the same hits (a synthetic scan's;
        :func:`boresight.engine.simulate`).

    Returns
    -------
    boresight.mapmaking.Maps, or (the sky's, Q = U = 0's) with ``zero_qu``
    """
    if isinstance(scan, Schedule):
        if zero_qu:
            raise ValueError("zero_qu needs a synthetic scan; simulate sky.without_polarisation()")
        return engine.simulate_samples(
            sky,
            pointing.pointing(scan),
            instrument,
            systematics,
            evaluation=run.evaluation,
            leak_template=leak_template,
            nthreads=run.nthreads,
            backend=run.backend,
        )
    return engine.simulate(
        sky,
        scan,
        instrument,
        systematics,
        pixels=pixels,
        leak_template=leak_template,
        zero_qu=zero_qu,
        progress=progress,
        **run.engine_kwargs(),
    )


class Moments(NamedTuple):
    """What the predictions need of a scan's crossings.

    h : numpy.ndarray, complex128, shape (N_MAX + 1, npix)
        h_n of one repeat's crossings (a real schedule's, rotations included), 0 where unobserved.
    crossings : numpy.ndarray, int64, shape (npix,)
        Crossings per pixel in one repeat.
    rotations_deg : tuple of float
        Boresight rotation of each repeat [deg]; (0,) for a real schedule.
    power : numpy.ndarray, shape (N_MAX + 1,)
        ``<|h_n|^2>`` of ``h`` over the pixels it was made on.
    """

    h: np.ndarray
    crossings: np.ndarray
    rotations_deg: tuple
    power: np.ndarray

    def rotated_power(self, n):
        """``<|h_n|^2>`` of all the repeats together: each repeat's h_n is the first's times
        e^{i n alpha}, so their mean is h_n <e^{i n alpha}>."""
        turn = np.mean(np.exp(1j * n * np.radians(self.rotations_deg)))
        return self.power[n] * abs(turn) ** 2


def moments(
    scan: SyntheticScan | Schedule,
    nside: int,
    pixels: np.ndarray,
    run: RunOptions = RunOptions(),
    n_max: int = N_MAX,
) -> Moments:
    """h_n of a synthetic or real scan.

    Parameters
    ----------
    scan : boresight.scan.SyntheticScan or boresight.schedule.Schedule
    nside : int
    pixels : numpy.ndarray
        Pixels of a synthetic scan, and those :attr:`Moments.power` averages over: a boolean
        map (npix,) or increasing RING indices.
    run : boresight.config.RunOptions
    n_max : int
        The highest moment of a synthetic scan (:func:`n_max_for`); a real schedule's are
        :data:`boresight.scanstats.N_MAX`.

    Returns
    -------
    Moments
    """
    if isinstance(scan, Schedule):
        stats = scanstats.characterise_schedule(scan, nside)
        return Moments(stats.h, stats.hits, (0.0,), _mean_power(stats.h, pixels))
    h, crossings = engine.scan_moments(
        scan.one_repeat(), nside, n_max, pixels=pixels, nthreads=run.nthreads, backend=run.backend
    )
    return Moments(h, crossings, scan.rotations_deg, _mean_power(h, pixels))


def _mean_power(h, pixels):
    """``<|h_n|^2>`` over ``pixels`` (a boolean map or RING indices) for each n of h."""
    out = np.empty(h.shape[0])
    for n, hn in enumerate(h):
        values = hn[pixels].view(np.float64)  # (re, im) pairs: |h|^2 summed is one dot product
        out[n] = np.dot(values, values) / (values.size // 2)
    return out


def n_max_for(systematics: Systematics) -> int:
    """The highest h_n a prediction of these systematics uses: the beams' reach h_6
    (:data:`boresight.predict.BEAM_N_MAX`), the others h_4.

    Parameters
    ----------
    systematics : boresight.instrument.Systematics

    Returns
    -------
    int
    """
    return predict.BEAM_N_MAX if systematics.has_beams else N_MAX


def _masked_b(qu, footprint, lmax, run, overwrite=True):
    """B alm of (2, nobs) Q, U on the footprint's pixels, masked in place unless ``overwrite`` is
    False (the reference's maps, which later jobs read)."""
    eb = footprint.alm(qu, lmax, 2, run.nthreads, run.analysis, overwrite)
    return eb[1].copy()  # not a view that keeps E alive with the reference


def reference(
    sky: Sky,
    scan: SyntheticScan | Schedule,
    mask: np.ndarray | spectra.Footprint,
    lmax: int,
    instrument: Instrument = Instrument(),
    run: RunOptions = RunOptions(),
    transforms: Transforms | None = None,
    progress: bool = False,
) -> tuple[Reference, Maps]:
    """Simulate a scan without a systematic.

    Parameters
    ----------
    sky, scan, instrument, run, progress
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
    maps = simulate(sky, scan, instrument, Systematics(), footprint.pixels, run, progress=progress)
    return reference_from_maps(maps, footprint, lmax, run, transforms), maps


def reference_from_maps(
    maps: Maps,
    mask: np.ndarray | spectra.Footprint,
    lmax: int,
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
        auto = spectra.harmonics.alm2cl(_masked_b(d_qu, footprint, lmax, run))
        return np.zeros_like(auto), auto
    b_ref = ref.b_alm.result()
    return spectra.difference_bb_parts(
        d_qu, b_ref, footprint, lmax, run.nthreads, run.analysis, overwrite=True
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
    reference_: Reference | None = None,
    prediction: Prediction | None = None,
    predict_map: bool = False,
    moments_: Moments | None = None,
    leak_template: np.ndarray | None = None,
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
    systematics : boresight.instrument.Systematics
    mask : numpy.ndarray, shape (npix,), or boresight.spectra.Footprint
        Weights in [0, 1] (RING); pixels with weight > 0 are simulated. Jobs on one mask share
        its footprint when given one (:func:`boresight.spectra.as_footprint`).
    lmax : int
        Band limit of the spectra.
    instrument : boresight.instrument.Instrument
    run : RunOptions
        Evaluation, backend, chunking and threads of the engine.
    reference_ : Reference, optional
        The no-systematic side, when shared by several jobs (the same sky and scan positions);
        simulated here by default. ``Reference.zero()`` measures the systematic's own spectrum.
    prediction : Prediction, optional
        Predict the residual from h_n; the C_ell level where :func:`boresight.predict.supports`
        the instrument and its repeats.
    predict_map : bool
        Also transform the predicted spurious map (the map-level check).
    moments_ : Moments, optional
        The moments of a synthetic ``scan``'s one repeat (:func:`moments`), when several jobs
        share them (the same scan at other rotations); ``scan``'s rotations replace theirs.
    leak_template : numpy.ndarray, optional
        Template map of the additive leak (default: the sky's I).
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
    transforms = Transforms() if transforms is None else transforms
    stages, t0 = {}, time.perf_counter()
    footprint = spectra.as_footprint(mask)
    pixels = footprint.pixels
    ref_maps = None
    if reference_ is None:
        reference_, ref_maps = reference(
            sky, scan, footprint, lmax, instrument, run, transforms, progress
        )
    sims = simulate(
        sky, scan, instrument, systematics, pixels, run, leak_template, progress, zero_qu
    )
    sim, sim_qu0 = sims if zero_qu else (sims, None)
    del sims
    parts = transforms.submit(
        _difference_parts, sim.qu_at(pixels), reference_, footprint, lmax, run
    )
    stages["simulate"] = time.perf_counter() - t0
    result = Residual(parts, maps=(ref_maps, sim) if keep_maps else None, stages=stages)
    del sim  # kept in the result only when asked for
    if zero_qu:
        result.zero_qu = Residual(
            transforms.submit(
                _difference_parts, sim_qu0.qu_at(pixels), Reference.zero(), footprint, lmax, run
            )
        )
        del sim_qu0
    if prediction is None:
        return result
    t0 = time.perf_counter()
    n_max = n_max_for(systematics)
    if moments_ is None or isinstance(scan, Schedule):
        mom = moments(scan, sky.nside, pixels, run, n_max)
    elif moments_.h.shape[0] <= n_max:
        raise ValueError(f"moments_ hold h_n to {moments_.h.shape[0] - 1}; these need {n_max}")
    else:
        mom = moments_._replace(rotations_deg=tuple(scan.rotations_deg))
    result.h_power = {n: float(mom.rotated_power(n)) for n in range(1, N_MAX + 1)}
    if predict.supports(instrument, mom.rotations_deg):
        field_cl = prediction.field_cl
        field_cl = interrupts.result(field_cl) if isinstance(field_cl, Future) else field_cl
        result.predicted_cl = predict.residual_pseudo_bb(
            mom.h,
            footprint,
            prediction.couplings,
            systematics,
            prediction.theory,
            prediction.fwhm_arcmin,
            instrument,
            field_cl=field_cl,
            rotations_deg=mom.rotations_deg,
            crossings=mom.crossings,
            leaked=prediction.leaked,
            # the hits' spread over their pixels, and the maps read by interpolation there
            in_pixel=getattr(scan, "in_pixel", "random"),
            interpolated=run.evaluation == "interp",
            sky=sky if prediction.field_cl is not None else None,
            analysis=run.analysis,
        )
    if predict_map:
        gradient = (
            prediction.gradient(sky, pixels, run.nthreads) if systematics.has_pointing else None
        )
        dp = predict.delta_p(
            sky,
            mom.h,
            systematics,
            instrument,
            leak_template,
            run.nthreads,
            mom.rotations_deg,
            pixels,
            gradient,
        )
        result.predicted_map_parts = transforms.submit(
            _parts, _as_qu(dp), reference_, footprint, lmax, run
        )
    stages["predict"] = time.perf_counter() - t0
    return result


def load_sky(study: Study) -> Sky:
    """A study's sky.

    Parameters
    ----------
    study : boresight.config.Study

    Returns
    -------
    boresight.sky.Sky
        The seeded realisation of [sky], or the I, Q, U maps of its sky.maps file (alm computed).
    """
    from . import sky

    if study.sky_maps is None:
        return sky.make_sky(study.sky, nthreads=study.run.nthreads)
    import healpy as hp

    maps = hp.read_map(study.sky_maps, field=(0, 1, 2))
    return sky.Sky.from_maps(
        maps, lmax=study.sky.lmax, fwhm_arcmin=study.sky.fwhm_arcmin, nthreads=study.run.nthreads
    )


def load_template(study: Study) -> np.ndarray | None:
    """A study's leak template.

    Parameters
    ----------
    study : boresight.config.Study

    Returns
    -------
    numpy.ndarray or None
        The (npix,) map of systematics.leak_template [muK], or None (the leak scales the sky's I).
    """
    if study.leak_template is None:
        return None
    import healpy as hp

    return hp.read_map(study.leak_template)


def study_prediction(
    study: Study, the_sky: Sky, mask: np.ndarray, couplings: Coupling | None = None
) -> Prediction | None:
    """The :class:`Prediction` of a study's residual.

    Parameters
    ----------
    study : boresight.config.Study
    the_sky : boresight.sky.Sky
    mask : numpy.ndarray, shape (npix,)
    couplings : boresight.coupling.Coupling, optional
        Reuse this coupling of the mask (default: computed here).

    Returns
    -------
    Prediction
        With the sky's own spectra inside the mask.
    """
    from . import coupling
    from .cosmology import load_spectra

    lmax, nthreads = study.output.lmax, study.run.nthreads
    if couplings is None:
        couplings = coupling.mask_coupling(mask, lmax, nthreads, band=study.sky.lmax)
    field_cl = predict.local_cl(
        the_sky, mask, lmax, nthreads, study.systematics.has_beams, study.run.analysis
    )
    return Prediction(load_spectra(), couplings, study.sky.fwhm_arcmin, field_cl)


def from_study(
    study: Study,
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
    from . import masks

    mask = masks.from_config(study.mask, study.sky.nside) if mask is None else mask
    the_sky = load_sky(study)
    prediction = study_prediction(study, the_sky, mask, couplings)
    job = residual(
        the_sky,
        study.scan,
        study.systematics,
        mask,
        study.output.lmax,
        instrument=study.instrument,
        run=study.run,
        prediction=prediction,
        leak_template=load_template(study),
        keep_maps=keep_maps,
        progress=progress,
    )
    return job, the_sky, mask


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
