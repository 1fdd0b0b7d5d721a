"""Shared low-resolution fixtures: CI runs on 2 cores, so skies here are Nside <= 512."""

import os


def _own_cores_per_xdist_worker():
    """Under ``pytest -n N`` on at least N cores, each worker runs on its own share of them.

    A study's kernels run on all the cores its process may use: two workers on two cores would
    otherwise each start two threads per kernel and fight over the cores (the suite took 96 s
    instead of 83 s on 2 cores). This runs before numba is imported, and keeps NUMBA_NUM_THREADS
    at the machine's count, so tests may still ask for more threads than their share of cores.
    """
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    if workers < 2 or not hasattr(os, "sched_setaffinity"):
        return
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < workers:
        return
    os.environ.setdefault("NUMBA_NUM_THREADS", str(len(cores)))
    os.sched_setaffinity(0, cores[int(worker.removeprefix("gw")) % workers :: workers])


_own_cores_per_xdist_worker()

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from boresight import cosmology, sky  # noqa: E402


@pytest.fixture(scope="session")
def theory():
    return cosmology.load_spectra()


@pytest.fixture(scope="session")
def small_sky(theory):
    """Nside 64 sky with a 1-degree beam (smooth on the pixel scale)."""
    return sky.make_sky(sky.SkyConfig(nside=64, lmax=191, fwhm_arcmin=60.0, seed=7), theory)


@pytest.fixture(scope="session")
def small_sky_unpolarised(theory):
    return sky.make_sky(
        sky.SkyConfig(nside=64, lmax=191, fwhm_arcmin=60.0, seed=7, polarised=False), theory
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


def rel_max(a, b):
    """Largest |a - b| relative to the largest |b|."""
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(b)))


def pytest_configure(config):
    """Under xdist, compile the registered kernels (boresight.precompile.KERNELS) that numba's
    cache lacks once, on all cores, before the workers start, rather than in each worker at once."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None and getattr(config.option, "numprocesses", 0):
        from boresight import precompile

        precompile.precompile(list(precompile.KERNELS))


#: Modules whose module fixtures cost seconds: each runs on one xdist worker, which builds them once
MODULES_ON_ONE_WORKER = {"tests/test_predict.py", "tests/test_toast.py"}


@pytest.hookimpl(optionalhook=True)  # an xdist hook: unknown to pytest without xdist
def pytest_xdist_make_scheduler(config, log):
    """Under ``--dist load`` (the default here), schedule test by test, except that each module of
    :data:`MODULES_ON_ONE_WORKER` goes whole to one worker. Split between the two, they built the
    Nside-512 study of test_predict (3.5 s) and TOAST's schedules (1.2 s) twice. xdist's own
    ``--dist loadgroup`` renames the items' node ids, which pytest 9.2 ignores."""
    if config.getvalue("dist") != "load":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ModulesOnOneWorker(LoadScopeScheduling):
        def _split_scope(self, nodeid):
            module = nodeid.split("::", 1)[0]
            return module if module in MODULES_ON_ONE_WORKER else nodeid

    return ModulesOnOneWorker(config, log)
