"""The suite's shared fixtures: low-resolution skies (CI runs on 2 cores) and pointing inputs."""

import os

import numpy as np
import pytest

from boresight import cosmology
from boresight.sky import SkyConfig, make_sky


@pytest.fixture(scope="session")
def theory():
    return cosmology.load_spectra()


@pytest.fixture(scope="session")
def small_sky(theory):
    """Nside 64 sky with a 1-degree beam (smooth on the pixel scale)."""
    return make_sky(SkyConfig(nside=64, lmax=191, fwhm_arcmin=60.0, seed=7), theory)


@pytest.fixture(scope="session")
def small_sky_unpolarised(theory):
    return make_sky(
        SkyConfig(nside=64, lmax=191, fwhm_arcmin=60.0, seed=7, polarised=False), theory
    )


@pytest.fixture(scope="session")
def offset_inputs():
    """Hits for detector B's pointing (theta, phi, psi [rad]; rotations, pair angles, rho, chi
    [rad]) with 1-2 arcmin offsets, four of them so near a pole that B's point folds over it."""
    rng = np.random.default_rng(4)
    n = 2000
    theta = np.concatenate([np.arccos(rng.uniform(-1, 1, n - 4)), [1e-4, 2e-4, np.pi - 1e-4, 3.0]])
    phi, psi = rng.uniform(0, 2 * np.pi, n), rng.uniform(-np.pi, np.pi, n)
    rot, ang = np.radians([0.0, 90.0, 180.0]), np.radians([0.0, 45.0])
    rho, chi = np.array([3e-4, 5e-4]), np.radians([10.0, -30.0])
    return theta, phi, psi, rot, ang, rho, chi


@pytest.fixture(scope="session", autouse=True)
def _one_share_of_the_cores_per_xdist_worker():
    """Under ``pytest -n N`` on at least N cores, each worker (and the command-line runs it
    starts) runs on its own share of the cores, so that two workers' kernels do not each start a
    thread per core and fight over them (the command-line tests run a process per trial).
    NUMBA_NUM_THREADS stays at the machine's count, so a test may still ask for more threads
    than its share."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    if workers < 2 or not hasattr(os, "sched_setaffinity"):
        return
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < workers:
        return
    os.environ.setdefault("NUMBA_NUM_THREADS", str(len(cores)))
    os.sched_setaffinity(0, cores[int(worker.removeprefix("gw")) % workers :: workers])


@pytest.fixture(scope="module")
def plain_sky():
    return make_sky(SkyConfig(nside=16, lmax=32, fwhm_arcmin=120.0, seed=4))
