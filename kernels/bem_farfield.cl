/* Far-field radiation integrals of surface currents by a direct quadrature sum (bem3d/farfield.py).
 *
 * For each direction d (unit vector) and each of `nsets` current sets (polarizations x {J, M}):
 *   F[d][s] = sum_q  c[q][s] * exp(+j k d . r[q])        (3 complex components)
 * r: (npoints, 3) positions; c: (npoints, nsets, 3) complex weights (current x area weight).
 * One work-item per direction. NumPy twin: radiation_integrals_numpy.
 */
#include "wb_complex.h"

#ifndef BEM_NSETS
#define BEM_NSETS 4
#endif

__kernel void bem_radiation_integrals(__global const real_t *dirs, const int ndirs,
                                      __global const real_t *points, __global const cplx_t *c,
                                      const int npoints, const real_t k, __global cplx_t *out)
{
    const int d = get_global_id(0);
    if (d >= ndirs) return;
    const real_t dx = dirs[3 * d], dy = dirs[3 * d + 1], dz = dirs[3 * d + 2];
    cplx_t acc[BEM_NSETS][3];
    for (int s = 0; s < BEM_NSETS; ++s)
        for (int i = 0; i < 3; ++i) acc[s][i] = c_new(R(0.0), R(0.0));
    for (int q = 0; q < npoints; ++q) {
        const real_t phase = k * (dx * points[3 * q] + dy * points[3 * q + 1] + dz * points[3 * q + 2]);
        const cplx_t e = c_expj(phase);
        __global const cplx_t *cq = c + 3 * BEM_NSETS * q;
        for (int s = 0; s < BEM_NSETS; ++s)
            for (int i = 0; i < 3; ++i) acc[s][i] = c_fma(e, cq[3 * s + i], acc[s][i]);
    }
    __global cplx_t *o = out + 3 * BEM_NSETS * d;
    for (int s = 0; s < BEM_NSETS; ++s)
        for (int i = 0; i < 3; ++i) o[3 * s + i] = acc[s][i];
}
