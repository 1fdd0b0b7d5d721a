"""boresight: differential-systematic B-modes and partial boresight rotation for CMB scans.

The pipeline, one module per stage: cosmology -> sky -> scan -> instrument -> engine (tod_cpu /
tod_gpu kernels) -> mapmaking -> masks -> spectra / coupling -> predict -> paper / report -> plots
-> studies / cli.

The names below are imported on first use, so ``import boresight`` (and the command line, which
notes Ctrl-C before anything heavy is imported) stays light.
"""

from importlib import import_module

#: the public names and the module of each
_EXPORTS = {
    "simulate": "engine",
    "scan_moments": "engine",
    "Instrument": "instrument",
    "Systematics": "instrument",
    "PAPER_GAIN": "instrument",
    "PAPER_POINTING": "instrument",
    "SyntheticScan": "scan",
    "paper_scan": "scan",
    "Sky": "sky",
    "SkyConfig": "sky",
    "make_sky": "sky",
}

__all__ = list(_EXPORTS)


def _version():
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("boresight")
    except PackageNotFoundError:  # a checkout on the path without an install
        return "0+unknown"


def __getattr__(name):
    if name == "__version__":
        return _version()
    if name in _EXPORTS:
        return getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module 'boresight' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__ + ["__version__"])
