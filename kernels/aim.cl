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
 *              points of entries g*S + slot), race-free.
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

__kernel void aim_scatter(__global const int *pointer, __global const int *entries, const int4 grid,
                          const int4 layout, const int S, const int nb, const int nh, __global const weight_t *W,
                          __global const cplx_t *x, __global cplx_t *q)
{
    /* grid = (nx, ny, nz): the compact grid the inverse map refers to; q in layout dims */
    const int npoints = grid.x * grid.y * grid.z;
    const int p = get_global_id(0);
    if (p >= npoints) return;
    const int iz = p % grid.z, iy = (p / grid.z) % grid.y, ix = p / (grid.z * grid.y);
    const size_t lp = ((size_t)ix * layout.y + iy) * layout.z + iz;
    const size_t lpoints = (size_t)layout.x * layout.y * layout.z;
    cplx_t acc[AIM_BATCH][8];
    for (int b = 0; b < AIM_BATCH; ++b)
        for (int c = 0; c < 8; ++c) acc[b][c] = c_new(R(0.0), R(0.0));
    const size_t wstride = (size_t)nb * S;
    for (int e = pointer[p]; e < pointer[p + 1]; ++e) {
        const int entry = entries[e];
        const int g = entry / S;
        const weight_t wt = W[entry], wz = W[wstride + entry], wd = W[2 * wstride + entry];
        const int ct = g < nh ? 0 : 1;
        for (int b = 0; b < AIM_BATCH; ++b) {
            const cplx_t xj = x[(size_t)b * 2 * nb + g], xm = x[(size_t)b * 2 * nb + nb + g];
            acc[b][ct] = c_add(acc[b][ct], aim_wmul(wt, xj));
            acc[b][2] = c_add(acc[b][2], aim_wmul(wz, xj));
            acc[b][3] = c_add(acc[b][3], aim_wmul(wd, xj));
            acc[b][4 + ct] = c_add(acc[b][4 + ct], aim_wmul(wt, xm));
            acc[b][6] = c_add(acc[b][6], aim_wmul(wz, xm));
            acc[b][7] = c_add(acc[b][7], aim_wmul(wd, xm));
        }
    }
    for (int b = 0; b < AIM_BATCH; ++b)
        for (int c = 0; c < 8; ++c) q[((size_t)b * 8 + c) * lpoints + lp] = acc[b][c];
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
                for (int b = 0; b < AIM_BATCH; ++b) {
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
