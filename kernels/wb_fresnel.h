/* Fresnel reflection coefficients of a flat interface (e^{+jwt}, index n - j kappa).
 * solver/fresnel.py fresnel_rs_rp is the host twin. */
#ifndef WB_FRESNEL_H
#define WB_FRESNEL_H
#include "wb_complex.h"

/* (r_s, r_p) for relative index eta = n2/n1 at cos(theta) = c in the incident medium. */
inline void fresnel_rs_rp(cplx_t eta, real_t c, cplx_t *rs, cplx_t *rp)
{
    cplx_t eta2 = c_mul(eta, eta);
    cplx_t t = c_sqrt(c_add(eta2, c_new(c * c - R(1.0), R(0.0))));
    cplx_t cc = c_new(c, R(0.0));
    *rs = c_div(c_sub(cc, t), c_add(cc, t));
    cplx_t e2c = c_scale(eta2, c);
    *rp = c_div(c_sub(e2c, t), c_add(e2c, t));
}

#endif
