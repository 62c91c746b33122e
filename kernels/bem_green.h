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

/* (1 - z) e^z - 1 = -z^2 sum_{m>=0} (m+1) z^m / (m+2)!  (Horner to m = 13 for |z| < 1/2, where
 * the tail is below 1e-16; closed form otherwise, where it has no cancellation) */
inline vcplx_t bem_one_minus_z_expz_m1(vcplx_t z)
{
    vcplx_t p = vc_new((vreal_t)(R(14.0) / R(1307674368000.0)), (vreal_t)(R(0.0))); /* 14/15! */
    real_t factorial = R(1307674368000.0); /* (m+2)! at m = 13 */
    for (int m = 12; m >= 0; --m) {
        factorial /= (real_t)(m + 3);
        p = vc_mul(p, z);
        p.re += (real_t)(m + 1) / factorial;
    }
    const vcplx_t series = vc_scale(vc_mul(vc_mul(z, z), p), (vreal_t)(R(-1.0)));
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
