"""The design objective of a pipeline that filters before binning: each unit's filtered leak,
simulated once per sky, turned by any assignment.

A filter (:class:`boresight.mitigation.Filtering`) acts on a CES's pair differences in time, so
no closed form carries the sky's expectation through it (the raw pipeline's
:func:`boresight.design.exact.exact_objective`). It is linear, CES by CES, and a boresight angle a
enters a pair difference only through the crossing angle psi + a, so a unit's filtered leak on
the map-maker's P = Q + i U is, per sky,

    dP_u(a) = sum_n exp(i n a) X_u,n,

over the moments n the budget's systematics reach (:func:`moments_of`): the TOD's spin-(n - 2)
part, filtered, binned with exp(2 i (psi + a)), the pointing offsets' and the beams' leaks of P
and their higher orders included. With pairs whose 4 x angles cancel
the map-maker's 2 x 2 system is N/2 times the identity, so a schedule's map is the hits-weighted
sum of its units' maps, dP = sum_u (N_u / N) dP_u(a_u), and the sky's own filtered map does not
depend on the angles (its h_4 P* cancels between the pairs as in the raw maps). So each unit is
simulated at as many angles as the budget has moments, X_u,n solved from them, per sky, and every
assignment's filtered maps follow, exactly, as :class:`boresight.design.exact.ExactObjective`'s
channels: one per sky and moment, whose (E, B) alm turn by n a_u, and one per sky for its own map.

The objective estimates the expected total residual, pseudo-C_BB(P + dP) - pseudo-C_BB(P) =
C(dB, dB) + 2 C(B, dB), from the budget's ``[filter] skies`` skies (seeded from
:data:`FIRST_SEED`, apart from the TOD check's): each sky's leaked power, and its cross term with
the sky's B through the moment no angle turns only. The turned leaks' cross terms with the sky's
B have no mean where they leak T (independent of B), but on a few skies they are large and a
search would choose the angles that align them by chance with those skies' B (on the test's 16
units, two skies: a total residual below zero where the TOD gives 0.17); the turned leaks of P
(h_4 P* of angle errors that differ between pairs, a pointing offset's gradient of P) go with
them, small beside the leaks of T of the budgets here. Each sky's spectra are
corrected by the filter's F_ell^BB (:func:`boresight.jobs.transfer.transfer_function`, per band of
:func:`boresight.jobs.suppression.hwp.bands`) and read as delta_r, the objective their mean, with
a standard error from their spread (:meth:`FilteredObjective.delta_r_se`, which the TOD check adds
to its own); the survey's sigma(r) reads N_ell / F_ell^BB. The search
(:func:`boresight.design.exact.search`) is the raw pipeline's. Without a filter the same route is
the raw pipeline's exact expectation within its skies' error (``tests/design/test_filtered.py``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from .. import harmonics, predict, spectra
from .._util import interrupts
from ..config import RunOptions
from ..constants import DEG
from ..coupling import mask_coupling
from ..instrument.pairs import Systematics
from ..jobs.residual import simulate_maps
from ..jobs.suppression.hwp import bands
from ..jobs.transfer import Transfer, transfer_function
from ..mitigation import ces_scans
from ..noise import sigma_r
from ..predict.expectation import ExpectedResidual
from ..sky import SkyConfig, make_sky
from .exact import Channel, ExactObjective, QuadraticForm

if TYPE_CHECKING:
    from ..cosmology import Spectra
    from ..moments.units import UnitMoments
    from ..schedule import Schedule
    from .budget import Budget
    from .constraints import Feasibility

#: the seed of the objective's first sky (the TOD check's are 0, 1, ...: the two are independent)
FIRST_SEED = 1000
#: pairs of pure skies of the filter's transfer function
TRANSFER_SIMS = 4
#: the worst condition number of the angles' system that solves for the moments
MAX_CONDITION = 1e6


@dataclass
class FilteredObjective(ExactObjective):
    """:class:`boresight.design.exact.ExactObjective` of a filtering pipeline (module docstring):
    channel (k, n) is sky k's moment n, its rows those of the units' X_u,n.

    Parameters
    ----------
    sky_alm : numpy.ndarray, complex128, shape (skies, 2, nalm)
        Each sky's own filtered (E, B) alm, which no angle turns (each sky's last channel, a
        unit's share 1 / n_units).
    leak_moments : tuple of int
        The moments of each sky's leak channels (:func:`moments_of`).
    kept_bb : numpy.ndarray, shape (lmax + 1,)
        F_ell^BB of each multipole (:func:`kept_bands`; 1 outside the bands).
    transfer : boresight.jobs.transfer.Transfer
        The filter's transfer function on the schedule.
    """

    sky_alm: np.ndarray | None = None
    leak_moments: tuple = ()
    kept_bb: np.ndarray | None = None
    transfer: Transfer | None = None

    def per_sky(self, angles_deg, steps_deg=None, *, chance=False) -> np.ndarray:
        """Each sky's leaked and total pseudo-C_BB (skies, 2, lmax + 1), corrected by F_ell^BB:
        the total with the sky's cross term with the moment that does not turn (the objective's),
        or with ``chance`` with every moment (the TOD's: the turned leaks' chance alignments with
        the sky's B too)."""
        alm = self.alm(angles_deg, steps_deg)[2:]
        skies = self.sky_alm.shape[0]
        rows = alm.reshape(skies, -1, 2, alm.shape[-1])  # (skies, moments + 1, 2, nalm)
        zero = self.leak_moments.index(0)
        out = np.empty((skies, 2, self.lmax + 1))
        for k in range(skies):
            sky, leak = self.sky_alm[k, 1], rows[k, :-1, 1].sum(axis=0)
            out[k, 0] = harmonics.alm2cl(leak)
            near = leak if chance else rows[k, zero, 1]
            out[k, 1] = out[k, 0] + 2 * harmonics.alm2cl(sky, near)
        return out / self.kept_bb

    def expected(self, angles_deg, steps_deg=None) -> ExpectedResidual:
        """The skies' mean leaked and total pseudo-C_BB, each corrected by F_ell^BB."""
        leaked, total = self.per_sky(angles_deg, steps_deg).mean(axis=0)
        return ExpectedResidual(leaked, total)

    def delta_r_se(self, angles_deg, steps_deg=None) -> float:
        """The standard error of the objective's delta_r from its skies' spread."""
        values = [
            predict.delta_r(total, self.template)
            for _, total in self.per_sky(angles_deg, steps_deg)
        ]
        return float(np.std(values, ddof=1) / np.sqrt(len(values)))


def moments_of(systematics: Systematics) -> tuple[int, ...]:
    """The moments n a budget's filtered leak may carry: a pair difference's spin-s parts (s = 0
    of a gain, +-1 of a pointing offset, +-2 of a beam's ellipticity or width, each on T, and
    those +-2 on P) binned with exp(2 i psi), n = 2 + s, every order of the offsets within
    -s_max .. 4 + s_max."""
    s_max = 2 if systematics.has_beams else 1 if systematics.has_pointing else 0
    return tuple(range(-s_max, 5 + s_max))


def probe_angles(ns: tuple[int, ...]) -> np.ndarray:
    """Angles [deg] at which a unit's maps give its moments ``ns``: len(ns) angles 360 / (max n -
    min n + 1) apart, where exp(i n a) are independent (consecutive moments: a discrete Fourier
    transform, perfectly conditioned)."""
    step = 360.0 / (max(ns) - min(ns) + 1)
    return step * np.arange(len(ns))


def unit_leaks(moments, schedule, budget, sky, *, systematics, ns, run=RunOptions()):
    """One sky's X_u,n (n_units, len(ns), n_obs) and its own map P (n_obs,), complex, each
    weighted by N_u / N on the design's observed pixels (the module docstring)."""
    angles = probe_angles(ns)
    vandermonde = np.exp(1j * np.outer(angles * DEG, ns))
    if np.linalg.cond(vandermonde) > MAX_CONDITION:
        raise ValueError(f"the moments {ns} are not resolved by the angles {angles}")
    solve = np.linalg.inv(vandermonde)
    leaks = np.zeros((moments.n_units, len(ns), moments.pixels.size), dtype=np.complex128)
    own = np.zeros(moments.pixels.size, dtype=np.complex128)
    hits = np.zeros(moments.pixels.size)
    options = dict(sky=sky, schedule=schedule, budget=budget, run=run)
    for u, idx in enumerate(moments.units):
        rows = [moments.rows[i] for i in idx]
        pixels, reference, n_u = _unit_maps(rows, 0.0, Systematics(), **options)
        sampled = [_unit_maps(rows, a, systematics, **options)[1] - reference for a in angles]
        where = np.searchsorted(moments.pixels, pixels)
        leaks[u][:, where] = (solve @ np.array(sampled)) * n_u
        own[where] += reference * n_u
        hits[where] += n_u
    return leaks / hits, own / hits


def _unit_maps(rows, angle, systematics, *, sky, schedule, budget, run):
    """A unit's CESs at one angle through the budget's pipeline: its observed pixels, its P = Q +
    i U there and its hits."""
    interrupts.check()
    ces = tuple(dataclasses.replace(r, boresight_deg=float(angle)) for r in rows)
    scan = dataclasses.replace(schedule, ces=ces, repeat_boresight_deg=(0.0,))
    out = simulate_maps(
        sky, scan, budget.instrument, systematics, run=run, filtering=budget.pipeline
    )
    return out.pixels, out.q_obs + 1j * out.u_obs, out.hits_obs.astype(float)


def filtered_objective(
    moments: UnitMoments,
    schedule: Schedule,
    budget: Budget,
    theory: Spectra,
    *,
    change_cost: float = 0.0,
    feasibility: Feasibility | None = None,
    skies: int | None = None,
    nthreads: int = 0,
    progress: bool = False,
) -> FilteredObjective:
    """The design objective of ``budget``'s filtering pipeline over ``schedule``'s units (module
    docstring).

    Parameters
    ----------
    moments : boresight.moments.UnitMoments
        The units and the observed pixels, whose mask the spectra are taken on.
    schedule : boresight.schedule.Schedule
    budget : boresight.design.budget.Budget
        With a ``[filter]`` (:attr:`~boresight.design.budget.Budget.pipeline`).
    theory : boresight.cosmology.Spectra
    change_cost : float
    feasibility : boresight.design.constraints.Feasibility, optional
    skies : int, optional
        Sky realisations the objective averages (default the budget's ``[filter] skies``).
    nthreads : int
    progress : bool

    Returns
    -------
    FilteredObjective
    """
    ces_scans(budget.pipeline, schedule)  # a filter the CESs cannot take, before any work
    skies = budget.filter_skies if skies is None else int(skies)
    nside, lmax = moments.nside, 2 * moments.nside
    run = RunOptions(evaluation=budget.design.evaluation, nthreads=nthreads)
    ns = moments_of(budget.systematics)
    footprint = spectra.as_footprint(moments.mask)
    edges = bands(nside)
    once = moments.schedule(schedule, np.zeros(moments.n_units))
    transfer = transfer_function(
        once, budget.pipeline, footprint, edges, nside=nside,
        fwhm_arcmin=budget.noise.fwhm_arcmin, n_sims=TRANSFER_SIMS, run=run,
    )  # fmt: skip
    kept = spectra.per_ell(kept_bands(transfer), edges, lmax, outside=1.0)
    couplings = mask_coupling(moments.mask, lmax, nthreads)
    template = predict.tensor_template(couplings, theory, budget.noise.fwhm_arcmin, nside)
    weight = predict.delta_r_weights(template, lmax) / kept
    nalm = (lmax + 1) * (lmax + 2) // 2
    per = len(ns) + 1  # each sky's leak moments and its own map
    channels = tuple(
        Channel(n, f"sky {k}") for k in range(skies) for n in (*ns, 0)
    )  # fmt: skip
    unit_alm = np.zeros((moments.n_units, len(channels), 2, nalm), dtype=np.complex128)
    sky_alm = np.zeros((skies, 2, nalm), dtype=np.complex128)
    bar = tqdm(total=skies * moments.n_units, desc="filtered leaks", unit="unit",
               disable=not progress)  # fmt: skip
    for k in range(skies):
        seed = FIRST_SEED + k
        sky = make_sky(
            SkyConfig(nside=nside, lmax=lmax, fwhm_arcmin=budget.noise.fwhm_arcmin, seed=seed)
        )
        systematics = dataclasses.replace(budget.systematics, seed=seed)
        leaks, own = unit_leaks(
            moments, schedule, budget, sky, systematics=systematics, ns=ns, run=run
        )
        sky_alm[k] = footprint.alm(np.array([own.real, own.imag]), lmax, 2, nthreads=nthreads)
        for u in range(moments.n_units):
            for j in range(len(ns)):
                x = leaks[u, j]
                alm = footprint.alm(np.array([x.real, x.imag]), lmax, 2, nthreads=nthreads)
                unit_alm[u, k * per + j] = alm
            unit_alm[u, k * per + len(ns)] = sky_alm[k] / moments.n_units
            bar.update()
    bar.close()
    j_count = 2 + 2 * len(channels)
    lam = np.zeros((j_count, j_count, lmax + 1))
    for k in range(skies):  # each sky's |dB|^2, and 2 Re <B, dB> of the moment that never turns
        b_rows = [3 + 2 * (k * per + j) for j in range(len(ns))]
        lam[np.ix_(b_rows, b_rows)] = weight / skies
        own, zero = 3 + 2 * (k * per + len(ns)), b_rows[ns.index(0)]
        lam[own, zero] = lam[zero, own] = weight / skies
    return FilteredObjective(
        moments, QuadraticForm(lam, lmax), np.zeros((2, nalm), dtype=np.complex128), unit_alm,
        0.0, change_cost, template, lmax, lmax, channels, None, feasibility, sky_alm, ns, kept,
        transfer,
    )  # fmt: skip


def objective_runs(budget: Budget) -> int:
    """The objective's passes of the schedule, for the resource estimate: per sky each unit at
    each probe angle and once without systematics, and the transfer function's pure skies."""
    if budget.filtering is None:
        return 0
    probes = len(moments_of(budget.systematics)) + 1
    return budget.filter_skies * probes + 2 * 2 * TRANSFER_SIMS


def objective_alm(budget: Budget) -> dict:
    """What a filtering pipeline's objective holds per unit, for the resource estimate
    (:func:`boresight.jobs.resources.schedule_estimate`'s ``design_channels`` and
    ``design_band``): a channel per sky and moment and one for each sky's own map, to lmax."""
    if budget.filtering is None:
        return {}
    channels = budget.filter_skies * (len(moments_of(budget.systematics)) + 1)
    return dict(design_channels=channels, design_band=2 * budget.design.nside)


def filtered_sigma_r(budget: Budget, theory: Spectra, obj: FilteredObjective) -> float:
    """The survey's sigma(r) read as N_ell / F_ell^BB over the objective's bands, the last band's
    F_ell^BB held to the end of :data:`boresight.predict.R_RANGE`."""
    edges = np.array(obj.transfer.edges)
    edges[-1] = max(edges[-1], predict.R_RANGE[1] + 1)
    return sigma_r(budget.noise, theory, edges, transfer_bb=kept_bands(obj.transfer))


def kept_bands(transfer: Transfer) -> np.ndarray:
    """F_BB per band as the objective reads it: an estimate above 1 (its noise) keeps the whole
    band, as the filtered table reads it."""
    return np.clip(transfer.entry("BB", "BB"), 1e-12, 1.0)
