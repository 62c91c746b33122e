/* Hankel functions of the second kind H0^(2)(z), H1^(2)(z) for complex z (fiber.md §8).
 *
 * Domain: z != 0 with -pi/2 < arg z <= 0 (the fiber's k_rho R: real outside, Im <= 0 inside a
 * lossy fiber). NumPy mirror with the same names: wavebrdf.solver.fiber.hankel.
 *
 *   |z| <  HANKEL_SERIES_MAX        ascending series (bessel01_series)
 *   |z| >= HANKEL_SERIES_MAX        Gauss-Laguerre quadrature of the integral representation
 *       H_nu(z) = sqrt(2/(pi z)) e^{-j(z - nu pi/2 - pi/4)} / Gamma(nu+1/2)
 *                 * int_0^inf e^{-u} u^{nu-1/2} (1 - j u/(2z))^{nu-1/2} du
 *     (20 nodes below HANKEL_LAGUERRE_FINE_MAX, 10 below HANKEL_LAGUERRE_MID_MAX, 6 above; each
 *     rule has the weight u^{-1/2} e^{-u} and serves both orders since u^{1/2} = u * u^{-1/2}).
 * The series is used only where J and Y are not exponentially larger than H, so there is no
 * cancellation for complex z; the quadrature is accurate to ~1e-13 for |z| >= 2.5.
 */
#ifndef WB_HANKEL_H
#define WB_HANKEL_H
#include "wb_complex.h"
#include "hankel_laguerre.h"

#define WB_EULER_GAMMA R(0.57721566490153286061)
#define WB_2_OVER_PI   R(0.63661977236758134308)
#define WB_INV_PI      R(0.31830988618379067154)
#define WB_INV_SQRT_PI R(0.56418958354775628695)

/* Ascending series without logarithm and pole:
 *   J0 = 1 + j0m1,  Y0 = (2/pi) ln(z/2) J0 + y0r,  Y1 = (2/pi) ln(z/2) J1 - 2/(pi z) + y1r. */
inline void bessel01_series(cplx_t z, cplx_t *j0m1, cplx_t *j1, cplx_t *y0r, cplx_t *y1r)
{
    const cplx_t q = c_scale(c_mul(z, z), R(-0.25));
    cplx_t t = c_new(R(1.0), R(0.0));   /* q^k / (k!)^2 */
    cplx_t u = c_new(R(1.0), R(0.0));   /* q^k / (k! (k+1)!) */
    cplx_t a0 = c_new(R(0.0), R(0.0));  /* sum_{k>=1} t_k */
    cplx_t s0 = c_new(R(0.0), R(0.0));  /* sum_{k>=1} H_k t_k */
    cplx_t a1 = c_new(R(1.0), R(0.0));  /* sum_k u_k */
    cplx_t s1 = c_new(R(1.0), R(0.0));  /* sum_k (H_k + H_{k+1}) u_k */
    real_t harmonic = R(0.0);
    for (int k = 1; k <= HANKEL_SERIES_TERMS; ++k) {
        const real_t rk = (real_t)k;
        harmonic += R(1.0) / rk;
        t = c_scale(c_mul(t, q), R(1.0) / (rk * rk));
        u = c_scale(c_mul(u, q), R(1.0) / (rk * (rk + R(1.0))));
        a0 = c_add(a0, t);
        s0 = c_fma(t, c_new(harmonic, R(0.0)), s0);
        a1 = c_add(a1, u);
        s1 = c_fma(u, c_new(R(2.0) * harmonic + R(1.0) / (rk + R(1.0)), R(0.0)), s1);
    }
    const cplx_t half_z = c_scale(z, R(0.5));
    *j0m1 = a0;
    *j1 = c_mul(half_z, a1);
    const cplx_t j0 = c_new(R(1.0) + a0.x, a0.y);
    *y0r = c_scale(c_sub(c_scale(j0, WB_EULER_GAMMA), s0), WB_2_OVER_PI);
    *y1r = c_sub(c_scale(*j1, WB_2_OVER_PI * WB_EULER_GAMMA), c_scale(c_mul(half_z, s1), WB_INV_PI));
}

/* J - jY as (J.x + Y.y, J.y - Y.x) */
inline cplx_t c_j_minus_jy(cplx_t j, cplx_t y) { return c_new(j.x + y.y, j.y - y.x); }

inline void hankel2_01_series(cplx_t z, cplx_t *h0, cplx_t *h1)
{
    cplx_t j0m1, j1, y0r, y1r;
    bessel01_series(z, &j0m1, &j1, &y0r, &y1r);
    const cplx_t log_half = c_log(c_scale(z, R(0.5)));
    const cplx_t j0 = c_new(R(1.0) + j0m1.x, j0m1.y);
    const cplx_t y0 = c_add(c_scale(c_mul(log_half, j0), WB_2_OVER_PI), y0r);
    const cplx_t pole = c_div(c_new(WB_2_OVER_PI, R(0.0)), z);
    const cplx_t y1 = c_add(c_sub(c_scale(c_mul(log_half, j1), WB_2_OVER_PI), pole), y1r);
    *h0 = c_j_minus_jy(j0, y0);
    *h1 = c_j_minus_jy(j1, y1);
}

inline void hankel2_01_laguerre(cplx_t z, __constant const real_t *nodes,
                                __constant const real_t *weights, int n, cplx_t *h0, cplx_t *h1)
{
    /* -j/(2z) */
    const cplx_t c = c_div(c_new(R(0.0), R(-0.5)), z);
    cplx_t i0 = c_new(R(0.0), R(0.0));
    cplx_t i1 = c_new(R(0.0), R(0.0));
    for (int k = 0; k < n; ++k) {
        const real_t x = nodes[k], w = weights[k];
        const cplx_t s = c_sqrt(c_new(R(1.0) + x * c.x, x * c.y));
        i0 = c_add(i0, c_scale(c_div(c_new(R(1.0), R(0.0)), s), w));
        i1 = c_add(i1, c_scale(s, w * x));
    }
    /* sqrt(2/(pi z)) e^{-j(z - pi/4)} / sqrt(pi) */
    const cplx_t root = c_sqrt(c_div(c_new(WB_2_OVER_PI, R(0.0)), z));
    const cplx_t phase = c_exp(c_new(z.y, R(0.25) * WB_PI - z.x));
    const cplx_t pre = c_scale(c_mul(root, phase), WB_INV_SQRT_PI);
    *h0 = c_mul(pre, i0);
    const cplx_t p1 = c_mul(pre, i1);   /* times j * 2 (Gamma(3/2) = sqrt(pi)/2) */
    *h1 = c_new(R(-2.0) * p1.y, R(2.0) * p1.x);
}

inline void hankel2_01(cplx_t z, cplx_t *h0, cplx_t *h1)
{
    const real_t r = c_abs(z);
    if (r < HANKEL_SERIES_MAX) {
        hankel2_01_series(z, h0, h1);
    } else {
        /* one quadrature loop with the rule chosen by |z| (less divergent code than three calls) */
        const int fine = r < HANKEL_LAGUERRE_FINE_MAX, mid = r < HANKEL_LAGUERRE_MID_MAX;
        hankel2_01_laguerre(z, fine ? HANKEL_LAG_FINE_X : (mid ? HANKEL_LAG_MID_X : HANKEL_LAG_COARSE_X),
                            fine ? HANKEL_LAG_FINE_W : (mid ? HANKEL_LAG_MID_W : HANKEL_LAG_COARSE_W),
                            fine ? HANKEL_LAG_FINE_N : (mid ? HANKEL_LAG_MID_N : HANKEL_LAG_COARSE_N), h0, h1);
    }
}

#endif
