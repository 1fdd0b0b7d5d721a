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

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from . import engine, ground, predict, scanstats, spectra
from .instrument import Instrument, Systematics
from .mapmaking import Maps
from .config import RunOptions
from .scan import SyntheticScan

N_MAX = predict.N_MAX


class Transforms:
    """A queue of spherical-harmonic jobs: run inline (``background=False``) or in order on one
    background thread, with at most ``depth`` jobs waiting (each holds full-sky maps).

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
        """Run or queue ``fn(*args)``; returns a Future of its result."""
        if self._pool is None:
            future = Future()
            future.set_result(fn(*args))
            return future
        while len(self._queued) >= self.depth:
            self._queued.popleft().result()
        future = self._pool.submit(fn, *args)
        self._queued.append(future)
        self._all.append(future)
        return future

    def wait(self):
        """Wait for every job; re-raises the first job's exception."""
        for future in self._all:
            future.result()


@dataclass(frozen=True)
class Reference:
    """The no-systematic side of a residual: Q, U maps (2, npix) [muK], 0 where invalid, and a
    Future of the B alm of the masked maps. ``Reference.zero()`` is the empty reference: the
    residual is then the systematic's own spectrum (the paper's Q = U = 0 check)."""

    qu: np.ndarray = None
    b_alm: Future = None

    @classmethod
    def zero(cls):
        return cls()


@dataclass(frozen=True)
class Prediction:
    """What the h_n prediction of a residual needs.

    theory : :class:`boresight.cosmology.Spectra`; couplings : :class:`boresight.coupling.Coupling`
    of the mask at the job's lmax; fwhm_arcmin : the sky's beam; field_cl : optional (TT, EE + BB)
    of the sky inside the mask [muK^2], an array pair or a Future of one
    (:func:`boresight.predict.local_cl`).
    """

    theory: object
    couplings: object
    fwhm_arcmin: float
    field_cl: object = None


@dataclass
class Residual:
    """A residual job's result: unbinned spectra (lmax + 1,) [muK^2] from ell = 0.

    ``cross`` (2 Re<B, dB>) and ``auto`` (<dB, dB>) are resolved from the transform queue on first
    use; ``total`` is their sum, C_BB(sys) - C_BB(no sys). ``predicted_cl``: the h_n prediction of
    the residual pseudo-C_BB (None when not predicted); ``predicted_map``: the residual of the
    predicted spurious map (None unless asked for). ``h_power``: <|h_n|^2> over the observed pixels,
    n = 1..4. ``maps``: (reference, with systematic) Maps when kept. ``stages``: seconds per stage.
    """

    parts: Future
    predicted_cl: np.ndarray = None
    predicted_map_parts: Future = None
    h_power: dict = field(default_factory=dict)
    maps: tuple = None
    stages: dict = field(default_factory=dict)

    @property
    def cross(self):
        return self.parts.result()[0]

    @property
    def auto(self):
        return self.parts.result()[1]

    @property
    def total(self):
        return self.cross + self.auto

    @property
    def predicted_map(self):
        return None if self.predicted_map_parts is None else sum(self.predicted_map_parts.result())

    #: the band-table columns (results.csv, bands.csv, sweep tables) and the spectrum each bins:
    #: a new column is one entry here
    COLUMNS: ClassVar[dict] = {
        "residual_bb": "total",
        "residual_auto_bb": "auto",
        "residual_cross_bb": "cross",
        "predicted_bb": "predicted_cl",
    }

    def columns(self):
        """The unbinned spectra of the band tables by column name (None: not computed)."""
        return {name: getattr(self, spectrum) for name, spectrum in self.COLUMNS.items()}


def simulate(
    sky, scan, instrument, systematics, pixels, run=RunOptions(), leak_template=None, progress=False
):
    """Maps of a synthetic scan (:class:`SyntheticScan`) or a real one (:class:`ground.Schedule`,
    whose sample stream covers its own pixels)."""
    if isinstance(scan, ground.Schedule):
        return engine.simulate_samples(
            sky,
            ground.pointing(scan),
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
        progress=progress,
        **run.engine_kwargs(),
    )


def moments(scan, nside, pixels, run=RunOptions()):
    """h_n (N_MAX + 1, npix) of a synthetic or real scan (0 where unobserved)."""
    if isinstance(scan, ground.Schedule):
        return scanstats.characterise_schedule(scan, nside).h
    h, _ = engine.scan_moments(
        scan, nside, pixels=pixels, nthreads=run.nthreads, backend=run.backend
    )
    return h


def _masked_b(qu, mask, lmax, nthreads):
    return spectra.masked_pol_alm(qu, mask, lmax, nthreads)[1]


def reference(
    sky,
    scan,
    mask,
    lmax,
    instrument=Instrument(),
    run=RunOptions(),
    transforms=None,
    progress=False,
):
    """Simulate ``scan`` without a systematic; returns (its :class:`Reference`, its Maps)."""
    maps = simulate(sky, scan, instrument, Systematics(), mask > 0, run, progress=progress)
    return reference_from_maps(maps, mask, lmax, run, transforms), maps


def reference_from_maps(maps, mask, lmax, run=RunOptions(), transforms=None):
    """The :class:`Reference` of simulated no-systematic Maps: their Q, U and, queued on
    ``transforms``, the B alm of the masked maps."""
    transforms = Transforms() if transforms is None else transforms
    qu = maps.qu
    return Reference(qu, transforms.submit(_masked_b, qu, mask, lmax, run.nthreads))


def _parts(d_qu, ref, mask, lmax, nthreads):
    """(cross, auto) from the difference map; the cross part is 0 against a zero reference."""
    if ref.qu is None:
        auto = spectra.harmonics.alm2cl(_masked_b(d_qu, mask, lmax, nthreads))
        return np.zeros_like(auto), auto
    return spectra.difference_bb_parts(d_qu, ref.b_alm.result(), mask, lmax, nthreads)


def _difference_parts(sim_qu, ref, mask, lmax, nthreads):
    if ref.qu is not None:
        sim_qu -= ref.qu  # in place: the job owns its maps
    return _parts(sim_qu, ref, mask, lmax, nthreads)


def residual(
    sky,
    scan,
    systematics,
    mask,
    lmax,
    *,
    instrument=Instrument(),
    run=RunOptions(),
    reference_=None,
    prediction=None,
    predict_map=False,
    leak_template=None,
    transforms=None,
    keep_maps=False,
    progress=False,
):
    """Simulate ``scan`` over ``sky`` with ``systematics`` and return its :class:`Residual`.

    Parameters
    ----------
    sky : boresight.sky.Sky
    scan : boresight.scan.SyntheticScan or boresight.ground.Schedule
    systematics : boresight.instrument.Systematics
    mask : numpy.ndarray, shape (npix,)
        Weights in [0, 1] (RING); pixels with weight > 0 are simulated.
    lmax : int
        Band limit of the spectra.
    instrument : boresight.instrument.Instrument
    run : RunOptions
        Evaluation, backend, chunking and threads of the engine.
    reference_ : Reference, optional
        The no-systematic side, when shared by several jobs (the same sky and scan positions);
        simulated here by default. ``Reference.zero()`` measures the systematic's own spectrum.
    prediction : Prediction, optional
        Predict the residual from h_n (needs the paper's Q/U pair layout; None otherwise).
    predict_map : bool
        Also transform the predicted spurious map (the map-level check).
    leak_template : numpy.ndarray, optional
        Template map of the additive leak (default: the sky's I).
    transforms : Transforms, optional
        Where the transforms run (default: inline).
    keep_maps : bool
        Keep (reference, systematic) Maps in the result.
    progress : bool
        Show a progress bar.

    Returns
    -------
    Residual
    """
    import time

    transforms = Transforms() if transforms is None else transforms
    stages, t0 = {}, time.perf_counter()
    obs = mask > 0
    ref_maps = None
    if reference_ is None:
        reference_, ref_maps = reference(
            sky, scan, mask, lmax, instrument, run, transforms, progress
        )
    sim = simulate(sky, scan, instrument, systematics, obs, run, leak_template, progress)
    parts = transforms.submit(_difference_parts, sim.qu, reference_, mask, lmax, run.nthreads)
    stages["simulate"] = time.perf_counter() - t0
    result = Residual(parts, maps=(ref_maps, sim) if keep_maps else None, stages=stages)
    if prediction is None:
        return result
    t0 = time.perf_counter()
    h = moments(scan, sky.nside, obs, run)
    result.h_power = {n: float(np.mean(np.abs(h[n, obs]) ** 2)) for n in range(1, N_MAX + 1)}
    if predict.supports(instrument):
        field_cl = prediction.field_cl
        field_cl = field_cl.result() if isinstance(field_cl, Future) else field_cl
        result.predicted_cl = predict.residual_pseudo_bb(
            h,
            mask,
            prediction.couplings,
            systematics,
            prediction.theory,
            prediction.fwhm_arcmin,
            instrument,
            field_cl=field_cl,
        )
        if predict_map:
            dp = predict.delta_p(sky, h, systematics, nthreads=run.nthreads)
            dp *= obs
            result.predicted_map_parts = transforms.submit(
                _parts, np.array([dp.real, dp.imag]), reference_, mask, lmax, run.nthreads
            )
    stages["predict"] = time.perf_counter() - t0
    return result


def load_sky(study):
    """A study's sky: the seeded realisation of [sky], or the I, Q, U maps of sky.maps."""
    from . import sky

    if study.sky_maps is None:
        return sky.make_sky(study.sky, nthreads=study.run.nthreads)
    import healpy as hp

    maps = hp.read_map(study.sky_maps, field=(0, 1, 2))
    return sky.Sky.from_maps(
        maps, lmax=study.sky.lmax, fwhm_arcmin=study.sky.fwhm_arcmin, nthreads=study.run.nthreads
    )


def load_template(study):
    """A study's leak template map, or None (the leak then scales the sky's I)."""
    if study.leak_template is None:
        return None
    import healpy as hp

    return hp.read_map(study.leak_template)


def study_prediction(study, the_sky, mask, couplings=None):
    """The :class:`Prediction` of a study's residual, with the sky's own spectra inside the mask
    (None where the instrument has no prediction). ``couplings``: reuse these matrices."""
    if not predict.supports(study.instrument):
        return None
    from . import coupling
    from .cosmology import load_spectra

    lmax, nthreads = study.output.lmax, study.run.nthreads
    if couplings is None:
        couplings = coupling.coupling_matrices(mask, lmax, nthreads)
    field_cl = predict.local_cl(the_sky, mask, lmax, nthreads)
    return Prediction(load_spectra(), couplings, study.sky.fwhm_arcmin, field_cl)


def from_study(study, mask=None, couplings=None, keep_maps=False, progress=False):
    """Run the residual job a :class:`boresight.config.Study` describes.

    ``mask`` and ``couplings``: the study's mask and its coupling matrices, when already made.
    Returns (Residual, sky, mask): the job, with its prediction where the instrument allows, and
    the sky and mask (npix,) it used.
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


def band_rows(edges, columns, **fixed):
    """One row per band [edges[i], edges[i+1]): ell_lo, ell_hi, the band mean of every unbinned
    spectrum in ``columns`` (name -> (lmax + 1,) array, or None for NaN) and the ``fixed`` values.

    The one table builder of the package: results.csv, sweep points and compare.csv use it.
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
