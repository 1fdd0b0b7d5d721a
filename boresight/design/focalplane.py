"""The design objective on a real focal plane, and its search.

Off the axis a pair's hits move when the boresight turns, so a unit's moments at angle a are not
those at 0 turned by exp(i n a): they are built once per allowed angle, per pair
(:func:`boresight.moments.unit_sums`: S_n,i of every unit u at every allowed angle k, n = 0 its hits).

With the hits N(p) and the map-maker's H_4(p) of a reference assignment held fixed, every term
of dP (:func:`boresight.predict.focalplane.expected_residual`) is linear in the units' sums, so
the expected total-residual delta_r of an assignment c (one allowed angle per unit) is a dense
quadratic (:class:`DenseForm`)

    delta_r(c) = const + sum_u L[u, c_u] + sum_uv G[(u, c_u), (v, c_v)],

G the coherent part (the focal plane's combination at the parameters' means) plus the scattered
part (rms^2 times each pair's own unit leak), made once per reference from the weights' alm with
the kernels of :func:`boresight.predict.field_products.bb_kernels`. ``const`` anchors it to the
exact expectation at the reference, so it is exact there, and :func:`search` re-linearises at
each round's optimum until the assignment stays (a fixed point), keeping the best exact value.
A move of one unit costs O(n_units x n_allowed); the memory is (n_units x n_allowed)^2 numbers
plus one pair's alm at a time.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from tqdm import tqdm

from .._util import interrupts
from ..constants import N_MAX
from ..moments.focalplane import characterise_focalplane
from ..moments.offsets import centroid_moments
from ..moments.units import UnitMoments, UnitSums, allowed_index, unit_sums
from ..predict import R_RANGE, delta_r
from ..predict import field_products as fp
from ..predict import focalplane as predict_fp
from ..predict.expectation import budget_terms, sky_fields, smoothed_spectra
from . import descent
from .exact import (
    EXHAUSTIVE_LIMIT,
    QuadraticForm,
    angle_changes,
    change_cost_delta,
    kernel_form,
    pair_change_cost_delta,
)
from .white import Design

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..cosmology import Spectra
    from ..instrument.focalplane import FocalPlane
    from ..instrument.pairs import Systematics
    from ..schedule import Schedule


class Target(NamedTuple):
    """What the delta_r is of: the budget's systematics, the theory and the sky's beam, the
    analysis mask (npix,) and the tensor template through it (lmax + 1,), lmax, and how the
    engine reads the sky at the samples (:func:`boresight.predict.focalplane.expected_residual`'s
    ``evaluation``)."""

    systematics: Systematics
    theory: Spectra
    fwhm_arcmin: float
    mask: np.ndarray
    template: np.ndarray
    lmax: int
    evaluation: str = "interp"


@dataclass
class DenseForm:
    """delta_r(c) = const + sum_u linear[u, c_u] + sum_uv gram[u, c_u, v, c_v] of one allowed
    angle index per unit, with a change cost per change of angle between consecutive units.

    Parameters
    ----------
    gram : numpy.ndarray, shape (U, K, U, K)
        Symmetric in (u, k) <-> (v, l).
    linear : numpy.ndarray, shape (U, K)
    const : float
    allowed_deg : numpy.ndarray, shape (K,)
    change_cost : float
    """

    gram: np.ndarray
    linear: np.ndarray
    const: float
    allowed_deg: np.ndarray
    change_cost: float = 0.0

    @property
    def unit_count(self) -> int:
        return self.linear.shape[0]

    def value(self, choice: np.ndarray) -> float:
        """delta_r of allowed-angle indices (U,), without the change cost."""
        u = np.arange(choice.size)
        quad = self.gram[u[:, None], choice[:, None], u[None, :], choice[None, :]]
        return float(self.const + np.sum(self.linear[u, choice]) + np.sum(quad))

    def changes(self, angles_deg: np.ndarray) -> int:
        """Changes of angle between consecutive units."""
        return angle_changes(angles_deg)

    def __call__(self, angles_deg: np.ndarray) -> float:
        """The search's objective of angles (U,): delta_r + change_cost x changes."""
        index = allowed_index(self.allowed_deg, angles_deg)
        return self.value(index) + self.change_cost * angle_changes(angles_deg)


class _Terms:
    """The focal plane's terms of dP and the kernels of delta_r over them (fixed per budget):
    ``terms`` lists each term's key among the pairs' shares and its moment n; the beams' terms
    (:func:`boresight.predict.focalplane.beam_terms`) are keyed as there, with their shares."""

    def __init__(self, target, nside, hits, beams):
        systematics, theory, fwhm_arcmin, _, template, lmax, evaluation = target
        self.lmax, self.band, self.lw = lmax, lmax, 2 * lmax
        read = sky_fields(nside, lmax, hits=hits, evaluation=evaluation)
        fields = read[0]
        named = budget_terms(systematics, read)
        self.terms = [(name, n) for name, (n, _, _) in named.items()]
        spins, term_fields = [], []
        for n, kind, _ in named.values():  # each term, then its H_4 conjugate
            spins += [n, 4 - n]
            term_fields += [fields[kind], fp.conjugate(fields[kind])]
        for key, term in beams.items():
            field = predict_fp.beam_sky_field(term.filter, term.moment, read[2].window)
            self.terms.append((key, term.moment))
            spins += [term.moment, 4 - term.moment]
            term_fields += [field, fp.conjugate(field)]
        spins.append(0)  # the sky's own P, with the mask's weight
        term_fields.append(fields["polarisation"])
        self.spins = spins
        weight_l = np.zeros(lmax + 1)
        lo, hi = R_RANGE[0], min(R_RANGE[1], lmax)
        weight_l[lo : hi + 1] = template[lo : hi + 1] / np.sum(template[lo : hi + 1] ** 2)
        sky_cl = smoothed_spectra(theory, fwhm_arcmin, lmax)
        kappa = fp.bb_kernels(spins, term_fields, sky_cl, weight_l)
        rows = list(range(len(spins)))
        self.form = kernel_form(spins, *kappa, self.lw, rows=rows, j_count=2 * len(spins))
        # the rows a drawn parameter moves: the named terms' (first); the beams' are not drawn
        self.drawn, self.drawn_form = slice(None), self.form
        if beams:
            self.drawn = slice(0, 4 * len(named))
            self.drawn_form = QuadraticForm(self.form.lam[self.drawn, self.drawn], self.lw)


def _rotate(alm, c):
    """(E, B) (2, nalm) of c times the weight: (E Re c - B Im c, E Im c + B Re c)."""
    return np.array([c.real * alm[0] - c.imag * alm[1], c.imag * alm[0] + c.real * alm[1]])


def linearised(
    sums: UnitSums,
    reference: np.ndarray,
    target: Target,
    *,
    exact: float,
    change_cost: float = 0.0,
    nthreads: int = 0,
) -> DenseForm:
    """The dense quadratic of delta_r with the hits, H_4 and valid pixels of ``reference``
    (allowed-angle indices, (U,)), anchored to its ``exact`` value (module docstring).

    Parameters
    ----------
    sums : boresight.moments.UnitSums
    reference : numpy.ndarray, int, shape (n_units,)
    target : Target
    exact : float
        The reference's exact expected delta_r (:func:`exact_delta_r`), which ``const`` makes
        the form's value there.
    change_cost : float
    nthreads : int

    Returns
    -------
    DenseForm
    """
    systematics, _theory, fwhm_arcmin, mask, _template, lmax, _evaluation = target
    focal, npix = sums.focalplane, mask.size
    params, drawn = predict_fp.at_means(systematics, focal.n_pairs)
    shares = predict_fp.pair_shares(params, focal)
    beams = predict_fp.beam_terms(params, focal, fwhm_arcmin, lmax, n_max=N_MAX)
    shares.update({key: term.shares for key, term in beams.items()})
    deltas = [(rms, d) for _, rms, d in predict_fp.unit_shares(params, drawn, shares, focal)]
    hits, s4 = np.zeros(npix), np.zeros(npix, dtype=np.complex128)
    for u, k in enumerate(reference):
        pix, s = sums.pixels[u][k], sums.sums[u][k]
        hits[pix] += s[:, 0].real.sum(axis=0)
        s4[pix] += shares["m4"] @ s[:, 4]
    h4 = np.where(hits > 0, s4 / np.maximum(hits, 1), 0.0)
    ok = (hits > 0) & ((1 - np.abs(h4)) >= predict_fp.RCOND_EXPECTATION * (1 + np.abs(h4)))
    solved = mask * ok  # the reference's valid pixels (predict.focalplane.valid)
    inverse = np.where(ok, solved / np.where(ok, hits * (1.0 - np.abs(h4) ** 2), 1.0), 0.0)
    terms = _Terms(target, sums.nside, hits, beams)
    n_units, n_allowed = sums.unit_count, sums.allowed_deg.size
    rows = 2 * len(terms.spins)
    nalm = fp.weight_alm(fp.Weight(0, np.zeros(npix, dtype=complex), None), terms.lw).shape[1]
    coherent = np.zeros((n_units, n_allowed, rows, nalm), dtype=np.complex128)
    gram = np.zeros((n_units * n_allowed, n_units * n_allowed))
    for i in range(focal.n_pairs):
        direct, conj = _pair_alm(sums, i, inverse, h4, terms, nthreads)
        coherent += _rows(direct, conj, terms, {k: v[i] for k, v in shares.items()})
        for rms, delta in deltas:
            x = _rows(direct, conj, terms, {k: v[i] for k, v in delta.items()})[:, :, terms.drawn]
            gram += rms**2 * _gram(terms.drawn_form, x.reshape(n_units * n_allowed, -1, nalm))
    flat = coherent.reshape(n_units * n_allowed, rows, nalm)
    gram += _gram(terms.form, flat)
    sky = np.zeros((rows, nalm), dtype=np.complex128)
    sky[-2:] = fp.weight_alm(fp.Weight(0, solved + 0j, None), terms.lw, nthreads)
    g_sky = terms.form.apply(sky)
    linear = 2 * np.array([np.sum(x.real * g_sky.real + x.imag * g_sky.imag) for x in flat])
    form = DenseForm(
        gram.reshape(n_units, n_allowed, n_units, n_allowed),
        linear.reshape(n_units, n_allowed),
        0.0,
        sums.allowed_deg,
        change_cost,
    )
    form.const = exact - form.value(np.asarray(reference))
    return form


def _pair_alm(sums, i, inverse, h4, terms, nthreads):
    """Pair i's weight alm per unit and angle, by moment: w S_n,i / (N det) (spin n) and its
    H_4 conjugate -w H_4 conj(S_n,i) / (N det) (spin 4 - n), {n: (U, K, 2, nalm)} each;
    S_-n = conj(S_n)."""
    moments = sorted({n for _, n in terms.terms})
    direct, conj = {n: [] for n in moments}, {n: [] for n in moments}
    weight = np.zeros(inverse.size, dtype=np.complex128)
    for u in range(sums.unit_count):
        for n in moments:
            direct[n].append([])
            conj[n].append([])
        for k in range(sums.allowed_deg.size):
            interrupts.check()
            pix, s = sums.pixels[u][k], sums.sums[u][k][i]
            for n in moments:
                moment = s[n] if n >= 0 else np.conj(s[-n])
                weight[:] = 0.0
                weight[pix] = inverse[pix] * moment
                direct[n][-1].append(fp.weight_alm(fp.Weight(n, weight, None), terms.lw, nthreads))
                weight[pix] = -inverse[pix] * h4[pix] * np.conj(moment)
                conj[n][-1].append(
                    fp.weight_alm(fp.Weight(4 - n, weight, None), terms.lw, nthreads)
                )
    return ({n: np.array(v) for n, v in direct.items()}, {n: np.array(v) for n, v in conj.items()})


def _rows(direct, conj, terms, share):
    """(U, K, rows, nalm): every term's (E, B), then its conjugate's, for one pair's shares."""
    any_n = next(iter(direct.values()))
    out = np.zeros((*any_n.shape[:2], 2 * len(terms.spins), any_n.shape[-1]), dtype=np.complex128)
    for t, (key, n) in enumerate(terms.terms):
        c = share.get(key, 0.0)  # the beams' terms are not drawn: no change of their shares
        if c == 0:
            continue
        for u in range(out.shape[0]):
            for k in range(out.shape[1]):
                # a weight of negative spin holds the alm of its conjugate: c turns it by conj(c)
                out[u, k, 4 * t : 4 * t + 2] = _rotate(direct[n][u, k], c if n >= 0 else np.conj(c))
                out[u, k, 4 * t + 2 : 4 * t + 4] = _rotate(conj[n][u, k], np.conj(c))
    return out


def _gram(form, x):
    """[a, b] = sum_jj' omega Re(x_a,j conj x_b,j') of vectors x (M, J, nalm)."""
    g = np.array([form.apply(v) for v in x])
    xr, gr = x.view(np.float64).reshape(x.shape[0], -1), g.view(np.float64).reshape(x.shape[0], -1)
    out = xr @ gr.T
    return 0.5 * (out + out.T)


def exact_delta_r(
    moments: UnitMoments,
    schedule: Schedule,
    focal: FocalPlane,
    angles_deg: np.ndarray,
    *,
    target: Target,
) -> tuple:
    """The exact expected delta_r of an assignment on the focal plane and its
    :class:`boresight.predict.focalplane.FocalPlaneResidual` (every pair on its own samples;
    read exactly, with each pair's samples' offsets from their pixel centres)."""
    scan = moments.schedule(schedule, angles_deg)
    stats = characterise_focalplane(scan, focal, moments.nside, per_pair=True)
    offsets = None
    if target.evaluation == "exact":
        offsets = centroid_moments(scan, moments.nside, focalplane=focal)
    expected = predict_fp.expected_residual(
        stats, target.mask, target.systematics, target.theory, target.fwhm_arcmin,
        lmax=target.lmax, evaluation=target.evaluation, offsets=offsets,
    )  # fmt: skip
    return delta_r(expected.residual, target.template), expected


def descend(
    form: DenseForm,
    start: np.ndarray,
    *,
    sweeps: int = 8,
    restarts: int = 4,
    seed: int = 0,
    progress: Callable | None = None,
    exhaustive_limit: int = EXHAUSTIVE_LIMIT,
) -> Design:
    """The best allowed-angle indices of a :class:`DenseForm`: enumeration where there are at
    most ``exhaustive_limit`` assignments, else coordinate descent with moves of one unit and of
    two consecutive units, from ``start`` and ``restarts`` random starts (as
    :func:`boresight.design.exact.search`). ``Design.angles_deg`` holds the angles."""
    allowed = form.allowed_deg
    n_units, n_allowed = form.linear.shape
    if n_allowed**n_units <= exhaustive_limit:
        return _enumerate(form)
    rng = np.random.default_rng(seed)
    starts = [np.asarray(start)] + [rng.integers(0, n_allowed, n_units) for _ in range(restarts)]
    return descent.descend(
        starts,
        state_of=lambda start: _DenseState(form, start),
        sweep=lambda state: state.sweep(rng, progress),
        value_of=lambda state: form(allowed[state.choice]),
        design_of=lambda state, value, history: Design(
            allowed[state.choice].copy(), value, history
        ),
        sweeps=sweeps,
    )


def _enumerate(form):
    """Every assignment of a small form, the best kept."""
    n_units, n_allowed = form.linear.shape
    grid = np.array(np.meshgrid(*([np.arange(n_allowed)] * n_units), indexing="ij"))
    choices = grid.reshape(n_units, -1).T
    values = np.array([form(form.allowed_deg[c]) for c in choices])
    best = int(np.argmin(values))
    angles = form.allowed_deg[choices[best]]
    return Design(
        angles, float(values[best]), [dict(start=0, sweep=0, objective=values[best], moves=0)]
    )


class _DenseState:
    """A descent's choice and field F[u, k] = sum_v gram[u, k, v, c_v]."""

    def __init__(self, form, choice):
        self.form = form
        self.choice = np.array(choice, dtype=np.int64)
        u = np.arange(self.choice.size)
        self.field = np.einsum("ukv->uk", form.gram[:, :, u, self.choice])

    def gains(self, u):
        """The change of delta_r (K,) of moving unit u to each allowed angle."""
        g, k = self.form.gram, self.choice[u]
        f = self.field[u]
        return (
            self.form.linear[u] - self.form.linear[u, k]
            + 2 * (f - f[k]) - 2 * (g[u, :, u, k] - g[u, k, u, k])
            + np.diagonal(g[u, :, u, :]) - g[u, k, u, k]
        )  # fmt: skip

    def move(self, u, k):
        self.field += self.form.gram[:, :, u, k] - self.form.gram[:, :, u, self.choice[u]]
        self.choice[u] = k

    def angles(self):
        return self.form.allowed_deg[self.choice]

    def sweep(self, rng, progress):
        """One pass of one- and two-unit moves; the number of moves accepted."""
        form, allowed, moves = self.form, self.form.allowed_deg, 0
        for u in rng.permutation(self.choice.size):
            interrupts.check()
            change = self.gains(u) + change_cost_delta(form, self.angles(), u, allowed)
            best = int(np.argmin(change))
            if change[best] < -1e-14 and best != self.choice[u]:
                self.move(u, best)
                moves += 1
            if u + 1 < self.choice.size:
                moves += self._pair(u, allowed)
            if progress is not None:
                progress(1)
        return moves

    def _pair(self, u, allowed):
        v, g = u + 1, self.form.gram
        ku, kv = self.choice[u], self.choice[v]
        cross = g[u, :, v, :] - g[u, :, v, kv][:, None] - g[u, ku, v, :][None, :] + g[u, ku, v, kv]
        change = self.gains(u)[:, None] + self.gains(v)[None, :] + 2 * cross
        change = change + pair_change_cost_delta(self.form, self.angles(), u, allowed)
        i, j = np.unravel_index(int(np.argmin(change)), change.shape)
        if change[i, j] >= -1e-14 or (i == ku and j == kv):
            return 0
        self.move(u, i)
        self.move(v, j)
        return 1


def search(
    sums: UnitSums,
    moments: UnitMoments,
    schedule: Schedule,
    target: Target,
    start_deg: np.ndarray,
    *,
    change_cost: float = 0.0,
    rounds: int = 3,
    sweeps: int = 8,
    restarts: int = 4,
    seed: int = 0,
    progress: Callable | None = None,
) -> Design:
    """The best assignment on the focal plane: :func:`descend` on the form linearised at the
    start, then at each round's optimum, until it stays or ``rounds`` are done; the best exact
    delta_r (plus the change cost) is kept. ``history`` rows carry their round."""
    focal = sums.focalplane

    def exact(angles):
        return exact_delta_r(moments, schedule, focal, angles, target=target)[0]

    reference = np.asarray(start_deg, dtype=float)
    value = exact(reference)
    best = Design(reference, value + change_cost * angle_changes(reference), [])
    history = []
    try:
        for r in range(rounds):
            form = linearised(
                sums, sums.choices(reference), target, exact=value, change_cost=change_cost
            )
            found = descend(
                form, sums.choices(reference), sweeps=sweeps, restarts=restarts,
                seed=seed + r, progress=progress,
            )  # fmt: skip
            if found.interrupted is not None:  # keep the best exact value of the rounds done
                raise found.interrupted
            history += [dict(row, round=r) for row in found.history]
            if np.array_equal(found.angles_deg, reference):
                break
            value = exact(found.angles_deg)
            total = value + change_cost * angle_changes(found.angles_deg)
            history.append(dict(start=-1, sweep=-1, objective=total, moves=0, round=r))
            reference = found.angles_deg
            if total < best.value:
                best = Design(reference.copy(), total, [])
    except KeyboardInterrupt as err:
        best.interrupted = (
            err if isinstance(err, interrupts.Interrupted) else interrupts.Interrupted()
        )
    best.history = history
    return best


def search_strategies(
    budget, moments, obj, schedule, strategies, *, startable, theory, timer, tick, progress
):
    """The search on the focal plane (:func:`boresight.design.focalplane.search`) from the best
    baseline there; every baseline's exact expectation on the mask they share."""
    opts, focal = budget.design, budget.focalplane
    with timer("every baseline on the focal plane"):
        expected = on_focalplane(
            budget, moments, obj, schedule, strategies, theory=theory, progress=progress
        )
    exact = {n: delta_r(e.residual, obj.template) for n, e in expected.items()}
    start = (
        strategies[min(startable, key=lambda n: exact[n] + opts.change_cost * obj.changes(
            strategies[n]))]
        if startable
        else np.full(moments.n_units, opts.angles_deg[0])
    )  # fmt: skip
    with timer("per-unit, per-angle moments of every pair"):
        sums = unit_sums(moments, schedule, focal, opts.angles_deg, progress=tick)
    with timer("search"):
        found = search(
            sums, moments, schedule, target_of(budget, theory, moments, obj), start,
            change_cost=opts.change_cost, sweeps=opts.sweeps, restarts=opts.restarts,
            seed=opts.seed, progress=tick,
        )  # fmt: skip
    return found, expected


def target_of(budget, theory, moments, obj):
    """The focal-plane search's :class:`boresight.design.focalplane.Target`."""
    return Target(
        budget.systematics, theory, budget.noise.fwhm_arcmin, moments.mask, obj.template,
        obj.lmax, budget.design.evaluation,
    )  # fmt: skip


def on_focalplane(budget, moments, obj, schedule, strategies, *, theory, progress):
    """Each strategy's exact expected residual on the focal plane, every pair on its own samples
    (:func:`boresight.design.focalplane.exact_delta_r`), on the boresight's footprint."""
    target = target_of(budget, theory, moments, obj)
    expected = {}
    for name, angles in tqdm(
        strategies.items(), desc="baselines on the focal plane", unit="strategy",
        disable=not progress,
    ):  # fmt: skip
        interrupts.check()
        _, expected[name] = exact_delta_r(
            moments, schedule, budget.focalplane, angles, target=target
        )
    return expected


def strategy_columns(expected, template, sigma, row):
    """strategies.csv's focal-plane columns: delta_r becomes the focal plane's, the on-axis
    objective's is kept as delta_r_on_axis."""
    total = delta_r(expected.residual, template)
    return dict(
        delta_r=total,
        delta_r_over_sigma_r=total / sigma,
        delta_r_on_axis=row["delta_r"],
        fp_delta_r_coherent=delta_r(expected.coherent.residual, template),
        fp_delta_r_scattered=delta_r(expected.scattered, template),
    )
