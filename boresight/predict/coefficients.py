"""The coefficients of every term of the spurious polarisation, for a focal plane's pairs and the
rotation repeats, and their expectation over per-pair draws of {mean, rms} parameters.

A sample's pair difference departs from the ideal Re[P* e^{2 i phi}] by terms whose least-squares
maps are c h_n F: each coefficient c is a mean over (repeat, pair) of the pair's parameters times
e^{i n (alpha + a)} (the package docstring and docs/conventions.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..constants import DEG
from ..instrument.pairs import BEAM_KEYS, LIMITS, UNITS, Instrument, Spread, Systematics
from .terms import MOMENT_ORDER, deprojected_by

if TYPE_CHECKING:
    from collections.abc import Sequence

    from ..instrument.pairs import Systematics


M4_TOLERANCE = 1e-9  #: ``|m_4|`` below which the map-maker's h_4 coupling vanishes


@dataclass(frozen=True)
class Coefficients:
    """The coefficients of every term of the spurious polarisation (module docstring).

    Parameters
    ----------
    t2, s2, g1, g3, p0, p4 : complex
        Of h_2 T, h_2 S, h_1 G [rad], h_3 G* [rad], P and h_4 P*.
    m4 : complex
        The map-maker's <e^{4i(alpha + a)}> over (repeat, pair).
    jitter_var : float
        ``<sigma^2>`` of the gain jitter over pairs.
    n_samples : int
        Samples per crossing: repeats x pairs.
    """

    t2: complex
    s2: complex
    g1: complex
    g3: complex
    p0: complex
    p4: complex
    m4: complex
    jitter_var: float
    n_samples: int


def coefficients(
    systematics: Systematics,
    instrument: Instrument | None = None,
    rotations_deg: Sequence[float] = (0.0,),
) -> Coefficients:
    """The coefficients of the spurious polarisation of an instrument's systematics.

    Parameters
    ----------
    systematics : boresight.instrument.pairs.Systematics
    instrument : boresight.instrument.pairs.Instrument, optional
        Default: the paper's pairs at (0, 45) deg.
    rotations_deg : sequence of float
        The boresight rotation of each repeat [deg]; (0,) for a scan whose h_n already include
        its rotations (a real schedule).

    Returns
    -------
    Coefficients
    """
    instrument, alpha, par = drawn_pairs(systematics, instrument, rotations_deg)
    terms = pair_terms(par, instrument.pair_angles_rad, alpha, systematics.per_repeat(alpha.size))
    return Coefficients(
        **{name: complex(np.mean(f)) for name, f in terms.items()},
        jitter_var=float(np.mean(par.dg_jitter**2)),
        n_samples=int(alpha.size * instrument.n_pairs),
    )


def drawn_pairs(systematics, instrument, rotations_deg):
    """(instrument, rotations [rad], the pairs' parameters): the paper's pairs by default."""
    instrument = Instrument() if instrument is None else instrument
    alpha = np.asarray(rotations_deg, dtype=np.float64) * DEG
    return instrument, alpha, systematics.per_pair(instrument.n_pairs)


def pair_terms(par, pair_angles, alpha, dg_repeat):
    """Each coefficient's share from every pair: its mean over the repeats, (n_pairs,) complex
    (a coefficient is the mean of these over the pairs)."""
    ang = alpha[:, None] + pair_angles[None, :]
    dg = par.dg[None, :] + dg_repeat[:, None]
    off = par.pol_angle[None, :]
    half = 0.5 * par.nonortho[None, :]
    gamma = 0.5 * (np.exp(2j * (off - half)) + (1 - dg) * np.exp(2j * (off + half))) - 1
    e2 = np.exp(2j * ang)
    terms = dict(
        t2=dg * e2,
        s2=par.leak * e2,
        g1=-0.5 * par.rho * np.exp(1j * (ang - par.chi)),
        g3=-0.5 * par.rho * np.exp(1j * (3 * ang + par.chi)),
        p0=np.conj(gamma),
        p4=gamma * e2**2,
        m4=e2**2,
    )
    return {name: np.mean(f, axis=0) for name, f in terms.items()}


QUADRATURE_NODES = 3  #: Gauss-Hermite nodes per drawn parameter (exact for powers of linear terms)


def deprojected(coefs: Coefficients, templates) -> Coefficients:
    """``coefs`` with the terms a pipeline deprojecting ``templates`` takes out set to 0
    (:func:`boresight.predict.terms.deprojected_by`: a gain template takes h_2 T and h_2 S, the
    pointing templates h_1 G and h_3 G*; the leaks of P stay).

    Parameters
    ----------
    coefs : Coefficients
    templates : tuple of str
        :class:`boresight.mitigation.Deprojection`'s ``templates``.

    Returns
    -------
    Coefficients
    """
    return replace(coefs, **dict.fromkeys(deprojected_by(templates), 0.0))


class ExpectedPower(NamedTuple):
    """The power of each coefficient averaged over the per-pair draws of {mean, rms} parameters:
    E``|c|^2`` of t2, s2, g1, g3, p4, and of the h_0 term E Re p0, E Im p0, E (Re p0)^2,
    E (Im p0)^2, E Re p0 Im p0; t2_mean, E t2, gives the cross term with the beams' h_2 fields
    (:func:`leak_terms`)."""

    t2_mean: complex
    t2: float
    s2: float
    g1: float
    g3: float
    p4: float
    re_p0: float
    im_p0: float
    re_p0_2: float
    im_p0_2: float
    re_im_p0: float


def jitter_variance(systematics: Systematics, coefs: Coefficients, expected: bool) -> float:
    """<sigma^2> of the gain jitter over the focal plane.

    Parameters
    ----------
    systematics : boresight.instrument.pairs.Systematics
    coefs : Coefficients
        Of the drawn pairs.
    expected : bool
        The expectation over the draws of a {mean, rms} jitter, mean^2 + rms^2, rather than the
        drawn pairs' mean of sigma^2.

    Returns
    -------
    float
    """

    jitter = systematics.dg_jitter
    if expected and isinstance(jitter, Spread):
        return jitter.mean**2 + jitter.rms**2
    return coefs.jitter_var


def expected_coefficients(coefs: Coefficients, power: ExpectedPower) -> Coefficients:
    """Coefficients whose ``|c|^2`` are the expected powers (their phases are dropped): what the
    spectra of the terms c h_n F need, which see ``|c|^2`` only.

    Parameters
    ----------
    coefs : Coefficients
    power : ExpectedPower

    Returns
    -------
    Coefficients
    """
    return replace(coefs, **{k: np.sqrt(getattr(power, k)) for k in MOMENT_NAMES if k != "p0"})


def expected_power(
    systematics: Systematics,
    instrument: Instrument | None = None,
    rotations_deg: Sequence[float] = (0.0,),
) -> ExpectedPower:
    """What a focal plane's coefficients give on average over its pairs' random draws.

    A coefficient c is the mean over N pairs of independent shares F_m, so
    E``|c|^2`` = ``|E c|^2`` (coherent: the means of the parameters) + sum_m Var(F_m) / N^2
    (incoherent: rms^2 / N for a linear term). E F_m and E``|F_m|^2`` are Gauss-Hermite sums over
    the pair's drawn parameters (:data:`QUADRATURE_NODES` per parameter).

    Parameters
    ----------
    systematics : boresight.instrument.pairs.Systematics
        With numbers for the beams and ``dg_repeat`` (the filters of :func:`beam_filters` and the
        drift are taken as given).
    instrument : boresight.instrument.pairs.Instrument, optional
    rotations_deg : sequence of float

    Returns
    -------
    ExpectedPower
    """

    terms, weight, n = _node_terms(systematics, instrument, rotations_deg)

    def moments(f):
        f = f.reshape(n, -1)
        return f @ weight, (f.real**2) @ weight, (f.imag**2) @ weight, (f.real * f.imag) @ weight

    out, means = {}, {}
    for name in MOMENT_NAMES:
        mean, re2, im2, reim = moments(terms[name])
        means[name] = complex(np.mean(mean))
        re, im = np.mean(mean.real), np.mean(mean.imag)
        out[name] = (
            abs(np.mean(mean)) ** 2 + np.sum(re2 + im2 - np.abs(mean) ** 2) / n**2,
            re**2 + np.sum(re2 - mean.real**2) / n**2,
            im**2 + np.sum(im2 - mean.imag**2) / n**2,
            re * im + np.sum(reim - mean.real * mean.imag) / n**2,
        )
    p0 = out.pop("p0")
    return ExpectedPower(
        t2_mean=means["t2"],
        **{name: float(v[0]) for name, v in out.items()},
        re_p0=means["p0"].real,
        im_p0=means["p0"].imag,
        re_p0_2=float(p0[1]),
        im_p0_2=float(p0[2]),
        re_im_p0=float(p0[3]),
    )


def _node_terms(systematics, instrument, rotations_deg):
    """Each coefficient's share from every pair at the Gauss-Hermite nodes of its drawn
    parameters: (terms, node weights (n_nodes,), n_pairs); terms[name] is (n_pairs x n_nodes,)."""
    shared = ("dg_repeat",) + BEAM_KEYS["a"] + BEAM_KEYS["b"]
    if any(isinstance(getattr(systematics, k), Spread) for k in shared):
        raise ValueError(
            "the expected focal-plane power covers per-pair gain, pointing, leak and angle "
            "errors: give the beams and dg_repeat as numbers"
        )
    instrument, alpha, par = drawn_pairs(systematics, instrument, rotations_deg)
    n = instrument.n_pairs
    drawn = [
        name
        for name in LIMITS
        if isinstance(getattr(systematics, name), Spread) and getattr(systematics, name).rms > 0
    ]
    z, w = np.polynomial.hermite_e.hermegauss(QUADRATURE_NODES)
    grids = np.meshgrid(*([z] * len(drawn)), indexing="ij")
    nodes = np.stack([g.ravel() for g in grids], axis=1) if drawn else np.zeros((1, 0))
    weight = np.prod(np.meshgrid(*([w] * len(drawn)), indexing="ij"), axis=0).ravel()
    weight = np.atleast_1d(weight) / np.sum(weight)
    values = {}
    for name, column in zip(par._fields, par):
        values[name] = np.repeat(column, nodes.shape[0])
    for j, name in enumerate(drawn):
        spread = getattr(systematics, name)
        field = par._fields[list(LIMITS).index(name)]
        values[field] = np.tile((spread.mean + spread.rms * nodes[:, j]) * UNITS[name], n)
    virtual = type(par)(**values)
    terms = pair_terms(
        virtual,
        np.repeat(instrument.pair_angles_rad, nodes.shape[0]),
        alpha,
        systematics.per_repeat(alpha.size),
    )

    return terms, weight, n


MOMENT_NAMES = MOMENT_ORDER  #: the coefficients of coefficient_moments, in its order


def coefficient_moments(
    systematics: Systematics,
    instrument: Instrument | None = None,
    rotations_deg: Sequence[float] = (0.0,),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mean and second moments of the coefficients over the pairs' random draws.

    With c the mean over N independent pairs of their shares F_m, E[c c^H] = E c (E c)^H
    + sum_m Cov(F_m) / N^2, and the same for E[c c^T]; what a leak's exact expectation, bilinear
    in the coefficients, needs (:func:`boresight.predict.expected_leak`). Numbers enter as
    themselves (no variance).

    Parameters
    ----------
    systematics, instrument, rotations_deg
        As :func:`expected_power`.

    Returns
    -------
    mean : numpy.ndarray, complex128, shape (6,)
        E c of :data:`MOMENT_NAMES`.
    second, pseudo : numpy.ndarray, complex128, shape (6, 6)
        E[c c^H] and E[c c^T].
    """
    terms, weight, n = _node_terms(systematics, instrument, rotations_deg)
    shares = np.stack([terms[name].reshape(n, -1) for name in MOMENT_NAMES])  # (6, n, nodes)
    mean_m = shares @ weight  # (6, n): each pair's E F_m
    mean = mean_m.mean(axis=1)
    outer = np.einsum("imq,jmq,q->ij", shares, np.conj(shares), weight)
    plain = np.einsum("imq,jmq,q->ij", shares, shares, weight)
    second = np.outer(mean, np.conj(mean)) + (outer - mean_m @ np.conj(mean_m).T) / n**2
    pseudo = np.outer(mean, mean) + (plain - mean_m @ mean_m.T) / n**2
    return mean, second, pseudo


def supports(instrument: Instrument | None, rotations_deg: Sequence[float] = (0.0,)) -> bool:
    """Whether the C_ell-level prediction covers an instrument and repeats: m_4 = 0.

    Parameters
    ----------
    instrument : boresight.instrument.pairs.Instrument or None
        None stands for the paper's pairs.
    rotations_deg : sequence of float

    Returns
    -------
    bool
    """

    return abs(coefficients(Systematics(), instrument, rotations_deg).m4) < M4_TOLERANCE


def check_supported(coefs):
    if abs(coefs.m4) >= M4_TOLERANCE:
        raise ValueError(
            "the C_ell-level prediction needs pair angles whose 4 x angles cancel over the pairs "
            f"and repeats (m_4 = {coefs.m4:.3g}); use the map-level delta_p"
        )


def rotation_suppression(n: int, rotations_deg: Sequence[float]) -> float:
    """``|h_n|^2`` after / before repeating every hit at each angle alpha_k:
    ``|<exp(i n alpha_k)>|^2``.

    For the schedule (0, alpha) this is cos^2(n alpha / 2).

    Parameters
    ----------
    n : int
    rotations_deg : sequence of float

    Returns
    -------
    float
    """
    alpha = np.radians(np.asarray(rotations_deg, dtype=np.float64))
    return float(np.abs(np.mean(np.exp(1j * n * alpha))) ** 2)
