/* The AIM base matrix B = Lambda^T G Lambda applied on the grid (solver/bem3d/aim/convolution.py).
 *
 * Unknowns x = [J (nb) | M~ (nb)] per right-hand side (AIM_BATCH = 1, 2 or 4 of them, build define).
 * Grid arrays: 8 components per right-hand side, row-major with layout dims (Lx, Ly, Lz) >= (nx, ny, nz):
 * (p_x, n_y, n_z) for host FFTs (x padded: the x transform runs in place), the zero-padded FFT size
 * for device FFTs; "points" = Lx Ly Lz:
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
 * aim_fourier  one work-item per WB_VW Fourier samples (vc_load deinterleaves them into SIMD
 *              vectors): F^ = K^ q^ with the PMCHWT coefficients (in place), for AIM_NMED grid
 *              media sharing the projection:
 *   E_c = A q_c[J] + (B x q[M])_c,  E_d = D q_d[J],  H_c = A' q_c[M] + (B x q[J])_c,  H_d = D' q_d[M]
 *   A = sum_i ee_vec_i G_i, A' = sum_i mm_vec_i G_i, D = sum_i ee_div_i G_i, D' = sum_i mm_div_i G_i,
 *   B_a = eta0 sum_i FFT(d_a g_i)  (precombined on the host).
 * NumPy twins: scatter_numpy, gather_numpy, fourier_numpy in aim/convolution.py.
 */
#include "aim_weights.h"
#include "wb_vcomplex.h"

#ifndef AIM_BATCH
#define AIM_BATCH 1
#endif
#ifndef AIM_NMED
#define AIM_NMED 1
#endif

/* Scatter and gather work on packs: the 2 AIM_BATCH complex numbers (J, M) or (E, H) of every
   right-hand side side by side in one real vector, (re, im) pairs, so one weight multiplies them
   all in two vector FMAs (PoCL does not vectorize work-items that run inner loops). */
#if AIM_BATCH == 1
#define AIM_PACK 4
#elif AIM_BATCH == 2
#define AIM_PACK 8
#elif AIM_BATCH == 4
#define AIM_PACK 16
#else
#error "AIM_BATCH must be 1, 2 or 4"
#endif
typedef WB_REALN(AIM_PACK) pack_t;

/* acc + w z for every complex pair of z; zs = (-im, re) of every pair (aim_swap) */
inline pack_t aim_pmad(const weight_t w, const pack_t z, const pack_t zs, const pack_t acc)
{
#if AIM_COMPLEX_W
    return fma((pack_t)(w.x), z, fma((pack_t)(w.y), zs, acc));
#else
    return fma((pack_t)(w), z, acc);
#endif
}
inline pack_t aim_swap(const pack_t z)
{
#if AIM_COMPLEX_W
#if AIM_PACK == 4
    return z.s1032 * (pack_t)(-1, 1, -1, 1);
#elif AIM_PACK == 8
    return z.s10325476 * (pack_t)(-1, 1, -1, 1, -1, 1, -1, 1);
#else
    return z.s1032547698badcfe * (pack_t)(-1, 1, -1, 1, -1, 1, -1, 1, -1, 1, -1, 1, -1, 1, -1, 1);
#endif
#else
    return z;
#endif
}
/* (a[b], c[b]) of every right-hand side b, a and c at stride `stride` per right-hand side */
inline pack_t aim_pack(__global const cplx_t *a, __global const cplx_t *c, const size_t stride)
{
#if AIM_PACK == 4
    return (pack_t)(a[0], c[0]);
#elif AIM_PACK == 8
    return (pack_t)(a[0], c[0], a[stride], c[stride]);
#else
    return (pack_t)(a[0], c[0], a[stride], c[stride], a[2 * stride], c[2 * stride], a[3 * stride], c[3 * stride]);
#endif
}

/* charges of the inverse-map entries [e0, e1) of one grid point: tangential parts into qt (one of
   x, y), z and divergence parts into qz, qd */
inline void aim_scatter_entries(__global const int *entries, const int e0, const int e1, const int S,
                                const size_t wstride, const int nb, __global const weight_t *W,
                                __global const cplx_t *x, pack_t *qt, pack_t *qz, pack_t *qd)
{
    for (int e = e0; e < e1; ++e) {
        const int g = entries[e] / S;
        const pack_t z = aim_pack(x + g, x + nb + g, 2 * (size_t)nb), zs = aim_swap(z);
        *qt = aim_pmad(W[e], z, zs, *qt);
        *qz = aim_pmad(W[wstride + e], z, zs, *qz);
        *qd = aim_pmad(W[2 * wstride + e], z, zs, *qd);
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
    pack_t qc[4] = {(pack_t)(R(0.0)), (pack_t)(R(0.0)), (pack_t)(R(0.0)), (pack_t)(R(0.0))};  /* x, y, z, d */
    aim_scatter_entries(entries, e0, e1, S, wstride, nb, W_by_point, x, &qc[0], &qc[2], &qc[3]);
    aim_scatter_entries(entries, e1, e2, S, wstride, nb, W_by_point, x, &qc[1], &qc[2], &qc[3]);
#pragma unroll
    for (int b = 0; b < AIM_BATCH; ++b)
#pragma unroll
        for (int c = 0; c < 4; ++c) {
            q[((size_t)b * 8 + c) * lpoints + lp] = c_new(VLANE(qc[c], 4 * b), VLANE(qc[c], 4 * b + 1));
            q[((size_t)b * 8 + 4 + c) * lpoints + lp] = c_new(VLANE(qc[c], 4 * b + 2), VLANE(qc[c], 4 * b + 3));
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
    pack_t acc = (pack_t)(R(0.0));  /* (E, H) of every right-hand side */
    int s = 0;
    for (int a = 0; a < sx; ++a)
        for (int bb = 0; bb < sy; ++bb)
            for (int c = 0; c < sz; ++c, ++s) {
                const size_t p = ((size_t)(ox + a) * ny + (oy + bb)) * nz + (oz + c);
                const size_t e = (size_t)g * S + s;
                __global const cplx_t *f = F + p;
                const pack_t ft = aim_pack(f + ct * npoints, f + (4 + ct) * npoints, 8 * npoints);
                const pack_t fz = aim_pack(f + 2 * npoints, f + 6 * npoints, 8 * npoints);
                const pack_t fd = aim_pack(f + 3 * npoints, f + 7 * npoints, 8 * npoints);
                acc = aim_pmad(W[e], ft, aim_swap(ft), acc);
                acc = aim_pmad(W[wstride + e], fz, aim_swap(fz), acc);
                acc = aim_pmad(W[2 * wstride + e], fd, aim_swap(fd), acc);
            }
#pragma unroll
    for (int b = 0; b < AIM_BATCH; ++b) {
        __global cplx_t *yb = y + (size_t)b * 2 * nb + g;
        yb[0] = c_add(yb[0], c_new(VLANE(acc, 4 * b), VLANE(acc, 4 * b + 1)));
        yb[nb] = c_add(yb[nb], c_new(VLANE(acc, 4 * b + 2), VLANE(acc, 4 * b + 3)));
    }
}

/* (B x q)_a = B_{a+1} q_{a+2} - B_{a+2} q_{a+1}  (indices mod 3) */
inline void aim_curl(const vcplx_t B[3], const vcplx_t q[3], vcplx_t out[3])
{
    for (int a = 0; a < 3; ++a) {
        const int a1 = (a + 1) % 3, a2 = (a + 2) % 3;
        out[a] = vc_sub(vc_mul(B[a1], q[a2]), vc_mul(B[a2], q[a1]));
    }
}

/* one work-item per WB_VW consecutive samples (aim/convolution.py picks WB_VW; the host launches whole
   vectors, then the rest with WB_VW = 1), from sample `first` of Q; Q may be a slab of the spectrum
   (host FFTs in slabs): its sample v is the kernels' sample `offset` + v */
__kernel void aim_fourier(__global const cplx_t *green, __global const cplx_t *gradient, const long nfreq,
                          __constant const cplx_t *coef, __global cplx_t *Q, const long first, const long qfreq,
                          const long offset)
{
    /* green (AIM_NMED, nfreq); gradient (3, nfreq) = B_a; coef (4, AIM_NMED): ee_vec, mm_vec,
       ee_div, mm_div; Q (AIM_BATCH, 8, qfreq) in place */
    const size_t v = first + get_global_id(0) * WB_VW;
    if (v + WB_VW > (size_t)qfreq) return;
    const size_t g = offset + v;
    vcplx_t k[4] = {vc_zero(), vc_zero(), vc_zero(), vc_zero()};  /* A, A', D, D' */
    for (int m = 0; m < AIM_NMED; ++m) {
        const vcplx_t G = vc_load(green + m * nfreq + g);
        for (int r = 0; r < 4; ++r) {
            const cplx_t c = coef[r * AIM_NMED + m];
            k[r] = vc_fma(vc_new((vreal_t)(c.x), (vreal_t)(c.y)), G, k[r]);
        }
    }
    const vcplx_t B[3] = {vc_load(gradient + g), vc_load(gradient + nfreq + g), vc_load(gradient + 2 * nfreq + g)};
#pragma unroll
    for (int b = 0; b < AIM_BATCH; ++b) {
        __global cplx_t *q = Q + (size_t)b * 8 * qfreq + v;
        vcplx_t qe[3], qh[3], ce[3], ch[3];
        for (int a = 0; a < 3; ++a) {
            qe[a] = vc_load(q + a * qfreq);
            qh[a] = vc_load(q + (4 + a) * qfreq);
        }
        aim_curl(B, qh, ce);  /* B x q[M] */
        aim_curl(B, qe, ch);  /* B x q[J] */
        for (int a = 0; a < 3; ++a) {
            vc_store(vc_fma(k[0], qe[a], ce[a]), q + a * qfreq);
            vc_store(vc_fma(k[1], qh[a], ch[a]), q + (4 + a) * qfreq);
        }
        vc_store(vc_mul(k[2], vc_load(q + 3 * qfreq)), q + 3 * qfreq);
        vc_store(vc_mul(k[3], vc_load(q + 7 * qfreq)), q + 7 * qfreq);
    }
}
