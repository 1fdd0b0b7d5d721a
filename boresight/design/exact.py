"""The design objective: the exact expected delta_r of an angle assignment, and its search.

:func:`boresight.predict.expected_residual` is bilinear in the weights' spectra, and delta_r is
linear in the pseudo-C_BB, so per budget one set of kernels gives
(:func:`boresight.predict.field_products.bb_kernels`)

    delta_r = const + sum_jj' sum_lm omega_jj'(l) Re(a_j,lm conj(a_j',lm)),

with a_j the (E, B) alm of w h_n (j = (n, E or B)). A unit's share of w h_n is w S_n,u / hits at
angle 0, whose (E, B) alm are computed once; at angle a it turns by n a, (E, B) -> (E cos na -
B sin na, E sin na + B cos na), so the alm are linear in (cos n a_u, sin n a_u). Changing one
unit (or two) changes delta_r by a linear term in the current omega a, which costs O(nalm) per
unit visited, plus a quadratic term from an 8 x 8 matrix per unit made once. Nothing assumes h_n
white: on a real schedule's striped h_n the paper's approximation
(:class:`boresight.design.Objective`) can rank strategies wrongly.

The rows come in channels (:class:`Channel`), each a unit weight that an assignment turns by a
phase: the pairs' h_1 .. h_4; read exactly, the sums of the samples' offsets from their pixel
centres, which turn alike; behind a HWP, the plate's IP through the crossing angles' own h_2,
turned by the boresight angle alone, while a stepped plate's step b turns the pairs' channels by
2 n b as well, so that a unit's choice is an (angle, step) pair.

The search (:func:`search`) enumerates every assignment where there are at most 3^10
(:func:`exhaustive`); beyond, it is coordinate descent with moves of one unit and of two
consecutive units (a slot's rising and setting CESs), from the best of the baselines and from
random restarts, the best kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import healpy as hp
import numpy as np

from .. import coupling, predict
from .._util import interrupts
from .._util.jit import njit
from ..constants import DEG, N_MAX
from ..instrument.hwp import pairs_behind
from ..predict import field_products as fp
from ..predict.expectation import OFFSETS_BEHIND_HWP
from . import descent
from .white import Design

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..cosmology import Spectra
    from ..instrument.hwp import HWP
    from ..instrument.pairs import Instrument, Systematics
    from ..moments.units import UnitMoments
    from .constraints import Feasibility
    from .operations import TimePrice

#: (E, B) rows of Y_n = i X_n: the unit's alm turned by a quarter of a period of n a
_QUARTER = np.array([[0.0, -1.0], [1.0, 0.0]])
#: the most assignments :func:`search` enumerates rather than descends (3^10)
EXHAUSTIVE_LIMIT = 59049


class Channel(NamedTuple):
    """Two rows (E, B) of the objective's alm: the weight w h_n of ``moment`` n of a source.

    ``source`` "pairs": the pairs' own h_n (behind a HWP, of their reflected angle psi + 2 chi),
    which a unit at boresight angle a and a stepped plate's step b turns by n (a + 2 b);
    "plate": the crossing angles' own h_n (h_{n,0}), which a plate's instrumental polarisation
    reaches through and which only a turns, by n a; "delta", "conj delta": half the sums of
    exp(i n psi) delta and exp(i n psi) conj(delta) over the hits, delta the samples' offsets
    from their pixel centres (:attr:`boresight.moments.UnitMoments.centroids`), and "conjugate
    conj delta" the conjugate of the latter (turned by -n a: ``moment`` is then -n). ``spin``:
    the weight's, as :class:`boresight.predict.field_products.Weight` takes it (default n).
    """

    moment: int
    source: str = "pairs"
    spin: int | None = None

    @property
    def weight_spin(self) -> int:
        return self.moment if self.spin is None else self.spin


#: the channels of bare pairs: their h_1 .. h_N_MAX
PAIRS = tuple(Channel(n) for n in range(1, N_MAX + 1))


def choices(angles_deg, steps_deg=None) -> np.ndarray:
    """(angle, step) rows [deg] (K, 2) of angles (K,) and steps (K,) (default 0)."""
    angles = np.asarray(angles_deg, dtype=float)
    steps = np.zeros_like(angles) if steps_deg is None else np.asarray(steps_deg, dtype=float)
    return np.stack([angles, steps], axis=-1)


def options(allowed_deg, steps_deg=None) -> np.ndarray:
    """Every (angle, step) a unit may take (K, 2) [deg], the angles outer: with one step, the
    allowed angles in their order."""
    steps = (0.0,) if steps_deg is None else steps_deg
    return np.array([(float(a), float(b)) for a in allowed_deg for b in steps])


def angle_changes(choice) -> int:
    """Changes of angle (or of step) between consecutive units, of angles (U,) or choices (U, 2)."""
    moved = np.diff(np.asarray(choice, dtype=float), axis=0) != 0
    return int(np.sum(moved if moved.ndim == 1 else moved.any(axis=1)))


@dataclass
class ExactObjective:
    """The exact expected total-residual delta_r of an assignment (module docstring).

    Parameters
    ----------
    moments : boresight.moments.UnitMoments
    form : QuadraticForm
        omega, j = 2 (c + 1) + (0 for E, 1 for B) for channel c, j = 0, 1 the h_0 terms.
    fixed : numpy.ndarray, complex128, shape (2, nalm)
        The (E, B) alm of the h_0 terms' weight (the mask).
    unit_alm : numpy.ndarray, complex128, shape (n_units, n_channels, 2, nalm)
        Each unit's (E, B) alm of w S_n,u / hits of each channel at angle 0.
    const : float
        The angle-independent delta_r of the in-pixel scatter.
    change_cost : float
    template : numpy.ndarray
        Pseudo-C_BB of tensors at r = 1 over the mask.
    lmax, band : int
    channels : tuple of Channel
        Default the bare pairs' h_1 .. h_N_MAX (:data:`PAIRS`).
    time_price : boresight.design.operations.TimePrice, optional
        The delta_r equivalent of the observing time the assignment's changes lose, added to
        the search's objective (the budget's ``[operations]``).
    feasibility : boresight.design.constraints.Feasibility, optional
        The mount's constraints: an assignment that breaks one costs infinity.
    """

    moments: UnitMoments
    form: QuadraticForm
    fixed: np.ndarray
    unit_alm: np.ndarray
    const: float
    change_cost: float
    template: np.ndarray
    lmax: int
    band: int
    channels: tuple = PAIRS
    time_price: TimePrice | None = None
    feasibility: Feasibility | None = None

    @property
    def unit_count(self) -> int:
        return self.unit_alm.shape[0]

    def phases(self, choice: np.ndarray) -> np.ndarray:
        """n_c times each channel's angle [rad] (K, n_channels) of (angle, step) rows (K, 2)."""
        choice = np.atleast_2d(np.asarray(choice, dtype=float))
        n = np.array([c.moment for c in self.channels], dtype=float)
        stepped = np.array([c.source == "pairs" for c in self.channels], dtype=float)
        turn = (choice[:, :1] + 2.0 * choice[:, 1:] * stepped[None, :]) * DEG
        return turn * n[None, :]

    def alm_of(self, choice: np.ndarray) -> np.ndarray:
        """a_j (J, nalm) of (angle, step) rows (n_units, 2)."""
        theta = self.phases(choice)
        out = np.zeros((2 + 2 * len(self.channels), self.fixed.shape[1]), dtype=np.complex128)
        out[:2] = self.fixed
        for k in range(len(self.channels)):
            c, s = np.cos(theta[:, k]), np.sin(theta[:, k])
            e, b = self.unit_alm[:, k, 0], self.unit_alm[:, k, 1]
            out[2 * k + 2] = c @ e - s @ b
            out[2 * k + 3] = s @ e + c @ b
        return out

    def alm(self, angles_deg: np.ndarray, steps_deg: np.ndarray | None = None) -> np.ndarray:
        """a_j (J, nalm) of an assignment: angles (and a stepped plate's steps) [deg]."""
        return self.alm_of(choices(angles_deg, steps_deg))

    def value_of(self, alm: np.ndarray) -> float:
        """delta_r of a_j (J, nalm)."""
        return self.const + self.form.value(alm)

    def delta_r(self, angles_deg: np.ndarray, steps_deg: np.ndarray | None = None) -> float:
        """The expected delta_r of the total residual, without the change cost."""
        return self.value_of(self.alm(angles_deg, steps_deg))

    def changes(self, angles_deg: np.ndarray, steps_deg: np.ndarray | None = None) -> int:
        """Changes of angle, or of step, between consecutive units."""
        return angle_changes(choices(angles_deg, steps_deg))

    def __call__(self, angles_deg: np.ndarray, steps_deg: np.ndarray | None = None) -> float:
        """The search's objective: delta_r + change_cost x changes + the lost time's price."""
        return self.value_at(choices(angles_deg, steps_deg))

    def value_at(self, choice: np.ndarray) -> float:
        """The search's objective of (angle, step) rows (n_units, 2)."""
        return self.value_of(self.alm_of(choice)) + price_of(self, choice)


def price_of(obj, choice) -> float:
    """What an assignment's changes cost beside delta_r: change_cost per change and the
    delta_r equivalent of the observing time lost (``obj.time_price``); infinity where it breaks
    a constraint (``obj.feasibility``)."""
    choice = np.asarray(choice, dtype=float)
    feasibility = getattr(obj, "feasibility", None)
    if feasibility is not None and not feasibility.ok(choice if choice.ndim == 1 else choice[:, 0]):
        return np.inf
    cost = obj.change_cost * angle_changes(choice)
    price = getattr(obj, "time_price", None)
    if price is not None:
        cost += price.value(choice if choice.ndim == 1 else choice[:, 0])
    return cost


def exact_objective(
    moments: UnitMoments,
    systematics: Systematics,
    theory: Spectra,
    fwhm_arcmin: float,
    *,
    change_cost: float = 0.0,
    instrument: Instrument | None = None,
    lmax: int | None = None,
    evaluation: str = "interp",
    hwp: HWP | None = None,
    plate_moments: UnitMoments | None = None,
    nthreads: int = 0,
    time_price: TimePrice | None = None,
    feasibility: Feasibility | None = None,
    deprojected: tuple = (),
) -> ExactObjective:
    """The exact expected delta_r objective of a budget over a schedule's units.

    Parameters
    ----------
    moments : boresight.moments.UnitMoments
        The units' sums of the boresight's crossing angle.
    systematics, theory, fwhm_arcmin, instrument
        As :func:`boresight.predict.expected_residual`; the hits spread over their pixels as
        the schedule's do (``moments.hits``).
    change_cost : float
    lmax : int, optional
        The pseudo-spectra's and the sky's band limit (default 2 Nside); the weights' alm reach
        2 lmax, and memory goes as n_units x 8 x 2 lmax^2 complex numbers.
    evaluation : {"interp", "exact"}
        How the engine reads the sky at the samples (:func:`boresight.predict.
        expected_residual`).
    hwp : boresight.instrument.hwp.HWP, optional
        A HWP in front of the pairs (on the axis, their 4 x angles cancelling). The pairs'
        systematics reach the maps as the bare pairs' at their reflected angles do
        (:func:`boresight.instrument.hwp.reflected_systematics`), through the h_n of psi + 2 chi: a
        stepped plate's are ``moments``' turned by n (a + 2 b) with b its step per unit (a
        design variable: its ``angles_deg`` are the allowed steps, :func:`search`), a continuous plate's are ``plate_moments``'. The plate's
        instrumental polarisation reaches them through ``moments``' own h_2, which only the
        boresight angle turns (:func:`boresight.predict.hwp.ip_delta_p`). Its angle
        jitter and synchronous signal are not in the objective.
    plate_moments : boresight.moments.UnitMoments, optional
        A continuous plate's: :func:`boresight.moments.unit_moments` with ``hwp``; needed where
        the pairs carry systematics.
    nthreads : int
    time_price : boresight.design.operations.TimePrice, optional
        The lost observing time's price, added to the search's objective.
    feasibility : boresight.design.constraints.Feasibility, optional
        The mount's constraints, which the search keeps.
    deprojected : tuple of str
        Template sets the pipeline deprojects (:func:`boresight.predict.leak_model`): the leaks
        of T they fit are out of the objective.

    Returns
    -------
    ExactObjective
    """
    nside = moments.nside
    lmax = 2 * nside if lmax is None else int(lmax)
    band, lw = lmax, 2 * lmax
    mask = moments.mask
    hits = moments.full_sky(moments.hits)
    plate_ip = 0.0
    if hwp is not None and hwp.present:
        systematics, instrument, plate_ip = pairs_behind(hwp, systematics, instrument)
    model = predict.leak_model(
        systematics, theory, fwhm_arcmin, band, nside, instrument=instrument, hits=hits,
        with_sky=True, evaluation=evaluation, plate_ip=plate_ip, deprojected=deprojected,
    )  # fmt: skip
    if any(abs(n) > N_MAX for n in model.term_n):
        model = _within(model, N_MAX)
    channels, sources = _channels(model, hwp, moments, plate_moments, bool(plate_ip))
    rows = [0] * len(model.term_n)
    for k, n in enumerate(model.term_n[: model.n_leak - bool(plate_ip)]):
        if n:
            rows[k] = 1 + channels.index(Channel(abs(n)))
    if plate_ip:
        rows[model.n_leak - 1] = 1 + channels.index(Channel(2, "plate"))
    spins, fields = list(model.term_n), list(model.fields)
    second, pseudo = model.second, model.pseudo
    if evaluation == "exact" and moments.centroids is not None:
        if hwp is not None and hwp.present:
            raise ValueError(OFFSETS_BEHIND_HWP)
        k = model.n_leak
        extra = _offset_terms(model)
        new = list(dict.fromkeys(c for *_, c in extra))
        channels = channels + tuple(new)
        sources = list(sources) + [moments] * len(new)
        index = list(range(k)) + [t[2] for t in extra] + list(range(k, len(spins)))
        second, pseudo = second[np.ix_(index, index)], pseudo[np.ix_(index, index)]
        spins = spins[:k] + [t[0] for t in extra] + spins[k:]
        fields = fields[:k] + [t[1] for t in extra] + fields[k:]
        rows = rows[:k] + [1 + channels.index(t[3]) for t in extra] + rows[k:]
    couplings = coupling.mask_coupling(mask, lmax, nthreads)
    template = predict.tensor_template(couplings, theory, fwhm_arcmin, nside)
    weight_l = predict.delta_r_weights(template, lmax)
    kappa_w, kappa_v = fp.bb_kernels(
        spins, fields, model.sky_cl, weight_l, second=second, pseudo=pseudo
    )
    j_count = 2 + 2 * len(channels)
    form = kernel_form(spins, kappa_w, kappa_v, lw, rows=rows, j_count=j_count)
    alone = fp.bb_kernels((0,), model.fields[-1:], model.sky_cl, weight_l)
    sky_alm = fp.weight_alm(fp.Weight(0, mask + 0j, None), lw, nthreads)
    sky_form = kernel_form((0,), *alone, lw)
    const = model.scatter(mask) * float(np.sum(weight_l)) - sky_form.value(_padded(sky_alm))
    unit_alm = _unit_alm(moments, sources, channels, mask, lw, nthreads)
    return ExactObjective(
        moments, form, sky_alm, unit_alm, const, change_cost, template, lmax, band, channels,
        time_price, feasibility,
    )  # fmt: skip


def _offset_terms(model):
    """Each leak term's first-order changes across its pixels
    (:func:`boresight.predict.expected_residual`'s ``offsets``): for term k, h_n F, the spin
    n - 1 term on d F and the spin n + 1 term on dbar F, as (spin, field, k, channel). h_-n's
    share the channels of h_n's other one, conjugated by their spin's sign, but for the spin-0
    weight of n = -1, which has its own."""
    out = []
    for k in range(model.n_leak):
        n = model.term_n[k]
        m = abs(n)
        for raising in (True, False):
            spin = n - 1 if raising else n + 1
            if n >= 0:
                channel = Channel(m, "conj delta" if raising else "delta", spin)
            elif spin:
                channel = Channel(m, "delta" if raising else "conj delta", abs(spin))
            else:
                channel = Channel(-1, "conjugate conj delta", 0)
            out.append((spin, fp.derivative(model.fields[k], raising=raising), k, channel))
    return out


def _channels(model, hwp, moments, plate_moments, with_ip):
    """The objective's channels, and the unit moments each reads."""
    if hwp is None or not hwp.present:
        return PAIRS, [moments] * N_MAX
    pairs = any(n for n in model.term_n[: model.n_leak - with_ip])
    channels = list(PAIRS) if pairs else []
    sources = [moments] * len(channels)
    if pairs and hwp.spinning:
        if plate_moments is None:
            raise ValueError(
                "the pairs' systematics behind a continuous HWP: give plate_moments "
                "(boresight.moments.unit_moments with the HWP)"
            )
        if not np.array_equal(plate_moments.pixels, moments.pixels) or not np.array_equal(
            plate_moments.offsets, moments.offsets
        ):
            raise ValueError("plate_moments must be of the same schedule and units as moments")
        sources = [plate_moments] * len(channels)
    if with_ip:
        channels.append(Channel(2, "plate"))
        sources.append(moments)
    return tuple(channels), sources


def _within(model, n_max):
    """The model without terms beyond h_n_max (the beams' h_5, h_6 that the units do not hold)."""
    keep = [k for k, n in enumerate(model.term_n) if abs(n) <= n_max]
    return model._replace(
        term_n=tuple(model.term_n[k] for k in keep),
        fields=tuple(model.fields[k] for k in keep),
        readings=tuple(model.readings[k] for k in keep),
        second=model.second[np.ix_(keep, keep)],
        pseudo=model.pseudo[np.ix_(keep, keep)],
    )


def kernel_form(ns, kappa_w, kappa_v, lw, *, rows=None, j_count=2 * (N_MAX + 1)):
    """omega of the terms' kernels: W and V are sums over (p, q) of the real cross spectra of the
    (E, B) alm times alpha_p conj(alpha'_q) or alpha_p alpha'_q (the spin's sign pair,
    :func:`boresight.predict.field_products.weight_cross_spectra`), symmetrised. Term k's (E, B)
    are rows 2 rows[k] + (0, 1) of ``j_count`` (default: 2 abs(n), terms of one moment sharing
    its alm)."""
    rows = [abs(n) for n in ns] if rows is None else rows
    lam = np.zeros((j_count, j_count, lw + 1))
    for k, n in enumerate(ns):
        pk = fp.spin_pair(n)
        for kp, npr in enumerate(ns):
            pkp = fp.spin_pair(npr)
            for p in (0, 1):
                for q in (0, 1):
                    value = (
                        kappa_w[k, kp] * pk[p] * np.conj(pkp[q]) - kappa_v[k, kp] * pk[p] * pkp[q]
                    )
                    lam[2 * rows[k] + p, 2 * rows[kp] + q] += value.real
    return QuadraticForm(0.5 * (lam + lam.transpose(1, 0, 2)), lw)


def _padded(alm, j_count=2 * (N_MAX + 1)):
    """(2, nalm) h_0 alm as (J, nalm) with the other rows zero."""
    out = np.zeros((j_count, alm.shape[1]), dtype=np.complex128)
    out[:2] = alm
    return out


class QuadraticForm:
    """sum_jj' sum_lm omega_jj'(l) Re(a_j,lm conj(b_j',lm)), omega = lam_jj'(l) (1 or 2) / (2l + 1)
    for m = 0 or m > 0 (a cross spectrum's sum over -l..l), held as lam (J, J, lw + 1)."""

    def __init__(self, lam: np.ndarray, lw: int):
        self.lam = np.ascontiguousarray(lam)
        ell, m = hp.Alm.getlm(lw)
        self.ell = ell.astype(np.int64)
        self.factor = np.where(m > 0, 2.0, 1.0) / (2 * ell + 1.0)

    def apply(self, x: np.ndarray, rows: range | None = None) -> np.ndarray:
        """omega x (J, nalm) of x (J, nalm) complex, from the rows of x in ``rows`` (all)."""
        rows = range(x.shape[0]) if rows is None else rows
        out = np.zeros_like(x)
        _apply(self.lam, self.ell, self.factor, x, rows.start, rows.stop, out)
        return out

    def value(self, x: np.ndarray) -> float:
        """sum Re(x conj(omega x))."""
        g = self.apply(x)
        return float(np.sum(x.real * g.real + x.imag * g.imag))

    def block(self, a: np.ndarray, b: np.ndarray, rows_a, rows_b) -> np.ndarray:
        """[r, t, p, q] = sum_i omega_{rows_a[p], rows_b[q]}(i) Re(a_r,i conj b_t,i) for a, b
        (2, nalm)."""
        prod = (a[:, None].real * b[None].real + a[:, None].imag * b[None].imag) * self.factor
        per_l = np.stack([np.bincount(self.ell, p, self.lam.shape[2]) for p in prod.reshape(4, -1)])
        lam = self.lam[np.ix_(rows_a, rows_b)]  # (2, 2, lw + 1)
        return (per_l @ lam.reshape(4, -1).T).reshape(2, 2, 2, 2)


@njit
def _apply(lam, ell, factor, x, lo, hi, out):
    """out[j, i] = factor[i] sum_{lo <= k < hi} lam[j, k, ell[i]] x[k, i]."""
    for i in range(x.shape[1]):
        li = ell[i]
        for j in range(out.shape[0]):
            acc = 0j
            for k in range(lo, hi):
                acc += lam[j, k, li] * x[k, i]
            out[j, i] = acc * factor[i]


def _unit_alm(m, sources, channels, mask, lw, nthreads):
    """(n_units, n_channels, 2, nalm): the (E, B) alm of w S_n,u / hits of each unit and
    channel at angle 0, S_n,u of the channel's unit moments (``sources``, on the units and
    pixels of ``m``); one transform per distinct (moments, n)."""
    out = np.zeros((m.n_units, len(channels), 2, hp.Alm.getsize(lw)), dtype=np.complex128)
    for u in range(m.n_units):
        interrupts.check()
        lo, hi = m.offsets[u], m.offsets[u + 1]
        pix = m.pixels[m.index[lo:hi]]
        inverse = mask[pix] / m.hits[m.index[lo:hi]]
        done = {}
        for k, (channel, source) in enumerate(zip(channels, sources)):
            kind = "sums" if channel.source in ("pairs", "plate") else channel.source
            key = (id(source), kind, channel.moment, channel.weight_spin)
            if key not in done:
                weight = np.zeros(12 * m.nside**2, dtype=np.complex128)
                weight[pix] = _unit_share(source, channel, lo, hi) * inverse
                spin = channel.weight_spin
                done[key] = fp.weight_alm(fp.Weight(spin, weight, None), lw, nthreads)
            out[u, k] = done[key]
    return out


def _unit_share(source, channel, lo, hi):
    """Entries lo:hi of a channel's unit sums (:class:`Channel`)."""
    n = channel.moment
    if channel.source in ("pairs", "plate"):
        return source.sums[n - 1, lo:hi]
    if channel.source == "delta":
        return 0.5 * source.centroids[0, n, lo:hi]
    if channel.source == "conj delta":
        return 0.5 * source.centroids[1, n, lo:hi]
    return 0.5 * np.conj(source.centroids[1, -n, lo:hi])


class _State:
    """The search's running a_j and g = omega a, with each unit's (angle, step) row."""

    def __init__(self, obj: ExactObjective, choice):
        self.obj = obj
        self.choice = np.array(choice, dtype=float)
        self.a = obj.alm_of(self.choice)
        self.g = obj.form.apply(self.a)
        self.value = obj.value_of(self.a)

    def steps(self, u, opts):
        """(c, s) (K, n_channels): cos and sin of each channel's phase at the options (K, 2)
        minus those of the unit's current one."""
        new = self.obj.phases(opts)
        old = self.obj.phases(self.choice[u])
        return np.cos(new) - np.cos(old), np.sin(new) - np.sin(old)

    def linear(self, u):
        """2 Re <X_c, g> and 2 Re <Y_c, g> (2, n_channels) of unit u."""
        base = self.obj.unit_alm[u].view(np.float64)  # (C, 2, 2 nalm): Re, Im interleaved
        g = self.g[2:].view(np.float64).reshape(base.shape[0], 2, -1)
        inner = base @ g.transpose(0, 2, 1)  # [c, r, p] = Re sum_i base[c, r] conj(g[c, p])
        x = inner[:, 0, 0] + inner[:, 1, 1]  # X_c: (E, B) rows are the unit's (E, B)
        y = -inner[:, 1, 0] + inner[:, 0, 1]  # Y_c: (E, B) rows are (-B, E)
        return 2 * np.array([x, y])

    def apply(self, u, c, s, option):
        """Move unit u to ``option`` (angle, step): c, s (n_channels,) of its step."""
        base = self.obj.unit_alm[u]
        delta = np.zeros_like(self.a)
        for k in range(base.shape[0]):
            e, b = base[k]
            delta[2 * k + 2] = c[k] * e - s[k] * b
            delta[2 * k + 3] = s[k] * e + c[k] * b
        self.a += delta
        self.g += self.obj.form.apply(delta, range(2, delta.shape[0]))  # h_0 rows never move
        self.choice[u] = option


def _blocks(obj: ExactObjective, u: int, v: int) -> np.ndarray:
    """Q (2, C, 2, C): sum_jj' omega Re(A_j conj B_j') of unit u's vectors A in {X_c, Y_c}
    against unit v's; the quadratic term of a move is c^T Q c over its (c, s)."""
    bu, bv = obj.unit_alm[u], obj.unit_alm[v]  # (C, 2, nalm)
    rows = (np.eye(2), _QUARTER)  # X: p from r by identity; Y: by the quarter turn
    count = bu.shape[0]
    out = np.zeros((2, count, 2, count))
    for n in range(count):
        for m in range(count):
            rows_n, rows_m = [2 * n + 2, 2 * n + 3], [2 * m + 2, 2 * m + 3]
            if not obj.form.lam[np.ix_(rows_n, rows_m)].any():  # channels the form never joins
                continue
            g = obj.form.block(bu[n], bv[m], rows_n, rows_m)  # [r, t, p, q]
            for ia, ma in enumerate(rows):
                for ib, mb in enumerate(rows):
                    out[ia, n, ib, m] = np.einsum("pr,qt,rtpq->", ma, mb, g)
    return out


def _design(choice, value, history, stepped):
    """The Design of (angle, step) rows: its steps where the plate's are chosen."""
    return Design(
        choice[:, 0].copy(), value, history, steps_deg=choice[:, 1].copy() if stepped else None
    )


def exhaustive(
    obj: ExactObjective, allowed_deg: tuple, *, steps_deg: tuple | None = None
) -> Design:
    """The global optimum by enumeration, for small problems (:data:`EXHAUSTIVE_LIMIT`).

    With t_u = (cos, sin) of each channel's phase of unit u the assignment's delta_r is the
    quadratic const + 2 sum_u L_u . t_u + sum_uv t_u^T Q_uv t_v, with L_u unit u's vectors
    against omega times the h_0 terms' alm and Q_uv its blocks (:func:`_blocks`) for every pair
    of units, so every assignment costs O(n_units^2) once those are made. ``steps_deg``: a
    stepped plate's allowed steps, chosen per unit with the angles (:func:`search`).
    """
    opts = options(allowed_deg, steps_deg)
    u_count = obj.unit_count
    j_count = obj.form.lam.shape[0]
    fixed = obj.form.apply(_padded(obj.fixed, j_count))  # omega a_0 of the h_0 rows
    zero = _State.__new__(_State)  # its linear() against omega a_0
    zero.obj, zero.g = obj, np.ascontiguousarray(fixed)
    lin = np.array([zero.linear(u) for u in range(u_count)])  # 2 Re<A, omega a_0>: (U, 2, C)
    q = np.array([[_blocks(obj, u, v) for v in range(u_count)] for u in range(u_count)])
    theta = obj.phases(opts)
    t = np.stack([np.cos(theta), np.sin(theta)], 1)
    picks = np.array(np.meshgrid(*([np.arange(len(opts))] * u_count), indexing="ij"))
    picks = picks.reshape(u_count, -1).T  # (M, U)
    vec = t[picks]  # (M, U, 2, C)
    value = obj.const + obj.form.value(_padded(obj.fixed, j_count))
    value = value + np.einsum("muan,uan->m", vec, lin)
    value = value + np.einsum("muan,uvanbk,mvbk->m", vec, q, vec, optimize=True)
    chosen = opts[picks]  # (M, U, 2)
    priced = obj.change_cost or obj.time_price is not None
    cost = np.array([price_of(obj, c) for c in chosen]) if priced else 0
    total = value + cost
    best = int(np.argmin(total))
    history = [dict(start=0, sweep=0, objective=float(total[best]), moves=0)]
    return _design(chosen[best], float(total[best]), history, steps_deg is not None)


def search(
    obj: ExactObjective,
    allowed_deg: tuple,
    start_deg: np.ndarray,
    *,
    steps_deg: tuple | None = None,
    start_steps_deg: np.ndarray | None = None,
    sweeps: int = 8,
    restarts: int = 4,
    seed: int = 0,
    progress: Callable | None = None,
    exhaustive_limit: int = EXHAUSTIVE_LIMIT,
) -> Design:
    """The best assignment found by coordinate descent with one- and two-unit moves, or by
    enumeration (:func:`exhaustive`) where there are at most ``exhaustive_limit`` assignments.

    From ``start_deg`` and from ``restarts`` random assignments of the allowed angles: each pass
    visits the units in an order drawn from ``seed`` and moves a unit, then it and the next unit
    together, to the allowed angles that lower the objective most; passes repeat until one
    changes nothing or ``sweeps`` are done. The best end point is kept.

    Parameters
    ----------
    obj : ExactObjective
    allowed_deg : tuple of float
    start_deg : numpy.ndarray, shape (n_units,)
    steps_deg : tuple of float, optional
        A stepped HWP's allowed angles, one chosen per unit with its boresight angle (every
        pair of the two is an option); the plate's steps are then in ``Design.steps_deg``.
    start_steps_deg : numpy.ndarray, shape (n_units,), optional
        The start's steps (default the first allowed step).
    sweeps, restarts, seed : int
    progress : callable, optional
        Called with 1 after each unit visited.
    exhaustive_limit : int

    Returns
    -------
    Design
        ``history`` has one row per pass: start, sweep, objective, moves.
    """
    opts = options(allowed_deg, steps_deg)
    if len(opts) ** obj.unit_count <= exhaustive_limit:
        return exhaustive(obj, allowed_deg, steps_deg=steps_deg)
    stepped = steps_deg is not None
    if stepped and start_steps_deg is None:
        start_steps_deg = np.full(obj.unit_count, float(steps_deg[0]))
    rng = np.random.default_rng(seed)
    single = [_blocks(obj, u, u) for u in range(obj.unit_count)]
    cross = [_blocks(obj, u, u + 1) for u in range(obj.unit_count - 1)]
    starts = [choices(start_deg, start_steps_deg)] + _random_starts(obj, opts, restarts, rng)
    return descent.descend(
        starts,
        state_of=lambda start: _State(obj, start),
        sweep=lambda state: _sweep(obj, state, opts, single, cross, rng, progress),
        value_of=lambda state: obj.value_at(state.choice),
        design_of=lambda state, value, history: _design(state.choice, value, history, stepped),
        sweeps=sweeps,
    )


def _random_starts(obj, opts, restarts, rng):
    """``restarts`` random assignments of the options; under constraints each unit's drawn
    from those it may take, and an assignment that breaks the most changes per day dropped."""
    feasibility = getattr(obj, "feasibility", None)
    out = []
    for _ in range(restarts):
        pick = opts[rng.choice(len(opts), obj.unit_count)]
        if feasibility is not None:
            for u in range(obj.unit_count):
                mine = [k for k, o in enumerate(opts) if feasibility.unit_ok(u, o[0])]
                pick[u] = opts[mine[rng.integers(len(mine))]]
            if not feasibility.ok(pick[:, 0]):
                continue
        out.append(pick)
    return out


def _sweep(obj, state, opts, single, cross, rng, progress):
    """One pass of one- and two-unit moves; the number of moves accepted."""
    moves = 0
    tol = 1e-12 * max(abs(state.value), 1e-300)
    for u in rng.permutation(obj.unit_count):
        interrupts.check()
        c, s = state.steps(u, opts)  # (K, C)
        step = np.stack([c, s], axis=1)  # (K, 2, C)
        lin = np.einsum("kan,an->k", step, state.linear(u))
        quad = np.einsum("kan,anbm,kbm->k", step, single[u], step)
        change = lin + quad + change_cost_delta(obj, state.choice, u, opts)
        best = int(np.argmin(change))
        if change[best] < -tol and _differs(opts[best], state.choice[u]):
            state.apply(u, c[best], s[best], opts[best])
            state.value += lin[best] + quad[best]
            moves += 1
        if u + 1 < obj.unit_count:
            moves += _pair_move(obj, state, opts, single, cross[u], u, tol)
        if progress is not None:
            progress(1)
    return moves


def _pair_move(obj, state, opts, single, q_uv, u, tol):
    """Move units u and u + 1 together to the pair of options that lowers the objective most;
    1 if it moved."""
    v = u + 1
    cu, su = state.steps(u, opts)
    cv, sv = state.steps(v, opts)
    step_u, step_v = np.stack([cu, su], axis=1), np.stack([cv, sv], axis=1)
    lin_u = np.einsum("kan,an->k", step_u, state.linear(u))
    lin_v = np.einsum("kan,an->k", step_v, state.linear(v))
    quad_u = np.einsum("kan,anbm,kbm->k", step_u, single[u], step_u)
    quad_v = np.einsum("kan,anbm,kbm->k", step_v, single[v], step_v)
    both = 2 * np.einsum("kan,anbm,lbm->kl", step_u, q_uv, step_v)
    gain = (lin_u + quad_u)[:, None] + (lin_v + quad_v)[None, :] + both
    change = gain + pair_change_cost_delta(obj, state.choice, u, opts)
    i, j = np.unravel_index(int(np.argmin(change)), change.shape)
    if change[i, j] >= -tol or not (
        _differs(opts[i], state.choice[u]) or _differs(opts[j], state.choice[v])
    ):
        return 0
    state.apply(u, cu[i], su[i], opts[i])
    state.apply(v, cv[j], sv[j], opts[j])  # each step is from the unit's own current option
    state.value += gain[i, j]
    return 1


def _differs(a, b) -> bool:
    """Whether two angles, or two (angle, step) rows, differ."""
    return bool(np.any(np.asarray(a) != np.asarray(b)))


def change_cost_delta(obj, choice, u, opts):
    """The change of what the changes cost (K,) of moving unit u to each option (an allowed
    angle, or an (angle, step) row): change_cost and the lost time's price."""
    out = np.zeros(len(opts))
    if obj.change_cost:
        near = [choice[v] for v in (u - 1, u + 1) if 0 <= v < len(choice)]
        count = np.array([sum(_differs(a, b) for b in near) for a in opts])
        out += obj.change_cost * (count - sum(_differs(choice[u], b) for b in near))
    price = getattr(obj, "time_price", None)
    if price is not None:
        trial = _angles(choice)
        now = price.value(trial)
        for k, a in enumerate(opts):
            trial[u] = np.atleast_1d(a)[0]
            out[k] += price.value(trial) - now
    feasibility = getattr(obj, "feasibility", None)
    if feasibility is not None:  # only the moved unit's rules and the days can break
        trial = _angles(choice)
        for k, a in enumerate(opts):
            trial[u] = np.atleast_1d(a)[0]
            if not (feasibility.unit_ok(u, trial[u]) and feasibility.days_ok(trial)):
                out[k] = np.inf
    return out


def pair_change_cost_delta(obj, choice, u, opts):
    """The change of what the changes cost (K, K) of moving units u and u + 1."""
    out = np.zeros((len(opts), len(opts)))
    v = u + 1
    if obj.change_cost:
        before = angle_changes(choice[max(u - 1, 0) : v + 2])
        trial = np.array(choice, dtype=float)
        for i, a in enumerate(opts):
            for j, b in enumerate(opts):
                trial[u], trial[v] = a, b
                out[i, j] = angle_changes(trial[max(u - 1, 0) : v + 2]) - before
        out *= obj.change_cost
    price = getattr(obj, "time_price", None)
    if price is not None:
        trial = _angles(choice)
        now = price.value(trial)
        for i, a in enumerate(opts):
            for j, b in enumerate(opts):
                trial[u], trial[v] = np.atleast_1d(a)[0], np.atleast_1d(b)[0]
                out[i, j] += price.value(trial) - now
    feasibility = getattr(obj, "feasibility", None)
    if feasibility is not None:  # only the moved units' rules and the days can break
        trial = _angles(choice)
        for i, a in enumerate(opts):
            for j, b in enumerate(opts):
                trial[u], trial[v] = np.atleast_1d(a)[0], np.atleast_1d(b)[0]
                if not (
                    feasibility.unit_ok(u, trial[u])
                    and feasibility.unit_ok(v, trial[v])
                    and feasibility.days_ok(trial)
                ):
                    out[i, j] = np.inf
    return out


def _angles(choice):
    """The angles [deg] (U,) of angles (U,) or (angle, step) rows (U, 2), as a new array."""
    choice = np.array(choice, dtype=float)
    return choice if choice.ndim == 1 else choice[:, 0].copy()
