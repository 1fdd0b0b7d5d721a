"""The survey's noise as the yardstick: the noise power N_ell^BB and sigma(r) from a Fisher sum.

A residual's bias on r means something only next to the survey's own uncertainty on r. The noise
is white (optionally with a 1/f knee in ell), given as a polarisation map depth or as the NET of
detector pairs, their number and the observing time over a sky fraction:

    depth_P = sqrt(2) NET sqrt(4 pi f_sky / (N_det t))        [muK rad -> muK arcmin]

(pair differencing: a polarisation map is sqrt(2) noisier than a temperature map of the same
detectors). Then N_ell = depth_P^2 (1 + (ell_knee / ell)^alpha) / B_ell^2 with the Gaussian beam
B_ell. At a fiducial r, sigma(r) follows from the Fisher information of C_BB (Knox 1995), summed
over the multipoles of the chosen bands,

    F_b = sum_{ell in b} f_sky (2 ell + 1) / 2 (C_ell^tensor / (A_lens C_ell^lens
          + r C_ell^tensor + N_ell))^2,

and sigma(r) = (sum_b F_b)^(-1/2): the uncertainty of the inverse-variance weighted estimate.

A pipeline that filters its TOD keeps a fraction F_b^BB of the sky's B in band b and moves a
fraction T_b^(EE->BB) of its E into B (:mod:`boresight.jobs.transfer`). Its spectra corrected by
F_b^BB carry the noise N_ell / F_b^BB and, where the E-to-B part is not purified, the sky's E
leaked into B, T_b^(EE->BB) C_ell^EE / F_b^BB, whose sample variance adds to the total in the
Fisher sum as the noise does (``transfer_bb``, ``e_to_b``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from . import validation
from .constants import ARCMIN

if TYPE_CHECKING:
    from .cosmology import Spectra

YEAR_S = 365.25 * 86400.0


@dataclass(frozen=True)
class SurveyNoise:
    """White polarisation noise of a survey, from a map depth or from detectors and time.

    Give ``depth_uk_arcmin``, or all of ``net_uk_sqrt_s``, ``n_detectors`` and ``years``.

    Parameters
    ----------
    fsky : float
        Observed sky fraction, in (0, 1].
    fwhm_arcmin : float
        Gaussian beam FWHM [arcmin], >= 0.
    depth_uk_arcmin : float, optional
        Polarisation map depth [muK arcmin], > 0.
    net_uk_sqrt_s : float, optional
        Temperature NET of one detector [muK sqrt(s)], > 0.
    n_detectors : int, optional
        Detectors observing (pairs count twice), >= 1.
    years : float, optional
        Observing time on the sky fraction [yr], > 0 (efficiencies folded in).
    ell_knee : float
        1/f knee in ell (0: white).
    alpha : float
        1/f slope in ell.
    nl_bb_file : str, optional
        Instead: a table of N_ell^BB [muK^2] of the beam-deconvolved B map, two columns (ell,
        N_ell; whitespace or commas, ``#`` comments), linearly interpolated in ell; for example
        an experiment's published noise curve with its foreground residuals folded in.
    sigma_r : float, optional
        Instead: sigma(r) itself, > 0, for example a published forecast's.

    The built-in white + 1/f model has no foregrounds, no filtering and no delensing residual: it
    gives a smaller sigma(r) than published forecasts (docs/guide/design.md says by how much).
    """

    fsky: float
    fwhm_arcmin: float
    depth_uk_arcmin: float | None = None
    net_uk_sqrt_s: float | None = None
    n_detectors: int | None = None
    years: float | None = None
    ell_knee: float = 0.0
    alpha: float = 2.0
    nl_bb_file: str | None = None
    sigma_r: float | None = None

    def __post_init__(self):
        validation.number("noise fsky", self.fsky, 1e-6, 1.0)
        validation.number("noise fwhm_arcmin", self.fwhm_arcmin, 0.0, 600.0)
        validation.number("noise ell_knee", self.ell_knee, 0.0, 1e4)
        validation.number("noise alpha", self.alpha, 0.0, 10.0)
        detector = (self.net_uk_sqrt_s, self.n_detectors, self.years)
        given = [
            self.depth_uk_arcmin is not None,
            any(x is not None for x in detector),
            self.nl_bb_file is not None,
            self.sigma_r is not None,
        ]
        if sum(given) != 1:
            raise ValueError(
                "noise needs exactly one of depth_uk_arcmin; net_uk_sqrt_s, n_detectors and "
                "years; nl_bb_file; sigma_r"
            )
        if self.sigma_r is not None:
            validation.number("noise sigma_r", self.sigma_r, 1e-12, 1e3)
        elif self.nl_bb_file is not None:
            object.__setattr__(self, "_table", _read_nl(self.nl_bb_file))
        elif self.depth_uk_arcmin is not None:
            validation.number("noise depth_uk_arcmin", self.depth_uk_arcmin, 1e-6, 1e6)
        else:
            if any(x is None for x in detector):
                raise ValueError("noise needs all of net_uk_sqrt_s, n_detectors and years")
            validation.number("noise net_uk_sqrt_s", self.net_uk_sqrt_s, 1e-6, 1e7)
            validation.integer("noise n_detectors", self.n_detectors, 1)
            validation.number("noise years", self.years, 1e-9, 1e3)

    @property
    def has_spectrum(self) -> bool:
        """Whether N_ell is known (everything but a given sigma_r)."""
        return self.sigma_r is None

    def summary(self) -> str:
        """The survey in a few words: its depth (or N_ell table, or sigma(r)), sky fraction and
        beam."""
        if self.sigma_r is not None:
            level = f"sigma(r) {self.sigma_r:g}"
        elif self.nl_bb_file is not None:
            level = f"N_ell of {self.nl_bb_file}"
        else:
            level = f"{self.depth:.3g} muK arcmin"
        return f"{level}, fsky {self.fsky:.3g}, beam {self.fwhm_arcmin:g} arcmin"

    @property
    def depth(self) -> float:
        """Polarisation map depth [muK arcmin] (of a white-noise model only)."""
        if self.nl_bb_file is not None or self.sigma_r is not None:
            raise ValueError("a noise given as nl_bb_file or sigma_r has no map depth")
        if self.depth_uk_arcmin is not None:
            return float(self.depth_uk_arcmin)
        seconds = self.years * YEAR_S
        depth_rad = (
            np.sqrt(2.0)
            * self.net_uk_sqrt_s
            * np.sqrt(4 * np.pi * self.fsky / (self.n_detectors * seconds))
        )
        return float(depth_rad / ARCMIN)

    def n_ell(self, lmax: int) -> np.ndarray:
        """Noise power of the beam-deconvolved B (or E) map.

        Parameters
        ----------
        lmax : int

        Returns
        -------
        numpy.ndarray, shape (lmax + 1,)
            N_ell [muK^2]; ell = 0, 1 hold the ell = 2 value's white level.
        """
        ell = np.arange(lmax + 1, dtype=float)
        if self.sigma_r is not None:
            raise ValueError("a noise given as sigma_r has no N_ell")
        if self.nl_bb_file is not None:
            table_ell, table_nl = self._table
            if lmax > table_ell[-1]:
                raise validation.ConfigError(
                    f"noise nl_bb_file {self.nl_bb_file}: N_ell reaches ell = {table_ell[-1]:g}, "
                    f"the bands need {lmax}; extend the table"
                )
            out = np.interp(ell, table_ell, table_nl)
            out[:2] = out[2] if lmax >= 2 else out[:2]
            return out
        white = (self.depth * ARCMIN) ** 2
        knee = np.ones_like(ell)
        if self.ell_knee > 0:
            knee[2:] += (self.ell_knee / ell[2:]) ** self.alpha
            knee[:2] = knee[2]
        beam = hp.gauss_beam(self.fwhm_arcmin * ARCMIN, lmax=lmax)
        return white * knee / beam**2


def _read_nl(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(ell, N_ell) of a noise table, checked: a regular UTF-8 text file (a FIFO or a device
    would block), increasing ell from <= 2, N_ell > 0, finite."""
    what = "noise nl_bb_file"
    if isinstance(path, bool) or not isinstance(path, (str, os.PathLike)):
        raise ValueError(
            f"{what} = {path!r}: give the path of a text table of ell, N_ell rows, as a string"
        )
    if not Path(path).exists():
        raise ValueError(f"{what} {path}: no such file")
    if not Path(path).is_file():
        raise ValueError(f"{what} {path}: not a regular file (a directory, FIFO or device)")
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        raise ValueError(f"{what} {path}: {err.strerror}") from None
    if b"\0" in data:
        raise ValueError(
            f"{what} {path}: binary (or UTF-16) data; give a UTF-8 text table of ell, N_ell rows"
        )
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ValueError(
            f"{what} {path}: not UTF-8 text (byte {err.start}); save it as UTF-8"
        ) from None
    rows = []
    for number, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].replace(",", " ").split()
        if not line:
            continue
        try:
            ell, nl = (float(x) for x in line[:2])
        except ValueError:
            raise ValueError(
                f"noise nl_bb_file {path}, line {number}: two numbers (ell, N_ell) expected"
            ) from None
        rows.append((ell, nl))
    table = np.array(rows, dtype=float).reshape(-1, 2)
    if table.shape[0] < 2 or table[0, 0] > 2 or np.any(np.diff(table[:, 0]) <= 0):
        raise ValueError(f"noise nl_bb_file {path}: ell must increase from 2 or below")
    if not np.all(np.isfinite(table)) or np.any(table[:, 1] <= 0):
        raise ValueError(f"noise nl_bb_file {path}: N_ell must be finite and > 0")
    return table[:, 0], table[:, 1]


def band_fisher(
    noise: SurveyNoise,
    theory: Spectra,
    edges: np.ndarray,
    *,
    r: float = 0.0,
    a_lens: float = 1.0,
    time_fraction: float = 1.0,
    transfer_bb: np.ndarray | None = None,
    e_to_b: np.ndarray | None = None,
    noise_kept: np.ndarray | None = None,
) -> np.ndarray:
    """The Fisher information on r of each band of C_BB.

    Parameters
    ----------
    noise : SurveyNoise
    theory : boresight.cosmology.Spectra
    edges : numpy.ndarray, int
        Band edges: band b is edges[b] <= ell < edges[b + 1], ell >= 2.
    r, a_lens : float
        Fiducial tensor-to-scalar ratio and lensing amplitude.
    time_fraction : float
        The share of the survey's observing time kept, in (0, 1]: N_ell / time_fraction.
    transfer_bb : numpy.ndarray, optional
        A filtering pipeline's F_b^BB per band, in (0, 1]: the noise becomes N_ell / F_b^BB.
    e_to_b : numpy.ndarray, optional
        Its T_b^(EE->BB) per band (negative estimates count as 0): the sky's E leaked into B,
        T_b C_ell^EE / F_b^BB, joins the noise.
    noise_kept : numpy.ndarray, optional
        What the pipeline keeps of the noise's own B power per band, K_b > 0 (a filter takes
        noise as it takes the sky): the noise becomes N_ell K_b / F_b^BB (default K_b = 1, the
        raw survey's noise read through the filter, an upper bound).

    Returns
    -------
    numpy.ndarray, shape (len(edges) - 1,)
        F_b, the sum over the band's multipoles of f_sky (2 ell + 1) / 2 (C^tensor / C^total)^2.
    """
    edges = np.asarray(edges, dtype=int)
    if edges.ndim != 1 or edges.size < 2 or edges[0] < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError(f"band edges must increase from ell >= 2, got {edges}")
    lmax = int(edges[-1]) - 1
    if lmax > theory.lmax:
        raise ValueError(f"bands reach ell = {lmax}, beyond the spectra's lmax = {theory.lmax}")
    ell = np.arange(lmax + 1)
    validation.number("time_fraction", time_fraction, 1e-12, 1.0)
    extra = noise.n_ell(lmax) / time_fraction
    if transfer_bb is not None or e_to_b is not None or noise_kept is not None:
        extra = extra + _filtered(theory, edges, transfer_bb, e_to_b, noise_kept, extra)
    total = theory.bb(r=r, a_lens=a_lens)[: lmax + 1] + extra
    per_ell = 0.5 * noise.fsky * (2 * ell + 1) * (theory.bb_tensor[: lmax + 1] / total) ** 2
    return np.array([per_ell[lo:hi].sum() for lo, hi in zip(edges[:-1], edges[1:])])


def _filtered(theory, edges, transfer_bb, e_to_b, noise_kept, noise_ell):
    """What a filter adds to N_ell (``noise_ell``, to the last band's end) per multipole of the
    bands: N_ell (K_b / F_b - 1) and T_b^(EE->BB) C_ell^EE / F_b."""
    nbands = edges.size - 1
    f = np.ones(nbands) if transfer_bb is None else np.asarray(transfer_bb, dtype=float)
    t = np.zeros(nbands) if e_to_b is None else np.asarray(e_to_b, dtype=float)
    k = np.ones(nbands) if noise_kept is None else np.asarray(noise_kept, dtype=float)
    if f.shape != (nbands,) or t.shape != (nbands,) or k.shape != (nbands,):
        raise ValueError(f"transfer_bb, e_to_b and noise_kept need one value per band ({nbands})")
    if not (np.all(np.isfinite(f)) and np.all(f > 0) and np.all(f <= 1 + 1e-6)):
        raise ValueError(f"transfer_bb must lie in (0, 1], got {f}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"e_to_b must be finite, got {t}")
    if not (np.all(np.isfinite(k)) and np.all(k > 0)):
        raise ValueError(f"noise_kept must be positive, got {k}")
    added = np.zeros_like(noise_ell)
    for lo, hi, fb, tb, kb in zip(edges[:-1], edges[1:], f, np.maximum(t, 0.0), k):
        added[lo:hi] = noise_ell[lo:hi] * (kb / fb - 1.0) + tb * theory.ee[lo:hi] / fb
    return added


def sigma_r(
    noise: SurveyNoise,
    theory: Spectra,
    edges: np.ndarray,
    *,
    r: float = 0.0,
    a_lens: float = 1.0,
    time_fraction: float = 1.0,
    transfer_bb: np.ndarray | None = None,
    e_to_b: np.ndarray | None = None,
    noise_kept: np.ndarray | None = None,
) -> float:
    """The survey's 1-sigma uncertainty on r: the Fisher sum over the bands, F^(-1/2).

    Parameters
    ----------
    noise, theory, edges, r, a_lens, time_fraction, transfer_bb, e_to_b, noise_kept
        As in :func:`band_fisher`; a filter's ``transfer_bb``, ``e_to_b`` and ``noise_kept``
        need N_ell (not a sigma_r given as a number).

    Returns
    -------
    float
        The given sigma(r) where the noise states it, times time_fraction^(-1/2) (the
        white-noise Knox regime: a sigma(r) given as a number has no N_ell to scale).
    """
    if noise.sigma_r is not None:
        if transfer_bb is not None or e_to_b is not None or noise_kept is not None:
            raise ValueError("a sigma_r given as a number has no N_ell for a filter to scale")
        validation.number("time_fraction", time_fraction, 1e-12, 1.0)
        return float(noise.sigma_r) / math.sqrt(time_fraction)
    fisher = band_fisher(
        noise,
        theory,
        edges,
        r=r,
        a_lens=a_lens,
        time_fraction=time_fraction,
        transfer_bb=transfer_bb,
        e_to_b=e_to_b,
        noise_kept=noise_kept,
    )
    return float(1.0 / np.sqrt(np.sum(fisher)))
