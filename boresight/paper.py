"""The paper's study as a recipe: wide survey + pointing, deep survey + gain, with and without
partial boresight rotation, the analytic predictions, the reference curves and the Q = U = 0 check.

``run_study`` returns plain arrays per experiment; :mod:`boresight.report` turns them into the CSV,
the computed verdicts and the report, :mod:`boresight.plots` into the figures. The pseudo-spectra
(most of the time at lmax 4000) are transformed on a background thread while the next rotation
angle is simulated and predicted; the stage times in the manifest are the main thread's.
"""

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field

import numpy as np

from . import coupling, engine, harmonics, masks, predict, provenance, sky, spectra
from .cosmology import load_spectra
from .instrument import PAPER_GAIN, PAPER_POINTING, Systematics
from .scan import paper_scan


@dataclass(frozen=True)
class Experiment:
    """One of the paper's two experiments: a survey, a systematic and its rotation angles."""

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


@dataclass(frozen=True)
class StudyConfig:
    """Resolution and numerics of the reproduction; the defaults are the paper's."""

    nside: int = 2048
    lmax: int = 4000
    fwhm_arcmin: float = 7.0
    seed: int = 1
    evaluation: str = "interp"
    lmin_bands: int = 20
    n_bands: int = 14
    nthreads: int = 0
    backend: str = "cpu"

    @classmethod
    def quick(cls, **overrides):
        """Reduced resolution that still shows every effect (Nside 512, lmax 1535)."""
        return cls(**{"nside": 512, "lmax": 1535, **overrides})

    @property
    def lmax_bands(self):
        """Highest multipole of the bands: 2 Nside, beyond which pixelisation dominates."""
        return min(self.lmax, 2 * self.nside)

    def edges(self):
        return spectra.log_bins(self.lmin_bands, self.lmax_bands, self.n_bands)


@dataclass
class ExperimentResult:
    """Unbinned spectra [muK^2] of one experiment, keyed by rotation angle (None: no rotation)."""

    experiment: Experiment
    fsky: float
    cross: dict = field(default_factory=dict)  #: 2 Re<B, dB> per angle
    auto: dict = field(default_factory=dict)  #: <dB, dB> per angle
    predicted_cl: dict = field(default_factory=dict)  #: eq. 10 per angle
    predicted_map: dict = field(default_factory=dict)  #: predicted-map residual (no / ideal angle)
    zero_qu: dict = field(default_factory=dict)  #: residual with Q = U = 0 input per angle
    references: dict = field(default_factory=dict)  #: pseudo-C_ell BB per reference value

    def residual(self, angle):
        return self.cross[angle] + self.auto[angle]


def run_study(cfg=StudyConfig(), experiments=EXPERIMENTS, log=lambda msg: None, progress=False):
    """Run the paper's study; returns ({name: ExperimentResult}, {stage: seconds})."""
    timer = provenance.Timer(log)
    theory = load_spectra()
    sky_cfg = sky.SkyConfig(
        nside=cfg.nside, lmax=cfg.lmax, fwhm_arcmin=cfg.fwhm_arcmin, seed=cfg.seed
    )
    with timer("sky"):
        the_sky = sky.make_sky(sky_cfg, theory, cfg.nthreads)
        unpolarised = sky.Sky(
            alm=_temperature_only(the_sky.alm),
            maps=_temperature_only(the_sky.maps),
            nside=cfg.nside,
            lmax=cfg.lmax,
            fwhm_arcmin=cfg.fwhm_arcmin,
        )
    results = {}
    for exp in experiments:
        results[exp.name] = _run_experiment(exp, cfg, the_sky, unpolarised, theory, timer, progress)
    return results, timer.stages


def _temperature_only(stack):
    """(T, 0, 0) copy of a (3, n) stack; the zero rows stay untouched pages until used."""
    out = np.zeros_like(stack)
    out[0] = stack[0]
    return out


class _Transforms:
    """The study's spherical-harmonic transforms, run in order on one background thread.

    ducc0 uses every core with the GIL released, so the transforms of one angle overlap the
    simulation and prediction of the next. At most ``depth`` jobs are queued or running, since
    each holds full-sky maps. Results are those of running the jobs in turn. Jobs must not call
    numba's parallel kernels, which run on the main thread (its threading layer is not re-entrant).
    """

    def __init__(self, depth=2):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="boresight-transforms")
        self._queued = deque()
        self._all = []
        self.depth = depth

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._pool.shutdown(wait=True, cancel_futures=exc[0] is not None)

    def submit(self, fn, *args):
        """Queue fn(*args) once fewer than ``depth`` jobs wait; returns its Future."""
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


def _run_experiment(exp, cfg, the_sky, unpolarised, theory, timer, progress):
    lmax_s, nthreads = cfg.lmax_bands, cfg.nthreads
    sim_kw = dict(
        evaluation=cfg.evaluation, nthreads=nthreads, backend=cfg.backend, progress=progress
    )
    with _Transforms() as transforms:
        with timer(f"{exp.name}: mask and coupling"):
            mask = masks.survey_mask(exp.survey, cfg.nside)
            obs = mask > 0
            local = transforms.submit(predict.local_cl, the_sky, mask, lmax_s, nthreads)
            couplings = coupling.coupling_matrices(mask, lmax_s, nthreads)
        res = ExperimentResult(exp, masks.fsky(mask))
        key = "r" if exp.reference == "r" else "a_lens"
        for value in exp.reference_values:
            res.references[value] = predict.reference_bb(
                couplings, theory, cfg.fwhm_arcmin, cfg.nside, **{key: value}
            )

        def b_of(qu):
            return spectra.masked_pol_alm(qu, mask, lmax_s, nthreads)[1]

        def parts_of(d_qu, b_ref):
            return spectra.difference_bb_parts(d_qu, b_ref, mask, lmax_s, nthreads)

        def residual(angle, d_qu, ref_qu, b_ref):
            d_qu -= ref_qu
            res.cross[angle], res.auto[angle] = parts_of(d_qu, b_ref.result())

        def predicted_map(angle, dp, b_ref):
            res.predicted_map[angle] = sum(parts_of(np.array([dp.real, dp.imag]), b_ref.result()))

        def zero_qu(angle, qu):  # the reference is zero: the residual is the auto part alone
            res.zero_qu[angle] = harmonics.alm2cl(b_of(qu))

        with timer(f"{exp.name}: reference (no systematic)"):
            ref = engine.simulate(
                the_sky, paper_scan(exp.survey, seed=cfg.seed), pixels=obs, **sim_kw
            )
            ref_qu = ref.qu
            del ref
            b_ref = transforms.submit(b_of, ref_qu)
        for angle in (None,) + exp.angles_deg:
            label = "no rotation" if angle is None else f"rotation {angle:g} deg"
            scan = paper_scan(exp.survey, angle, seed=cfg.seed)
            with timer(f"{exp.name}: {label}"):
                sim = engine.simulate(
                    the_sky, scan, systematics=exp.systematics, pixels=obs, **sim_kw
                )
                transforms.submit(residual, angle, sim.qu, ref_qu, b_ref)
                del sim  # full-sky arrays: free them before the next ones are allocated
                h, _ = engine.scan_moments(
                    scan, cfg.nside, pixels=obs, nthreads=nthreads, backend=cfg.backend
                )
                res.predicted_cl[angle] = predict.residual_pseudo_bb(
                    h,
                    mask,
                    couplings,
                    exp.systematics,
                    theory,
                    cfg.fwhm_arcmin,
                    field_cl=local.result(),
                )
                if angle in (None, exp.ideal_deg):  # the map-level check needs no other angle
                    dp = predict.delta_p(the_sky, h, exp.systematics, nthreads=nthreads)
                    dp *= obs
                    transforms.submit(predicted_map, angle, dp, b_ref)
                del h
            if angle in (None, exp.ideal_deg):
                with timer(f"{exp.name}: Q = U = 0, {label}"):
                    sim0 = engine.simulate(
                        unpolarised, scan, systematics=exp.systematics, pixels=obs, **sim_kw
                    )
                    transforms.submit(zero_qu, angle, sim0.qu)
                    del sim0
        with timer(f"{exp.name}: transforms still running"):
            transforms.wait()
    return res


def tidy_rows(results, cfg):
    """One row per (experiment, rotation angle, ell band): the columns of results.csv."""
    edges = cfg.edges()
    rows = []
    for name, res in results.items():
        _, base = spectra.bin_spectrum(res.residual(None), edges)
        for angle in res.cross:
            _, total = spectra.bin_spectrum(res.residual(angle), edges)
            _, auto = spectra.bin_spectrum(res.auto[angle], edges)
            _, pred = spectra.bin_spectrum(res.predicted_cl[angle], edges)
            pmap = (
                spectra.bin_spectrum(res.predicted_map[angle], edges)[1]
                if angle in res.predicted_map
                else np.full(len(edges) - 1, np.nan)
            )
            for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
                rows.append(
                    dict(
                        experiment=name,
                        pbr_angle_deg="" if angle is None else angle,
                        ell_lo=int(lo),
                        ell_hi=int(hi) - 1,
                        residual_bb=total[i],
                        residual_auto_bb=auto[i],
                        residual_cross_bb=total[i] - auto[i],
                        predicted_bb=pred[i],
                        predicted_map_bb=pmap[i],
                        reduction=base[i] / total[i] if total[i] != 0 else np.inf,
                        nside=cfg.nside,
                        lmax=cfg.lmax,
                        seed=cfg.seed,
                        evaluation=cfg.evaluation,
                    )
                )
    return rows


CSV_COLUMNS = (
    "experiment",
    "pbr_angle_deg",
    "ell_lo",
    "ell_hi",
    "residual_bb",
    "residual_auto_bb",
    "residual_cross_bb",
    "predicted_bb",
    "predicted_map_bb",
    "reduction",
    "nside",
    "lmax",
    "seed",
    "evaluation",
)


def config_dict(cfg):
    return asdict(cfg)
