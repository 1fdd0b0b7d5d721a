"""Study configuration files (TOML) for `boresight simulate`, `predict` and `scan-stats`.

A config is validated whole before any work starts: unknown sections or keys, wrong types, values
out of range and missing files raise :class:`ConfigError` naming the key and what is allowed.
"""

import os
from dataclasses import dataclass, replace

import numpy as np

from . import io, validation
from .evaluation import METHODS
from .instrument import Instrument, Systematics
from .scan import SyntheticScan
from .sky import SkyConfig
from .threads import check_threads

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib


class ConfigError(ValueError):
    """A configuration problem, with the offending key in the message."""


NUM = (int, float)
LIST_OR_NUM = (int, float, list)
#: section -> key -> (allowed types, description of allowed values)
SCHEMA = {
    "sky": {
        "nside": (int, "a power of two, 1..8192"),
        "lmax": (int, "2..3*nside-1"),
        "fwhm_arcmin": (NUM, ">= 0"),
        "seed": (int, ">= 0"),
        "r": (NUM, ">= 0"),
        "a_lens": (NUM, ">= 0"),
        "polarised": (bool, "true or false"),
        "maps": (str, "a FITS file with I, Q, U maps (RING)"),
    },
    "scan": {
        "n_phi": ((int, str), "an integer >= 1 or a FITS map"),
        "range_rad": ((int, float, str), "a number in [0, 2 pi] or a FITS map"),
        "centre_rad": ((int, float, str), "a number or a FITS map"),
        "rotations_deg": (list, "a non-empty list of angles [deg]"),
        "in_pixel": (str, "'random' or 'centre'"),
        "seed": (int, ">= 0"),
    },
    "instrument": {"pair_angles_deg": (list, "a non-empty list of pair angles [deg]")},
    "systematics": {
        "dg": (LIST_OR_NUM, "a number or one per pair"),
        "rho_arcmin": (LIST_OR_NUM, ">= 0, a number or one per pair"),
        "chi_deg": (LIST_OR_NUM, "a number or one per pair"),
        "leak": (LIST_OR_NUM, "a number or one per pair"),
        "leak_template": (str, "a FITS map"),
    },
    "mask": {
        "survey": (str, "'deep', 'wide' or 'none'"),
        "file": (str, "a FITS mask"),
        "apodize_fwhm_deg": (NUM, "> 0"),
    },
    "run": {
        "evaluation": (str, f"one of {METHODS}"),
        "backend": (str, "'cpu' or 'gpu'"),
        "chunk_pixels": (int, ">= 1"),
        "nthreads": (int, ">= 0"),
    },
    "output": {
        "lmax": (int, "2..3*nside-1"),
        "n_bands": (int, ">= 1"),
        "lmin": (int, ">= 2"),
        "maps": (bool, "true or false"),
    },
}


@dataclass(frozen=True)
class Study:
    """A validated study: the dataclasses of each stage plus run and output options."""

    sky: SkyConfig
    sky_maps: str
    scan: SyntheticScan
    instrument: Instrument
    systematics: Systematics
    leak_template: str
    mask: dict
    run: dict
    output: dict
    raw: dict
    source: str = None  #: the TOML file it was read from (None when built from a dict)


def check_backend(key, backend):
    """ConfigError unless the backend is known and, for 'gpu', CuPy is installed."""
    import importlib.util

    if backend not in ("cpu", "gpu"):
        raise ConfigError(f"{key} = {backend!r}; allowed: 'cpu', 'gpu'")
    if backend == "gpu" and importlib.util.find_spec("cupy") is None:
        raise ConfigError(f"{key} = 'gpu' needs CuPy: pip install 'boresight[gpu]'")


def _check_types(raw):
    for section, body in raw.items():
        if section not in SCHEMA:
            raise ConfigError(f"unknown section [{section}]; allowed: {sorted(SCHEMA)}")
        if not isinstance(body, dict):
            raise ConfigError(f"[{section}] must be a table")
        for key, value in body.items():
            if key not in SCHEMA[section]:
                raise ConfigError(
                    f"unknown key {section}.{key}; allowed: {sorted(SCHEMA[section])}"
                )
            types, allowed = SCHEMA[section][key]
            types = types if isinstance(types, tuple) else (types,)
            bad_bool = isinstance(value, bool) and bool not in types
            if bad_bool or not isinstance(value, types):
                raise ConfigError(
                    f"{section}.{key} = {value!r} has the wrong type; allowed: {allowed}"
                )


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


def _build(section, cls, kwargs):
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as err:
        raise ConfigError(f"[{section}] {err}") from None


def read_toml(path, what="config"):
    """The parsed TOML of ``path``; a ConfigError names the file when it cannot be read."""
    if not os.path.isfile(path):
        raise ConfigError(f"{what} file not found (or not a file): {path}")
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path} is not valid TOML: {err}") from None


def load_study(path):
    """Read and validate a TOML study file; returns a :class:`Study`."""
    raw = read_toml(path)
    try:
        study = parse_study(raw, os.path.dirname(os.path.abspath(path)))
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None
    return replace(study, source=str(path))


def parse_study(raw, base="."):
    """Validate a study given as a dict (the parsed TOML); paths are relative to ``base``."""
    _check_types(raw)
    sky_raw = dict(raw.get("sky", {}))
    if "nside" not in sky_raw:
        raise ConfigError("sky.nside is required (a power of two; the paper's 2048 needs ~20 GiB)")
    sky_maps = sky_raw.pop("maps", None)
    sky_cfg = _build("sky", SkyConfig, sky_raw)
    npix = 12 * sky_cfg.nside**2
    if sky_maps is not None:
        sky_maps = _fits("sky", "maps", sky_maps, base, min_fields=3, npix=npix)
    scan_raw = dict(raw.get("scan", {}))
    scan_raw["n_phi"] = _map_or_value(
        "scan", "n_phi", scan_raw.get("n_phi", 4), base, np.int64, npix
    )
    for key in ("range_rad", "centre_rad"):
        if key in scan_raw:
            scan_raw[key] = _map_or_value("scan", key, scan_raw[key], base, np.float64, npix)
    if "rotations_deg" in scan_raw:
        scan_raw["rotations_deg"] = tuple(scan_raw["rotations_deg"])
    scan = _build("scan", SyntheticScan, scan_raw)
    inst_raw = dict(raw.get("instrument", {}))
    if "pair_angles_deg" in inst_raw:
        inst_raw["pair_angles_deg"] = tuple(inst_raw["pair_angles_deg"])
    instrument = _build("instrument", Instrument, inst_raw)
    sys_raw = dict(raw.get("systematics", {}))
    template = sys_raw.pop("leak_template", None)
    if template is not None:
        template = _fits("systematics", "leak_template", template, base, npix=npix)
    systematics = _build(
        "systematics",
        Systematics,
        {k: tuple(v) if isinstance(v, list) else v for k, v in sys_raw.items()},
    )
    try:
        systematics.per_pair(instrument.n_pairs)
    except ValueError as err:
        raise ConfigError(f"[systematics] {err}") from None
    mask = dict(raw.get("mask", {"survey": "none"}))
    if "file" in mask:
        if "survey" in mask:
            raise ConfigError("[mask] give either survey or file, not both")
        mask["file"] = _fits("mask", "file", mask["file"], base)
    elif mask.setdefault("survey", "none") not in ("deep", "wide", "none"):
        raise ConfigError(f"mask.survey = {mask['survey']!r}; allowed: 'deep', 'wide', 'none'")
    if "apodize_fwhm_deg" in mask:
        try:
            validation.number("mask.apodize_fwhm_deg", mask["apodize_fwhm_deg"], 1e-3, 180.0)
        except (TypeError, ValueError) as err:
            raise ConfigError(str(err)) from None
    run = {
        "evaluation": "interp",
        "backend": "cpu",
        "chunk_pixels": None,
        "nthreads": 0,
        **raw.get("run", {}),
    }
    if run["evaluation"] not in METHODS:
        raise ConfigError(f"run.evaluation = {run['evaluation']!r}; allowed: {METHODS}")
    if run["backend"] not in ("cpu", "gpu"):
        raise ConfigError(f"run.backend = {run['backend']!r}; allowed: 'cpu', 'gpu'")
    if (run["chunk_pixels"] is not None and run["chunk_pixels"] < 1) or run["nthreads"] < 0:
        raise ConfigError("run.chunk_pixels must be >= 1 and run.nthreads >= 0")
    try:
        check_threads("run.nthreads", run["nthreads"])
    except (TypeError, ValueError) as err:
        raise ConfigError(str(err)) from None
    check_backend("run.backend", run["backend"])
    output = {
        "lmax": min(sky_cfg.lmax, 2 * sky_cfg.nside),
        "n_bands": 14,
        "lmin": 20,
        "maps": True,
        **raw.get("output", {}),
    }
    if not 2 <= output["lmax"] <= 3 * sky_cfg.nside - 1:
        raise ConfigError(f"output.lmax = {output['lmax']}; allowed: 2..{3 * sky_cfg.nside - 1}")
    if output["n_bands"] < 1 or not 2 <= output["lmin"] < output["lmax"]:
        raise ConfigError("output.n_bands must be >= 1 and 2 <= output.lmin < output.lmax")
    return Study(sky_cfg, sky_maps, scan, instrument, systematics, template, mask, run, output, raw)
