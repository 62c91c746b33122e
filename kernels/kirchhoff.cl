/* Scalar Kirchhoff (by-parts form, approx.md §3.3) on OpenCL, and the transform shared by the
 * Kirchhoff-family rungs (Harvey–Shack, physical optics: kernels/harvey_shack.cl,
 * kernels/physical_optics.cl).
 *
 * The far-field integral I(s) = Σ g e^{+jk[s·x + (μ_i+μ_o) z]} (e^{+jωt}; s = u_i + u_o) of an
 * aperture g on the nodes has a μ_o-dependent phase. It is expanded exactly (Jacobi–Anger in
 * Chebyshev polynomials, t = 2μ_o − 1):
 *   e^{jkμ_o z} = e^{jkz/2} Σ_n ε_n j^n J_n(kz/2) T_n(t),  ε_0 = 1, ε_n = 2.
 *
 *   kirchhoff_fields:      g_n(a,b) = g e^{jk(μ_i + 1/2) z} ε_n j^n J_n(kz/2) · pre_x[a] pre_y[b]
 *                          for one aperture g (Kirchhoff's footprint Δ²W, or one of the six current
 *                          components × two polarizations of PO)
 *   (host: chirp-z convolution of every g_n along x and y, see solver/czt.py)
 *   kirchhoff_accumulate:  acc(j,l) += Σ_n T_n(t(j,l)) A_n(j,l)
 *   kirchhoff_farfield:    E of both polarizations from acc, Ω_K and Fresnel at the half vector.
 *
 * Build define NMAX_BUF: size of the private Bessel buffer (>= n_max + 1).
 */
#include "wb_complex.h"
#include "wb_fresnel.h"
#include "wb_hemisphere.h"

#ifndef NMAX_BUF
#define NMAX_BUF 64
#endif

/* J_0..J_nmax(x) for real x by Miller's backward recurrence, normalised with
 * J_0 + 2 Σ J_2k = 1. Tiny |x| uses the leading series term. */
void bessel_j_sequence(real_t x, int nmax, real_t *out)
{
    real_t ax = fabs(x);
    if (ax < R(1e-6)) {
        real_t term = R(1.0);
        for (int n = 0; n <= nmax; ++n) {
            out[n] = term;
            term *= R(0.5) * ax / (real_t)(n + 1);
        }
        out[0] -= R(0.25) * ax * ax;
    } else {
        int start = max(nmax, (int)ax) + 24;
        start += start & 1; /* even */
        real_t jp1 = R(0.0), jn = R(1e-30), norm = R(0.0);
        for (int n = start; n > 0; --n) {
            real_t jm1 = (R(2.0) * (real_t)n / ax) * jn - jp1;
            jp1 = jn;
            jn = jm1; /* now J_{n-1} */
            if ((n - 1) <= nmax) out[n - 1] = jn;
            if (((n - 1) & 1) == 0 && n - 1 > 0) norm += R(2.0) * jn;
            if (fabs(jn) > R(1e20)) { /* rescale to stay finite */
                jn *= R(1e-20); jp1 *= R(1e-20); norm *= R(1e-20);
                for (int m = n - 1; m <= nmax; ++m) out[m] *= R(1e-20);
            }
        }
        norm += jn; /* + J_0 */
        real_t inv = R(1.0) / norm;
        for (int n = 0; n <= nmax; ++n) out[n] *= inv;
    }
    if (x < R(0.0))
        for (int n = 1; n <= nmax; n += 2) out[n] = -out[n];
}

__kernel void kirchhoff_fields(
    __global const real_t *z,        /* (na, nb) heights − mid-height, µm */
    __global const cplx_t *window,   /* (na, nb) aperture, e.g. Δ² W (complex footprint) */
    __global const cplx_t *pre_x,    /* (na) chirp-z pre-factors along x */
    __global const cplx_t *pre_y,    /* (nb) */
    const int na, const int nb, const int nmax,
    const real_t k, const real_t mu_i,
    __global cplx_t *out)            /* (nmax+1, na, nb) */
{
    const int gid = get_global_id(0);
    if (gid >= na * nb) return;
    const int a = gid / nb, b = gid % nb;
    const real_t zz = z[gid];
    real_t jn[NMAX_BUF];
    bessel_j_sequence(R(0.5) * k * zz, nmax, jn);
    cplx_t base = c_mul(c_mul(c_expj(k * (mu_i + R(0.5)) * zz), c_mul(pre_x[a], pre_y[b])), window[gid]);
    const size_t plane = (size_t)na * nb;
    cplx_t jpow = c_new(R(1.0), R(0.0)); /* j^n */
    for (int n = 0; n <= nmax; ++n) {
        real_t w = (n == 0 ? R(1.0) : R(2.0)) * jn[n];
        out[n * plane + gid] = c_scale(c_mul(jpow, base), w);
        jpow = c_new(-jpow.y, jpow.x);
    }
}


__kernel void kirchhoff_accumulate(
    __global const cplx_t *chunk,   /* (count, res, row_stride) transforms of orders n0 .. n0+count-1 */
    const int n0, const int count, const int res, const int row_stride,
    __global cplx_t *acc)           /* (res, res) */
{
    const int gid = get_global_id(0);
    if (gid >= res * res) return;
    const int i = gid / res, j = gid % res;
    const real_t u = pixel_coordinate(i, res), v = pixel_coordinate(j, res);
    const real_t rho2 = u * u + v * v;
    if (rho2 >= R(1.0)) return;
    const real_t t = clamp(R(2.0) * sqrt(R(1.0) - rho2) - R(1.0), R(-1.0), R(1.0));
    const real_t theta = acos(t);
    const size_t plane = (size_t)res * row_stride;
    const size_t offset = (size_t)i * row_stride + j;
    /* T_n(t) = cos(nθ), continued by the (stable, |t| <= 1) three-term recurrence */
    real_t tn = cos((real_t)n0 * theta), tprev = cos((real_t)(n0 - 1) * theta);
    cplx_t sum = acc[gid];
    for (int m = 0; m < count; ++m) {
        sum = c_fma(chunk[m * plane + offset], c_new(tn, R(0.0)), sum);
        real_t tnext = R(2.0) * t * tn - tprev;
        tprev = tn;
        tn = tnext;
    }
    acc[gid] = sum;
}


/* Scalar far field of both polarizations at pixel gid: s ↔ φ̂_o (amplitude amp·r_s), p ↔ θ̂_o
 * (amp·r_p); φ = 0 at the pole. E: (2 pol, 3, res, res). */
inline void store_scalar_farfield(__global cplx_t *E, const int gid, const size_t plane, const real_t u,
                                  const real_t v, const real_t rho2, const real_t mu_o, const cplx_t amp,
                                  const cplx_t rs, const cplx_t rp)
{
    const real_t rho = sqrt(rho2);
    const real_t cphi = rho > R(0.0) ? u / rho : R(1.0), sphi = rho > R(0.0) ? v / rho : R(0.0);
    const real_t phat[3] = {-sphi, cphi, R(0.0)};
    const real_t that[3] = {mu_o * cphi, mu_o * sphi, -rho};
    cplx_t es = c_mul(amp, rs), ep = c_mul(amp, rp);
    for (int c = 0; c < 3; ++c) {
        E[(0 * 3 + c) * plane + gid] = c_scale(es, phat[c]);
        E[(1 * 3 + c) * plane + gid] = c_scale(ep, that[c]);
    }
}

/* Zero field outside the unit disk (6 components). */
inline void store_zero_farfield(__global cplx_t *E, const int gid, const size_t plane)
{
    for (int m = 0; m < 6; ++m) E[m * plane + gid] = c_new(R(0.0), R(0.0));
}

/* Pixel gid of the res × res projected hemisphere: its indices, direction cosines and ρ² = u² + v²;
 * 0 when its centre lies outside the unit disk. */
inline int pixel_in_disk(const int gid, const int res, int *i, int *j, real_t *u, real_t *v, real_t *rho2)
{
    *i = gid / res;
    *j = gid % res;
    *u = pixel_coordinate(*i, res);
    *v = pixel_coordinate(*j, res);
    *rho2 = *u * *u + *v * *v;
    return *rho2 < R(1.0);
}

/* pixel_in_disk with μ_o, storing a zero field in E for a pixel outside the disk. */
inline int disk_pixel(__global cplx_t *E, const int gid, const int res, int *i, int *j, real_t *u, real_t *v,
                      real_t *rho2, real_t *mu_o)
{
    if (!pixel_in_disk(gid, res, i, j, u, v, rho2)) {
        store_zero_farfield(E, gid, (size_t)res * res);
        return 0;
    }
    *mu_o = sqrt(R(1.0) - *rho2);
    return 1;
}


__kernel void kirchhoff_farfield(
    __global const cplx_t *acc,      /* (res, res) Σ_n T_n A_n (chirp-z post factors not applied) */
    __global const cplx_t *post_x,   /* (res) */
    __global const cplx_t *post_y,   /* (res) */
    const int res,
    const real_t k, const real_t ux_i, const real_t uy_i, const real_t mu_i,
    const real_t dz_ref,             /* mid-height − reference height, µm */
    const real_t inv_lambda1,        /* 1/λ₁ (µm⁻¹), wavelength in the exterior medium */
    const cplx_t eta,                /* n₂/n₁ */
    __global cplx_t *E)              /* (2 pol, 3, res, res) */
{
    const int gid = get_global_id(0);
    int i, j;
    real_t u, v, rho2, mu_o;
    if (gid >= res * res || !disk_pixel(E, gid, res, &i, &j, &u, &v, &rho2, &mu_o)) return;
    cplx_t I = c_mul(acc[gid], c_mul(post_x[i], post_y[j]));
    I = c_mul(I, c_expj(k * (mu_i + mu_o) * dz_ref));

    const real_t cos_io = ux_i * u + uy_i * v + mu_i * mu_o; /* ω_i · ω_o */
    const real_t s = mu_i + mu_o;
    const real_t omega_k = (R(1.0) + cos_io) * (R(1.0) + cos_io) / (mu_i * mu_o * s * s);
    const real_t cos_h = sqrt(fmax(R(0.5) * (R(1.0) + cos_io), R(0.0)));
    cplx_t rs, rp;
    fresnel_rs_rp(eta, cos_h, &rs, &rp);
    cplx_t amp = c_scale(I, sqrt(mu_i * mu_o * omega_k) * inv_lambda1);
    store_scalar_farfield(E, gid, (size_t)res * res, u, v, rho2, mu_o, amp, rs, rp);
}
