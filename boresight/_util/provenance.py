"""Provenance of a run: the time of each stage, package versions, the git revision, the machine.

Every job writes a ``manifest.json`` from :func:`manifest`, so a result can be traced to the code
and the inputs that made it.
"""

from __future__ import annotations

import logging
import platform
import subprocess
import time
from pathlib import Path

import healpy as hp
import numpy as np

from .. import __version__
from . import interrupts

_log = logging.getLogger(__name__)


class Timer:
    """Wall time of each named stage, for the manifest.

    Parameters
    ----------
    log : logging.Logger, optional
        Told "NAME ..." at INFO as each stage starts (default: this module's logger).

    Notes
    -----
    ``with timer("name"):`` records the stage's seconds in ``timer.stages``.
    """

    def __init__(self, log: logging.Logger | None = None):
        self.stages = {}
        self.log = _log if log is None else log

    def __call__(self, name):
        timer = self

        class _Stage:
            def __enter__(self):
                interrupts.check()
                timer.log.info("%s ...", name)
                self.t0 = time.perf_counter()

            def __exit__(self, *exc):
                timer.stages[name] = round(time.perf_counter() - self.t0, 3)
                if exc[0] is None:
                    interrupts.check()

        return _Stage()


def _versions():
    import ducc0
    import numba

    return {
        "boresight": __version__,
        "numpy": np.__version__,
        "healpy": hp.__version__,
        "ducc0": ducc0.__version__,
        "numba": numba.__version__,
        "python": platform.python_version(),
    }


def _git_revision():
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).parent,
            capture_output=True,
            text=True,
            timeout=5,
        )
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def manifest(config: dict, seeds: dict, stages: dict, estimate: dict | None = None) -> dict:
    """The manifest of a run.

    Parameters
    ----------
    config : dict
        The run's configuration.
    seeds : dict
    stages : dict
        Seconds per stage.
    estimate : dict, optional
        The job's memory and time estimate (:meth:`boresight.jobs.resources.Estimate.as_dict`).

    Returns
    -------
    dict
        config, versions, seeds, git_revision, machine, wall_time_s, estimate, created.
    """
    return {
        "config": config,
        "versions": _versions(),
        "seeds": seeds,
        "git_revision": _git_revision(),
        "machine": platform.platform(),
        "wall_time_s": stages,
        "estimate": estimate,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
