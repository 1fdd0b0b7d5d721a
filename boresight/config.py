"""The study: one config model for every command, read from TOML or built in Python.

A study file has one table per pipeline stage. Each table is a frozen dataclass that owns its
defaults, its allowed values and its validation: ``[sky]`` :class:`~boresight.sky.SkyConfig`,
``[scan]`` :class:`~boresight.scan.SyntheticScan`, ``[instrument]``
:class:`~boresight.instrument.pairs.Instrument`, ``[systematics]``
:class:`~boresight.instrument.pairs.Systematics`, ``[mask]`` :class:`MaskSpec`, ``[run]``
:class:`RunOptions` and ``[output]`` :class:`OutputOptions`. The schema below (types and help of
every key), the error messages and the command-line flags (:func:`add_flags`) are read from their
fields. A config is validated whole before any work starts: unknown sections or keys, wrong types,
values out of range and missing files raise :class:`ConfigError` naming the key and the file.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
from contextlib import contextmanager
from dataclasses import dataclass, replace

import healpy as hp
import numpy as np

from . import validation
from ._util import io
from ._util.io import toml_text, tomllib
from ._util.threads import check_threads
from .constants import ARCMIN
from .evaluation import METHODS
from .harmonics import ANALYSES
from .instrument.added import REGISTRY, split_table
from .instrument.beams import pair_beams
from .instrument.focalplane import focalplane_of_table
from .instrument.hwp import HWP, behind, reflected_systematics
from .instrument.pairs import Instrument, Spread, Systematics, response
from .kernels import BACKENDS
from .mapmaking import RCOND_MIN
from .masks import MaskSpec
from .scan import SyntheticScan
from .sky import Sky, SkyConfig, make_sky
from .spectra import log_bins
from .validation import ConfigError, option


def check_backend(name, backend):
    """Check a backend name, and that CuPy is installed for 'gpu'.

    Parameters
    ----------
    name : str
        The option's name in messages (``run.backend``, ``--backend``).
    backend : str

    Raises
    ------
    ConfigError
    """
    if backend not in BACKENDS:
        raise ConfigError(f"{name} = {backend!r}; allowed: {BACKENDS}")
    if backend == "gpu" and importlib.util.find_spec("cupy") is None:
        raise ConfigError(f"{name} = 'gpu' needs CuPy: pip install 'boresight[gpu]'")


@dataclass(frozen=True)
class RunOptions:
    """How the engine runs: the ``[run]`` table. Results do not depend on chunk_pixels, nthreads or
    the backend.

    Parameters
    ----------
    evaluation : {"interp", "exact"}
        The sky at each hit: bilinear interpolation, or exact band-limited evaluation.
    backend : {"cpu", "gpu"}
    chunk_pixels : int, optional
        Pixels per chunk (default: the backend's).
    nthreads : int
        CPU threads, 0 for all the cores this process may use (its CPU affinity).
    analysis : str
        How masked maps become pseudo-alm (:func:`boresight.harmonics.map2alm`): "auto" (one
        pass with ring weights at lmax <= 2 nside, LSQR above), "ring_weights", "jacobi"
        (healpy.anafast's 3 iterations) or "lsqr".
    rcond_min : float
        The map-maker's cut: pixels whose 2x2 (Q, U) system has a smaller reciprocal condition
        number are invalid (0 in the maps the spectra read), in [0, 1) (a 2x2 system's rcond is
        ``(1 - |h_4|) / (1 + |h_4|)``, at most 1).
    """

    evaluation: str = option("interp", "the sky at each hit", choices=METHODS)
    backend: str = option("cpu", "kernels: numba (cpu) or CuPy (gpu)", choices=BACKENDS)
    chunk_pixels: int = option(None, "pixels per chunk, >= 1 (default: the backend's)", (int,))
    nthreads: int = option(0, "CPU threads, 0 for all the cores this process may use")
    analysis: str = option("auto", "masked maps -> pseudo-alm", choices=ANALYSES)
    rcond_min: float = option(RCOND_MIN, "the map-maker's cut on each pixel's rcond, in [0, 1)")

    def __post_init__(self):
        if self.evaluation not in METHODS:
            raise ValueError(f"evaluation = {self.evaluation!r}; allowed: {METHODS}")
        check_backend("backend", self.backend)
        if self.chunk_pixels is not None:
            validation.integer("chunk_pixels", self.chunk_pixels, 1)
        check_threads("nthreads", self.nthreads)
        if self.analysis not in ANALYSES:
            raise ValueError(f"analysis = {self.analysis!r}; allowed: {ANALYSES}")
        if not 0.0 <= validation.number("rcond_min", self.rcond_min, 0.0) < 1.0:
            raise ValueError(f"rcond_min must be in [0, 1), got {self.rcond_min!r}")

    def engine_kwargs(self):
        """The keyword arguments :func:`boresight.engine.simulate` takes from these options.

        Returns
        -------
        dict
        """
        return dict(
            evaluation=self.evaluation,
            backend=self.backend,
            chunk_pixels=self.chunk_pixels,
            nthreads=self.nthreads,
            rcond_min=self.rcond_min,
        )


@dataclass(frozen=True)
class OutputOptions:
    """What a study writes: the ``[output]`` table.

    Parameters
    ----------
    lmax : int, optional
        Highest multipole of the spectra; default min(sky.lmax, 2 nside), set by :meth:`resolved`.
    n_bands : int
        About this many logarithmic ell bands.
    lmin : int
        Lowest multipole of the bands.
    maps : bool
        Write the FITS maps.
    """

    lmax: int = option(
        None, "highest multipole of the spectra (default min(sky.lmax, 2 nside))", (int,)
    )
    n_bands: int = option(14, "logarithmic ell bands, >= 1")
    lmin: int = option(20, "lowest multipole of the bands, >= 2")
    maps: bool = option(True, "write the FITS maps")

    def resolved(self, sky):
        """These options with lmax set for a sky and checked against it.

        Parameters
        ----------
        sky : boresight.sky.SkyConfig

        Returns
        -------
        OutputOptions
        """
        lmax = min(sky.lmax, 2 * sky.nside) if self.lmax is None else self.lmax
        validation.integer("lmax", lmax, 2, 3 * sky.nside - 1)
        validation.integer("n_bands", self.n_bands, 1)
        validation.integer("lmin", self.lmin, 2)
        if self.lmin >= lmax:
            origin = (
                f"min(sky.lmax, 2 x sky.nside) for sky.nside = {sky.nside}"
                if self.lmax is None
                else "given"
            )
            raise ValueError(
                f"lmin = {self.lmin} must be below lmax = {lmax} ({origin}); raise sky.nside or "
                "lmax, or lower lmin"
            )
        return replace(self, lmax=lmax)

    def edges(self):
        """Band edges.

        Returns
        -------
        numpy.ndarray of int
            About n_bands logarithmic edges from lmin to lmax + 1
            (:func:`boresight.spectra.log_bins`).
        """

        return log_bins(self.lmin, self.lmax, self.n_bands)


#: the tables of a study file and the dataclass behind each
SECTIONS = {
    "sky": SkyConfig,
    "scan": SyntheticScan,
    "instrument": Instrument,
    "systematics": Systematics,
    "mask": MaskSpec,
    "run": RunOptions,
    "output": OutputOptions,
}
#: keys that name input files rather than dataclass fields
FILE_KEYS = {
    "sky": {"maps": ((str,), "a FITS file with I, Q, U maps (RING) instead of a random sky")},
    "systematics": {"leak_template": ((str,), "a FITS map the additive leak scales")},
    "instrument": {
        "focalplane": (
            (str,),
            "a focal-plane file (TOAST HDF5, CSV, TOML) or preset ('axis') whose pairs all sit on "
            "the boresight: its pairs' angles",
        ),
        "hwp": (
            (str,),
            "a half-wave plate in front of the pairs: none, continuous (its angle uniform per "
            "hit) or stepped (one of hwp_angles_deg per rotation repeat)",
        ),
        "hwp_angles_deg": ((list,), "a stepped HWP's angles, one per repeat in turn [deg]"),
    },
}


#: the tables of a pipeline a study cannot take, and the command-line flag that runs each
PIPELINE_FLAGS = {"filter": "--filter p3+ground", "deprojection": "--deproject gain"}


def schema() -> dict:
    """The schema of a study file, read from the section dataclasses.

    Returns
    -------
    dict
        section -> key -> (allowed TOML types, help text).
    """
    return {
        section: {
            **{
                f.name: (f.metadata["types"], _help(f))
                for f in dataclasses.fields(cls)
                if f.metadata
            },
            **FILE_KEYS.get(section, {}),
            **(_added_keys() if section == "systematics" else {}),
        }
        for section, cls in SECTIONS.items()
    }


def _added_keys() -> dict:
    """The registered added systematics' keys (:mod:`boresight.instrument.added`), as
    :func:`schema` gives a key."""
    return {
        key: ((int, float, list, dict), one.help or f"added systematic {key}")
        for key, one in REGISTRY.items()
    }


def _help(f):
    choices = f.metadata.get("choices")
    return f.metadata["help"] + (f"; one of {choices}" if choices else "")


@dataclass(frozen=True)
class Study:
    """A validated study: one dataclass per table of a study file.

    Parameters
    ----------
    sky : boresight.sky.SkyConfig
    scan : boresight.scan.SyntheticScan
    instrument : boresight.instrument.pairs.Instrument
    systematics : boresight.instrument.pairs.Systematics
    mask : MaskSpec
    run : RunOptions
    output : OutputOptions
        Resolved against ``sky`` on construction.
    sky_maps : str, optional
        FITS file of I, Q, U replacing the random sky.
    leak_template : str, optional
        FITS map of the additive leak.
    raw : dict, optional
        The parsed TOML the study came from.
    source : str, optional
        The TOML file it was read from.
    hwp : boresight.instrument.hwp.HWP, optional
        ``[instrument] hwp``: a HWP in front of the pairs. ``scan``, ``instrument`` and
        ``systematics`` are then the bare ones that see the sky as the pairs behind it do
        (:func:`boresight.instrument.hwp.behind`, :func:`boresight.instrument.hwp.reflected_systematics`).
    """

    sky: SkyConfig
    scan: SyntheticScan = SyntheticScan()
    instrument: Instrument = Instrument()
    systematics: Systematics = Systematics()
    mask: MaskSpec = MaskSpec()
    run: RunOptions = RunOptions()
    output: OutputOptions = OutputOptions()
    sky_maps: str = None  #: FITS file of I, Q, U replacing the random sky
    leak_template: str = None  #: FITS map of the additive leak
    raw: dict = None  #: the parsed TOML the study came from
    source: str = None  #: the TOML file it was read from
    hwp: HWP = None  #: the HWP in front of the pairs (scan and instrument are then behind it)

    def __post_init__(self):
        object.__setattr__(self, "output", self.output.resolved(self.sky))

    @property
    def inputs(self):
        """The files the study reads (an output directory may not hold them)."""
        return [f for f in (self.source, self.sky_maps, self.leak_template, self.mask.file) if f]

    def load_sky(self) -> Sky:
        """The study's sky: the seeded realisation of [sky], or the I, Q, U maps of its sky.maps
        file (alm computed)."""
        if self.sky_maps is None:
            return make_sky(self.sky, nthreads=self.run.nthreads)
        maps = hp.read_map(self.sky_maps, field=(0, 1, 2))
        return Sky.from_maps(
            maps,
            lmax=self.sky.lmax,
            fwhm_arcmin=self.sky.fwhm_arcmin,
            nthreads=self.run.nthreads,
        )

    def load_leak_template(self) -> np.ndarray | None:
        """The (npix,) map of systematics.leak_template [muK], or None: the leak scales the
        sky's I."""
        return None if self.leak_template is None else hp.read_map(self.leak_template)


def add_flags(parser, cls, names=None, paper_defaults=False):
    """Add ``--name`` flags for fields of a section dataclass.

    Parameters
    ----------
    parser : argparse.ArgumentParser
    cls : type
        A section dataclass whose fields carry :func:`boresight.validation.option` metadata.
    names : iterable of str, optional
        The fields to expose (default: all).
    paper_defaults : bool
        Say in the help that the paper's preset sets the default (instead of the field's default).

    Notes
    -----
    Flags default to None, "not given", so the caller applies only what the user set.
    """
    for f in dataclasses.fields(cls):
        if names is not None and f.name not in names or not f.metadata:
            continue
        types = [t for t in f.metadata["types"] if t in (int, float, str)]
        kind = float if float in types else types[0] if types else str
        parser.add_argument(
            "--" + f.name.replace("_", "-"),
            type=kind,
            choices=f.metadata.get("choices"),
            help=_help(f)
            + (
                " (default: the paper's)"
                if paper_defaults
                else f" (default {f.default})"
                if f.default is not None
                else ""
            ),
        )


def check_types(raw):
    """Check a raw study's sections, keys and value types against :func:`schema`.

    Parameters
    ----------
    raw : dict

    Raises
    ------
    ConfigError
        An unknown section or key, or a value of the wrong type, naming section.key.
    """
    known = schema()
    for section, body in raw.items():
        if section in PIPELINE_FLAGS:  # a pipeline's, on a real schedule only
            raise ConfigError(
                f"[{section}]: a study's scan is synthetic, without the throws and CESs a "
                "pipeline filters or deprojects; run a real schedule through `boresight "
                f"suppression {PIPELINE_FLAGS[section]} --schedule ...` or a design budget's "
                f"[{section}]"
            )
        if section not in known:
            raise ConfigError(f"unknown section [{section}]; allowed: {sorted(known)}")
        if not isinstance(body, dict):
            raise ConfigError(f"[{section}] must be a table")
        for key, value in body.items():
            if key not in known[section]:
                raise ConfigError(f"unknown key {section}.{key}; allowed: {sorted(known[section])}")
            types, allowed = known[section][key]
            bad_bool = isinstance(value, bool) and bool not in types
            if bad_bool or not isinstance(value, types):
                raise ConfigError(
                    f"{section}.{key} = {value!r} has the wrong type; allowed: {allowed}"
                )


def check_systematics(
    systematics: Systematics,
    instrument: Instrument,
    rotations_deg: tuple,
    fwhm_arcmin: float,
) -> None:
    """What the focal plane's drawn values must pass before any work, in a study, a budget or a
    suppression map alike: lists as long as the pairs and the repeats, detector B's gain in
    [0, 2] for every (pair, repeat), and beams that the sky's beam can carry.

    Parameters
    ----------
    systematics : boresight.instrument.pairs.Systematics
    instrument : boresight.instrument.pairs.Instrument
    rotations_deg : sequence of float
        The rotation repeats of the scan.
    fwhm_arcmin : float
        The sky's beam.

    Raises
    ------
    ValueError
    """
    params = systematics.per_pair(instrument.n_pairs)
    rotations = np.radians(np.asarray(rotations_deg, dtype=np.float64))
    try:
        response(
            rotations, instrument.pair_angles_rad, params, systematics.per_repeat(rotations.size)
        )
    except ValueError as err:
        drawn = [k for k in ("dg", "dg_repeat") if isinstance(getattr(systematics, k), Spread)]
        if not drawn:
            raise
        spreads = ", ".join(f"{k} = {getattr(systematics, k)}" for k in drawn)
        raise ValueError(f"{err}, drawn from {spreads}") from None
    if systematics.has_beams:
        pair_beams(params, fwhm_arcmin * ARCMIN)


def _file(section, key, path, base):
    full = path if os.path.isabs(path) else os.path.join(base, path)
    if not os.path.isfile(full):
        raise ConfigError(f"{section}.{key}: file not found (or not a file): {full}")
    return full


def _fits(section, key, path, base, min_fields=1, npix=None):
    """The full path of a HEALPix FITS file, checked from its header: at least ``min_fields``
    columns and, when given, ``npix`` pixels."""
    full = _file(section, key, path, base)
    try:
        nfields, have = io.fits_map_shape(full)
    except ValueError as err:
        raise ConfigError(f"{section}.{key}: {err}") from None
    if nfields < min_fields:
        raise ConfigError(f"{section}.{key}: {full} has {nfields} map(s); needs {min_fields}")
    if npix is not None and have != npix:
        raise ConfigError(f"{section}.{key}: {full} has {have} pixels; sky.nside needs {npix}")
    return full


def _map_or_value(section, key, value, base, dtype, npix):
    if isinstance(value, str):
        import healpy as hp

        m = hp.read_map(_fits(section, key, value, base, npix=npix))
        if not np.isfinite(m).all():
            raise ConfigError(f"{section}.{key}: the map holds NaN or infinite values")
        return m.astype(dtype)
    return value


def build_section(section, cls, kwargs):
    """A section dataclass from a table, its errors as ConfigError.

    Parameters
    ----------
    section : str
    cls : type
    kwargs : dict

    Returns
    -------
    object
        ``cls(**kwargs)``.

    Raises
    ------
    ConfigError
        Naming section.key where the message starts with a field's name.
    """
    with section_errors(section, cls, kwargs):
        return cls(**kwargs)


@contextmanager
def section_errors(section, cls, kwargs):
    """Refuse keys of a table that are not fields of ``cls``, and turn the ValueError or
    TypeError of the block (``cls(**kwargs)``, made by the caller's own layer) into a
    ConfigError naming section.key where the message starts with a field's name.

    Parameters
    ----------
    section : str
    cls : type
        A dataclass.
    kwargs : dict

    Raises
    ------
    ConfigError
    """
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(kwargs) - names)
    if unknown:
        raise ConfigError(f"unknown key {section}.{unknown[0]}; allowed: {sorted(names)}")
    try:
        yield
    except (ValueError, TypeError) as err:
        text = str(err)
        where = f"{section}." if text.split(" ")[0] in names else f"[{section}] "
        raise ConfigError(where + text) from None


def read_toml(path: str, what: str = "config") -> dict:
    """The parsed TOML of a file.

    Parameters
    ----------
    path : str
    what : str
        What the file is, for messages ("config", "sweep", "sweep base").

    Returns
    -------
    dict

    Raises
    ------
    ConfigError
        The file is missing, not a file, or not valid UTF-8 TOML.
    """
    if not os.path.isfile(path):
        raise ConfigError(f"{what} file not found (or not a file): {path}")
    try:
        return toml_text(path)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path} is not valid TOML: {err}") from None


def load_study(path: str) -> Study:
    """Read and validate a TOML study file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    Study
        With ``source`` set to ``path``.

    Raises
    ------
    ConfigError
        Naming the file and the key.
    """
    raw = read_toml(path)
    try:
        study = parse_study(raw, os.path.dirname(os.path.abspath(path)))
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None
    return replace(study, source=str(path))


def _tuples(body, keys):
    return {k: tuple(v) if k in keys and isinstance(v, list) else v for k, v in body.items()}


def _hwp(table):
    """The HWP of [instrument]'s hwp keys, or None (the table without them, too)."""
    keys = {"hwp", "hwp_angles_deg"}
    rest = {k: v for k, v in table.items() if k not in keys}
    mode = table.get("hwp", "none")
    if mode == "none":
        if "hwp_angles_deg" in table:
            raise ConfigError("[instrument] hwp_angles_deg needs hwp = 'stepped'")
        return None, rest
    try:
        angles = table.get("hwp_angles_deg", HWP.angles_deg)
        return HWP(mode, angles_deg=tuple(angles), step="repeat"), rest
    except ConfigError as err:
        raise ConfigError(f"[instrument] {err}") from None


def _instrument(table, base):
    """[instrument]: its own keys, or a focal plane whose pairs all sit on the boresight (a
    synthetic scan has no pointing to move pairs off it)."""
    if "focalplane" not in table:
        return build_section("instrument", Instrument, _tuples(table, ("pair_angles_deg",)))
    focal = focalplane_of_table(table, base)
    if not focal.is_on_axis:
        raise ConfigError(
            f"[instrument] focalplane {focal.source!r}: its pairs sit up to "
            f"{np.max(focal.radius_deg):.3g} deg off the boresight, and a study's synthetic scan "
            "has no pointing to move them there; give the focal plane with a schedule instead "
            "(scan-stats, compare-scans or design --focalplane, or a budget's [instrument] "
            "focalplane)"
        )
    return Instrument(pair_angles_deg=focal.pair_angles_deg)


def parse_study(raw: dict, base: str = ".") -> Study:
    """Validate a study given as a dict (the parsed TOML).

    Parameters
    ----------
    raw : dict
        Tables as in a study file; ``sky.nside`` is required.
    base : str
        Directory that relative file paths start from.

    Returns
    -------
    Study

    Raises
    ------
    ConfigError
        An unknown section or key, a wrong type, a value out of range, a missing or bad file.
    """
    check_types(raw)
    sky_raw = dict(raw.get("sky", {}))
    if "nside" not in sky_raw:
        raise ConfigError("sky.nside is required (a power of two; the paper's 2048 needs ~20 GiB)")
    sky_maps = sky_raw.pop("maps", None)
    sky_cfg = build_section("sky", SkyConfig, sky_raw)
    npix = 12 * sky_cfg.nside**2
    if sky_maps is not None:
        sky_maps = _fits("sky", "maps", sky_maps, base, min_fields=3, npix=npix)
    scan_raw = _tuples(raw.get("scan", {}), ("rotations_deg",))
    for key, dtype in (("n_phi", np.int64), ("range_rad", np.float64), ("centre_rad", np.float64)):
        if key in scan_raw:
            scan_raw[key] = _map_or_value("scan", key, scan_raw[key], base, dtype, npix)
    scan = build_section("scan", SyntheticScan, scan_raw)
    hwp, instrument_raw = _hwp(raw.get("instrument", {}))
    instrument = _instrument(instrument_raw, base)
    sys_raw = dict(raw.get("systematics", {}))
    template = sys_raw.pop("leak_template", None)
    if template is not None:
        template = _fits("systematics", "leak_template", template, base, npix=npix)
    sys_raw, added = split_table(_tuples(sys_raw, set(sys_raw)))
    systematics = build_section(
        "systematics", Systematics, sys_raw | ({"added": added} if added else {})
    )
    if hwp is not None:
        try:
            systematics = reflected_systematics(hwp, systematics)
        except ValueError as err:
            raise ConfigError(f"[systematics] {err}") from None
        scan, instrument = behind(hwp, scan, instrument)
    try:
        check_systematics(systematics, instrument, scan.rotations_deg, sky_cfg.fwhm_arcmin)
    except ValueError as err:
        raise ConfigError(f"[systematics] {err}") from None
    mask_raw = dict(raw.get("mask", {}))
    if "file" in mask_raw:
        if "survey" in mask_raw:
            raise ConfigError("[mask] give either survey or file, not both")
        mask_raw["file"] = _fits("mask", "file", mask_raw["file"], base)
    mask = build_section("mask", MaskSpec, mask_raw)
    run = build_section("run", RunOptions, raw.get("run", {}))
    output = build_section("output", OutputOptions, raw.get("output", {}))
    try:
        return Study(
            sky_cfg,
            scan,
            instrument,
            systematics,
            mask,
            run,
            output,
            sky_maps,
            template,
            raw,
            hwp=hwp,
        )
    except (ValueError, TypeError) as err:
        raise ConfigError(f"[output] {err}") from None


def as_dict(study: Study) -> dict:
    """A study's sections as plain dicts, for manifests.

    Parameters
    ----------
    study : Study

    Returns
    -------
    dict
    """
    out = {
        section: dataclasses.asdict(getattr(study, section))
        for section in SECTIONS
        if not (section == "mask" and study.mask is None)
    }
    added = dict(out["systematics"].pop("added"))  # beside the built-in keys, as they are read
    out["systematics"] |= added
    return out | {"sky_maps": study.sky_maps, "leak_template": study.leak_template}
