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

__device__ __forceinline__ void draw_hit(u64 key, i64 j, i64 nside, i64 ix, i64 iy, i64 face,
        double range, double centre, int centred, double *theta, double *phi, double *psi) {
    *psi = centre + range * (uniform_from_key(key, (u64)j, 0) - 0.5);
    double u = 0.5, v = 0.5;
    if (!centred) { u = uniform_from_key(key, (u64)j, 1); v = uniform_from_key(key, (u64)j, 2); }
    xyf2ang((ix + u) / nside, (iy + v) / nside, face, theta, phi);
}
// Where detector B looks: theta + rho cos(beta), phi + rho sin(beta) / sin(theta), beta = psi +
// rotation + pair angle + chi, by angle addition from (cos, sin) psi of the hit and rho (cos, sin)
// of the rest, (rc, rs) per (rotation, pair), as tod_cpu.offset_points
__device__ __forceinline__ void offset_point(double theta, double phi, double inv_sin_t,
        double cos_psi, double sin_psi, double rc, double rs, double *tb, double *pb) {
    double t = theta + (cos_psi * rc - sin_psi * rs);
    double f = phi + (sin_psi * rc + cos_psi * rs) * inv_sin_t;
    if (t < 0.0) { t = -t; f += PI; } else if (t > PI) { t = TWOPI - t; f += PI; }
    double r = fmod(f, TWOPI);
    *tb = t; *pb = r < 0 ? r + TWOPI : r;
}
// (I, Q, U, template) at one point of the interleaved (npix, nf) stack; template 0 when nf = 3
__device__ __forceinline__ void interp_point(const double *stack, int nf, i64 nside,
        double theta, double phi, double *out) {
    i64 p[4]; double w[4];
    interp_weights(nside, theta, phi, p, w);
    out[3] = 0.0;
    for (int f = 0; f < nf; ++f)
        out[f] = w[0] * stack[p[0] * nf + f] + w[1] * stack[p[1] * nf + f]
               + w[2] * stack[p[2] * nf + f] + w[3] * stack[p[3] * nf + f];
}
struct Sums { double a11 = 0, a12 = 0, a22 = 0, b1 = 0, b2 = 0; };
// d = (d_A - d_B) / 2 of one pair at (c, s) = (cos, sin) 2 x A's angle (kernels.cpu._detectors)
__device__ __forceinline__ double pair_difference(const double *fa, const double *fb, double c,
        double s, double dg, double leak) {
    double da = fa[0] + fa[1] * c + fa[2] * s + 0.5 * leak * fa[3];
    double db = (1.0 - dg) * (fb[0] - fb[1] * c - fb[2] * s) - 0.5 * leak * fb[3];
    return 0.5 * (da - db);
}
__device__ __forceinline__ void add_terms(Sums &t, double c, double s, double d) {
    t.a11 += c * c; t.a12 += c * s; t.a22 += s * s; t.b1 += c * d; t.b2 += s * d;
}
// Normal-equation terms of one hit over every rotation r and pair m (tod_cpu._hit_sums);
// field_b(r, m, fb) fills what detector B sees. With zero, also those of the fields with
// Q = U = 0 (I and the template kept): the Q = U = 0 check from the same hits.
template <class FieldB>
__device__ __forceinline__ Sums hit_sums(double psi, const double *fa, FieldB field_b, int nk,
        int nm, const double *turn_c, const double *turn_s, const double *dg, const double *leak,
        Sums *zero) {
    Sums t;
    if (zero) *zero = Sums{};
    double c0 = cos(2.0 * psi), s0 = sin(2.0 * psi);
    for (int r = 0; r < nk; ++r) for (int m = 0; m < nm; ++m) {
        double c = c0 * turn_c[r * nm + m] - s0 * turn_s[r * nm + m];
        double s = s0 * turn_c[r * nm + m] + c0 * turn_s[r * nm + m];
        double fb[4];
        field_b(r, m, fb);
        add_terms(t, c, s, pair_difference(fa, fb, c, s, dg[m], leak[m]));
        if (zero) {
            double fa0[4] = {fa[0], 0.0, 0.0, fa[3]}, fb0[4] = {fb[0], 0.0, 0.0, fb[3]};
            add_terms(*zero, c, s, pair_difference(fa0, fb0, c, s, dg[m], leak[m]));
        }
    }
    return t;
}
__device__ __forceinline__ void add_sums(Sums &acc, const Sums &t) {
    acc.a11 += t.a11; acc.a12 += t.a12; acc.a22 += t.a22; acc.b1 += t.b1; acc.b2 += t.b2;
}
__device__ __forceinline__ void store_sums(double *out, i64 p, const Sums &t) {
    out[5 * p] = t.a11; out[5 * p + 1] = t.a12; out[5 * p + 2] = t.a22; out[5 * p + 3] = t.b1;
    out[5 * p + 4] = t.b2;
}
// (I, Q, U, template) of point k of a field-major (nf, n) array
__device__ __forceinline__ void load_fields(const double *v, int nf, i64 n, i64 k, double *out) {
    out[3] = 0.0;
    for (int f = 0; f < nf; ++f) out[f] = v[f * n + k];
}

extern "C" __global__ void generate_hits(const i64 *pixels, const i64 *offsets, const double *range,
        const double *centre, i64 n, u64 seed, i64 nside, int centred, double *theta, double *phi,
        double *psi) {
    i64 k = blockIdx.x * (i64)blockDim.x + threadIdx.x;
    if (k >= n) return;
    i64 ix, iy, face;
    u64 key = pixel_key(seed, (u64)pixels[k]);
    ring2xyf(nside, pixels[k], &ix, &iy, &face);
    for (i64 h = offsets[k]; h < offsets[k + 1]; ++h)
        draw_hit(key, h - offsets[k], nside, ix, iy, face, range[k], centre[k], centred, &theta[h],
                 &phi[h], &psi[h]);
}

extern "C" __global__ void offset_points(const double *theta, const double *phi,
        const double *psi, i64 nh, int nk, int nm, const double *rho_c, const double *rho_s,
        double *tb, double *pb) {
    i64 h = blockIdx.x * (i64)blockDim.x + threadIdx.x;
    if (h >= nh) return;
    double inv_sin_t = 1.0 / sin(theta[h]), cos_psi, sin_psi;
    sincos(psi[h], &sin_psi, &cos_psi);
    for (int k = 0; k < nk; ++k) for (int m = 0; m < nm; ++m) {
        i64 idx = (h * nk + k) * nm + m;
        offset_point(theta[h], phi[h], inv_sin_t, cos_psi, sin_psi, rho_c[k * nm + m],
                     rho_s[k * nm + m], &tb[idx], &pb[idx]);
    }
}

extern "C" __global__ void interpolate(const double *stack, int nfield, i64 nside,
        const double *theta, const double *phi, i64 n, double *out) {
    i64 k = blockIdx.x * (i64)blockDim.x + threadIdx.x;
    if (k >= n) return;
    double f[4];
    interp_point(stack, nfield, nside, theta[k], phi[k], f);
    for (int i = 0; i < nfield; ++i) out[i * n + k] = f[i];
}

// Sums of hit h of the field-major value arrays va (nf, nh) and vb (nf, nh, nk, nm) or null.
__device__ __forceinline__ Sums stored_hit_sums(i64 h, const double *psi, const double *va,
        const double *vb, i64 nh, int nf, int nk, int nm, const double *turn_c,
        const double *turn_s, const double *dg, const double *leak) {
    double fa[4];
    load_fields(va, nf, nh, h, fa);
    return hit_sums(psi[h], fa, [&](int r, int m, double *fb) {
        if (vb) load_fields(vb, nf, nh * nk * nm, (h * nk + r) * nm + m, fb);
        else for (int f = 0; f < 4; ++f) fb[f] = fa[f];
    }, nk, nm, turn_c, turn_s, dg, leak, nullptr);
}

// Adds the sums of each pixel's hits (offsets) onto its row of out: row target[p], or p when
// target is null. Each row is added in hit order, as tod_cpu.accumulate(_scatter) do.
extern "C" __global__ void accumulate(const i64 *offsets, const double *psi, i64 npix,
        const i64 *target, const double *va, const double *vb, i64 nh, int nf, int nk, int nm,
        const double *turn_c, const double *turn_s, const double *dg, const double *leak,
        double *out) {
    i64 p = blockIdx.x * (i64)blockDim.x + threadIdx.x;
    if (p >= npix) return;
    i64 row = target ? target[p] : p;
    const double *o = out + 5 * row;
    Sums acc{o[0], o[1], o[2], o[3], o[4]};
    for (i64 h = offsets[p]; h < offsets[p + 1]; ++h)
        add_sums(acc, stored_hit_sums(h, psi, va, vb, nh, nf, nk, nm, turn_c, turn_s, dg, leak));
    store_sums(out, row, acc);
}

extern "C" __global__ void bin_scan(const i64 *pixels, const i64 *n_phi, const double *range,
        const double *centre, i64 n, u64 seed, i64 nside, int centred, const double *stack,
        int nf, int nk, int nm, const double *turn_c, const double *turn_s, const double *dg,
        const double *rho_c, const double *rho_s, const double *leak, int pointing, int zero_qu,
        double *out) {
    i64 k = blockIdx.x * (i64)blockDim.x + threadIdx.x;
    if (k >= n) return;
    i64 ix, iy, face;
    u64 key = pixel_key(seed, (u64)pixels[k]);
    ring2xyf(nside, pixels[k], &ix, &iy, &face);
    Sums acc, acc0, zero;
    for (i64 j = 0; j < n_phi[k]; ++j) {
        double theta, phi, psi, fa[4];
        draw_hit(key, j, nside, ix, iy, face, range[k], centre[k], centred, &theta, &phi, &psi);
        interp_point(stack, nf, nside, theta, phi, fa);
        double inv_sin_t = 0.0, cos_psi = 0.0, sin_psi = 0.0;
        if (pointing) { inv_sin_t = 1.0 / sin(theta); sincos(psi, &sin_psi, &cos_psi); }
        add_sums(acc, hit_sums(psi, fa, [&](int r, int m, double *fb) {
            if (!pointing) { for (int f = 0; f < 4; ++f) fb[f] = fa[f]; return; }
            double tb, pb;
            offset_point(theta, phi, inv_sin_t, cos_psi, sin_psi, rho_c[r * nm + m],
                         rho_s[r * nm + m], &tb, &pb);
            interp_point(stack, nf, nside, tb, pb, fb);
        }, nk, nm, turn_c, turn_s, dg, leak, zero_qu ? &zero : nullptr));
        if (zero_qu) add_sums(acc0, zero);
    }
    store_sums(out, k, acc);
    if (zero_qu) store_sums(out + 5 * n, k, acc0);
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
