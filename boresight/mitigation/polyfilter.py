"""The polynomial filter: a Legendre polynomial of a given order fitted to each interval of a
time stream (a throw, scan plus turnaround, as TOAST's ``PolyFilter(view="throw")``; or a
half-scan, as BICEP/Keck's third-order filter) and subtracted.

Within an interval of n samples the templates are the Legendre polynomials P_0 .. P_order at the
samples' centres x_i = -1 + (2 i + 1) / n, i = 0 .. n - 1 (TOAST 3's ``filter_polynomial``). The
fit is the least-squares solution over the unflagged samples; the fitted polynomial is subtracted
from every sample of the interval, flagged ones included (so a masked source is filtered with the
rest). Samples outside every interval are left as they are, and an interval with no unflagged
sample is left whole. Because the fit is a projection, the filter is linear: it removes from a
leak exactly what it removes from the sky, and filtering twice is filtering once.
"""

from __future__ import annotations

import numpy as np

from ..validation import integer


def legendre_templates(n: int, order: int) -> np.ndarray:
    """The Legendre polynomials P_0 .. P_order at the centres of n samples on [-1, 1].

    Parameters
    ----------
    n : int
        Samples, >= 1.
    order : int
        Highest order, >= 0.

    Returns
    -------
    numpy.ndarray, float64, shape (n, order + 1)
    """
    x = -1.0 + (2.0 * np.arange(n) + 1.0) / n
    out = np.empty((n, order + 1))
    out[:, 0] = 1.0
    if order >= 1:
        out[:, 1] = x
    for k in range(2, order + 1):  # Bonnet's recursion, TOAST's
        out[:, k] = ((2 * k - 1) * x * out[:, k - 1] - (k - 1) * out[:, k - 2]) / k
    return out


def poly_filter(
    signal: np.ndarray,
    *,
    order: int,
    intervals: np.ndarray,
    flags: np.ndarray | None = None,
) -> np.ndarray:
    """Subtract a Legendre polynomial fitted to each interval of one or more time streams.

    Parameters
    ----------
    signal : numpy.ndarray, shape (n,) or (n_signals, n)
        The streams (pair differences, or detectors' samples) sharing the samples' flags.
    order : int
        The polynomial's order, >= 0 (0: the interval's mean; BICEP/Keck use 3).
    intervals : numpy.ndarray of int, shape (n_intervals, 2)
        Half-open sample ranges [start, stop), in order and not overlapping: TOAST 3's
        intervals (``first``, ``last``) as its compiled ``filter_polynomial`` reads them.
    flags : numpy.ndarray of bool, shape (n,), optional
        True where a sample is left out of the fit (it is still filtered).

    Returns
    -------
    numpy.ndarray, float64
        The filtered streams, shaped as ``signal``; a new array.

    Raises
    ------
    ValueError
        Intervals out of range, overlapping or empty; flags of another length; a negative order.
    """
    integer("order", order, 0, 64)
    out = np.array(signal, dtype=np.float64, copy=True)
    streams = out.reshape(-1, out.shape[-1])
    n = streams.shape[1]
    bounds = _checked(intervals, n)
    keep = np.ones(n, dtype=bool) if flags is None else ~_flags(flags, n)
    for start, stop in bounds:
        good = keep[start:stop]
        if not good.any():
            continue
        templates = legendre_templates(stop - start, order)
        chunk = streams[:, start:stop]
        coef = np.linalg.lstsq(templates[good], chunk[:, good].T, rcond=None)[0]
        chunk -= (templates @ coef).T
    return out


def _checked(intervals, n):
    bounds = np.asarray(intervals, dtype=np.int64).reshape(-1, 2)
    starts, stops = bounds[:, 0], bounds[:, 1]
    if bounds.size and (
        starts.min() < 0
        or stops.max() > n
        or np.any(stops <= starts)
        or np.any(starts[1:] < stops[:-1])
    ):
        raise ValueError(
            f"intervals must be [start, stop) ranges within 0 .. {n}, non-empty, in order and "
            "not overlapping"
        )
    return bounds


def _flags(flags, n):
    flags = np.asarray(flags, dtype=bool)
    if flags.shape != (n,):
        raise ValueError(f"flags must have shape ({n},), got {flags.shape}")
    return flags
