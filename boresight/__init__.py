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
  :func:`boresight.jobs.residual.residual`), its prediction from h_n (``Prediction``,
  ``residual_pseudo_bb``) and the bias on r it fakes (``delta_r``);
* a study file: ``load_study``, ``Study``; what bad input raises: ``BoresightError``,
  ``ConfigError``.

Public modules, by stage: :mod:`~boresight.sky`, :mod:`~boresight.scan`,
:mod:`~boresight.schedule`, :mod:`~boresight.pointing`, :mod:`~boresight.frames`,
:mod:`~boresight.instrument` (:mod:`~boresight.instrument.pairs`,
:mod:`~boresight.instrument.focalplane`, :mod:`~boresight.instrument.hwp`,
:mod:`~boresight.instrument.beams`), :mod:`~boresight.masks`, :mod:`~boresight.noise`,
:mod:`~boresight.cosmology`, :mod:`~boresight.engine`, :mod:`~boresight.spectra`,
:mod:`~boresight.coupling`, :mod:`~boresight.moments` (h_n: ``axis``, ``offsets``,
``focalplane``, ``hwp``), :mod:`~boresight.predict`, :mod:`~boresight.config`,
:mod:`~boresight.jobs` (``residual``, ``paper``, ``suppression``, ``sweep``),
:mod:`~boresight.design` (``budget``, ``white``, ``exact``, ``focalplane``),
:mod:`~boresight.outputs` (``so``, ``litebird``, ``report``, ``plots``) and
:mod:`~boresight.commands` (each command's ``run``).

Plumbing, not for use from outside: :mod:`~boresight._util`, :mod:`~boresight.kernels`,
:mod:`~boresight.harmonics`, :mod:`~boresight.evaluation`, :mod:`~boresight.mapmaking`,
:mod:`~boresight.jobs.transforms`, :mod:`~boresight.jobs.resources`,
:mod:`~boresight.validation`, :mod:`~boresight.constants` and :mod:`~boresight.cli`.
docs/architecture.md draws their layers.
"""

import os as _os
import sys as _sys
from importlib import import_module

if _sys.argv and _os.path.basename(_sys.argv[0]) == "boresight":
    # the console script: a Ctrl-C from here on, while the command line imports, is noted and
    # ends the command in one line (boresight.cli), not in a KeyboardInterrupt traceback
    from ._util.interrupts import install_early as _install_early

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
    "Residual": "jobs.residual",
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
