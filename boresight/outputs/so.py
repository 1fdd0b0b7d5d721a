"""h_n maps in the layout of the Simons Observatory's h_n operator and SMARTIES.

SMARTIES (``smarties.io.read_toast_h_maps``) reads each moment as two real HEALPix RING maps,
``{prefix}_cos_{n}.fits`` and ``{prefix}_sin_{n}.fits``, with h_n = cos + i sin, 0 outside the
observed region, and the crossing angle in TOAST's convention. boresight's crossing angle is
TOAST's + 180 deg, so

    h_n(TOAST/SO) = <exp(i n (psi - pi))> = (-1)^n h_n(boresight):

odd moments change sign and even ones do not. The hit map is ``{prefix}_hits.fits``.
"""

from __future__ import annotations

import os
from pathlib import Path

import healpy as hp
import numpy as np

from .._util.io import write_maps

#: header COMMENT stating the convention of every map written here
CONVENTION = "h_n = cos + i sin of n psi, psi in TOAST/SO's convention (boresight's psi - 180 deg)"


def to_so(h: np.ndarray, n: int) -> np.ndarray:
    """One moment in TOAST/SO's convention.

    Parameters
    ----------
    h : numpy.ndarray, complex, shape (npix,)
        h_n in boresight's convention.
    n : int

    Returns
    -------
    numpy.ndarray, complex, shape (npix,)
        (-1)^n h.
    """
    return h if n % 2 == 0 else -h


def write(
    directory: str | os.PathLike,
    prefix: str,
    h: np.ndarray,
    hits: np.ndarray,
    n_values: range = range(1, 5),
    *,
    frame: str = "icrs",
    partial: bool = False,
) -> list[Path]:
    """Write ``{prefix}_cos_{n}.fits``, ``{prefix}_sin_{n}.fits`` and ``{prefix}_hits.fits``.

    Parameters
    ----------
    directory : str or os.PathLike
    prefix : str
        File name prefix, for example ``"hn"`` or ``"w14_p082_f150_A"``.
    h : numpy.ndarray, complex, shape (n_max + 1, npix)
        h_n in boresight's convention, indexed by n.
    hits : numpy.ndarray, shape (npix,)
        Samples per pixel; 0 marks unobserved pixels, where every map is 0.
    n_values : iterable of int
        The moments written.
    frame : {"icrs", "galactic", "cirs"}
        The maps' sky frame (their COORDSYS card).
    partial : bool
        HEALPix partial maps of the observed pixels (healpy.read_map fills the rest with UNSEEN;
        SMARTIES' reader, which expects 0 there, then needs a mask within the hits map's
        pixels).

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    directory = Path(directory)
    seen = np.asarray(hits) > 0
    paths = []
    for n in n_values:
        h_so = np.where(seen, to_so(h[n], n), 0.0)
        for part, values in (("cos", h_so.real), ("sin", h_so.imag)):
            path = directory / f"{prefix}_{part}_{n}.fits"
            write_maps(
                path,
                [values],
                [f"{part.upper()}_{n}"],
                [""],
                comments=[CONVENTION],
                frame=frame,
                observed=seen if partial else None,
            )
            paths.append(path)
    path = directory / f"{prefix}_hits.fits"
    write_maps(
        path,
        [np.where(seen, hits, 0)],
        ["HITS"],
        [""],
        frame=frame,
        observed=seen if partial else None,
    )
    return paths + [path]


def read(directory: str | os.PathLike, prefix: str, n: int) -> np.ndarray:
    """One moment from the SO layout, back in boresight's convention (0 where unobserved, a
    partial map's UNSEEN included).

    Parameters
    ----------
    directory : str or os.PathLike
    prefix : str
    n : int

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
    """
    directory = Path(directory)
    cos = hp.read_map(directory / f"{prefix}_cos_{n}.fits", dtype=np.float64)
    sin = hp.read_map(directory / f"{prefix}_sin_{n}.fits", dtype=np.float64)
    h = np.where(cos == hp.UNSEEN, 0.0, cos) + 1j * np.where(sin == hp.UNSEEN, 0.0, sin)
    return to_so(h, n)
