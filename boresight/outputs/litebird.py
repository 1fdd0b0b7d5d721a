"""h_{n,m} maps in litebird_sim's layout (``litebird_sim.mapmaking.h_maps``, its ``save_hn_maps``
and ``load_h_map_from_file``), so that the two tools' moments can be compared.

One HDF5 file per detector, ``h_maps_det_{det}.h5``: a group ``"n,m"`` per moment holding two
RING maps, ``Re`` and ``Im``, 0 where unseen, and the group ``"0,0"`` holding the hits in ``Re``
as litebird_sim's ``make_h_maps`` writes it. The file's attributes are litebird_sim's
(``coordinate_system``, ``det``, ``detector_split``, ``time_split``, ``duration_s``,
``sampling_rate_Hz``) and boresight's ``psi_convention``: psi is boresight's crossing angle
(TOAST's + 180 deg) and chi the HWP's angle in the focal plane (:mod:`boresight.instrument.hwp`).
litebird_sim names its frames ``Ecliptic`` and ``Galactic`` only, so the maps must be Galactic.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..validation import ConfigError

#: litebird_sim's name of each frame it has
FRAMES = {"galactic": "Galactic"}


def check_frame(frame: str) -> str:
    """litebird_sim's name of ``frame``, or one clear error."""
    if frame not in FRAMES:
        raise ConfigError(
            f"litebird_sim's h_n files name their frame Ecliptic or Galactic, not {frame!r}: "
            "make the maps Galactic (--frame galactic)"
        )
    return FRAMES[frame]


def write(
    directory: str | os.PathLike,
    det: str,
    hits: np.ndarray,
    h: dict,
    *,
    frame: str,
    duration_s: float,
    sample_rate_hz: float,
) -> Path:
    """Write ``h_maps_det_{det}.h5``.

    Parameters
    ----------
    directory : str or os.PathLike
    det : str
        The detector's name (boresight writes ``"boresight"``: the pairs on the axis).
    hits : numpy.ndarray, shape (npix,)
    h : dict
        (n, m) -> (npix,) complex h_{n,m} in boresight's convention; (0, 0) is written as hits.
    frame : str
        The maps' frame (:func:`check_frame`).
    duration_s, sample_rate_hz : float
        The observation's seconds and samples per second.

    Returns
    -------
    pathlib.Path
    """
    import h5py

    name = check_frame(frame)
    path = Path(directory) / f"h_maps_det_{det}.h5"
    with h5py.File(path, "w") as f:
        f.attrs["coordinate_system"] = name
        f.attrs["det"] = det
        f.attrs["detector_split"] = "full"
        f.attrs["time_split"] = "full"
        f.attrs["duration_s"] = float(duration_s)
        f.attrs["sampling_rate_Hz"] = float(sample_rate_hz)
        f.attrs["psi_convention"] = "boresight: TOAST's psi + 180 deg; chi in the focal plane"
        moments = {**h, (0, 0): np.asarray(hits, dtype=np.float64) + 0j}
        for (n, m), moment in moments.items():
            group = f.create_group(f"{n},{m}")
            group.create_dataset("Re", data=np.ascontiguousarray(moment.real))
            group.create_dataset("Im", data=np.ascontiguousarray(moment.imag))
    return path
