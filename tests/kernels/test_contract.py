"""The kernel backend contract (boresight.kernels.contract): both backends provide every kernel with the
parameters the engine passes, checked without a GPU (the CuPy module is read, not imported)."""

import ast
import importlib.util
import inspect
import re
import sys
import types
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from boresight import engine
from boresight.instrument.pairs import Systematics, response
from boresight.kernels import contract, cpu

CONTRACT = {
    name: [p for p in inspect.signature(fn).parameters if p != "self"]
    for name, fn in vars(contract.KernelBackend).items()
    if inspect.isfunction(fn) and not name.startswith("_")
}


def _module_functions(tree):
    return {
        node.name: [a.arg for a in node.args.args]
        for node in tree.body
        if isinstance(node, ast.FunctionDef)
    }


def test_the_engine_uses_every_kernel_of_the_contract_and_no_other():
    files = Path(engine.__file__).parent.glob("*.py")  # every file of the engine's package
    source = "".join(f.read_text() for f in sorted(files))
    used = set(re.findall(r"(?:kernels|\bk)\.(\w+)\(", source))
    used |= set(re.findall(r"kernels\.(\w+),", source))  # passed on: offset_points
    assert used == set(CONTRACT)


def test_cpu_backend_implements_the_contract():
    assert isinstance(cpu, contract.KernelBackend)
    for name, params in CONTRACT.items():
        assert list(inspect.signature(getattr(cpu, name)).parameters) == params, name


def test_gpu_backend_implements_the_contract_without_a_gpu():
    tree = ast.parse((resources.files("boresight.kernels") / "gpu.py").read_text())
    functions = _module_functions(tree)
    for name, params in CONTRACT.items():
        assert functions.get(name) == params, name
    cuda = (resources.files("boresight.kernels") / "gpu.cu").read_text()
    for kernel in ("generate_hits", "offset_points", "interpolate", "accumulate", "bin_scan"):
        assert f"void {kernel}(" in cuda, kernel


def _cuda_parameters(source, kernel):
    """(type, is_pointer) of each parameter of a __global__ kernel in the CUDA source."""
    params = re.search(rf"void {kernel}\((.*?)\)\s*{{", source, re.S).group(1).split(",")
    return [
        (p.split()[-2] if "*" not in p else p.split()[-2].rstrip("*"), "*" in p) for p in params
    ]


def _fake_cupy():
    """A stand-in CuPy module: numpy arrays, and RawModule functions that record each launch."""
    fake = types.ModuleType("cupy")
    fake.__getattr__ = lambda name: getattr(np, name)
    fake.ndarray, fake.asnumpy, fake.launches = np.ndarray, np.asarray, []

    class RawModule:
        def __init__(self, code, options):
            pass

        def get_function(self, name):
            return lambda grid, block, args: fake.launches.append((name, args))

    fake.RawModule = RawModule
    fake.cuda = types.SimpleNamespace(runtime=types.SimpleNamespace(getDeviceCount=lambda: 1))
    return fake


@pytest.fixture
def gpu_without_cupy(monkeypatch):
    """boresight.kernels.gpu loaded over the stand-in CuPy, and that stand-in."""
    fake = _fake_cupy()
    monkeypatch.setitem(sys.modules, "cupy", fake)
    path = resources.files("boresight.kernels") / "gpu.py"
    spec = importlib.util.spec_from_file_location("gpu_without_cupy", path)
    gpu = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gpu)
    return gpu, fake


def test_gpu_kernel_launches_match_the_cuda_parameters_without_a_gpu(
    gpu_without_cupy, offset_inputs
):
    """Every launch passes as many arguments as its CUDA kernel has, each of the type the kernel
    reads (int64, uint64, int32 scalars; float64 or int64 arrays, or a null pointer): a launch
    that does not is undefined behaviour on the GPU, not an error."""
    gpu, fake = gpu_without_cupy
    theta, phi, psi, rot, ang, rho, chi = offset_inputs
    nside, pixels = 8, np.arange(0, 768, 7)
    sysm = Systematics(dg=0.01)
    resp = response(rot, ang, sysm.per_pair(2), sysm.per_repeat(rot.size))
    leak, none = np.zeros(2), np.zeros((2, 0, rot.size, 2))
    offsets = np.arange(pixels.size + 1) * 2
    stack = np.ones((768, 3))
    scan_args = (3, nside, pixels, offsets, np.full(pixels.size, 0.3), np.zeros(pixels.size), 0)
    gpu.generate_hits(*scan_args)
    gpu.offset_points(*offset_inputs)
    gpu.interpolate(stack, nside, theta, phi)
    values = np.ones((3, offsets[-1])), np.ones((3, offsets[-1], rot.size, 2))
    gpu.accumulate(offsets, psi[: offsets[-1]], *values, none, resp, leak, None, 3, pixels)
    out = np.zeros((768, 5))
    hit_pixels = np.repeat(pixels, 2)
    jitter = np.zeros(2)
    gpu.accumulate_scatter(
        hit_pixels, psi[: offsets[-1]], *values, none, resp, leak, jitter, 3, 0, out
    )
    gpu.bin_scan(*scan_args, stack, rot, ang, resp, rho, chi, leak, jitter, True, True)
    gpu.moments(offsets, psi[: offsets[-1]], rot, 4)
    launched = {name for name, _ in fake.launches}
    assert launched == set(re.findall(r"__global__ void (\w+)\(", gpu.SOURCE))
    scalar = {"i64": np.int64, "u64": np.uint64, "int": np.int32}
    array = {"i64": (np.int64,), "double": (np.float64, np.complex128)}
    for name, args in fake.launches:
        params = _cuda_parameters(gpu.SOURCE, name)
        assert len(args) == len(params), name
        for (ctype, pointer), arg in zip(params, args):
            if not pointer:
                assert type(arg) is scalar[ctype], (name, ctype, arg)
            elif not isinstance(arg, np.ndarray):
                assert type(arg) is np.uint64 and arg == 0, (name, ctype, arg)  # null
            else:
                assert arg.dtype in array[ctype] and arg.flags.c_contiguous, (name, ctype)


def test_unknown_backend_is_refused():
    with pytest.raises(ValueError, match="backend"):
        contract.get_backend("tpu")
