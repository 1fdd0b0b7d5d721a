"""Files in and out: TOML read (a byte-order mark dropped), and outputs written atomically: FITS maps
healpy reads, CSV tables, JSON, and output directories.

Every file is written to a temporary name beside its target and renamed into place, and a run's
directory is built under a staging name and renamed at the end, so an interruption never leaves a
half-written file or a half-filled output directory.
"""

from __future__ import annotations

import contextlib
import csv
import glob
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

from ..validation import OutputError, OutputExistsError
from . import interrupts

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator, Sequence


#: header cards of every map file; units are per column (TUNITn), set by :func:`write_maps`
FITS_HEADER = [
    ("POLCCONV", "COSMO", "Q/U polarisation convention (HEALPix)"),
    ("CREATOR", "boresight", ""),
]
#: the cards of each sky frame (boresight.frames.FRAMES): HEALPix's COORDSYS and, for the
#: equatorial frames, FITS's RADESYS
FRAME_CARDS = {
    "icrs": [("COORDSYS", "C", "equatorial coordinates"), ("RADESYS", "ICRS", "")],
    "galactic": [("COORDSYS", "G", "Galactic coordinates")],
    "cirs": [("COORDSYS", "C", "equatorial coordinates of date"), ("RADESYS", "CIRS", "")],
}
#: the file that marks a directory as boresight's own: only such a directory is ever replaced
MARKER = ".boresight-output"


def _umask() -> int:
    """The process's umask (read by setting it, then setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _refuse_special(path: Path) -> None:
    """OutputError for an existing path that is not a regular file (a FIFO, a device, a socket):
    renaming a file onto it would replace it."""
    if path.exists() and not path.is_file():
        raise OutputError(
            f"{path} exists and is not a regular file (a FIFO or device?); not replacing it"
        )


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[str]:
    """A temporary path beside ``path``, renamed onto it when the block succeeds, else deleted.

    The file gets the permissions a new file would (0666 less the umask), not mkstemp's 0600.
    A ``path`` that exists and is not a regular file is refused.

    Parameters
    ----------
    path : str or pathlib.Path

    Yields
    ------
    str
    """
    path = Path(path)
    _refuse_special(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())
        _refuse_special(path)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def toml_text(path: str) -> dict:
    """The parsed TOML of a UTF-8 file, a byte-order mark (which tomllib refuses) dropped.

    Parameters
    ----------
    path : str

    Returns
    -------
    dict

    Raises
    ------
    OSError, UnicodeDecodeError, tomllib.TOMLDecodeError
    """
    with open(path, encoding="utf-8-sig") as f:
        return tomllib.loads(f.read())


def write_maps(
    path: str | os.PathLike,
    maps: np.ndarray,
    names: Sequence[str],
    units: Sequence[str],
    *,
    comments: Sequence[str] = (),
    frame: str = "icrs",
    observed: np.ndarray | None = None,
) -> None:
    """Write RING maps as a FITS table healpy.read_map reads.

    Parameters
    ----------
    path : pathlib.Path
    maps : array_like, shape (nmap, npix)
        healpy.UNSEEN marks invalid pixels.
    names : list of str
        One column name per map.
    units : list of str
        One unit per map ("" for counts and ratios: no TUNIT card).
    comments : list of str
        COMMENT cards.
    frame : {"icrs", "galactic", "cirs"}
        The maps' sky frame, in their COORDSYS (and RADESYS) cards.
    observed : numpy.ndarray of bool, optional
        Write a HEALPix partial map of these pixels (explicit indexing: a PIXEL column beside
        the maps' values there), which healpy.read_map reads back on the sky with UNSEEN
        elsewhere; default the whole sky.
    """
    if len(units) != len(names):
        raise ValueError(f"{len(names)} column names but {len(units)} units")
    if frame not in FRAME_CARDS:
        raise ValueError(f"frame = {frame!r}; allowed: {tuple(FRAME_CARDS)}")
    maps = np.array(maps, dtype=np.float64, ndmin=2)
    if observed is not None:  # healpy takes the pixels of the first map that are not UNSEEN
        if not np.any(observed):
            raise ValueError("a partial map of no observed pixel")
        maps[0] = np.where(observed, maps[0], hp.UNSEEN)
    with atomic_path(path) as tmp:
        hp.write_map(
            tmp,
            maps,
            column_names=list(names),
            column_units=list(units),
            extra_header=FITS_HEADER + FRAME_CARDS[frame] + [("COMMENT", c) for c in comments],
            overwrite=True,
            dtype=np.float64,
            partial=observed is not None,
        )


def fits_map_shape(path: str) -> tuple[int, int]:
    """The shape of a HEALPix FITS map file, from its header only.

    Parameters
    ----------
    path : str

    Returns
    -------
    nfields : int
    npix : int

    Raises
    ------
    ValueError
        Naming the file, when it is not a FITS binary table of HEALPix maps.
    """
    from astropy.io import fits  # a dependency of healpy

    try:
        with fits.open(path, memmap=True) as hdus:
            if len(hdus) < 2 or not isinstance(hdus[1], fits.BinTableHDU):
                raise ValueError("no binary table in extension 1")
            header = hdus[1].header
            nside = header.get("NSIDE")
            nfields = int(header["TFIELDS"])
            npix = 12 * int(nside) ** 2 if nside else int(header["NAXIS2"])
    except (OSError, KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{path} is not a HEALPix FITS map ({err})") from None
    return nfields, npix


def write_csv(path: str | os.PathLike, rows: list[dict], columns: Sequence[str]) -> None:
    """Write rows as CSV, atomically.

    Parameters
    ----------
    path : pathlib.Path
    rows : list of dict
    columns : sequence of str
        The column order; missing keys are empty.
    """
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns)
        w.writeheader()
        for row in rows:
            w.writerow({k: row.get(k, "") for k in columns})


def write_npz(path: str | os.PathLike, **arrays) -> None:
    """Write arrays as an uncompressed NPZ, atomically.

    Parameters
    ----------
    path : pathlib.Path
    **arrays
        Name -> array.
    """
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)


def write_json(path: str | os.PathLike, data: object) -> None:
    """Write data as indented JSON, atomically (numpy values converted).

    Parameters
    ----------
    path : pathlib.Path
    data : object
    """
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        json.dump(data, f, indent=2, default=_jsonable)
        f.write("\n")


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write text, atomically.

    Parameters
    ----------
    path : pathlib.Path
    text : str
    """
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        f.write(text)


def _jsonable(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (np.ndarray, tuple)):
        return list(obj)
    return str(obj)


def check_output_path(path: str | os.PathLike, inputs: Iterable[str] = ()) -> Path:
    """Check, before any work, that a path is a safe place for an output directory.

    Refused: a symlink; the current directory, one of its ancestors or the home directory; a
    directory that is or holds one of ``inputs``; an existing file; a place where no directory can
    be created. Stale staging directories of killed runs beside it are removed.

    Parameters
    ----------
    path : str or pathlib.Path
    inputs : iterable of str
        Input files (or directories) of the run.

    Returns
    -------
    pathlib.Path
        The resolved path.

    Raises
    ------
    OutputError
    """
    path = Path(path)
    if path.is_symlink():
        raise OutputError(f"output path {path} is a symbolic link; give the real directory")
    target = path.resolve()
    cwd = Path.cwd().resolve()
    if target == cwd or target in cwd.parents or target == Path.home().resolve():
        raise OutputError(
            f"output path {path} is the current directory, one of its parents or the home "
            "directory; give a new directory for the outputs"
        )
    for item in inputs:  # files, or directories whose contents are inputs
        if item is not None and (
            target == Path(item).resolve() or target in Path(item).resolve().parents
        ):
            raise OutputError(f"output directory {path} holds the input {item}")
    if target.exists() and not target.is_dir():
        raise OutputError(f"output path {path} exists and is not a directory")
    _check_name(target)
    _check_writable(target.parent)
    _remove_stale(target)
    return target


def check_output_file(path: str | os.PathLike, force: bool, inputs: Iterable[str] = ()) -> Path:
    """Check, before any work, that a single output file may be written.

    Refused: a symlink, a directory, one of ``inputs``, an existing file without ``force``, a
    directory that cannot be written. The file itself is written atomically (:func:`atomic_path`).

    Parameters
    ----------
    path : str or pathlib.Path
    force : bool
        Replace an existing file.
    inputs : iterable of str

    Returns
    -------
    pathlib.Path
        The resolved path.

    Raises
    ------
    OutputError
    """
    path = Path(path)
    target = path.resolve()
    if path.is_symlink() or target.is_dir():
        raise OutputError(f"output file {path} is a symbolic link or a directory")
    _refuse_special(target)
    if any(item is not None and target == Path(item).resolve() for item in inputs):
        raise OutputError(f"output file {path} is an input of the run")
    if target.exists() and not force:
        raise OutputError(f"output file {path} exists; --force replaces it")
    if not target.parent.is_dir():
        raise OutputError(f"the directory of the output file {path} does not exist; create it")
    _check_name(target)
    _check_writable(target.parent)
    return target


#: the longest output name: its staging name (".NAME.staging.PID.XXXXXXXX") must fit in 255 bytes
MAX_NAME_BYTES = 200


def _check_name(target):
    if len(os.fsencode(target.name)) > MAX_NAME_BYTES:
        raise OutputError(
            f"the output name {target.name[:40]}... is {len(os.fsencode(target.name))} bytes; "
            f"at most {MAX_NAME_BYTES} (file names hold 255, and its staging name is longer)"
        )


def is_own(path: str | os.PathLike) -> bool:
    """Whether a path is a directory that boresight created (it holds :data:`MARKER`).

    Parameters
    ----------
    path : str or pathlib.Path

    Returns
    -------
    bool
    """
    path = Path(path)
    return not path.is_symlink() and (path / MARKER).is_file()


def check_output_dir(path: str | os.PathLike, force: bool, inputs: Iterable[str] = ()) -> None:
    """:func:`check_output_path`; and a non-empty directory is refused unless ``force`` and
    boresight created it.

    Parameters
    ----------
    path : str or pathlib.Path
    force : bool
    inputs : iterable of str

    Raises
    ------
    OutputError, OutputExistsError
    """
    target = check_output_path(path, inputs)
    if target.is_dir() and any(target.iterdir()):
        if not force:
            raise OutputExistsError(f"output directory {path} exists; use --force to overwrite it")
        if not is_own(target):
            raise OutputError(
                f"output directory {path} was not written by boresight (no {MARKER}); "
                "remove it yourself or choose another --out"
            )


def _check_writable(directory):
    """Create and remove a probe in the nearest existing ancestor of ``directory``."""
    existing = directory
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(f"cannot create the output directory: {existing} is not a directory")
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".boresight-probe.", dir=existing))
    except OSError as err:
        raise OutputError(f"cannot write in {existing}: {err.strerror}") from None


def _stage_name(target, kind):
    return f".{target.name}.{kind}.{os.getpid()}."


def _remove_stale(target):
    """Remove staging and replaced directories of ``target`` left by runs that were killed."""
    if not target.parent.is_dir():
        return
    for kind in ("staging", "old"):
        for stale in target.parent.glob(f".{glob.escape(target.name)}.{kind}.*"):
            try:
                pid = int(stale.name[len(target.name) + len(kind) + 3 :].split(".")[0])
            except ValueError:
                continue
            if stale.is_dir() and (stale / MARKER).exists() and not _alive(pid):
                shutil.rmtree(stale, ignore_errors=True)


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def make_output_dir(path: str | os.PathLike) -> Path:
    """Create a directory (and its parents) as boresight's own, marked with :data:`MARKER`.

    Parameters
    ----------
    path : str or pathlib.Path

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    (path / MARKER).touch()
    return path


def remove_output_dir(path: str | os.PathLike) -> None:
    """Remove a directory that boresight created; refuse any other.

    Parameters
    ----------
    path : str or pathlib.Path

    Raises
    ------
    OutputError
        The directory has no :data:`MARKER` or is a symlink.
    """
    path = Path(path)
    if not is_own(path):
        raise OutputError(f"{path} was not written by boresight (no {MARKER}); not removing it")
    shutil.rmtree(path)


def _swap_in(stage, target, path):
    """Rename ``stage`` to ``target`` unless something else wrote ``target`` since the checks:
    the rename replaces at most an empty directory, in one step, so a second run into the same
    ``--out`` cannot replace the first's output without ``--force``."""
    try:
        os.rename(stage, target)
    except OSError as err:
        if not target.exists():
            raise
        raise OutputExistsError(
            f"output directory {path} gained files while this run ran (another run's output, or "
            "the user's); it is kept as it is and this run's output was discarded (use --force "
            "to replace boresight's own output)"
        ) from err


@contextlib.contextmanager
def staged_dir(
    path: str | os.PathLike, force: bool = False, inputs: Iterable[str] = ()
) -> Iterator[Path]:
    """A staging directory that replaces ``path`` when the block finishes without error.

    The checks of :func:`check_output_dir` run again first. The staging directory carries
    :data:`MARKER`; a replaced output is renamed aside before the staging directory takes its place
    and removed after, so a kill at any moment leaves either the old or the new output (and at most
    a hidden staging or old directory, which the next run removes).

    Parameters
    ----------
    path : str or pathlib.Path
    force : bool
    inputs : iterable of str

    Yields
    ------
    pathlib.Path
    """
    path = Path(path)
    check_output_dir(path, force, inputs)
    target = path.resolve()
    target.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=_stage_name(target, "staging"), dir=target.parent))
    try:
        os.chmod(stage, 0o777 & ~_umask())  # mkdtemp's is 0700: collaborators could not read
        (stage / MARKER).touch()
        yield stage
        interrupts.check()  # the last moment at which nothing has been replaced
        old = None
        if not force:
            _swap_in(stage, target, path)
            return
        if target.exists() and not is_own(target):
            os.rmdir(target)  # an empty directory of the user's; fails if it has gained files
        elif target.exists():
            old = Path(tempfile.mkdtemp(prefix=_stage_name(target, "old"), dir=target.parent))
            (old / MARKER).touch()
            os.replace(target, old / "replaced")
        os.replace(stage, target)
        if old is not None:
            shutil.rmtree(old)
    finally:
        if stage.exists():
            shutil.rmtree(stage)
