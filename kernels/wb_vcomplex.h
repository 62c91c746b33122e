/* Complex arithmetic on explicit SIMD vectors: vreal_t = WB_VW lanes of real_t.
 *
 * CPU OpenCL runtimes (PoCL) do not vectorize kernels whose work-items run inner loops, so
 * kernels that need the speed process WB_VW independent items per work-item in vector lanes.
 * Build option -D WB_VW=1|2|4|8 (default 4; use 1 on GPUs, where lanes are work-items already).
 * vcplx_t holds WB_VW complex numbers as two vectors (real, imaginary parts).
 */
#ifndef WB_VCOMPLEX_H
#define WB_VCOMPLEX_H
#include "wb_complex.h"

#ifndef WB_VW
#define WB_VW 4
#endif
#define WB_PASTE_(a, b) a##b
#define WB_PASTE(a, b) WB_PASTE_(a, b)
/* the n-lane vector type of real_t (n = 2, 3, 4, 8, 16) */
#if WB_FP64
#define WB_REALN(n) WB_PASTE(double, n)
#else
#define WB_REALN(n) WB_PASTE(float, n)
#endif

#if WB_VW == 1
typedef real_t vreal_t;
#if WB_FP64
typedef long vmask_t;
#else
typedef int vmask_t;
#endif
#else
#if WB_FP64
typedef WB_PASTE(double, WB_VW) vreal_t;
typedef WB_PASTE(long, WB_VW) vmask_t;
#else
typedef WB_PASTE(float, WB_VW) vreal_t;
typedef WB_PASTE(int, WB_VW) vmask_t;
#endif
#endif

/* lane i of a private vector variable */
#define VLANE(v, i) (((real_t *)&(v))[i])

typedef struct {
    vreal_t re, im;
} vcplx_t;

inline vcplx_t vc_new(vreal_t re, vreal_t im)
{
    vcplx_t z;
    z.re = re;
    z.im = im;
    return z;
}
inline vcplx_t vc_zero(void) { return vc_new((vreal_t)(R(0.0)), (vreal_t)(R(0.0))); }
inline vcplx_t vc_add(vcplx_t a, vcplx_t b) { return vc_new(a.re + b.re, a.im + b.im); }
inline vcplx_t vc_sub(vcplx_t a, vcplx_t b) { return vc_new(a.re - b.re, a.im - b.im); }
inline vcplx_t vc_scale(vcplx_t a, vreal_t s) { return vc_new(a.re * s, a.im * s); }
inline vcplx_t vc_mul(vcplx_t a, vcplx_t b)
{
    return vc_new(a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re);
}
/* a*b + c */
inline vcplx_t vc_fma(vcplx_t a, vcplx_t b, vcplx_t c)
{
    return vc_new(fma(a.re, b.re, fma(-a.im, b.im, c.re)), fma(a.re, b.im, fma(a.im, b.re, c.im)));
}
/* a + b*s (s real vector) */
inline vcplx_t vc_fma_real(vcplx_t b, vreal_t s, vcplx_t a)
{
    return vc_new(fma(b.re, s, a.re), fma(b.im, s, a.im));
}
/* e^a */
inline vcplx_t vc_exp(vcplx_t a)
{
    vreal_t c, s = sincos(a.im, &c);
    const vreal_t m = exp(a.re);
    return vc_new(m * c, m * s);
}
/* lane-wise choice: mask lanes true (all bits set) take b, the others a */
inline vcplx_t vc_select(vcplx_t a, vcplx_t b, vmask_t mask)
{
    return vc_new(select(a.re, b.re, mask), select(a.im, b.im, mask));
}
/* lane i as a scalar complex */
inline cplx_t vc_lane(vcplx_t a, int i) { return c_new(VLANE(a.re, i), VLANE(a.im, i)); }

/* WB_VW consecutive complex numbers of an interleaved (re, im) array as a vcplx_t, and back */
#if WB_VW == 1
inline vcplx_t vc_load(__global const cplx_t *p) { return vc_new(p[0].x, p[0].y); }
inline void vc_store(const vcplx_t z, __global cplx_t *p) { p[0] = c_new(z.re, z.im); }
#else
#if WB_VW == 2
#define WB_VW2 4
#define VC_PAIRS(T, z) ((T)((z).re.s0, (z).im.s0, (z).re.s1, (z).im.s1))
#elif WB_VW == 4
#define WB_VW2 8
#define VC_PAIRS(T, z) ((T)((z).re.s0, (z).im.s0, (z).re.s1, (z).im.s1, (z).re.s2, (z).im.s2, (z).re.s3, (z).im.s3))
#else
#define WB_VW2 16
#define VC_PAIRS(T, z) ((T)((z).re.s0, (z).im.s0, (z).re.s1, (z).im.s1, (z).re.s2, (z).im.s2, (z).re.s3, (z).im.s3, \
                            (z).re.s4, (z).im.s4, (z).re.s5, (z).im.s5, (z).re.s6, (z).im.s6, (z).re.s7, (z).im.s7))
#endif
typedef WB_REALN(WB_VW2) vpair_t;
inline vcplx_t vc_load(__global const cplx_t *p)
{
    const vpair_t v = WB_PASTE(vload, WB_VW2)(0, (__global const real_t *)p);
    return vc_new(v.even, v.odd);
}
inline void vc_store(const vcplx_t z, __global cplx_t *p)
{
    WB_PASTE(vstore, WB_VW2)(VC_PAIRS(vpair_t, z), 0, (__global real_t *)p);
}
#endif

#endif
