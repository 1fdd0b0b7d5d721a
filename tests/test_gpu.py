"""GPU backend: the same maps as the CPU to <= 1e-12 relative (skipped without CuPy and a GPU)."""

import importlib.util

import numpy as np
import pytest

from boresight import engine
from boresight.instrument.pairs import Instrument, Systematics
from boresight.scan import SyntheticScan
from boresight.schedule import CES, Schedule


def _gpu_available():
    if importlib.util.find_spec("cupy") is None:
        return False
    import cupy

    try:
        return cupy.cuda.runtime.getDeviceCount() > 0
    except Exception:
        return False


gpu = pytest.mark.skipif(not _gpu_available(), reason="needs CuPy and a CUDA GPU")


@pytest.mark.skipif(importlib.util.find_spec("cupy") is not None, reason="CuPy is installed")
def test_clear_error_without_cupy(small_sky):
    with pytest.raises(ImportError, match=r"boresight\[gpu\]"):
        engine.simulate(small_sky, SyntheticScan(), backend="gpu")


CASES = [
    (
        SyntheticScan(n_phi=4, range_rad=0.719, rotations_deg=(0, 90), seed=3),
        Systematics(dg=(0.01, -0.01)),
        "interp",
    ),
    (
        SyntheticScan(n_phi=2, range_rad=0.169, rotations_deg=(0, 179), seed=4),
        Systematics(rho_arcmin=3.0, chi_deg=(10.0, -20.0)),
        "interp",
    ),
    (
        SyntheticScan(n_phi=np.arange(12 * 64**2) % 5 + 1, range_rad=1.0, in_pixel="centre"),
        Systematics(dg=0.02, rho_arcmin=1.0, leak=(0.01, 0.0)),
        "interp",
    ),
    (
        SyntheticScan(n_phi=3, range_rad=0.5, rotations_deg=(0, 45, 90, 135), seed=5),
        Systematics(rho_arcmin=2.0),
        "exact",
    ),
]


@gpu
@pytest.mark.gpu
@pytest.mark.parametrize("scan, sysm, evaluation", CASES)
def test_gpu_matches_cpu(small_sky, scan, sysm, evaluation):
    kw = dict(systematics=sysm, evaluation=evaluation, chunk_pixels=5000)
    cpu = engine.simulate(small_sky, scan, **kw)
    gpu_maps = engine.simulate(small_sky, scan, backend="gpu", **kw)
    scale = np.max(np.abs(cpu.q[cpu.valid]))
    assert np.array_equal(cpu.valid, gpu_maps.valid) and np.array_equal(cpu.hits, gpu_maps.hits)
    # Only sin/cos/acos differ (CUDA libdevice vs LLVM), by an ulp or so: 1e-12 leaves room.
    assert np.max(np.abs(cpu.q - gpu_maps.q)) <= 1e-12 * scale
    assert np.max(np.abs(cpu.u - gpu_maps.u)) <= 1e-12 * scale


@gpu
@pytest.mark.gpu
def test_gpu_offset_points_match_cpu_past_the_poles_too(offset_inputs):
    """The same angle-addition route as tod_cpu: B's points agree to a few ulp (CUDA may fuse
    the multiply-adds), folded past the poles alike."""
    from boresight.kernels import cpu, gpu

    theta = offset_inputs[0]
    tb_cpu, pb_cpu = cpu.offset_points(*offset_inputs)
    tb_gpu, pb_gpu = (gpu.to_host(x) for x in gpu.offset_points(*offset_inputs))
    assert tb_gpu.shape == tb_cpu.shape == (theta.size, 3, 2)
    np.testing.assert_allclose(tb_gpu, tb_cpu, rtol=0, atol=4e-15)
    dphi = np.angle(np.exp(1j * (pb_gpu - pb_cpu)))  # phi wraps at 2 pi
    assert np.max(np.abs(dphi * np.sin(tb_cpu))) < 4e-15
    assert ((pb_gpu >= 0) & (pb_gpu < 2 * np.pi)).all()


@gpu
@pytest.mark.gpu
def test_gpu_zero_qu_maps_match_cpu(small_sky):
    """The fused kernel's Q = U = 0 sums from the same hits: gain, pointing and leak."""
    scan = SyntheticScan(n_phi=2, range_rad=0.169, rotations_deg=(0, 179), seed=4)
    sysm = Systematics(dg=0.01, rho_arcmin=3.0, chi_deg=(10.0, -20.0), leak=(0.01, 0.0))
    cpu = engine.simulate_with_zero_qu(small_sky, scan, systematics=sysm)
    gpu_maps = engine.simulate_with_zero_qu(small_sky, scan, systematics=sysm, backend="gpu")
    for a, b in zip(cpu, gpu_maps):
        assert np.array_equal(a.valid, b.valid) and np.array_equal(a.hits, b.hits)
        scale = np.max(np.abs(a.q[a.valid]))
        assert np.max(np.abs(a.q - b.q)) <= 1e-12 * scale
        assert np.max(np.abs(a.u - b.u)) <= 1e-12 * scale
    assert not np.array_equal(gpu_maps[0].q, gpu_maps[1].q)


@gpu
@pytest.mark.gpu
def test_gpu_moments_match_cpu():
    scan = SyntheticScan(n_phi=4, range_rad=0.719, rotations_deg=(0, 89), seed=9)
    h_cpu, n_cpu = engine.scan_moments(scan, 128)
    h_gpu, n_gpu = engine.scan_moments(scan, 128, backend="gpu", chunk_pixels=77777)
    assert np.array_equal(n_cpu, n_gpu)
    assert np.max(np.abs(h_cpu - h_gpu)) < 1e-13


@gpu
@pytest.mark.gpu
def test_gpu_other_pair_layouts(small_sky):
    inst = Instrument((10.0, 55.0, 100.0))
    scan = SyntheticScan(n_phi=2, range_rad=0.3)
    a = engine.simulate(small_sky, scan, inst, Systematics(dg=0.01))
    b = engine.simulate(small_sky, scan, inst, Systematics(dg=0.01), backend="gpu")
    assert np.max(np.abs(a.q - b.q)) <= 1e-12 * np.max(np.abs(a.q))


@gpu
@pytest.mark.gpu
def test_gpu_sample_streams_match_cpu(small_sky):
    """Real-scan sample streams (host arrays) through the GPU kernels, pointing included."""
    from boresight import pointing

    ces = CES(
        start_unix=1.79e9, duration_s=600, elevation_deg=50, az_centre_deg=134, az_throw_deg=40
    )
    sched = Schedule((ces,), sample_rate_hz=20.0)
    sysm = Systematics(dg=(0.01, -0.01), rho_arcmin=1.0)
    a = engine.simulate_samples(small_sky, pointing.pointing(sched), systematics=sysm)
    b = engine.simulate_samples(
        small_sky, pointing.pointing(sched), systematics=sysm, backend="gpu"
    )
    c = engine.simulate_samples(
        small_sky, pointing.pointing(sched), systematics=sysm, backend="gpu"
    )
    assert np.array_equal(b.q, c.q)  # sorted, not atomic, sums: the GPU result is deterministic
    ok = a.valid
    assert np.array_equal(ok, b.valid) and np.array_equal(a.hits, b.hits)
    assert np.max(np.abs(a.q[ok] - b.q[ok])) <= 1e-12 * np.max(np.abs(a.q[ok]))
