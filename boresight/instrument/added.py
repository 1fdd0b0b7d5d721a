"""Pair systematics added from one file: what a new effect declares, and the registry that the
engine, the prediction and the suppression table read.

A built-in systematic (gain, pointing, angles, beams) runs in the engine's compiled kernels. A new
one need not: it declares, in one :class:`PairSystematic`,

* its ``[systematics]`` key and the range of its amplitude (a number, one per pair, or
  ``{mean, rms}`` drawn per pair like every other key);
* its signal in the time-ordered data: what detectors A and B see beyond the sky at each hit
  (:meth:`PairSystematic.signal`);
* its term of the leak: the spin moment h_n it couples through and the field F it multiplies,
  so that the map-maker's Y gains ``coefficient x h_n x F`` (:meth:`PairSystematic.coefficient`,
  :meth:`PairSystematic.field`);
* its row of the suppression table (an amplitude, in words and in value).

and :func:`register` makes it a key of :class:`boresight.instrument.pairs.Systematics` (and of a
study's ``[systematics]`` table), a signal of :func:`boresight.engine.simulate` and its sample
streams (on the CPU backend; a focal plane's too), a term of :func:`boresight.predict.delta_p`
(the map-level prediction, exact for pixel-centre hits) and a row of
:data:`boresight.jobs.suppression.axis.CATALOGUE` (predicted from the map where the C_ell level,
whose spectra assume a field much finer than h_n, does not apply). What it is not yet carried
through (a HWP, the focal-plane expectation, the design) refuses it with :data:`NOT_CARRIED`.

The default model is an **additive** term, the shape of the built-in ``leak``: detector A sees
``+a F / 2`` and detector B ``-a F / 2`` for pair amplitude a and a spin-0 field F read in the
hit's pixel, so the pair difference gains ``a F / 2`` and

    Y = 2 <e^{2 i phi} dd> = <a e^{2 i (alpha + angle)}> h_2 F

(docs/conventions.md, "Polarisation-angle errors, gain drift and jitter, focal planes"): the
coefficient is the mean over rotation repeats alpha_k and pairs of a_m e^{2 i (alpha_k + a_m)}.
A systematic of another shape overrides :meth:`PairSystematic.signal`,
:meth:`PairSystematic.coefficient` and ``n``. docs/guide/adding_a_systematic.md works one
through.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..kernels import rng
from ..kernels.pixels import ang2pix_array

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..sky import Sky

#: what a run not yet carrying an added systematic says
NOT_CARRIED = (
    "{keys}: an added systematic (boresight.instrument.added) runs on the axis and on a focal "
    "plane's sample streams, bare and on the CPU backend, and is predicted at the map level; "
    "{where} does not carry it yet"
)


@dataclass(frozen=True)
class PairSystematic:
    """One pair systematic, declared whole (the module's docstring).

    Parameters
    ----------
    key : str
        Its ``[systematics]`` key; not a built-in one.
    limits : tuple of float
        (lo, hi) of its amplitude.
    field : callable
        ``field(sky) -> (npix,)`` the spin-0 map F the amplitude scales [muK or the amplitude's
        unit], read in each hit's pixel.
    symbol : str
        F in the docs' notation, for the "couples through" column (``"1"`` for a constant).
    amplitude : float
        The suppression table's amplitude of it.
    words : str
        That amplitude in words (``"c = 10 muK"``).
    n : int
        The spin moment its term multiplies: 2 for an additive term.
    help : str
        One line of what it is.
    """

    key: str
    limits: tuple
    field: Callable
    symbol: str
    amplitude: float
    words: str
    n: int = 2
    help: str = ""

    @property
    def salt(self) -> np.uint64:
        """The key of its per-pair draws: the pairs' salt mixed with its name, so that a
        ``{mean, rms}`` amplitude draws the same values whatever else is registered."""
        return np.uint64(int(rng.PAIR_SALT) ^ zlib.crc32(self.key.encode()))

    def signal(self, amplitude, field, theta, phi, psi, *, rotations, angles) -> np.ndarray:
        """Detectors A's and B's signal beyond the sky at each hit, rotation and pair.

        Parameters
        ----------
        amplitude : numpy.ndarray, shape (M,)
            Each pair's amplitude.
        field : numpy.ndarray, shape (npix,)
            :attr:`field` of the sky.
        theta, phi, psi : numpy.ndarray, shape (H,)
            The hits' position and crossing angle [rad].
        rotations, angles : numpy.ndarray, shapes (K,) and (M,)
            The boresight rotations and the pairs' angles [rad].

        Returns
        -------
        numpy.ndarray, shape (2, H, K, M)
            Added to what A and B see: here +-a F / 2.
        """
        nside = int(round(np.sqrt(field.size / 12)))
        f = field[ang2pix_array(nside, theta, phi)]
        half = 0.5 * f[:, None, None] * amplitude[None, None, :]
        half = np.broadcast_to(half, (theta.size, rotations.size, amplitude.size))
        return np.stack((half, -half))

    def coefficient(self, amplitude, rotations, angles) -> complex:
        """Its coefficient in Y: the mean over (k, m) of a_m e^{2 i (alpha_k + angle_m)}.

        Parameters
        ----------
        amplitude : numpy.ndarray, shape (M,)
        rotations, angles : numpy.ndarray, shapes (K,) and (M,)
            [rad].

        Returns
        -------
        complex
        """
        turn = np.exp(2j * (rotations[:, None] + angles[None, :]))
        return complex(np.mean(amplitude[None, :] * turn))

    def y(self, sky: Sky, h: np.ndarray, coefficient: complex) -> np.ndarray:
        """Its part of the map-maker's Y on every pixel: coefficient x h_n x F, (npix,) complex.

        Parameters
        ----------
        sky : boresight.sky.Sky
        h : numpy.ndarray, complex, shape (> n, npix)
            The h_n maps (h_0 = 1).
        coefficient : complex
            :meth:`coefficient`.
        """
        if h.shape[0] <= abs(self.n):
            raise ValueError(
                f"{self.key} couples through h_{self.n}; h holds h_0..h_{h.shape[0] - 1}"
            )
        moment = h[self.n] if self.n >= 0 else np.conj(h[-self.n])
        return coefficient * moment * np.asarray(self.field(sky), dtype=np.float64)


#: the added systematics, by key, in the order they were registered
REGISTRY: dict[str, PairSystematic] = {}
#: the built-in ``[systematics]`` keys, which no added one may take (the fields of
#: :class:`boresight.instrument.pairs.Systematics`, checked equal by its tests)
BUILT_IN = frozenset(
    (
        "dg",
        "rho_arcmin",
        "chi_deg",
        "leak",
        "pol_angle_deg",
        "nonortho_deg",
        "dg_jitter",
        "dfwhm_a_arcmin",
        "dfwhm_b_arcmin",
        "ellipticity_a",
        "ellipticity_b",
        "ellipticity_angle_a_deg",
        "ellipticity_angle_b_deg",
        "dg_repeat",
        "seed",
        "added",
        "leak_template",
    )
)


def register(systematic: PairSystematic) -> PairSystematic:
    """Add a systematic to :data:`REGISTRY` (again: replaced), and return it.

    Raises
    ------
    ValueError
        A built-in key, or limits that are not lo < hi.
    """
    if systematic.key in BUILT_IN:
        raise ValueError(f"{systematic.key!r} is a built-in [systematics] key")
    lo, hi = systematic.limits
    if not lo < hi:
        raise ValueError(f"{systematic.key}: limits must be lo < hi, got {systematic.limits}")
    REGISTRY[systematic.key] = systematic
    return systematic


def unregister(key: str) -> None:
    """Remove a systematic from :data:`REGISTRY` (nothing if absent)."""
    REGISTRY.pop(key, None)


def split_table(table: dict) -> tuple[dict, dict]:
    """A ``[systematics]`` table split into its built-in keys and its added ones (registered).

    Returns
    -------
    built_in, added : dict
    """
    added = {k: v for k, v in table.items() if k in REGISTRY}
    return {k: v for k, v in table.items() if k not in REGISTRY}, added


def refuse(systematics, where: str) -> None:
    """Raise :data:`NOT_CARRIED` if ``systematics`` holds an added systematic.

    Parameters
    ----------
    systematics : boresight.instrument.pairs.Systematics
    where : str
        What does not carry it, for the message (``"a HWP"``).

    Raises
    ------
    ValueError
    """
    keys = [key for key, _ in systematics.added]
    if keys:
        raise ValueError(NOT_CARRIED.format(keys=", ".join(keys), where=where))
