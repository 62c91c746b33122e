/* Near-field correction C x on the rooftop lattice (solver/bem3d/nearfield.py, NearMatrix).
 *
 * Both orientations live on one N x N lattice: rooftop (x, y) of either orientation sits at
 * site p = N y + x (near_index.h gives the rooftop ranges; sites without a rooftop hold zeros),
 * and every array keeps a guard of G zero sites on each side (length L = G + sites + G). An
 * offset (a, b) of the pattern is then one constant shift s = a + N b for all rows, so C x is a
 * sum of shifted element-wise products (diagonal storage), streamed in WB_VW-lane vectors
 * (wb_vcomplex.h: PoCL does not vectorize work-items that run inner loops).
 *
 * Values, per block, real storage type near_s: (n_offsets, 3, 2, L) = [ee, em, mm] x [re, im],
 * zero where the column lies outside the patch, at empty sites and in the guards. HH and VV keep
 * the upper half of the offsets, HV all offsets from horizontal rows to vertical columns.
 * Lattice vectors X (input) and Y (output): (NEAR_BATCH, 2 orientations, 2 [J, M] or [E, H],
 * 2 [re, im], L) of real_t.
 *
 * Z is complex-symmetric, so a stored pair (row m, column n = m + s) acts twice:
 *   forward     Y_E[m] += ee X_J[n] + em X_M[n],   Y_H[m] += em X_J[n] + mm X_M[n]
 *   transposed  the same with m and n exchanged, the values read at the row m = n - s.
 * near_lattice gathers the rows of one orientation o (one work-item per WB_VW sites, no
 * atomics): its own block forward and transposed, and the cross block forward (o = 0: values at
 * the row, X_V at row + s) or transposed (o = 1: values and X_H at row - s); Y accumulates.
 * near_move puts x onto the lattice, and adds Y into y (zeroing Y).
 * NumPy twin: NearMatrix.apply_numpy (a scipy.sparse matrix of the same entries).
 */
#include "wb_vcomplex.h"
#include "near_index.h"

#ifndef NEAR_BATCH
#define NEAR_BATCH 1
#endif
#ifndef NEAR_FP64
#define NEAR_FP64 WB_FP64
#endif
#if NEAR_FP64
typedef double near_s;
#else
typedef float near_s;
#endif

/* WB_VW consecutive values of a near_s or real_t array as a vreal_t */
#if WB_VW == 1
#define VLOAD(p) ((real_t)((p)[0]))
#define VSTORE(v, p) ((p)[0] = (v))
#else
#if WB_FP64
#define VLOAD(p) WB_PASTE(convert_double, WB_VW)(WB_PASTE(vload, WB_VW)(0, (p)))
#else
#define VLOAD(p) WB_PASTE(convert_float, WB_VW)(WB_PASTE(vload, WB_VW)(0, (p)))
#endif
#define VSTORE(v, p) WB_PASTE(vstore, WB_VW)((v), 0, (p))
#endif

/* one stored slice: v at [ee re][site] (component c, part r at v + (2c + r) L); x at [J re][site]
   of one orientation of right-hand side 0 (J at x, x + L; M at x + 2L, x + 3L; next RHS + 8L) */
inline void near_pair(__global const near_s *v, __global const real_t *x, const int L,
                      vcplx_t ye[NEAR_BATCH], vcplx_t yh[NEAR_BATCH])
{
    const vcplx_t ee = vc_new(VLOAD(v), VLOAD(v + L));
    const vcplx_t em = vc_new(VLOAD(v + 2 * L), VLOAD(v + 3 * L));
    const vcplx_t mm = vc_new(VLOAD(v + 4 * L), VLOAD(v + 5 * L));
#pragma unroll
    for (int b = 0; b < NEAR_BATCH; ++b) {  /* unrolled: the accumulators stay in registers */
        __global const real_t *xb = x + (size_t)b * 8 * L;
        const vcplx_t xj = vc_new(VLOAD(xb), VLOAD(xb + L));
        const vcplx_t xm = vc_new(VLOAD(xb + 2 * L), VLOAD(xb + 3 * L));
        ye[b] = vc_fma(ee, xj, vc_fma(em, xm, ye[b]));
        yh[b] = vc_fma(em, xj, vc_fma(mm, xm, yh[b]));
    }
}

__kernel void near_lattice(const int o, const int L, const int G, const int sites,
                           __global const int *same_shift, const int nsame, __global const near_s *same,
                           __global const int *cross_shift, const int ncross, __global const near_s *cross,
                           __global const real_t *X, __global real_t *Y)
{
    const int first = get_global_id(0) * WB_VW;
    if (first >= sites) return;
    const int i = G + first;
    const size_t slice = 6 * (size_t)L;
    __global const real_t *Xown = X + (size_t)4 * L * o, *Xother = X + (size_t)4 * L * (1 - o);
    vcplx_t ye[NEAR_BATCH], yh[NEAR_BATCH];
    for (int b = 0; b < NEAR_BATCH; ++b) ye[b] = yh[b] = vc_zero();
    for (int j = 0; j < nsame; ++j) {
        const int s = same_shift[j];
        __global const near_s *v = same + j * slice;
        near_pair(v + i, Xown + i + s, L, ye, yh);
        if (s != 0) near_pair(v + i - s, Xown + i - s, L, ye, yh);
    }
    for (int j = 0; j < ncross; ++j) {
        const int s = cross_shift[j];
        const int row = o == 0 ? i : i - s, column = o == 0 ? i + s : i - s;
        near_pair(cross + j * slice + row, Xother + column, L, ye, yh);
    }
    for (int b = 0; b < NEAR_BATCH; ++b) {
        __global real_t *y = Y + (size_t)b * 8 * L + (size_t)4 * L * o + i;
        VSTORE(VLOAD(y) + ye[b].re, y);
        VSTORE(VLOAD(y + L) + ye[b].im, y + L);
        VSTORE(VLOAD(y + 2 * L) + yh[b].re, y + 2 * L);
        VSTORE(VLOAD(y + 3 * L) + yh[b].im, y + 3 * L);
    }
}

/* lattice site (guard included) of rooftop g (0 <= g < 2 N (N - 1)) and its orientation o */
inline size_t near_site(const int N, const int G, const int g, int *o)
{
    const int nrows = N * (N - 1);
    *o = g < nrows ? 0 : 1;
    const int2 c = near_coords(*o, N, g - near_first(*o, N));
    return (size_t)G + (size_t)N * c.y + c.x;
}

/* to_lattice = 1: lattice X <- x at the sites of the rooftops; 0: y += lattice Y there, then Y <- 0 */
__kernel void near_move(const int to_lattice, const int N, const int L, const int G, __global real_t *lattice,
                        __global cplx_t *v)
{
    const int nb = 2 * N * (N - 1);
    const int g = get_global_id(0);
    if (g >= nb) return;
    int o;
    const size_t p = near_site(N, G, g, &o);
    for (int b = 0; b < NEAR_BATCH; ++b)
        for (int t = 0; t < 2; ++t) {
            __global real_t *s = lattice + (((size_t)b * 2 + o) * 2 + t) * 2 * L + p;
            const size_t k = ((size_t)b * 2 + t) * nb + g;
            if (to_lattice) {
                s[0] = v[k].x;
                s[L] = v[k].y;
            } else {
                v[k] = c_add(v[k], c_new(s[0], s[L]));
                s[0] = R(0.0);
                s[L] = R(0.0);
            }
        }
}
