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

/* e^z - 1 and (1 - z) e^z - 1 of z = -jkR without cancellation, from one sincos(Im z / 2) and one
 * expm1(Re z): cos = 1 - 2 sh^2, sin = 2 sh ch, e^z - 1 = (expm1(Re z) cos - 2 sh^2) + j e^{Re z} sin.
 * (1 - z) e^z - 1 = -z^2 sum_{m>=0} (m+1) z^m / (m+2)! by Horner to m = 13 for |z| < 1/2 (tail below
 * 1e-16), else (1 - z)(e^z - 1) - z, which has no cancellation there. */
inline void bem_remainders(vcplx_t z, vcplx_t *expm1_z, vcplx_t *one_minus_z_expz_m1)
{
    vreal_t ch, sh = sincos(R(0.5) * z.im, &ch);
    const vreal_t a = expm1(z.re);
    const vreal_t two_sh2 = R(2.0) * sh * sh;
    const vcplx_t em1 = vc_new(a * (R(1.0) - two_sh2) - two_sh2, (R(1.0) + a) * (R(2.0) * sh * ch));
    *expm1_z = em1;
    vcplx_t p = vc_new((vreal_t)(R(14.0) / R(1307674368000.0)), (vreal_t)(R(0.0))); /* 14/15! */
    real_t factorial = R(1307674368000.0); /* (m+2)! at m = 13 */
    for (int m = 12; m >= 0; --m) {
        factorial /= (real_t)(m + 3);
        p = vc_mul(p, z);
        p.re += (real_t)(m + 1) / factorial;
    }
    const vcplx_t series = vc_scale(vc_mul(vc_mul(z, z), p), (vreal_t)(R(-1.0)));
    const vcplx_t direct = vc_sub(vc_mul(vc_new(R(1.0) - z.re, -z.im), em1), z);
    *one_minus_z_expz_m1 = vc_select(direct, series, z.re * z.re + z.im * z.im < R(0.25));
}

/* g and gk of one medium (scalar k) at distances r (inv_r = 1/r), kind BEM_FULL or BEM_REMAINDER */
inline void bem_green(int kind, cplx_t k, vreal_t r, vreal_t inv_r, vcplx_t *g, vcplx_t *gk)
{
    const vcplx_t z = vc_new(k.y * r, -k.x * r); /* -jkR */
    const vreal_t s1 = WB_INV_4PI * inv_r;
    const vreal_t s3 = s1 * inv_r * inv_r;
    if (kind == BEM_REMAINDER) {
        vcplx_t em1, p;
        bem_remainders(z, &em1, &p);
        *g = vc_scale(em1, s1);
        *gk = vc_scale(p, -s3);
    } else {
        const vcplx_t e = vc_exp(z);
        *g = vc_scale(e, s1);
        *gk = vc_scale(vc_mul(vc_new(R(1.0) - z.re, -z.im), e), -s3); /* (1 - z) = 1 + jkR */
    }
}

#endif
