/* Harvey–Shack rungs OHS and GHS (approx.md §3.3, "Unified discrete form"), e^{+jωt}:
 *
 *   f = K |r(θ_i)|² (μ_o/μ_i) |I(s)|² / (λ₁² Δ² Σ W²),   I(s) = Σ Δ² W e^{+jk[s·x + c_z (z − z_ref)]},
 *   OHS: c_z = 2k,  GHS: c_z = k(μ_i+μ_o)  (s = u_i + u_o; K = 1 for OHS).
 *
 * hs_farfield        the pixel assembly from acc (post factors per axis):
 *   per incidence:   acc from the Chebyshev/chirp-z transform of kernels/kirchhoff.cl (GHS:
 *                    Kirchhoff's own integral; OHS: the flat transform of W e^{2jkz}).
 *   all incidences:  acc interpolated (sgrid_rows, sgrid_columns) from one transform per (surface,
 *                    λ, footprint) on the s = u_i + u_o grid (Gaussian gridding,
 *                    solver/approx/harvey_shack.py SGrid); GHS sums the τ-expansion orders with
 *                    T_n(μ_i + μ_o − 1).
 * E of both polarizations: s ↔ φ̂_o, p ↔ θ̂_o with amplitude I μ_o/λ₁ · r_s|r_p (K applied on the host).
 */
#include "kirchhoff.cl"

#ifndef SPREAD
#define SPREAD 6 /* half-width of the gridding stencil (build define) */
#endif

__kernel void hs_farfield(
    __global const cplx_t *acc,      /* (res, res) Σ_n T_n A_n (chirp-z post factors not applied) */
    __global const cplx_t *post_x,   /* (res) */
    __global const cplx_t *post_y,   /* (res) */
    const int res, const int ghs,
    const real_t k, const real_t mu_i,
    const real_t dz_ref,             /* mid-height − reference height, µm */
    const real_t inv_lambda1,        /* 1/λ₁ (µm⁻¹) */
    const cplx_t rs, const cplx_t rp, /* Fresnel at θ_i */
    __global cplx_t *E)              /* (2 pol, 3, res, res) */
{
    const int gid = get_global_id(0);
    int i, j;
    real_t u, v, rho2, mu_o;
    if (gid >= res * res || !disk_pixel(E, gid, res, &i, &j, &u, &v, &rho2, &mu_o)) return;
    /* e^{jk c_z dz_ref} (c_z = 2 for OHS, μ_i + μ_o for GHS), amplitude I μ_o/λ₁ (Ω = μ_o/μ_i) */
    const real_t cz = ghs ? mu_i + mu_o : R(2.0);
    cplx_t I = c_mul(acc[gid], c_mul(post_x[i], post_y[j]));
    I = c_mul(I, c_expj(k * cz * dz_ref));
    store_scalar_farfield(E, gid, (size_t)res * res, u, v, rho2, mu_o, c_scale(I, mu_o * inv_lambda1), rs, rp);
}


/* All incidences: the pixels form a tensor grid s = (u_i,x + u(i), u_i,y + u(j)), so the gridding
 * I_n = Wx Q_n Wyᵀ is separable (host: per-axis weights w, node indices idx, 2·SPREAD per pixel).
 * sgrid_rows:    R(i, c) = Σ_a wx(i,a) Q_n(ix(i,a), (c0 + c) mod M)       c < ncols
 * sgrid_columns: acc(i, j) += T_n(μ_i + μ_o − 1) Σ_b wy(j,b) R(i, (iy(j,b) − c0) mod M)
 * then hs_farfield with post factors e^{jk s_x x_c}, e^{jk s_y y_c}. */
__kernel void sgrid_rows(
    __global const cplx_t *Q,        /* (M, M) order n */
    __global const int *ix, __global const real_t *wx, /* (res, 2 SPREAD) */
    const int M, const int res, const int c0, const int ncols,
    __global cplx_t *Rows)           /* (res, ncols) */
{
    const int gid = get_global_id(0);
    if (gid >= res * ncols) return;
    const int i = gid / ncols, c = gid % ncols;
    int col = c0 + c;
    col = col >= M ? col - M : col;
    cplx_t sum = c_new(R(0.0), R(0.0));
    for (int a = 0; a < 2 * SPREAD; ++a) {
        const int m = i * 2 * SPREAD + a;
        sum = c_fma(Q[(size_t)ix[m] * M + col], c_new(wx[m], R(0.0)), sum);
    }
    Rows[gid] = sum;
}


__kernel void sgrid_columns(
    __global const cplx_t *Rows,     /* (res, ncols) */
    __global const int *iy, __global const real_t *wy, /* (res, 2 SPREAD) */
    const int M, const int res, const int c0, const int ncols,
    const int n, const real_t mu_i,  /* order n: weight T_n(μ_i + μ_o − 1) (1 for n = 0) */
    __global cplx_t *acc)            /* (res, res) */
{
    const int gid = get_global_id(0);
    int i, j;
    real_t u, v, rho2;
    if (gid >= res * res || !pixel_in_disk(gid, res, &i, &j, &u, &v, &rho2)) return;
    const real_t tau = clamp(mu_i + sqrt(R(1.0) - rho2) - R(1.0), R(-1.0), R(1.0));
    const real_t tn = n == 0 ? R(1.0) : cos((real_t)n * acos(tau));
    __global const cplx_t *row = Rows + (size_t)i * ncols;
    cplx_t sum = c_new(R(0.0), R(0.0));
    for (int b = 0; b < 2 * SPREAD; ++b) {
        const int m = j * 2 * SPREAD + b;
        int col = iy[m] - c0;
        col = col < 0 ? col + M : col;
        sum = c_fma(row[col], c_new(wy[m], R(0.0)), sum);
    }
    acc[gid] = c_fma(sum, c_new(tn, R(0.0)), acc[gid]);
}
