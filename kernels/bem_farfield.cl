/* Far-field radiation integrals of surface currents by a direct quadrature sum (bem3d/farfield.py).
 *
 * For each direction d (unit vector) and each of BEM_NSETS current sets (polarizations x {J, M}):
 *   F[d][s] = sum_q  c[q][s] * exp(+j k d . r[q])        (3 complex components)
 * r: (npoints, 3) positions; c: (npoints, nsets, 3) complex weights (current x area weight).
 * Each work-item sums WB_VW directions at once (vector lanes, wb_vcomplex.h).
 * NumPy twin: radiation_integrals_numpy.
 */
#include "wb_vcomplex.h"

#ifndef BEM_NSETS
#define BEM_NSETS 4
#endif

__kernel void bem_radiation_integrals(__global const real_t *dirs, const int ndirs,
                                      __global const real_t *points, __global const cplx_t *c,
                                      const int npoints, const real_t k, __global cplx_t *out)
{
    const int first = get_global_id(0) * WB_VW;
    if (first >= ndirs) return;
    vreal_t dx, dy, dz;
    for (int i = 0; i < WB_VW; ++i) {
        const int d = min(first + i, ndirs - 1);
        VLANE(dx, i) = k * dirs[3 * d];
        VLANE(dy, i) = k * dirs[3 * d + 1];
        VLANE(dz, i) = k * dirs[3 * d + 2];
    }
    vcplx_t acc[BEM_NSETS][3];
    for (int s = 0; s < BEM_NSETS; ++s)
        for (int i = 0; i < 3; ++i) acc[s][i] = vc_zero();
    for (int q = 0; q < npoints; ++q) {
        const vreal_t phase = dx * points[3 * q] + dy * points[3 * q + 1] + dz * points[3 * q + 2];
        vreal_t cs, sn = sincos(phase, &cs);
        __global const cplx_t *cq = c + 3 * BEM_NSETS * q;
        for (int s = 0; s < BEM_NSETS; ++s) {
            for (int i = 0; i < 3; ++i) {
                const cplx_t w = cq[3 * s + i];
                /* (cs + j sn) (w.x + j w.y) */
                acc[s][i].re += cs * w.x - sn * w.y;
                acc[s][i].im += cs * w.y + sn * w.x;
            }
        }
    }
    for (int l = 0; l < WB_VW; ++l) {
        if (first + l >= ndirs) break;
        __global cplx_t *o = out + 3 * BEM_NSETS * (first + l);
        for (int s = 0; s < BEM_NSETS; ++s)
            for (int i = 0; i < 3; ++i) o[3 * s + i] = vc_lane(acc[s][i], l);
    }
}
