"""Choosing the boresight-rotation schedule against a systematics budget and the survey's noise.

The paper's design rule is to rotate so that the spin moments that couple to the systematics
vanish. A schedule's CESs are grouped into units, each given one boresight angle, and the h_n of
any assignment are the units' spin sums turned by their angles (:mod:`boresight.moments.units`,
which derives it). The design objective, the exact expected delta_r of these h_n maps, and its
search are in :mod:`boresight.design.exact`. Here is also the paper's slowly-varying-h_n
approximation of it, which ``boresight design`` reports beside: linear in the survey means
``<|h_n|^2>`` and their coherent parts,

    delta_r = const + sum_n (alpha_n ``<|h_n|^2>`` + beta_n coh_n),

with alpha_n, beta_n and const computed once from the budget (:class:`Objective`). It misses the
power that a real schedule's striped h_n carry across scales: 0.42 against a simulated 0.65 for
the stepped strategy of the deep example (``bench/results/design_validation.json``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from .. import coupling, predict, validation
from .._util import interrupts
from ..constants import N_MAX
from ..evaluation import METHODS
from ..instrument.pairs import LIMITS, Instrument, Spread, Systematics
from ..moments.units import GROUPS, UnitMoments
from ..predict.terms import deprojected_by
from ..validation import option

if TYPE_CHECKING:
    from ..cosmology import Spectra
    from ..instrument.pairs import Systematics

#: BICEP2/Keck's four deck angles [deg]
KECK_DECKS = (68.0, 113.0, 248.0, 293.0)


@dataclass(frozen=True)
class DesignOptions:
    """The ``[design]`` table: what the optimiser may choose and how it searches.

    Parameters
    ----------
    angles_deg : tuple of float
        The allowed boresight angles [deg], for example a mount's fixed positions.
    group : {"ces", "day", "pass"}
        One angle per CES, per UTC day of the CES start, or per TOAST pass (scan_index).
    change_cost : float
        Added to delta_r for each change of angle between consecutive units (time order).
    sweeps : int
        Most passes of coordinate descent over the units, per start.
    restarts : int
        Random starts besides the best baseline; the best end point is kept.
    seed : int
        Order of the units in each pass, the random starts and the random baseline.
    nside : int
        Resolution of the h_n maps and the prediction.
    validation_skies : int
        Sky realisations of the TOD check of every strategy.
    evaluation : {"interp", "exact"}
        How the TOD check reads the sky at each sample (the engine's ``evaluation``), and so
        how the prediction reads it: bilinear interpolation of the maps (fast), or the
        band-limited sky itself, as a telescope sees it.

    The beam of the sky the systematics act on is the instrument's, ``[noise] fwhm_arcmin``.
    """

    angles_deg: tuple = option(
        (-90.0, -45.0, 0.0, 45.0, 90.0), "allowed boresight angles [deg]", (list,)
    )
    group: str = option("ces", "one angle per: ces, day or pass", (str,), GROUPS)
    change_cost: float = option(0.0, "delta_r added per change of angle", (int, float))
    sweeps: int = option(8, "most coordinate-descent passes per start", (int,))
    restarts: int = option(4, "random starts besides the best baseline", (int,))
    seed: int = option(0, "seed of the unit order and the random baseline", (int,))
    nside: int = option(128, "resolution of the h_n maps", (int,))
    validation_skies: int = option(4, "sky realisations of the TOD check", (int,))
    evaluation: str = option("interp", "the sky at each sample: interp or exact", (str,), METHODS)

    def __post_init__(self):
        angles = validation.numbers_array("design.angles_deg", self.angles_deg, -3600.0, 3600.0)
        if angles.ndim != 1 or angles.size == 0:
            raise ValueError("angles_deg must list at least one allowed angle")
        if angles.size > MAX_ANGLES:  # the search's work grows with them, unestimated
            raise ValueError(
                f"angles_deg lists {angles.size} angles; at most {MAX_ANGLES} (one every half "
                "degree of a turn)"
            )
        object.__setattr__(self, "angles_deg", tuple(float(a) for a in angles))
        if self.group not in GROUPS:
            raise ValueError(f"group must be one of {GROUPS}, got {self.group!r}")
        validation.number("change_cost", self.change_cost, 0.0, 1e6)
        validation.integer("sweeps", self.sweeps, 1, 1000)
        validation.integer("restarts", self.restarts, 0, 1000)
        validation.integer("validation_skies", self.validation_skies, 1, 1000)
        if self.evaluation not in METHODS:
            raise ValueError(f"evaluation must be one of {METHODS}, got {self.evaluation!r}")
        validation.integer("seed", self.seed, 0)
        validation.integer("nside", self.nside, 16, 2048)
        if self.nside & (self.nside - 1):
            raise ValueError(f"nside must be a power of two, got {self.nside}")


#: the most allowed angles a design takes: its search tries each one for each unit, every sweep
MAX_ANGLES = 720


@dataclass
class Objective:
    """Predicted delta_r of an angle assignment: const + sum_n alpha_n ``<|h_n|^2>`` + beta_n coh_n.

    Parameters
    ----------
    moments : boresight.moments.UnitMoments
    alpha, beta : numpy.ndarray, shape (N_MAX + 1,)
        Coefficients of the mean ``|h_n|^2`` and of its coherent part (index n).
    const : float
        The angle-independent part that is not leaked power (the gain's common rescaling of the
        signal).
    template : numpy.ndarray
        Pseudo-C_BB of tensors at r = 1 over the observed pixels.
    coupling : boresight.coupling.Coupling
    leaked_const : float
        The angle-independent part's delta_r: a beam ellipticity's h_0 term, its leaked power
        plus its first-order cross term with the sky's E (through TE and the mask's E-to-B
        leakage; it can be negative), and the gain jitter's white leaked power.
    """

    moments: UnitMoments
    alpha: np.ndarray
    beta: np.ndarray
    const: float
    template: np.ndarray
    coupling: object
    leaked_const: float = 0.0
    parent: np.ndarray = field(init=False)
    block_weight: np.ndarray = field(init=False)

    def __post_init__(self):
        m = self.moments
        nest = hp.ring2nest(m.nside, m.pixels) // (predict.COHERENT_BLOCK**2)
        blocks, self.parent = np.unique(nest, return_inverse=True)
        self.block_weight = np.bincount(self.parent, minlength=blocks.size).astype(float)
        if m.nside < predict.COHERENT_BLOCK:  # as PixelBlocks: every pixel is its own block
            self.parent = np.arange(m.pixels.size)
            self.block_weight = np.ones(m.pixels.size)

    @property
    def terms(self):
        """The moments n with a non-zero coefficient."""
        return [n for n in range(1, N_MAX + 1) if self.alpha[n] or self.beta[n]]

    def powers(self, h: np.ndarray) -> dict:
        """``<|h_n|^2>`` and its coherent part of each n, from observed-pixel h_n."""
        out = {}
        n_obs = self.moments.pixels.size
        for n in range(1, N_MAX + 1):
            b = np.bincount(self.parent, h[n].real) + 1j * np.bincount(self.parent, h[n].imag)
            out[n] = (
                float(np.sum(np.abs(h[n]) ** 2) / n_obs),
                float(np.sum(np.abs(b) ** 2 / self.block_weight) / n_obs),
            )
        return out

    def delta_r(self, angles_deg: np.ndarray) -> float:
        """Predicted delta_r, without the change cost."""
        return self.delta_r_of(self.moments.h(angles_deg))

    def delta_r_of(self, h: np.ndarray) -> float:
        """Predicted delta_r of observed-pixel h_n (:meth:`boresight.moments.UnitMoments.h`)."""
        powers = self.powers(h)
        return (
            self.const
            + self.leaked_const
            + sum(self.alpha[n] * powers[n][0] + self.beta[n] * powers[n][1] for n in self.terms)
        )


def objective(
    moments: UnitMoments,
    systematics: Systematics,
    theory: Spectra,
    fwhm_arcmin: float,
    *,
    nthreads: int = 0,
    instrument: Instrument | None = None,
    deprojected: tuple = (),
) -> Objective:
    """The predicted-delta_r objective of a budget over a schedule's observed pixels.

    The coefficients follow :func:`boresight.predict.residual_pseudo_bb` term by term: each term
    c h_n F adds 0.5 ``|c|^2`` [coh_n C^FF + (``<|h_n|^2>`` - coh_n) Omega_pix sigma_F^2] to the
    full-sky spurious spectrum, which the mask's coupling turns into pseudo-C_BB and
    :func:`boresight.predict.delta_r` into a bias on r. Parameters given as {mean, rms} enter by
    their expectation over the focal plane's draws (:func:`boresight.predict.expected_power`,
    coherent part plus rms^2 / N_pairs); beams by their filters
    (:func:`boresight.predict.beam_filters`), whose h_0 term no rotation changes.

    Parameters
    ----------
    moments : boresight.moments.UnitMoments
    systematics : boresight.instrument.pairs.Systematics
    theory : boresight.cosmology.Spectra
    fwhm_arcmin : float
    nthreads : int
    instrument : boresight.instrument.pairs.Instrument, optional
        The focal plane (default: the paper's Q/U pairs).
    deprojected : tuple of str
        Template sets the pipeline deprojects: the leaks of T they fit are out
        (:func:`boresight.predict.deprojected`).

    Returns
    -------
    Objective
    """
    nside = moments.nside
    lmax = 2 * nside
    couplings = coupling.mask_coupling(moments.mask, lmax, nthreads)
    template = predict.tensor_template(couplings, theory, fwhm_arcmin, nside)

    def bias(cl_e, cl_b):
        cl = np.array([cl_e, cl_b], dtype=float)
        cl[:, :2] = 0.0
        return predict.delta_r(couplings.pseudo_bb(cl[1], cl[0]), template)

    cl_tt, cl_ee, cl_bb = predict.field_spectra(theory, lmax, fwhm_arcmin)
    ell = np.arange(lmax + 1)
    omega_pix = 4 * np.pi / (12 * nside**2)
    white_unit = bias(np.ones(lmax + 1), np.ones(lmax + 1))
    alpha, beta = np.zeros(N_MAX + 1), np.zeros(N_MAX + 1)
    coefs = predict.coefficients(systematics, instrument)
    power = t2_mean = beam = None
    if drawn(systematics):
        power = predict.expected_power(systematics, instrument)
        coefs, t2_mean = predict.expected_coefficients(coefs, power), power.t2_mean
    coefs = predict.deprojected(coefs, deprojected)
    if "t2" in deprojected_by(deprojected):  # its mean goes with its power
        t2_mean = None if t2_mean is None else 0.0
    leaked_const = 0.0
    beam_cl = predict.beam_spectra(theory, lmax, fwhm_arcmin)
    if systematics.has_beams:
        beam = predict.beam_filters(systematics, instrument, (0.0,), fwhm_arcmin, lmax, n_max=N_MAX)
        h0 = predict.beam_h0_bb(couplings, beam[0], beam_cl)
        leaked_const = predict.delta_r(h0, template)
    terms = predict.leak_terms(
        coefs, systematics, cl_tt, cl_ee + cl_bb, beam=beam, beam_cl=beam_cl, t2_mean=t2_mean
    )
    for n, c, cl_e, cl_b, _ in terms:
        n = abs(n)
        weight = 0.5 * abs(c) ** 2
        variance = np.sum((2 * ell + 1) / (4 * np.pi) * (cl_e + cl_b)) / 2
        white = omega_pix * variance * white_unit
        alpha[n] += weight * white
        beta[n] += weight * (bias(cl_e, cl_b) - white)
    signal = predict.signal_bb(couplings, coefs, cl_ee, cl_bb, expected=power)
    const = predict.delta_r(signal, template)
    jitter_var = predict.jitter_variance(systematics, coefs, expected=power is not None)
    if jitter_var > 0:  # leaked white power, whatever the angles: <sigma^2> T^2 / N per pixel
        variance_t = np.sum((2 * ell + 1) / (4 * np.pi) * cl_tt)
        inverse_samples = np.mean(1.0 / (moments.hits * coefs.n_samples))
        leaked_const += 0.5 * omega_pix * jitter_var * variance_t * inverse_samples * white_unit
    return Objective(moments, alpha, beta, float(const), template, couplings, float(leaked_const))


def drawn(systematics: Systematics) -> bool:
    """Whether a budget gives any parameter as {mean, rms} with rms > 0.

    Parameters
    ----------
    systematics : boresight.instrument.pairs.Systematics

    Returns
    -------
    bool
    """

    return any(
        isinstance(v, Spread) and v.rms > 0 for v in (getattr(systematics, k) for k in LIMITS)
    )


@dataclass
class Design:
    """The optimiser's result.

    Parameters
    ----------
    angles_deg : numpy.ndarray, shape (n_units,)
        The best assignment found.
    value : float
        Its objective.
    history : list of dict
        sweep, objective, moves (accepted in that sweep), after each sweep; sweep 0 is the start.
    interrupted : boresight._util.interrupts.Interrupted, optional
        What stopped the search (Ctrl-C or SIGTERM); ``angles_deg`` is then the best found until
        then (:func:`boresight.design.exact.search`).
    steps_deg : numpy.ndarray, shape (n_units,), optional
        A stepped HWP's angle per unit, where the search chose them too.
    """

    angles_deg: np.ndarray
    value: float
    history: list
    interrupted: interrupts.Interrupted | None = None
    steps_deg: np.ndarray | None = None


def baselines(n_units: int, allowed_deg: tuple, seed: int = 0) -> dict[str, np.ndarray]:
    """The strategies a design must beat, one angle per unit in time order.

    Parameters
    ----------
    n_units : int
    allowed_deg : tuple of float
        The mount's allowed angles: the stepped and random baselines draw from them.
    seed : int

    Returns
    -------
    dict of str -> numpy.ndarray
        no rotation; the paper's 0/90 and 0/180 repeats (alternate units); BICEP2/Keck's four
        deck angles in turn; the allowed angles stepped in turn; random allowed angles.
    """
    u = np.arange(n_units)
    allowed = np.asarray(allowed_deg, dtype=float)
    return {
        "none": np.zeros(n_units),
        "paper 0/90": np.where(u % 2 == 0, 0.0, 90.0),
        "paper 0/180": np.where(u % 2 == 0, 0.0, 180.0),
        "keck 4 decks": np.asarray(KECK_DECKS)[u % 4],
        "stepped": allowed[u % allowed.size],
        "random": np.random.default_rng(seed).choice(allowed, n_units),
    }
