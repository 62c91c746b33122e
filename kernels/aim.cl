/* The AIM base matrix B = Lambda^T G Lambda applied on the grid (solver/bem3d/aim_base.py).
 *
 * Unknowns x = [J (nb) | M~ (nb)] per right-hand side (AIM_BATCH of them, build define).
 * Grid arrays: 8 components per right-hand side, row-major with layout dims (Lx, Ly, Lz) >= (nx, ny, nz):
 * compact (L = n) for host FFTs, the zero-padded FFT size for device FFTs; "points" = Lx Ly Lz:
 *   charges  q = [Jx, Jy, Jz, Jd, Mx, My, Mz, Md]   (x from horizontal, y from vertical rooftops)
 *   fields   F = [Ex, Ey, Ez, Ed, Hx, Hy, Hz, Hd]   (after the convolution, tested the same way)
 * Projection weights W: (3, nb, S) for components (t, z, d); real (AIM_COMPLEX_W = 0,
 * moment matching) or complex (far-field matching). Rooftops g < nh are horizontal.
 *
 * aim_scatter  one work-item per grid point: q = Lambda x through the inverse map (CSR over grid
 *              points of entries g*S + slot), race-free. It reads its own copy of the weights in
 *              inverse-map order (3, nb S), so its weight reads stream: read in rooftop order
 *              they cost 2.3x the time (measured, PoCL, 36 480 and 101 760 unknowns).
 * aim_gather   one work-item per rooftop: y += Lambda^T F over its stencil.
 * aim_fourier  one work-item per Fourier sample: F^ = K^ q^ with the PMCHWT coefficients
 *              (in place), for AIM_NMED grid media sharing the projection:
 *   E_c = A q_c[J] + (B x q[M])_c,  E_d = D q_d[J],  H_c = A' q_c[M] + (B x q[J])_c,  H_d = D' q_d[M]
 *   A = sum_i ee_vec_i G_i, A' = sum_i mm_vec_i G_i, D = sum_i ee_div_i G_i, D' = sum_i mm_div_i G_i,
 *   B_a = eta0 sum_i FFT(d_a g_i)  (precombined on the host).
 * NumPy twins: scatter_numpy, gather_numpy, fourier_numpy in aim_base.py.
 */
#include "aim_weights.h"

#ifndef AIM_BATCH
#define AIM_BATCH 1
#endif
#ifndef AIM_NMED
#define AIM_NMED 1
#endif

/* charges of the inverse-map entries [e0, e1) of one grid point: tangential parts into qt (one of
   x, y), z and divergence parts into qz, qd; [b][0] from J, [b][1] from M */
inline void aim_scatter_entries(__global const int *entries, const int e0, const int e1, const int S,
                                const size_t wstride, const int nb, __global const weight_t *W,
                                __global const cplx_t *x, cplx_t qt[AIM_BATCH][2], cplx_t qz[AIM_BATCH][2],
                                cplx_t qd[AIM_BATCH][2])
{
    for (int e = e0; e < e1; ++e) {
        const int g = entries[e] / S;
        const weight_t wt = W[e], wz = W[wstride + e], wd = W[2 * wstride + e];
#pragma unroll
        for (int b = 0; b < AIM_BATCH; ++b) {  /* unrolled: the accumulators stay in registers */
            const cplx_t xj = x[(size_t)b * 2 * nb + g], xm = x[(size_t)b * 2 * nb + nb + g];
            qt[b][0] = c_add(qt[b][0], aim_wmul(wt, xj));
            qz[b][0] = c_add(qz[b][0], aim_wmul(wz, xj));
            qd[b][0] = c_add(qd[b][0], aim_wmul(wd, xj));
            qt[b][1] = c_add(qt[b][1], aim_wmul(wt, xm));
            qz[b][1] = c_add(qz[b][1], aim_wmul(wz, xm));
            qd[b][1] = c_add(qd[b][1], aim_wmul(wd, xm));
        }
    }
}

__kernel void aim_scatter(__global const int *pointer, __global const int *entries, const int4 grid,
                          const int4 layout, const int S, const int nb, const int nh,
                          __global const weight_t *W_by_point, __global const cplx_t *x, __global cplx_t *q)
{
    /* grid = (nx, ny, nz): the compact grid the inverse map refers to; q in layout dims. A point's
       entries are sorted, so those of horizontal rooftops (entry < nh S: x component) come first. */
    const int npoints = grid.x * grid.y * grid.z;
    const int p = get_global_id(0);
    if (p >= npoints) return;
    const int iz = p % grid.z, iy = (p / grid.z) % grid.y, ix = p / (grid.z * grid.y);
    const size_t lp = ((size_t)ix * layout.y + iy) * layout.z + iz;
    const size_t lpoints = (size_t)layout.x * layout.y * layout.z;
    const size_t wstride = (size_t)nb * S;
    const int e0 = pointer[p], e2 = pointer[p + 1];
    int e1 = e0;
    while (e1 < e2 && entries[e1] < nh * S) ++e1;
    cplx_t qx[AIM_BATCH][2], qy[AIM_BATCH][2], qz[AIM_BATCH][2], qd[AIM_BATCH][2];
#pragma unroll
    for (int b = 0; b < AIM_BATCH; ++b)
        for (int t = 0; t < 2; ++t) qx[b][t] = qy[b][t] = qz[b][t] = qd[b][t] = c_new(R(0.0), R(0.0));
    aim_scatter_entries(entries, e0, e1, S, wstride, nb, W_by_point, x, qx, qz, qd);
    aim_scatter_entries(entries, e1, e2, S, wstride, nb, W_by_point, x, qy, qz, qd);
#pragma unroll
    for (int b = 0; b < AIM_BATCH; ++b) {
        __global cplx_t *out = q + (size_t)b * 8 * lpoints + lp;
        for (int t = 0; t < 2; ++t) {
            out[(4 * t + 0) * lpoints] = qx[b][t];
            out[(4 * t + 1) * lpoints] = qy[b][t];
            out[(4 * t + 2) * lpoints] = qz[b][t];
            out[(4 * t + 3) * lpoints] = qd[b][t];
        }
    }
}

__kernel void aim_gather(__global const int *origins, const int4 layout, const int sx, const int sy,
                         const int sz, const int nb, const int nh, __global const weight_t *W,
                         __global const cplx_t *F, __global cplx_t *y)
{
    const int g = get_global_id(0);
    if (g >= nb) return;
    const int S = sx * sy * sz;
    const int ny = layout.y, nz = layout.z;
    const size_t npoints = (size_t)layout.x * ny * nz;
    const size_t wstride = (size_t)nb * S;
    const int ct = g < nh ? 0 : 1;
    const int ox = origins[3 * g], oy = origins[3 * g + 1], oz = origins[3 * g + 2];
    cplx_t ye[AIM_BATCH], yh[AIM_BATCH];
    for (int b = 0; b < AIM_BATCH; ++b) ye[b] = yh[b] = c_new(R(0.0), R(0.0));
    int s = 0;
    for (int a = 0; a < sx; ++a)
        for (int bb = 0; bb < sy; ++bb)
            for (int c = 0; c < sz; ++c, ++s) {
                const size_t p = ((size_t)(ox + a) * ny + (oy + bb)) * nz + (oz + c);
                const size_t e = (size_t)g * S + s;
                const weight_t wt = W[e], wz = W[wstride + e], wd = W[2 * wstride + e];
#pragma unroll
                for (int b = 0; b < AIM_BATCH; ++b) {  /* unrolled: accumulators in registers */
                    __global const cplx_t *f = F + (size_t)b * 8 * npoints + p;
                    ye[b] = c_add(ye[b], c_add(aim_wmul(wt, f[ct * npoints]),
                                               c_add(aim_wmul(wz, f[2 * npoints]), aim_wmul(wd, f[3 * npoints]))));
                    yh[b] = c_add(yh[b], c_add(aim_wmul(wt, f[(4 + ct) * npoints]),
                                               c_add(aim_wmul(wz, f[6 * npoints]), aim_wmul(wd, f[7 * npoints]))));
                }
            }
    for (int b = 0; b < AIM_BATCH; ++b) {
        y[(size_t)b * 2 * nb + g] = c_add(y[(size_t)b * 2 * nb + g], ye[b]);
        y[(size_t)b * 2 * nb + nb + g] = c_add(y[(size_t)b * 2 * nb + nb + g], yh[b]);
    }
}

/* (B x q)_a = B_{a+1} q_{a+2} - B_{a+2} q_{a+1}  (indices mod 3) */
inline void aim_curl(const cplx_t B[3], const cplx_t q[3], cplx_t out[3])
{
    out[0] = c_sub(c_mul(B[1], q[2]), c_mul(B[2], q[1]));
    out[1] = c_sub(c_mul(B[2], q[0]), c_mul(B[0], q[2]));
    out[2] = c_sub(c_mul(B[0], q[1]), c_mul(B[1], q[0]));
}

__kernel void aim_fourier(__global const cplx_t *green, __global const cplx_t *gradient, const long nfreq,
                          __constant const cplx_t *coef, __global cplx_t *Q)
{
    /* green (AIM_NMED, nfreq); gradient (3, nfreq) = B_a; coef (4, AIM_NMED): ee_vec, mm_vec,
       ee_div, mm_div; Q (AIM_BATCH, 8, nfreq) in place */
    const size_t v = get_global_id(0);
    if (v >= (size_t)nfreq) return;
    cplx_t A = c_new(R(0.0), R(0.0)), Ap = A, D = A, Dp = A;
    for (int m = 0; m < AIM_NMED; ++m) {
        const cplx_t G = green[m * nfreq + v];
        A = c_fma(coef[0 * AIM_NMED + m], G, A);
        Ap = c_fma(coef[1 * AIM_NMED + m], G, Ap);
        D = c_fma(coef[2 * AIM_NMED + m], G, D);
        Dp = c_fma(coef[3 * AIM_NMED + m], G, Dp);
    }
    const cplx_t B[3] = {gradient[v], gradient[nfreq + v], gradient[2 * nfreq + v]};
#pragma unroll
    for (int b = 0; b < AIM_BATCH; ++b) {
        __global cplx_t *q = Q + (size_t)b * 8 * nfreq + v;
        const cplx_t qj[3] = {q[0], q[nfreq], q[2 * nfreq]};
        const cplx_t qm[3] = {q[4 * nfreq], q[5 * nfreq], q[6 * nfreq]};
        const cplx_t qjd = q[3 * nfreq], qmd = q[7 * nfreq];
        cplx_t cj[3], cm[3];
        aim_curl(B, qj, cj);
        aim_curl(B, qm, cm);
        for (int a = 0; a < 3; ++a) {
            q[a * nfreq] = c_fma(A, qj[a], cm[a]);
            q[(4 + a) * nfreq] = c_fma(Ap, qm[a], cj[a]);
        }
        q[3 * nfreq] = c_mul(D, qjd);
        q[7 * nfreq] = c_mul(Dp, qmd);
    }
}
