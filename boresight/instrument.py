"""Detector pairs and their differential systematics.

Pair i has detector A at polarisation angle psi + angle_i and detector B at psi + angle_i + 90 deg,
where psi is the crossing angle of the hit. Systematics, per pair:

* differential gain ``dg``: detector B's signal is scaled by (1 - dg);
* differential pointing ``rho_arcmin``, ``chi_deg``: detector B looks at
  theta + rho cos(beta), phi + rho sin(beta) / sin(theta) with beta = psi + angle_i + chi, i.e. the
  offset is fixed in the focal plane and chi is measured from the pair's own polarisation axis
  (the convention behind the paper's eq. 6, see docs/conventions.md);
* additive leak ``leak`` (bandpass mismatch or any crossing-angle-independent term): detector A sees
  +leak/2 and detector B -leak/2 times a template map (default: the sky's I), so the pair
  difference gains leak/2 * template, like a gain error with its own template.
"""

from dataclasses import dataclass

import numpy as np

from . import validation
from .constants import ARCMIN, DEG
from .validation import option

MAX_ANGLE_DEG = 3600.0  #: angles beyond ten turns are input mistakes
#: allowed range of each systematic parameter: detector B's gain 1 - dg stays in [0, 2]; pointing
#: offsets up to 10 deg (far beyond any pair, still handled exactly by the engine)
LIMITS = {
    "dg": (-1.0, 1.0),
    "rho_arcmin": (0.0, 600.0),
    "chi_deg": (-MAX_ANGLE_DEG, MAX_ANGLE_DEG),
    "leak": (-1.0, 1.0),
}


@dataclass(frozen=True)
class Instrument:
    """The detector pairs: the ``[instrument]`` table.

    Parameters
    ----------
    pair_angles_deg : tuple of float
        Polarisation angle of each pair's detector A [deg]; detector B is at +90 deg. The paper's
        Q and U pairs by default.
    """

    pair_angles_deg: tuple = option((0.0, 45.0), "polarisation angles of the pairs [deg]")

    def __post_init__(self):
        a = validation.numbers_array(
            "pair_angles_deg", self.pair_angles_deg, -MAX_ANGLE_DEG, MAX_ANGLE_DEG
        )
        if a.ndim != 1 or a.size == 0:
            raise ValueError(
                f"pair_angles_deg must be a non-empty list, got {self.pair_angles_deg!r}"
            )
        object.__setattr__(self, "pair_angles_deg", tuple(float(x) for x in a))

    @property
    def n_pairs(self):
        return len(self.pair_angles_deg)

    @property
    def pair_angles_rad(self):
        return np.asarray(self.pair_angles_deg) * DEG


@dataclass(frozen=True)
class Systematics:
    """Per-pair differential systematics: the ``[systematics]`` table.

    A scalar applies to every pair, a tuple gives one value per pair.

    Parameters
    ----------
    dg : float or tuple
        Differential gain: detector B's signal is scaled by (1 - dg), in [-1, 1].
    rho_arcmin : float or tuple
        Differential pointing [arcmin], in [0, 600].
    chi_deg : float or tuple
        Direction of the pointing offset from the pair's polarisation axis [deg].
    leak : float or tuple
        Additive leak: the pair difference gains leak / 2 times a template, in [-1, 1].
    """

    dg: object = option(0.0, "differential gain, a number or one per pair", (int, float, list))
    rho_arcmin: object = option(
        0.0, "differential pointing [arcmin], >= 0, a number or one per pair", (int, float, list)
    )
    chi_deg: object = option(
        0.0, "pointing offset direction [deg], a number or one per pair", (int, float, list)
    )
    leak: object = option(0.0, "additive leak, a number or one per pair", (int, float, list))

    def __post_init__(self):
        for name, (lo, hi) in LIMITS.items():
            validation.numbers_array(name, getattr(self, name), lo, hi)

    def per_pair(self, n_pairs):
        """The parameters of each pair, in radians.

        Parameters
        ----------
        n_pairs : int

        Returns
        -------
        dg, rho, chi, leak : numpy.ndarray, float64, shape (n_pairs,)
            rho and chi in rad.
        """
        out = []
        for name, unit in (("dg", 1.0), ("rho_arcmin", ARCMIN), ("chi_deg", DEG), ("leak", 1.0)):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.ndim == 1 and v.size != n_pairs:
                raise ValueError(
                    f"{name} has {v.size} entries but the instrument has {n_pairs} pairs"
                )
            out.append(np.broadcast_to(v, (n_pairs,)).astype(np.float64) * unit)
        return out

    @property
    def has_pointing(self):
        return bool(np.any(np.asarray(self.rho_arcmin) != 0))

    @property
    def has_leak(self):
        return bool(np.any(np.asarray(self.leak) != 0))


#: The paper's systematics: ``|dg|`` = 0.01 with opposite signs, rho = 0.1 arcmin, chi = 0.
PAPER_GAIN = Systematics(dg=(0.01, -0.01))
PAPER_POINTING = Systematics(rho_arcmin=0.1, chi_deg=0.0)
