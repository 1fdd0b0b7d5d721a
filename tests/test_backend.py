"""The kernel backend contract (boresight.backend): both backends provide every kernel with the
parameters the engine passes, checked without a GPU (the CuPy module is read, not imported)."""

import ast
import inspect
import re
from importlib import resources

import numpy as np
import pytest

from boresight import backend, engine, scan, tod_cpu
from boresight.instrument import Systematics, response

CONTRACT = {
    name: [p for p in inspect.signature(fn).parameters if p != "self"]
    for name, fn in vars(backend.KernelBackend).items()
    if inspect.isfunction(fn) and not name.startswith("_")
}


def _module_functions(tree):
    return {
        node.name: [a.arg for a in node.args.args]
        for node in tree.body
        if isinstance(node, ast.FunctionDef)
    }


def test_the_engine_uses_every_kernel_of_the_contract_and_no_other():
    source = inspect.getsource(engine)
    used = set(re.findall(r"(?:kernels|\bk)\.(\w+)\(", source))
    used |= set(re.findall(r"kernels\.(\w+),", source))  # passed on: offset_points
    assert used == set(CONTRACT)


def test_cpu_backend_implements_the_contract():
    assert isinstance(tod_cpu, backend.KernelBackend)
    for name, params in CONTRACT.items():
        assert list(inspect.signature(getattr(tod_cpu, name)).parameters) == params, name


def test_gpu_backend_implements_the_contract_without_a_gpu():
    tree = ast.parse((resources.files("boresight") / "tod_gpu.py").read_text())
    functions = _module_functions(tree)
    for name, params in CONTRACT.items():
        assert functions.get(name) == params, name
    cuda = (resources.files("boresight") / "tod_gpu.cu").read_text()
    for kernel in ("generate_hits", "offset_points", "interpolate", "accumulate", "bin_scan"):
        assert f"void {kernel}(" in cuda, kernel


def test_cpu_bin_scan_equals_its_stages(small_sky):
    """bin_scan is generate_hits -> interpolate -> offset_points -> accumulate, to the bit."""
    pixels = np.arange(0, 12 * 64**2, 97, dtype=np.int64)
    n_phi = np.full(pixels.size, 3)
    rng_rad, centre = np.full(pixels.size, 0.7), np.zeros(pixels.size)
    rot, ang = np.radians([0.0, 180.0]), np.radians([0.0, 45.0])
    systematics = Systematics(rho_arcmin=0.1, pol_angle_deg=0.5, dg=0.01, dg_jitter=0.02)
    par = systematics.per_pair(2)
    table = response(rot, ang, par, systematics.per_repeat(2))
    rho, chi, leak, jitter = par.rho, par.chi, par.leak, par.dg_jitter
    stack = small_sky.interleaved
    args = (rot, ang, table, rho, chi, leak, jitter, True)
    fused = tod_cpu.bin_scan(5, 64, pixels, n_phi, rng_rad, centre, False, stack, *args)
    offsets = scan.hit_offsets(n_phi)
    theta, phi, psi = tod_cpu.generate_hits(5, 64, pixels, offsets, rng_rad, centre, False)
    values_a = tod_cpu.interpolate(stack, 64, theta, phi)
    tb, pb = tod_cpu.offset_points(theta, phi, psi, rot, ang, rho, chi)
    values_b = tod_cpu.interpolate(stack, 64, tb.ravel(), pb.ravel()).reshape((3,) + tb.shape)
    no_beams = np.empty((2, 0) + tb.shape[1:])
    staged = tod_cpu.accumulate(
        offsets, psi, values_a, values_b, no_beams, table, leak, jitter, 5, pixels
    )
    np.testing.assert_array_equal(fused, staged)


def test_unknown_backend_is_refused():
    with pytest.raises(ValueError, match="backend"):
        backend.get_backend("tpu")
