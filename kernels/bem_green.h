/* 3D Helmholtz Green's function pieces for the BEM element integrals (e^{+jwt}), on vector lanes.
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
#include "wb_vcomplex.h"

#define BEM_FULL 0
#define BEM_REMAINDER 1
#define BEM_STATIC 2

/* (1 - z) e^z - 1 = -sum_{n>=2} (n-1) z^n / n!  (series for |z| < 1/2, closed form otherwise) */
inline vcplx_t bem_one_minus_z_expz_m1(vcplx_t z)
{
    vcplx_t term = vc_scale(vc_mul(z, z), (vreal_t)(R(0.5))); /* z^n / n! at n = 2 */
    vcplx_t series = vc_scale(term, (vreal_t)(R(-1.0)));
    for (int n = 3; n <= 22; ++n) {
        term = vc_scale(vc_mul(term, z), (vreal_t)(R(1.0) / (real_t)n));
        series = vc_fma_real(term, (vreal_t)(-(real_t)(n - 1)), series);
    }
    const vcplx_t one_minus_z = vc_new(R(1.0) - z.re, -z.im);
    vcplx_t direct = vc_mul(one_minus_z, vc_exp(z));
    direct.re -= R(1.0);
    return vc_select(direct, series, z.re * z.re + z.im * z.im < R(0.25));
}

/* g and gk of one medium (scalar k) at distances r (inv_r = 1/r), kind BEM_FULL or BEM_REMAINDER */
inline void bem_green(int kind, cplx_t k, vreal_t r, vreal_t inv_r, vcplx_t *g, vcplx_t *gk)
{
    const vcplx_t z = vc_new(k.y * r, -k.x * r); /* -jkR */
    const vreal_t s1 = WB_INV_4PI * inv_r;
    const vreal_t s3 = s1 * inv_r * inv_r;
    if (kind == BEM_REMAINDER) {
        *g = vc_scale(vc_expm1(z), s1);
        *gk = vc_scale(bem_one_minus_z_expz_m1(z), -s3);
    } else {
        const vcplx_t e = vc_exp(z);
        *g = vc_scale(e, s1);
        *gk = vc_scale(vc_mul(vc_new(R(1.0) - z.re, -z.im), e), -s3); /* (1 - z) = 1 + jkR */
    }
}

#endif
