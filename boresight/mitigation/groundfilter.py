"""The ground filter: a template of the scan's azimuth fitted to a CES and subtracted, the
scan-synchronous signal (ground pickup) a ground-based pipeline removes.

The templates of one CES of n samples (TOAST 3's ``GroundFilter``):

* the trend: Legendre polynomials of orders 1 .. ``trend_order`` in time, x = 2 i / n - 1, fitted
  beside the ground template and kept in the data unless ``detrend``;
* in azimuth, on the phase p = 2 (az - az_min) / (az_max - az_min) - 1 (azimuths unwrapped from
  below 0; a CES going all the way round uses [0, 2 pi)): Legendre polynomials of orders 0 ..
  ``filter_order`` of p, or the indicator of each azimuth bin of width ``bin_width`` that the
  scan hits (not both: TOAST 3.0.6's binned template with a polynomial fails with a NameError);
* with ``split``, each azimuth template twice, once zeroed on the left-going throws and once on
  the right-going ones, so that the two directions have their own template.

Every polynomial is normalised as TOAST's, by sqrt((2 l + 1) / 2), which changes no fit. The
fit solves the templates' normal equations over the unflagged samples, with the inverse where
their reciprocal condition number exceeds 1e-6 and the pseudo-inverse (rcond 1e-12) below, and
the fitted azimuth templates (and the trend with ``detrend``) are subtracted from every sample.
Like the polynomial filter it is a projection, so it acts on a leak as on the sky.
"""

from __future__ import annotations

import numpy as np

from ..validation import integer, number

RCOND_INVERSE = 1e-6  #: below this, the fit takes the pseudo-inverse (TOAST's threshold)


def _legendre(x, first, last):
    """Normalised Legendre polynomials P_first .. P_last at x, (last - first + 1, n)."""
    out = np.polynomial.legendre.legvander(x, last).T[first:]
    return out * np.sqrt((2.0 * np.arange(first, last + 1) + 1.0) / 2.0)[:, None]


def azimuth_phase(az: np.ndarray) -> np.ndarray:
    """The scan's azimuth mapped onto [-1, 1] over its range (TOAST's phase).

    A range below zero is lifted by whole turns, samples and range together: TOAST 3.0.6 lifts the
    range only, which puts a scan with negative azimuths outside [-1, 1]. Azimuths in [0, 2 pi),
    TOAST's, give TOAST's phase.

    Parameters
    ----------
    az : numpy.ndarray, shape (n,)
        Boresight azimuth [rad].

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    az = np.asarray(az, dtype=np.float64)
    lo, hi = float(np.min(az)), float(np.max(az))
    turns = np.ceil(-lo / (2 * np.pi)) if lo < 0 else 0.0
    az, lo, hi = az + turns * 2 * np.pi, lo + turns * 2 * np.pi, hi + turns * 2 * np.pi
    if hi - lo > 2 * np.pi:  # all the way round
        lo, hi, az = 0.0, 2 * np.pi, az % (2 * np.pi)
    return (az - lo) / (hi - lo) * 2 - 1


def ground_templates(
    az: np.ndarray,
    *,
    filter_order: int | None = 5,
    bin_width_rad: float | None = None,
    trend_order: int | None = 5,
    split: tuple | None = None,
) -> tuple[np.ndarray, int]:
    """The templates of one CES: the trend's, then the azimuth's.

    Parameters
    ----------
    az : numpy.ndarray, shape (n,)
        Boresight azimuth [rad].
    filter_order : int, optional
        Legendre orders 0 .. this in azimuth; None for none.
    bin_width_rad : float, optional
        Azimuth bins of this width [rad] instead (with ``filter_order`` None).
    trend_order : int, optional
        Legendre orders 1 .. this in time; None for none.
    split : tuple of two numpy.ndarray of bool, optional
        The samples of the left-going throws and of the right-going ones.

    Returns
    -------
    templates : numpy.ndarray, shape (n_templates, n)
    n_trend : int
        How many of them (the first) are the trend's.

    Raises
    ------
    ValueError
        Neither or both of ``filter_order`` and ``bin_width_rad``; split masks of another length.
    """
    az = np.asarray(az, dtype=np.float64)
    n = az.size
    if (filter_order is None) == (bin_width_rad is None):
        raise ValueError(
            "give filter_order (Legendre in azimuth) or bin_width_rad (azimuth bins), one of them"
        )
    parts = []
    if trend_order is not None:
        integer("trend_order", trend_order, 1, 64)
        parts.append(_legendre(np.arange(n) / n * 2 - 1, 1, trend_order))
    if filter_order is not None:
        integer("filter_order", filter_order, 0, 64)
        ground = _legendre(azimuth_phase(az), 0, filter_order)
    else:
        width = number("bin_width_rad", bin_width_rad, 0.0, 2 * np.pi)
        if width <= 0:
            raise ValueError("bin_width_rad must be > 0")
        ibin = np.floor_divide(az, width).astype(np.int64)
        ground = (ibin[None, :] == np.unique(ibin)[:, None]).astype(np.float64)
    if split is not None:
        masks = [np.asarray(m, dtype=bool) for m in split]
        if len(masks) != 2 or any(m.shape != (n,) for m in masks):
            raise ValueError(f"split must be two boolean masks of shape ({n},)")
        ground = np.stack([np.where(m, 0.0, t) for t in ground for m in masks])
    parts.append(ground)
    n_trend = 0 if trend_order is None else trend_order
    return np.vstack(parts), n_trend


def ground_filter(
    signal: np.ndarray,
    *,
    az: np.ndarray,
    filter_order: int | None = 5,
    bin_width_rad: float | None = None,
    trend_order: int | None = 5,
    detrend: bool = False,
    split: tuple | None = None,
    flags: np.ndarray | None = None,
) -> np.ndarray:
    """Fit a CES's ground templates to each stream and subtract them.

    Parameters
    ----------
    signal : numpy.ndarray, shape (n,) or (n_signals, n)
        One CES's streams.
    az : numpy.ndarray, shape (n,)
        Boresight azimuth [rad].
    filter_order, bin_width_rad, trend_order, split
        As :func:`ground_templates`.
    detrend : bool
        Subtract the fitted trend too.
    flags : numpy.ndarray of bool, shape (n,), optional
        True where a sample is left out of the fit (it is still filtered).

    Returns
    -------
    numpy.ndarray, float64
        The filtered streams, shaped as ``signal``; a new array (a copy of it when every sample
        is flagged).
    """
    out = np.array(signal, dtype=np.float64, copy=True)
    streams = out.reshape(-1, out.shape[-1])
    templates, n_trend = ground_templates(
        az,
        filter_order=filter_order,
        bin_width_rad=bin_width_rad,
        trend_order=trend_order,
        split=split,
    )
    if templates.shape[1] != streams.shape[1]:
        raise ValueError(f"az has {templates.shape[1]} samples, the signal {streams.shape[1]}")
    good = np.ones(streams.shape[1], dtype=bool) if flags is None else ~np.asarray(flags, bool)
    if good.shape != (streams.shape[1],):
        raise ValueError(f"flags must have shape ({streams.shape[1]},), got {good.shape}")
    if not good.any():
        return out
    used = templates[:, good]
    normal = used @ used.T
    if 1.0 / np.linalg.cond(normal) > RCOND_INVERSE:
        cov = np.linalg.inv(normal)
    else:
        cov = np.linalg.pinv(normal, rcond=1e-12, hermitian=True)
    coeff = cov @ (used @ streams[:, good].T)
    first = 0 if detrend else n_trend
    streams -= (templates[first:].T @ coeff[first:]).T
    return out
