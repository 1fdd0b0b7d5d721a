"""The hot loop on an NVIDIA GPU: CuPy RawKernels with the same algorithms as ``tod_cpu``.

The CUDA source below ports boresight.rng, boresight.pixels and boresight.tod_cpu line by line
(same integer arithmetic for the counter-based random numbers), so CPU and GPU maps agree to the
rounding of sin/cos/acos (tests/test_gpu.py: <= 1e-12 relative). CuPy is chosen over JAX because
the kernels are scatter-free per-pixel loops with 64-bit integer hashing, which raw CUDA expresses
directly; spherical-harmonic transforms stay on ducc0 (CPU). Install with `pip install
boresight[gpu]` (CuPy for CUDA 12; use cupy-cuda13x for CUDA 13).
"""

import numpy as np

try:
    import cupy as cp
except ImportError as err:  # pragma: no cover - exercised where CuPy is missing
    raise ImportError(
        "backend 'gpu' needs CuPy: pip install 'boresight[gpu]' (or cupy-cuda13x for CUDA 13)"
    ) from err

_THREADS = 256
SOURCE = r"""
typedef unsigned long long u64;
typedef long long i64;
__constant__ i64 JRLL[12] = {2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4};
__constant__ i64 JPLL[12] = {1, 3, 5, 7, 0, 2, 4, 6, 1, 3, 5, 7};
#define PI 3.141592653589793238462643383279502884
#define TWOPI (2.0 * PI)

__device__ __forceinline__ u64 mix64(u64 z) {
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}
__device__ __forceinline__ u64 pixel_key(u64 seed, u64 pix) {
    return mix64(mix64(seed ^ 0x9E3779B97F4A7C15ULL) ^ pix);
}
__device__ __forceinline__ double uniform_from_key(u64 key, u64 hit, u64 stream) {
    u64 h = mix64(key ^ (hit * 4ULL + stream));
    return (double)(h >> 11) * 1.1102230246251565e-16;
}
__device__ __forceinline__ i64 floordiv(i64 a, i64 b) {
    i64 q = a / b;
    return (a % b != 0 && ((a < 0) != (b < 0))) ? q - 1 : q;
}
__device__ __forceinline__ i64 isqrt(i64 v) {
    i64 r = (i64)sqrt((double)v + 0.5);
    if (r * r > v) r -= 1; else if ((r + 1) * (r + 1) <= v) r += 1;
    return r;
}
__device__ void ring2xyf(i64 nside, i64 pix, i64 *ix, i64 *iy, i64 *face) {
    i64 ncap = 2 * nside * (nside - 1), npix = 12 * nside * nside, nl2 = 2 * nside;
    i64 iring, iphi, kshift, nr, f;
    if (pix < ncap) {
        iring = (1 + isqrt(1 + 2 * pix)) >> 1;
        iphi = (pix + 1) - 2 * iring * (iring - 1);
        kshift = 0; nr = iring; f = floordiv(iphi - 1, nr);
    } else if (pix < npix - ncap) {
        i64 ip = pix - ncap, tmp = floordiv(ip, 4 * nside);
        iring = tmp + nside;
        iphi = ip - tmp * 4 * nside + 1;
        kshift = (iring + nside) & 1; nr = nside;
        i64 ire = tmp + 1, irm = nl2 + 1 - tmp;
        i64 ifm = floordiv(iphi - (ire >> 1) + nside - 1, nside);
        i64 ifp = floordiv(iphi - (irm >> 1) + nside - 1, nside);
        f = (ifp == ifm) ? (ifp | 4) : ((ifp < ifm) ? ifp : ifm + 8);
    } else {
        i64 ip = npix - pix;
        iring = (1 + isqrt(2 * ip - 1)) >> 1;
        iphi = 4 * iring + 1 - (ip - 2 * iring * (iring - 1));
        kshift = 0; nr = iring; iring = 2 * nl2 - iring;
        f = 8 + floordiv(iphi - 1, nr);
    }
    i64 irt = iring - ((2 + (f >> 2)) * nside) + 1;
    i64 ipt = 2 * iphi - JPLL[f] * nr - kshift - 1;
    if (ipt >= nl2) ipt -= 8 * nside;
    *ix = (ipt - irt) >> 1; *iy = (-ipt - irt) >> 1; *face = f;
}
__device__ void xyf2ang(double x, double y, i64 face, double *theta, double *phi) {
    double jr = JRLL[face] - x - y, nr, tmp;
    if (jr < 1.0) {
        nr = jr; tmp = nr * nr / 3.0;
        *theta = 2.0 * asin(fmin(1.0, sqrt(tmp / 2.0)));
    } else if (jr > 3.0) {
        nr = 4.0 - jr; tmp = nr * nr / 3.0;
        *theta = PI - 2.0 * asin(fmin(1.0, sqrt(tmp / 2.0)));
    } else {
        nr = 1.0; *theta = acos((2.0 - jr) * 2.0 / 3.0);
    }
    tmp = JPLL[face] * nr + x - y;
    if (tmp < 0) tmp += 8.0;
    if (tmp >= 8) tmp -= 8.0;
    *phi = (nr < 1e-15) ? 0.0 : (0.5 * (0.5 * PI) * tmp) / nr;
}
__device__ void ring_neighbours(i64 nside, i64 ring, double phi, i64 *pa, i64 *pb, double *wa,
                                double *wb, double *theta) {
    i64 npix = 12 * nside * nside;
    i64 northring = ring > 2 * nside ? 4 * nside - ring : ring;
    i64 startpix, ringpix; bool shifted; double th;
    if (northring < nside) {
        double tmp = northring * northring * (4.0 / npix);
        th = atan2(sqrt(tmp * (2.0 - tmp)), 1.0 - tmp);
        ringpix = 4 * northring; shifted = true; startpix = 2 * northring * (northring - 1);
    } else {
        th = acos((2 * nside - northring) * (8.0 * nside / npix));
        ringpix = 4 * nside; shifted = ((northring - nside) & 1) == 0;
        startpix = 2 * nside * (nside - 1) + (northring - nside) * ringpix;
    }
    if (northring != ring) { th = PI - th; startpix = npix - startpix - ringpix; }
    double dphi = TWOPI / ringpix;
    double tmp = phi / dphi - 0.5 * shifted;
    i64 i1 = tmp < 0 ? (i64)tmp - 1 : (i64)tmp;
    double w1 = (phi - (i1 + 0.5 * shifted) * dphi) / dphi;
    i64 i2 = i1 + 1;
    if (i1 < 0) i1 += ringpix;
    if (i2 >= ringpix) i2 -= ringpix;
    *pa = startpix + i1; *pb = startpix + i2; *wa = 1.0 - w1; *wb = w1; *theta = th;
}
__device__ void interp_weights(i64 nside, double theta, double phi, i64 *p, double *w) {
    i64 npix = 12 * nside * nside;
    double z = cos(theta), az = fabs(z);
    i64 ir1;
    if (az <= 2.0 / 3.0) ir1 = (i64)(nside * (2.0 - 1.5 * z));
    else { i64 ir = (i64)(nside * sqrt(3.0 * (1.0 - az))); ir1 = z > 0 ? ir : 4 * nside - ir - 1; }
    i64 ir2 = ir1 + 1;
    double theta1 = 0, theta2 = 0;
    for (int k = 0; k < 4; ++k) { p[k] = 0; w[k] = 0.0; }
    if (ir1 > 0) ring_neighbours(nside, ir1, phi, &p[0], &p[1], &w[0], &w[1], &theta1);
    if (ir2 < 4 * nside) ring_neighbours(nside, ir2, phi, &p[2], &p[3], &w[2], &w[3], &theta2);
    if (ir1 == 0) {
        double wt = theta / theta2, fac = (1.0 - wt) * 0.25;
        w[2] *= wt; w[3] *= wt; w[0] = fac; w[1] = fac; w[2] += fac; w[3] += fac;
        p[0] = (p[2] + 2) & 3; p[1] = (p[3] + 2) & 3;
    } else if (ir2 == 4 * nside) {
        double wt = (theta - theta1) / (PI - theta1), fac = wt * 0.25;
        w[0] *= 1.0 - wt; w[1] *= 1.0 - wt; w[0] += fac; w[1] += fac; w[2] = fac; w[3] = fac;
        p[2] = ((p[0] + 2) & 3) + npix - 4; p[3] = ((p[1] + 2) & 3) + npix - 4;
    } else {
        double wt = (theta - theta1) / (theta2 - theta1);
        w[0] *= 1.0 - wt; w[1] *= 1.0 - wt; w[2] *= wt; w[3] *= wt;
    }
}

extern "C" __global__ void generate_hits(const i64 *pixels, const i64 *offsets, const double *range,
        const double *centre, i64 n, u64 seed, i64 nside, int centred, double *theta, double *phi,
        double *psi) {
    i64 k = blockIdx.x * (i64)blockDim.x + threadIdx.x;
    if (k >= n) return;
    i64 p = pixels[k], ix, iy, face;
    u64 key = pixel_key(seed, (u64)p);
    ring2xyf(nside, p, &ix, &iy, &face);
    for (i64 h = offsets[k]; h < offsets[k + 1]; ++h) {
        u64 j = (u64)(h - offsets[k]);
        psi[h] = centre[k] + range[k] * (uniform_from_key(key, j, 0) - 0.5);
        double u = 0.5, v = 0.5;
        if (!centred) { u = uniform_from_key(key, j, 1); v = uniform_from_key(key, j, 2); }
        xyf2ang((ix + u) / nside, (iy + v) / nside, face, &theta[h], &phi[h]);
    }
}

extern "C" __global__ void offset_points(const double *theta, const double *phi,
        const double *psi, i64 nh, const double *rot, int nk, const double *ang, int nm,
        const double *rho, const double *chi, double *tb, double *pb) {
    i64 h = blockIdx.x * (i64)blockDim.x + threadIdx.x;
    if (h >= nh) return;
    double sin_t = sin(theta[h]);
    for (int k = 0; k < nk; ++k) for (int m = 0; m < nm; ++m) {
        double beta = psi[h] + rot[k] + ang[m] + chi[m];
        double t = theta[h] + rho[m] * cos(beta), f = phi[h] + rho[m] * sin(beta) / sin_t;
        if (t < 0.0) { t = -t; f += PI; } else if (t > PI) { t = TWOPI - t; f += PI; }
        double r = fmod(f, TWOPI);
        if (r < 0) r += TWOPI;
        i64 idx = (h * nk + k) * nm + m;
        tb[idx] = t; pb[idx] = r;
    }
}

extern "C" __global__ void interpolate(const double *stack, int nfield, i64 nside,
        const double *theta, const double *phi, i64 n, double *out) {
    i64 k = blockIdx.x * (i64)blockDim.x + threadIdx.x;
    if (k >= n) return;
    i64 p[4]; double w[4];
    interp_weights(nside, theta[k], phi[k], p, w);
    for (int f = 0; f < nfield; ++f)
        out[f * n + k] = w[0] * stack[p[0] * nfield + f] + w[1] * stack[p[1] * nfield + f]
                       + w[2] * stack[p[2] * nfield + f] + w[3] * stack[p[3] * nfield + f];
}

extern "C" __global__ void accumulate(const i64 *offsets, const double *psi, i64 npix,
        const double *va, const double *vb, i64 nh, int nfield, int nk, int nm,
        const double *turn_c, const double *turn_s, const double *dg, const double *leak,
        double *out) {
    i64 p = blockIdx.x * (i64)blockDim.x + threadIdx.x;
    if (p >= npix) return;
    double a11 = 0, a12 = 0, a22 = 0, b1 = 0, b2 = 0;
    for (i64 h = offsets[p]; h < offsets[p + 1]; ++h) {
        double ia = va[h], qa = va[nh + h], ua = va[2 * nh + h];
        double sa = nfield > 3 ? va[3 * nh + h] : 0.0;
        double c0 = cos(2.0 * psi[h]), s0 = sin(2.0 * psi[h]);
        for (int k = 0; k < nk; ++k) for (int m = 0; m < nm; ++m) {
            double c = c0 * turn_c[k * nm + m] - s0 * turn_s[k * nm + m];
            double s = s0 * turn_c[k * nm + m] + c0 * turn_s[k * nm + m];
            double ib = ia, qb = qa, ub = ua, sb = sa;
            if (vb) {
                i64 stride = nh * nk * nm, idx = (h * nk + k) * nm + m;
                ib = vb[idx]; qb = vb[stride + idx]; ub = vb[2 * stride + idx];
                sb = nfield > 3 ? vb[3 * stride + idx] : 0.0;
            }
            double da = ia + qa * c + ua * s + 0.5 * leak[m] * sa;
            double db = (1.0 - dg[m]) * (ib - qb * c - ub * s) - 0.5 * leak[m] * sb;
            double d = 0.5 * (da - db);
            a11 += c * c; a12 += c * s; a22 += s * s; b1 += c * d; b2 += s * d;
        }
    }
    out[5 * p] = a11; out[5 * p + 1] = a12; out[5 * p + 2] = a22; out[5 * p + 3] = b1;
    out[5 * p + 4] = b2;
}

extern "C" __global__ void moments(const i64 *offsets, const double *psi, i64 npix,
        const double *rot, int nk, int nmax, double *out) {
    i64 p = blockIdx.x * (i64)blockDim.x + threadIdx.x;
    if (p >= npix) return;
    i64 count = (offsets[p + 1] - offsets[p]) * nk;
    for (int n = 0; n <= nmax; ++n) {
        double re = 0, im = 0;
        for (i64 h = offsets[p]; h < offsets[p + 1]; ++h)
            for (int k = 0; k < nk; ++k) {
                double a = n * (psi[h] + rot[k]);
                re += cos(a); im += sin(a);
            }
        if (count > 0) { re /= count; im /= count; }
        out[2 * (p * (nmax + 1) + n)] = re; out[2 * (p * (nmax + 1) + n) + 1] = im;
    }
}
"""
_module = None


def _kernel(name):
    global _module
    if _module is None:
        try:
            if cp.cuda.runtime.getDeviceCount() < 1:
                raise RuntimeError
        except Exception as err:
            raise RuntimeError(
                "backend 'gpu': no CUDA GPU is visible (CuPy found no device)"
            ) from err
        _module = cp.RawModule(code=SOURCE, options=("--std=c++17",))
    return _module.get_function(name)


def _launch(name, n, args):
    if n > 0:
        _kernel(name)(((n + _THREADS - 1) // _THREADS,), (_THREADS,), args)


def _d(array, dtype=np.float64):
    return cp.ascontiguousarray(cp.asarray(array, dtype=dtype))


def to_device(array):
    """Copy an array to the GPU once (e.g. the interleaved sky fields)."""
    return _d(array)


def to_host(array):
    return cp.asnumpy(array) if isinstance(array, cp.ndarray) else array


def generate_hits(seed, nside, pixels, offsets, range_rad, centre_rad, centred):
    offsets_d = _d(offsets, np.int64)
    nhit = int(offsets[-1])
    theta, phi, psi = (cp.empty(nhit) for _ in range(3))
    _launch(
        "generate_hits",
        pixels.size,
        (
            _d(pixels, np.int64),
            offsets_d,
            _d(range_rad),
            _d(centre_rad),
            np.int64(pixels.size),
            np.uint64(seed),
            np.int64(nside),
            np.int32(bool(centred)),
            theta,
            phi,
            psi,
        ),
    )
    return theta, phi, psi


def offset_points(theta, phi, psi, rotations, pair_angles, rho, chi):
    nh, nk, nm = theta.size, rotations.size, pair_angles.size
    tb = cp.empty((nh, nk, nm))
    pb = cp.empty((nh, nk, nm))
    _launch(
        "offset_points",
        nh,
        (
            _d(theta),
            _d(phi),
            _d(psi),
            np.int64(nh),
            _d(rotations),
            np.int32(nk),
            _d(pair_angles),
            np.int32(nm),
            _d(rho),
            _d(chi),
            tb,
            pb,
        ),
    )
    return tb, pb


def interpolate(stack, nside, theta, phi):
    """Bilinear interpolation of the interleaved (npix, nfield) stack -> (nfield, npoints)."""
    stack = stack if isinstance(stack, cp.ndarray) else _d(stack)
    theta, phi = _d(theta), _d(phi)
    out = cp.empty((stack.shape[1], theta.size))
    _launch(
        "interpolate",
        theta.size,
        (stack, np.int32(stack.shape[1]), np.int64(nside), theta, phi, np.int64(theta.size), out),
    )
    return out


def accumulate(offsets, psi, values_a, values_b, rotations, pair_angles, dg, leak):
    npix, nk, nm = offsets.size - 1, rotations.size, pair_angles.size
    turn = 2.0 * (rotations[:, None] + pair_angles[None, :])
    va = _d(values_a)
    vb = _d(values_b) if values_b.shape[1] > 0 else None
    out = cp.empty((npix, 5))
    _launch(
        "accumulate",
        npix,
        (
            _d(offsets, np.int64),
            _d(psi),
            np.int64(npix),
            va,
            vb if vb is not None else np.uint64(0),
            np.int64(va.shape[1]),
            np.int32(va.shape[0]),
            np.int32(nk),
            np.int32(nm),
            _d(np.cos(turn)),
            _d(np.sin(turn)),
            _d(dg),
            _d(leak),
            out,
        ),
    )
    return out


def moments(offsets, psi, rotations, n_max):
    npix = offsets.size - 1
    out = cp.empty((npix, n_max + 1), dtype=cp.complex128)
    _launch(
        "moments",
        npix,
        (
            _d(offsets, np.int64),
            _d(psi),
            np.int64(npix),
            _d(rotations),
            np.int32(rotations.size),
            np.int32(n_max),
            out,
        ),
    )
    return out
