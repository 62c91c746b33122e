/* Complex arithmetic on real2_t (x = real part, y = imaginary part).
 *
 * Never use the vector operators * or / on complex values: they act component-wise.
 * Conventions of the project: time dependence e^{+jwt}, outgoing waves e^{-jkR}.
 */
#ifndef WB_COMPLEX_H
#define WB_COMPLEX_H
#include "wb_types.h"

typedef real2_t cplx_t;

inline cplx_t c_new(real_t re, real_t im) { return (cplx_t)(re, im); }
inline cplx_t c_add(cplx_t a, cplx_t b) { return a + b; }
inline cplx_t c_sub(cplx_t a, cplx_t b) { return a - b; }
inline cplx_t c_scale(cplx_t a, real_t s) { return a * s; }
inline cplx_t c_conj(cplx_t a) { return (cplx_t)(a.x, -a.y); }
inline real_t c_abs2(cplx_t a) { return a.x * a.x + a.y * a.y; }
inline real_t c_abs(cplx_t a) { return hypot(a.x, a.y); }
inline cplx_t c_mul(cplx_t a, cplx_t b)
{
    return (cplx_t)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}
/* a + b*c */
inline cplx_t c_fma(cplx_t b, cplx_t c, cplx_t a)
{
    return (cplx_t)(fma(b.x, c.x, fma(-b.y, c.y, a.x)), fma(b.x, c.y, fma(b.y, c.x, a.y)));
}
inline cplx_t c_div(cplx_t a, cplx_t b)
{
    /* Smith's algorithm: no overflow for large |b| */
    if (fabs(b.x) >= fabs(b.y)) {
        real_t r = b.y / b.x, den = b.x + b.y * r;
        return (cplx_t)((a.x + a.y * r) / den, (a.y - a.x * r) / den);
    } else {
        real_t r = b.x / b.y, den = b.x * r + b.y;
        return (cplx_t)((a.x * r + a.y) / den, (a.y * r - a.x) / den);
    }
}
/* e^{j phi} */
inline cplx_t c_expj(real_t phi)
{
    real_t c, s = sincos(phi, &c);
    return (cplx_t)(c, s);
}
inline cplx_t c_exp(cplx_t a) { return c_scale(c_expj(a.y), exp(a.x)); }
/* principal square root (branch cut on the negative real axis, Re >= 0) */
inline cplx_t c_sqrt(cplx_t a)
{
    real_t m = c_abs(a);
    real_t re = sqrt(R(0.5) * (m + fabs(a.x)));
    if (re == R(0.0)) return (cplx_t)(R(0.0), R(0.0));
    if (a.x >= R(0.0)) return (cplx_t)(re, a.y / (R(2.0) * re));
    return (cplx_t)(fabs(a.y) / (R(2.0) * re), copysign(re, a.y));
}
inline cplx_t c_log(cplx_t a) { return (cplx_t)(log(c_abs(a)), atan2(a.y, a.x)); }
/* e^a - 1 without cancellation for small |a|: Re = expm1(x) cos y - 2 sin^2(y/2) */
inline cplx_t c_expm1(cplx_t a)
{
    real_t c, s = sincos(a.y, &c);
    real_t sh = sin(R(0.5) * a.y);
    return (cplx_t)(expm1(a.x) * c - R(2.0) * sh * sh, exp(a.x) * s);
}

#endif
