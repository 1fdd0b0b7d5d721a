"""Synthetic scans (paper section 3.1) and the boresight-rotation schedule.

In every observed pixel, N_phi crossing angles are drawn uniformly in a range R about a centre
angle, each at a uniformly random position inside the pixel (or at its centre). Partial boresight
rotation (PBR) repeats every hit at crossing angle + alpha for each alpha in ``rotations_deg``
(``(0,)`` is no rotation; the paper's gain case is ``(0, 90)``). N_phi, R and the centre are scalars
or per-pixel RING maps. Angles are measured on the sky from e_theta towards e_phi (COSMO).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from . import validation
from .constants import DEG
from .instrument.pairs import MAX_ANGLE_DEG
from .sky import MAX_SEED
from .validation import option

#: most crossing angles per pixel of a synthetic scan (real scans have thousands of samples per
#: pixel but the paper's characterisation needs a handful of distinct angles)
MAX_N_PHI = 100_000


def _scalar_or_map(name, value, lo, hi):
    arr = np.asarray(value)
    if arr.ndim > 1 or arr.dtype == bool or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must be a finite scalar or 1-d map with values in [{lo}, {hi}]")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all() or (arr < lo).any() or (arr > hi).any():
        raise ValueError(f"{name} must be a finite scalar or 1-d map with values in [{lo}, {hi}]")
    return arr


@dataclass(frozen=True)
class SyntheticScan:
    """A synthetic scan (paper section 3.1): the ``[scan]`` table.

    Parameters
    ----------
    n_phi : int or numpy.ndarray of int
        Hits per pixel (crossing angles), >= 1, a scalar or a RING map (npix,).
    range_rad : float or numpy.ndarray
        Range R [rad] of the crossing angles, in [0, 2 pi].
    centre_rad : float or numpy.ndarray
        Centre of the range [rad].
    rotations_deg : tuple of float
        Boresight rotation angles alpha [deg]: every hit is repeated once per entry; (0,) is no
        rotation, the paper's gain case is (0, 90).
    in_pixel : {"random", "centre"}
        Hit positions: uniform in the pixel's solid angle, or its centre.
    seed : int
        Seed of the counter-based random numbers.
    """

    n_phi: object = option(
        4, "crossing angles per pixel, an integer >= 1 or a FITS map", (int, str)
    )
    range_rad: object = option(
        0.719, "range R of the crossing angles [rad] in [0, 2 pi], or a FITS map", (int, float, str)
    )
    centre_rad: object = option(0.0, "centre of the range [rad], or a FITS map", (int, float, str))
    rotations_deg: tuple = option((0.0,), "boresight angles [deg]: every hit is repeated at each")
    in_pixel: str = option("random", "hit positions in the pixel", choices=("random", "centre"))
    seed: int = option(0, "seed of the hits, >= 0")

    def __post_init__(self):
        nphi = np.asarray(self.n_phi)
        if (
            not np.issubdtype(nphi.dtype, np.integer)
            or nphi.ndim > 1
            or (nphi < 1).any()
            or (nphi > MAX_N_PHI).any()
        ):
            raise ValueError(
                f"n_phi must be an integer in [1, {MAX_N_PHI}] or such an integer map, "
                f"got {self.n_phi!r}"
            )
        _scalar_or_map("range_rad", self.range_rad, 0.0, 2 * np.pi)
        _scalar_or_map("centre_rad", self.centre_rad, -4 * np.pi, 4 * np.pi)
        rot = validation.numbers_array(
            "rotations_deg", self.rotations_deg, -MAX_ANGLE_DEG, MAX_ANGLE_DEG
        )
        if rot.ndim != 1 or rot.size == 0:
            raise ValueError(
                f"rotations_deg must be a non-empty list of angles, got {self.rotations_deg!r}"
            )
        if self.in_pixel not in ("random", "centre"):
            raise ValueError(f"in_pixel must be 'random' or 'centre', got {self.in_pixel!r}")
        validation.integer("seed", self.seed, 0, MAX_SEED)
        object.__setattr__(self, "rotations_deg", tuple(float(a) for a in rot))

    @property
    def rotations_rad(self):
        return np.asarray(self.rotations_deg) * DEG

    def one_repeat(self) -> SyntheticScan:
        """The same hits without boresight rotation: every repeat's h_n are these times
        exp(i n alpha_k), which is how the predictions use them."""
        return dataclasses.replace(self, rotations_deg=(0.0,))

    def per_pixel(self, pixels: np.ndarray, npix: int) -> list[np.ndarray]:
        """(n_phi, R, centre) of some pixels.

        Parameters
        ----------
        pixels : numpy.ndarray of int, shape (P,)
        npix : int
            Pixels of the sky (checks map-valued parameters).

        Returns
        -------
        n_phi : numpy.ndarray, int64, shape (P,)
        range_rad, centre_rad : numpy.ndarray, float64, shape (P,)
        """
        out = []
        for name, dtype in (
            ("n_phi", np.int64),
            ("range_rad", np.float64),
            ("centre_rad", np.float64),
        ):
            v = np.asarray(getattr(self, name))
            if v.ndim == 0:
                out.append(np.full(pixels.size, v, dtype=dtype))
            elif v.size != npix:
                raise ValueError(f"{name} map has {v.size} pixels, the sky has {npix}")
            else:
                out.append(v[pixels].astype(dtype))
        return out


def paper_scan(survey: str, rotation_deg: float | None = None, seed: int = 0) -> SyntheticScan:
    """The paper's synthetic scans.

    Parameters
    ----------
    survey : {"deep", "wide"}
        deep: N_phi = 4, R = 0.719 rad; wide: N_phi = 2, R = 0.169 rad.
    rotation_deg : float, optional
        Add one boresight repeat at this angle [deg] (None: no rotation).
    seed : int

    Returns
    -------
    SyntheticScan
    """
    params = {"deep": (4, 0.719), "wide": (2, 0.169)}
    if survey not in params:
        raise ValueError(f"survey must be 'deep' or 'wide', got {survey!r}")
    n_phi, r = params[survey]
    rotations = (0.0,) if rotation_deg is None else (0.0, float(rotation_deg))
    return SyntheticScan(n_phi=n_phi, range_rad=r, rotations_deg=rotations, seed=seed)
