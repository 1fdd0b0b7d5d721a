"""Detector pairs, their focal plane and their differential systematics.

Pair i has detector A at polarisation angle psi + angle_i and detector B at psi + angle_i + 90 deg,
where psi is the crossing angle of the hit. Systematics, per pair:

* differential gain ``dg``: detector B's signal is scaled by (1 - dg);
* differential pointing ``rho_arcmin``, ``chi_deg``: detector B looks at
  theta + rho cos(beta), phi + rho sin(beta) / sin(theta) with beta = psi + angle_i + chi, i.e. the
  offset is fixed in the focal plane and chi is measured from the pair's own polarisation axis
  (the convention behind the paper's eq. 6, see docs/conventions.md);
* additive leak ``leak`` (bandpass mismatch or any crossing-angle-independent term): detector A sees
  +leak/2 and detector B -leak/2 times a template map (default: the sky's I), so the pair
  difference gains leak/2 * template, like a gain error with its own template;
* polarisation-angle errors ``pol_angle_deg`` (delta) and ``nonortho_deg`` (epsilon): detector A
  is really at angle_i + delta - epsilon/2 and B at angle_i + 90 deg + delta + epsilon/2, while the
  map-maker assumes angle_i and angle_i + 90 deg;
* gain jitter ``dg_jitter``: every sample's differential gain gets a white normal deviate of this
  rms, drawn from the counter-based generator (:mod:`boresight.rng`);
* beams ``dfwhm_a_arcmin``, ``dfwhm_b_arcmin``, ``ellipticity_a``, ``ellipticity_b``,
  ``ellipticity_angle_a_deg``, ``ellipticity_angle_b_deg``: each detector's elliptical Gaussian
  beam, relative to the sky's (:mod:`boresight.instrument.beams`);

and per rotation repeat k, gain drift ``dg_repeat``: detector B of every pair is scaled by
(1 - dg - dg_repeat[k]) during repeat k.

Any per-pair parameter may be a table ``{mean, rms}`` instead of numbers: each pair then draws its
value from a normal distribution keyed by (``seed``, pair index), so a focal plane of many pairs
has scattered systematics that do not depend on how it is simulated. ``dg_repeat`` may be such a
table too, drawn per repeat.
"""

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .. import validation
from .._util.jit import njit
from ..constants import ARCMIN, DEG
from ..kernels import rng
from ..validation import option
from . import added as added_systematics

MAX_ANGLE_DEG = 3600.0  #: angles beyond ten turns are input mistakes
#: ellipticity (sigma_maj - sigma_min) / (sigma_maj + sigma_min) at most: axes 39:1
MAX_ELLIPTICITY = 0.95
#: allowed range of each per-pair systematic parameter: detector B's gain 1 - dg stays in [0, 2];
#: pointing offsets up to 10 deg (far beyond any pair, still handled exactly by the engine);
#: angle errors up to a quarter (common) and an eighth (non-orthogonality) of a turn
LIMITS = {
    "dg": (-1.0, 1.0),
    "rho_arcmin": (0.0, 600.0),
    "chi_deg": (-MAX_ANGLE_DEG, MAX_ANGLE_DEG),
    "leak": (-1.0, 1.0),
    "pol_angle_deg": (-90.0, 90.0),
    "nonortho_deg": (-45.0, 45.0),
    "dg_jitter": (0.0, 1.0),
    "dfwhm_a_arcmin": (-600.0, 600.0),
    "dfwhm_b_arcmin": (-600.0, 600.0),
    "ellipticity_a": (0.0, MAX_ELLIPTICITY),
    "ellipticity_b": (0.0, MAX_ELLIPTICITY),
    "ellipticity_angle_a_deg": (-MAX_ANGLE_DEG, MAX_ANGLE_DEG),
    "ellipticity_angle_b_deg": (-MAX_ANGLE_DEG, MAX_ANGLE_DEG),
}
#: the unit that turns each per-pair parameter into the engine's (radians for angles)
UNITS = {
    "dg": 1.0,
    "rho_arcmin": ARCMIN,
    "chi_deg": DEG,
    "leak": 1.0,
    "pol_angle_deg": DEG,
    "nonortho_deg": DEG,
    "dg_jitter": 1.0,
    "dfwhm_a_arcmin": ARCMIN,
    "dfwhm_b_arcmin": ARCMIN,
    "ellipticity_a": 1.0,
    "ellipticity_b": 1.0,
    "ellipticity_angle_a_deg": DEG,
    "ellipticity_angle_b_deg": DEG,
}
#: the per-pair parameters that set an amplitude (the others, chi_deg and the ellipticities'
#: angles, only orient one)
AMPLITUDES = tuple(
    k for k in LIMITS if k != "chi_deg" and "angle_a" not in k and "angle_b" not in k
)
#: the beam keys of each detector: FWHM change, ellipticity, major-axis angle
BEAM_KEYS = {
    "a": ("dfwhm_a_arcmin", "ellipticity_a", "ellipticity_angle_a_deg"),
    "b": ("dfwhm_b_arcmin", "ellipticity_b", "ellipticity_angle_b_deg"),
}
REPEAT_LIMITS = (-1.0, 1.0)  #: dg_repeat
#: focal-plane presets: the polarisation angle of pair i of n [deg]
PRESETS = {
    "uniform": lambda n: 90.0 * np.arange(n) / n,
    "0/45/90/135": lambda n: 45.0 * (np.arange(n) % 4),
}


@dataclass(frozen=True)
class Instrument:
    """The detector pairs: the ``[instrument]`` table.

    Parameters
    ----------
    pair_angles_deg : tuple of float, or str
        Polarisation angle of each pair's detector A [deg]; detector B is at +90 deg. The paper's
        Q and U pairs by default. Or a preset of ``n_pairs`` pairs: ``"uniform"`` puts pair i at
        90 i / n deg (the 2n detectors evenly over half a turn), ``"0/45/90/135"`` cycles
        through those four angles.
    n_pairs : int
        Number of pairs of a preset; with a list, 0 or the list's length.
    """

    pair_angles_deg: tuple = option(
        (0.0, 45.0),
        "polarisation angles of the pairs [deg], or a preset: " + ", ".join(PRESETS),
        (list, str),
    )
    n_pairs: int = option(0, "number of pairs of a preset (with a list: 0 or its length)")

    def __post_init__(self):
        n = validation.integer("n_pairs", self.n_pairs, 0, 1_000_000)
        angles = self.pair_angles_deg
        if isinstance(angles, str):
            if angles not in PRESETS:
                raise ValueError(
                    f"pair_angles_deg = {angles!r} is not a preset; allowed: {list(PRESETS)} "
                    "or a list of angles"
                )
            if n < 1:
                raise ValueError(f"n_pairs must be >= 1 for the preset {angles!r}")
            angles = PRESETS[angles](n)
        a = validation.numbers_array("pair_angles_deg", angles, -MAX_ANGLE_DEG, MAX_ANGLE_DEG)
        if a.ndim != 1 or a.size == 0:
            raise ValueError(
                f"pair_angles_deg must be a non-empty list, got {self.pair_angles_deg!r}"
            )
        if n not in (0, a.size):
            raise ValueError(f"n_pairs = {n} but pair_angles_deg lists {a.size} angles")
        object.__setattr__(self, "pair_angles_deg", tuple(float(x) for x in a))
        object.__setattr__(self, "n_pairs", int(a.size))

    @property
    def pair_angles_rad(self):
        return np.asarray(self.pair_angles_deg) * DEG


@dataclass(frozen=True)
class Spread:
    """A parameter drawn per pair (or per repeat): mean + rms x a normal deviate.

    Parameters
    ----------
    mean : float
    rms : float
        >= 0.
    """

    mean: float = 0.0
    rms: float = 0.0

    def __str__(self):
        return f"{{mean = {self.mean:g}, rms = {self.rms:g}}}"


class PairParameters(NamedTuple):
    """Every pair's systematics in engine units: arrays of shape (n_pairs,).

    dg, leak, dg_jitter and the ellipticities are fractions; rho, chi, pol_angle, nonortho, the
    FWHM changes and the ellipticities' angles are in rad.
    """

    dg: np.ndarray
    rho: np.ndarray
    chi: np.ndarray
    leak: np.ndarray
    pol_angle: np.ndarray
    nonortho: np.ndarray
    dg_jitter: np.ndarray
    dfwhm_a: np.ndarray
    dfwhm_b: np.ndarray
    ellipticity_a: np.ndarray
    ellipticity_b: np.ndarray
    ellipticity_angle_a: np.ndarray
    ellipticity_angle_b: np.ndarray

    def angle_errors(self) -> tuple[np.ndarray, np.ndarray]:
        """Detector A's and B's angle from the one assumed [rad]: pol_angle -+ nonortho / 2."""
        return self.pol_angle - 0.5 * self.nonortho, self.pol_angle + 0.5 * self.nonortho


#: the PairParameters field of each key, in engine units: the key less its unit
PARAMETER_OF = {name: name.removesuffix("_arcmin").removesuffix("_deg") for name in LIMITS}


def _spread_or_numbers(name, value, lo, hi):
    """A parameter as given (numbers) or as a :class:`Spread`, checked."""
    if isinstance(value, Spread):
        value = {"mean": value.mean, "rms": value.rms}
    if isinstance(value, dict):
        unknown = set(value) - {"mean", "rms"}
        if unknown or "mean" not in value:
            raise ValueError(
                f"{name} as a table needs mean and optionally rms, got keys {sorted(value)}"
            )
        mean = validation.number(f"{name}.mean", value["mean"], lo, hi)
        rms = validation.number(f"{name}.rms", value.get("rms", 0.0), 0.0, hi - lo)
        return Spread(mean, rms)
    validation.numbers_array(name, value, lo, hi)
    return value


def _values(name, value, n, seed, salt, index, what):
    """n values of a parameter: broadcast numbers, or draws of a Spread keyed by (seed, i)."""
    if isinstance(value, Spread):
        draws = [rng.normal_array(seed, i, salt, index + 1)[index] for i in range(n)]
        return value.mean + value.rms * np.asarray(draws, dtype=np.float64)
    v = np.asarray(value, dtype=np.float64)
    if v.ndim == 1 and v.size != n:
        raise ValueError(f"{name} has {v.size} entries but {what.format(n)}")
    return np.broadcast_to(v, (n,)).astype(np.float64)


def is_nonzero(value):
    if isinstance(value, Spread):
        return value.mean != 0 or value.rms != 0
    return bool(np.any(np.asarray(value) != 0))


_TABLE = (int, float, list, dict)


def _added(values):
    """Added systematics' amplitudes as sorted (key, value) pairs, each key registered and each
    value checked against its limits (:mod:`boresight.instrument.added`)."""
    pairs = values.items() if isinstance(values, dict) else values
    out = {}
    for key, value in pairs:
        if key not in added_systematics.REGISTRY:
            known = sorted(added_systematics.REGISTRY) or "none registered"
            raise ValueError(f"added systematic {key!r} is not registered; registered: {known}")
        lo, hi = added_systematics.REGISTRY[key].limits
        value = tuple(value) if isinstance(value, list) else value
        out[key] = _spread_or_numbers(key, value, lo, hi)
    return tuple(sorted(out.items()))


@dataclass(frozen=True)
class Systematics:
    """Per-pair differential systematics: the ``[systematics]`` table.

    A scalar applies to every pair, a tuple gives one value per pair, a table {mean, rms} draws one
    value per pair (keyed by ``seed``).

    Parameters
    ----------
    dg : float, tuple or Spread
        Differential gain: detector B's signal is scaled by (1 - dg), in [-1, 1].
    rho_arcmin : float, tuple or Spread
        Differential pointing [arcmin], in [0, 600].
    chi_deg : float, tuple or Spread
        Direction of the pointing offset from the pair's polarisation axis [deg].
    leak : float, tuple or Spread
        Additive leak: the pair difference gains leak / 2 times a template, in [-1, 1].
    pol_angle_deg : float, tuple or Spread
        Common polarisation-angle error delta of the pair [deg], in [-90, 90].
    nonortho_deg : float, tuple or Spread
        Non-orthogonality epsilon: B is at 90 + epsilon deg from A [deg], in [-45, 45].
    dg_jitter : float, tuple or Spread
        Rms of the white per-sample differential-gain jitter, in [0, 1].
    dfwhm_a_arcmin, dfwhm_b_arcmin : float, tuple or Spread
        Detector A's and B's beam FWHM less the sky's [arcmin] (:mod:`boresight.instrument.beams`).
    ellipticity_a, ellipticity_b : float, tuple or Spread
        Their beams' ellipticity (sigma_maj - sigma_min) / (sigma_maj + sigma_min), in [0, 0.95].
    ellipticity_angle_a_deg, ellipticity_angle_b_deg : float, tuple or Spread
        Direction of each major axis from the detector's polarisation axis [deg].
    dg_repeat : float, tuple or Spread
        Gain drift: added to every pair's dg during each rotation repeat (one per repeat).
    seed : int
        Key of the per-pair (and per-repeat) draws of {mean, rms} parameters.
    added : dict or tuple of (key, value)
        The amplitudes of added systematics (:mod:`boresight.instrument.added`), each a number,
        one per pair or {mean, rms} like the keys above; in a study's ``[systematics]`` table
        their keys stand beside the built-in ones. Held as (key, value) pairs sorted by key.
    """

    dg: object = option(0.0, "differential gain, a number, one per pair or {mean, rms}", _TABLE)
    rho_arcmin: object = option(
        0.0, "differential pointing [arcmin], >= 0, a number, one per pair or {mean, rms}", _TABLE
    )
    chi_deg: object = option(
        0.0, "pointing offset direction [deg], a number, one per pair or {mean, rms}", _TABLE
    )
    leak: object = option(0.0, "additive leak, a number, one per pair or {mean, rms}", _TABLE)
    pol_angle_deg: object = option(
        0.0, "common polarisation-angle error [deg], per pair or {mean, rms}", _TABLE
    )
    nonortho_deg: object = option(
        0.0, "non-orthogonality of A and B [deg], per pair or {mean, rms}", _TABLE
    )
    dg_jitter: object = option(
        0.0, "rms of the per-sample gain jitter, per pair or {mean, rms}", _TABLE
    )
    dfwhm_a_arcmin: object = option(
        0.0, "detector A's beam FWHM less the sky's [arcmin], per pair or {mean, rms}", _TABLE
    )
    dfwhm_b_arcmin: object = option(
        0.0, "detector B's beam FWHM less the sky's [arcmin], per pair or {mean, rms}", _TABLE
    )
    ellipticity_a: object = option(
        0.0, "detector A's beam ellipticity in [0, 0.95], per pair or {mean, rms}", _TABLE
    )
    ellipticity_b: object = option(
        0.0, "detector B's beam ellipticity in [0, 0.95], per pair or {mean, rms}", _TABLE
    )
    ellipticity_angle_a_deg: object = option(
        0.0, "A's beam major axis from its polarisation axis [deg], per pair or {mean, rms}", _TABLE
    )
    ellipticity_angle_b_deg: object = option(
        0.0, "B's beam major axis from its polarisation axis [deg], per pair or {mean, rms}", _TABLE
    )
    dg_repeat: object = option(
        0.0, "gain drift: dg added during each rotation repeat, one per repeat", _TABLE
    )
    seed: int = option(0, "seed of the per-pair draws of {mean, rms} parameters")
    added: tuple = field(default=())

    def __post_init__(self):
        for name, (lo, hi) in LIMITS.items():
            object.__setattr__(self, name, _spread_or_numbers(name, getattr(self, name), lo, hi))
        object.__setattr__(
            self, "dg_repeat", _spread_or_numbers("dg_repeat", self.dg_repeat, *REPEAT_LIMITS)
        )
        validation.integer("seed", self.seed, 0, 2**63 - 1)
        object.__setattr__(self, "added", _added(self.added))

    def per_pair(self, n_pairs):
        """The parameters of each pair, in engine units.

        Parameters
        ----------
        n_pairs : int

        Returns
        -------
        PairParameters
            Arrays of shape (n_pairs,), angles in rad.

        Raises
        ------
        ValueError
            A list of the wrong length.
        """
        return PairParameters(
            **{
                PARAMETER_OF[name]: _values(
                    name,
                    getattr(self, name),
                    n_pairs,
                    self.seed,
                    rng.PAIR_SALT,
                    i,  # the stream of each key: its place in LIMITS, which seeds its draws
                    "the instrument has {} pairs",
                )
                * UNITS[name]
                for i, name in enumerate(LIMITS)
            }
        )

    def added_per_pair(self, n_pairs):
        """Each added systematic with a non-zero amplitude, and its amplitude per pair.

        Parameters
        ----------
        n_pairs : int

        Returns
        -------
        tuple of (boresight.instrument.added.PairSystematic, numpy.ndarray of shape (n_pairs,))
        """
        registry = added_systematics.REGISTRY
        return tuple(
            (
                registry[key],
                _values(
                    key,
                    value,
                    n_pairs,
                    self.seed,
                    registry[key].salt,
                    0,
                    "the instrument has {} pairs",
                ),
            )
            for key, value in self.added
            if is_nonzero(value)
        )

    def per_repeat(self, n_repeats):
        """The gain drift of each rotation repeat.

        Parameters
        ----------
        n_repeats : int

        Returns
        -------
        numpy.ndarray, shape (n_repeats,)
        """
        return _values(
            "dg_repeat",
            self.dg_repeat,
            n_repeats,
            self.seed,
            rng.REPEAT_SALT,
            0,
            "the scan has {} rotation repeats",
        )

    @property
    def has_amplitude(self):
        """Whether any systematic has a non-zero amplitude (a drift or a per-pair one)."""
        return (
            is_nonzero(self.dg_repeat)
            or any(is_nonzero(getattr(self, k)) for k in AMPLITUDES)
            or any(is_nonzero(value) for _, value in self.added)
        )

    @property
    def added_on(self):
        """The added systematics with a non-zero amplitude
        (:class:`boresight.instrument.added.PairSystematic`)."""
        registry = added_systematics.REGISTRY
        return tuple(registry[key] for key, value in self.added if is_nonzero(value))

    @property
    def has_pointing(self):
        return is_nonzero(self.rho_arcmin)

    @property
    def has_leak(self):
        return is_nonzero(self.leak)

    @property
    def has_beams(self):
        """Whether a detector's beam differs from the sky's (FWHM or ellipticity)."""
        return any(is_nonzero(getattr(self, k)) for keys in BEAM_KEYS.values() for k in keys[:2])

    @property
    def has_jitter(self):
        return is_nonzero(self.dg_jitter)


#: columns of a :func:`response` table
RESPONSE_COLUMNS = ("c", "s", "c_a", "s_a", "c_b", "s_b", "g_b")


def response(rotations, pair_angles, params, dg_repeat):
    """What each detector responds to in every (rotation, pair), relative to the crossing angle.

    Parameters
    ----------
    rotations : numpy.ndarray, shape (K,)
        Boresight rotations [rad].
    pair_angles : numpy.ndarray, shape (M,)
        Nominal polarisation angles [rad].
    params : PairParameters
    dg_repeat : numpy.ndarray, shape (K,)

    Returns
    -------
    numpy.ndarray, float64, shape (K, M, 7)
        :data:`RESPONSE_COLUMNS`: cos, sin of 2 x the angle the map-maker assumes, of detector
        A's true angle and of detector B's true angle (less 90 deg), and B's gain 1 - dg -
        dg_repeat. Rotating each (cos, sin) by 2 psi gives the sample's.

    Raises
    ------
    ValueError
        A gain of detector B outside [0, 2].
    """
    rotations = np.ascontiguousarray(rotations, dtype=np.float64)
    dg_repeat = np.ascontiguousarray(dg_repeat, dtype=np.float64)
    if dg_repeat.shape != rotations.shape:
        raise ValueError(
            f"dg_repeat has {dg_repeat.size} entries but the scan has {rotations.size} repeats"
        )
    table = _response(
        rotations,
        np.ascontiguousarray(pair_angles, dtype=np.float64),
        *params.angle_errors(),
        params.dg,
        dg_repeat,
    )
    bad = np.argwhere(~((table[..., 6] >= 0) & (table[..., 6] <= 2)))
    if bad.size:
        k, m = bad[0]
        raise ValueError(
            f"dg + dg_repeat must stay in [-1, 1] (detector B's gain 1 - dg - dg_repeat in [0, 2]):"
            f" pair {m + 1} has dg = {params.dg[m]:.4g} and repeat {k + 1} dg_repeat = "
            f"{dg_repeat[k]:.4g}"
        )
    return table


@njit
def _response(rotations, pair_angles, off_a, off_b, dg, dg_repeat):
    out = np.empty((rotations.size, pair_angles.size, 7))
    for k in range(rotations.size):
        for m in range(pair_angles.size):
            base = rotations[k] + pair_angles[m]
            out[k, m, 0] = np.cos(2.0 * base)
            out[k, m, 1] = np.sin(2.0 * base)
            out[k, m, 2] = np.cos(2.0 * (base + off_a[m]))
            out[k, m, 3] = np.sin(2.0 * (base + off_a[m]))
            out[k, m, 4] = np.cos(2.0 * (base + off_b[m]))
            out[k, m, 5] = np.sin(2.0 * (base + off_b[m]))
            out[k, m, 6] = 1.0 - (dg[m] + dg_repeat[k])
    return out


#: The paper's systematics: ``|dg|`` = 0.01 with opposite signs, rho = 0.1 arcmin, chi = 0.
PAPER_GAIN = Systematics(dg=(0.01, -0.01))
PAPER_POINTING = Systematics(rho_arcmin=0.1, chi_deg=0.0)
