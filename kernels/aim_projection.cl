/* Plane-wave moments of rooftops for far-field-matched AIM projections (solver/bem3d/aim/projection.py).
 *
 *   moments[c][b][l] = sum_q psi[c][b][q] e^{j k_l . r[b][q]}      c = t, z, d
 *
 * r (B, Q, 3) µm: the basis' quadrature points relative to its stencil origin; psi (3, B, Q) the
 * component weights; kvec (L, 3) µm^-1 the matched wavevectors. One work-item per (b, l), the
 * waves of one basis adjacent (they read the same points). The stencil weights follow on the
 * host as moments P^T (P the matching operator). NumPy twin: the "farfield" branch of project().
 */
#include "wb_complex.h"

__kernel void aim_plane_wave_moments(__global const real_t *r, __global const real_t *psi, const int nb,
                                     const int nq, __global const real_t *kvec, const int nl,
                                     __global cplx_t *moments)
{
    const size_t gid = get_global_id(0);
    if (gid >= (size_t)nb * nl) return;
    const int b = gid / nl, l = gid - (size_t)b * nl;
    const real_t kx = kvec[3 * l], ky = kvec[3 * l + 1], kz = kvec[3 * l + 2];
    __global const real_t *rb = r + (size_t)b * nq * 3;
    const size_t cstride = (size_t)nb * nq;
    cplx_t m[3] = {c_new(R(0.0), R(0.0)), c_new(R(0.0), R(0.0)), c_new(R(0.0), R(0.0))};
    for (int q = 0; q < nq; ++q) {
        real_t c;
        const real_t s = sincos(kx * rb[3 * q] + ky * rb[3 * q + 1] + kz * rb[3 * q + 2], &c);
        const size_t e = (size_t)b * nq + q;
        for (int i = 0; i < 3; ++i) m[i] = c_add(m[i], c_new(psi[i * cstride + e] * c, psi[i * cstride + e] * s));
    }
    for (int i = 0; i < 3; ++i) moments[((size_t)i * nb + b) * nl + l] = m[i];
}
