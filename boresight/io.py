"""Writing outputs atomically: FITS maps healpy reads, CSV tables, JSON, and output directories.

Every file is written to a temporary name beside its target and renamed into place, and a run's
directory is built under a staging name and renamed at the end, so an interruption never leaves a
half-written file or a half-filled output directory.
"""

import contextlib
import csv
import json
import os
import shutil
import tempfile
from pathlib import Path

import healpy as hp
import numpy as np

FITS_HEADER = [
    ("POLCCONV", "COSMO", "Q/U polarisation convention (HEALPix)"),
    ("COORDSYS", "C", "equatorial coordinates"),
    ("TUNIT", "uK", "maps in micro-Kelvin CMB"),
    ("CREATOR", "boresight", ""),
]


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success, else delete."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    os.close(fd)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def write_maps(path, maps, names, unit="uK"):
    """Write RING maps (nmap, npix) as a FITS table healpy.read_map reads, with units and
    conventions in the header; healpy.UNSEEN marks invalid pixels."""
    with atomic_path(path) as tmp:
        hp.write_map(
            tmp,
            np.asarray(maps, dtype=np.float64),
            column_names=list(names),
            column_units=[unit] * len(names),
            extra_header=FITS_HEADER,
            overwrite=True,
            dtype=np.float64,
        )


def write_csv(path, rows, columns):
    """Write a list of dicts as CSV with the given column order."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns)
        w.writeheader()
        for row in rows:
            w.writerow({k: row.get(k, "") for k in columns})


def write_json(path, data):
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        json.dump(data, f, indent=2, default=_jsonable)
        f.write("\n")


def write_text(path, text):
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        f.write(text)


def _jsonable(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (np.ndarray, tuple)):
        return list(obj)
    return str(obj)


def check_output_dir(path, force):
    """Refuse to overwrite an existing non-empty directory unless ``force`` (before any work)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"output path {path} exists and is not a directory")
    if path.is_dir() and any(path.iterdir()) and not force:
        raise FileExistsError(f"output directory {path} exists; use --force to overwrite it")


@contextlib.contextmanager
def staged_dir(path, force=False):
    """Yield a staging directory that replaces ``path`` when the block finishes without error."""
    path = Path(path)
    check_output_dir(path, force)
    path.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{path.name}.staging.", dir=path.parent))
    try:
        yield stage
        if path.exists():
            shutil.rmtree(path)
        os.replace(stage, path)
    finally:
        if stage.exists():
            shutil.rmtree(stage)
