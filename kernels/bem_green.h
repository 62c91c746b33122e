/* 3D Helmholtz Green's function pieces for the BEM element integrals (e^{+jwt}).
 *
 *   G(R)  = e^{-jkR} / (4 pi R)                       (g)
 *   grad G = gk(R) * Rvec,  gk = -(1 + jkR) e^{-jkR} / (4 pi R^3)
 *
 * The static parts are G0 = 1/(4 pi R) and gk0 = -1/(4 pi R^3). The "remainder" versions return
 * G - G0 = expm1(-jkR)/(4 pi R) and gk - gk0 = -[(1 + jkR) e^{-jkR} - 1]/(4 pi R^3), evaluated
 * without cancellation (series for |kR| < 1/2). A complex k = k' - jk'' (k'' >= 0) decays.
 * NumPy twins: wavebrdf.solver.bem3d.elements.green_terms.
 */
#ifndef BEM_GREEN_H
#define BEM_GREEN_H
#include "wb_complex.h"

#define BEM_FULL 0
#define BEM_REMAINDER 1
#define BEM_STATIC 2

/* (1 - z) e^z - 1 = -sum_{n>=2} (n-1) z^n / n!  (accurate for all z) */
inline cplx_t bem_one_minus_z_expz_m1(cplx_t z)
{
    if (c_abs2(z) < R(0.25)) {
        cplx_t term = c_scale(c_mul(z, z), R(0.5)); /* z^n / n! at n = 2 */
        cplx_t sum = c_scale(term, R(-1.0));
        for (int n = 3; n <= 22; ++n) {
            term = c_scale(c_mul(term, z), R(1.0) / (real_t)n);
            sum = c_sub(sum, c_scale(term, (real_t)(n - 1)));
        }
        return sum;
    }
    cplx_t one_minus_z = c_new(R(1.0) - z.x, -z.y);
    return c_sub(c_mul(one_minus_z, c_exp(z)), c_new(R(1.0), R(0.0)));
}

/* g and gk of one medium for kind BEM_FULL or BEM_REMAINDER; inv_r = 1/R */
inline void bem_green(int kind, cplx_t k, real_t r, real_t inv_r, cplx_t *g, cplx_t *gk)
{
    cplx_t z = c_new(k.y * r, -k.x * r); /* -jkR */
    real_t s1 = WB_INV_4PI * inv_r;
    real_t s3 = s1 * inv_r * inv_r;
    if (kind == BEM_REMAINDER) {
        *g = c_scale(c_expm1(z), s1);
        *gk = c_scale(bem_one_minus_z_expz_m1(z), -s3);
    } else {
        cplx_t e = c_exp(z);
        *g = c_scale(e, s1);
        *gk = c_scale(c_mul(c_new(R(1.0) - z.x, -z.y), e), -s3); /* (1 - z) = 1 + jkR */
    }
}

#endif
