"""boresight: differential-systematic B-modes and partial boresight rotation for CMB scans.

How much false B-mode do pair-differencing systematics leave for a scan strategy, and how much
of it does rotating the instrument about its boresight remove? boresight simulates it end to end,
predicts it from the spin moments h_n, and designs a telescope's rotation schedule.

Public API
----------
At the top level (imported on first use, so ``import boresight`` stays light):

* a sky: ``make_sky``, ``Sky``, ``SkyConfig``;
* a scan: ``SyntheticScan``, ``paper_scan``; a real CES schedule: ``load_schedule``,
  ``Schedule``, ``CES``;
* the detector pairs and their systematics: ``Instrument``, ``Systematics``, ``PAPER_GAIN``,
  ``PAPER_POINTING``;
* TOD to maps: ``simulate``, ``simulate_with_zero_qu``, ``scan_moments``;
* the residual pseudo-C_BB a systematic leaves (``Residual``, from
  :func:`boresight.residual.residual`), its prediction from h_n (``Prediction``,
  ``residual_pseudo_bb``) and the bias on r it fakes (``delta_r``);
* a study file: ``load_study``, ``Study``; what bad input raises: ``BoresightError``,
  ``ConfigError``.

Public modules: :mod:`~boresight.sky`, :mod:`~boresight.scan`, :mod:`~boresight.schedule`,
:mod:`~boresight.pointing`, :mod:`~boresight.frames`, :mod:`~boresight.instrument`, :mod:`~boresight.focalplane`, :mod:`~boresight.hwp`,
:mod:`~boresight.beams`, :mod:`~boresight.masks`, :mod:`~boresight.noise`,
:mod:`~boresight.engine`, :mod:`~boresight.spectra`, :mod:`~boresight.coupling`,
:mod:`~boresight.predict`, :mod:`~boresight.scanstats`, :mod:`~boresight.config`,
:mod:`~boresight.residual`, :mod:`~boresight.design`, :mod:`~boresight.suppression`,
:mod:`~boresight.hwp_suppression`,
:mod:`~boresight.paper`, :mod:`~boresight.sweep`, :mod:`~boresight.so_maps`,
:mod:`~boresight.litebird_maps`,
:mod:`~boresight.cosmology` and
:mod:`~boresight.commands` (each command's ``run``).

Plumbing, not for use from outside: :mod:`~boresight.kernels`, :mod:`~boresight.harmonics`,
:mod:`~boresight.evaluation`, :mod:`~boresight.mapmaking`, :mod:`~boresight.transforms`,
:mod:`~boresight.threads`, :mod:`~boresight.interrupts`, :mod:`~boresight.io`,
:mod:`~boresight.validation`, :mod:`~boresight.resources`, :mod:`~boresight.precompile`,
:mod:`~boresight.provenance`, :mod:`~boresight.report`, :mod:`~boresight.plots`,
:mod:`~boresight.constants` and :mod:`~boresight.cli`.
docs/architecture.md draws their layers.
"""

import os as _os
import sys as _sys
from importlib import import_module

if _sys.argv and _os.path.basename(_sys.argv[0]) == "boresight":
    # the console script: a Ctrl-C from here on, while the command line imports, is noted and
    # ends the command in one line (boresight.cli), not in a KeyboardInterrupt traceback
    from .interrupts import install_early as _install_early

    _install_early()

#: the public names and the module of each
_EXPORTS = {
    "simulate": "engine",
    "simulate_with_zero_qu": "engine",
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
    "load_schedule": "schedule",
    "Schedule": "schedule",
    "CES": "schedule",
    "Residual": "residual",
    "Prediction": "predict",
    "residual_pseudo_bb": "predict",
    "delta_r": "predict",
    "load_study": "config",
    "Study": "config",
    "BoresightError": "validation",
    "ConfigError": "validation",
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
