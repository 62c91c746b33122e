/* Near-field correction C x in the offset format of solver/bem3d/nearfield.py.
 *
 * The pattern is translation invariant: block "same" (horizontal-horizontal or
 * vertical-vertical) stores the upper half of the offsets (a, b) (b > 0, or b = 0 and a >= 0)
 * of one orientation; block "cross" stores all offsets from horizontal rows to vertical
 * columns (vertical (x + a, y + b) of horizontal (x, y)). Values: (noff, nrows, 3) of storage
 * type near_t (NEAR_FP64 = 1: double2, 0: float2) = [ee, em, mm] of the pair, zero where the
 * column lies outside the patch. Column indices are implicit (near_index.h).
 *
 * Z is complex-symmetric, so every stored pair (m, n) acts twice:
 *   y_E[m] += ee x_J[n] + em x_M[n],   y_H[m] += em x_J[n] + mm x_M[n]   and (m <-> n).
 * Both kernels gather (one work-item per output rooftop, no atomics): the transposed half is
 * read from the row that stores it. NEAR_BATCH right-hand sides per launch; y accumulates.
 * NumPy twin: NearMatrix.apply_numpy (a scipy.sparse matrix of the same entries).
 */
#include "wb_complex.h"
#include "near_index.h"

#ifndef NEAR_BATCH
#define NEAR_BATCH 1
#endif
#ifndef NEAR_FP64
#define NEAR_FP64 WB_FP64
#endif
#if NEAR_FP64
typedef double2 near_t;
#if WB_FP64
#define NEAR_LOAD(v) (v)
#else
#define NEAR_LOAD(v) convert_float2(v)
#endif
#else
typedef float2 near_t;
#if WB_FP64
#define NEAR_LOAD(v) convert_double2(v)
#else
#define NEAR_LOAD(v) (v)
#endif
#endif

inline void near_accumulate(__global const near_t *v, __global const cplx_t *x, int col, int nb,
                            cplx_t ye[NEAR_BATCH], cplx_t yh[NEAR_BATCH])
{
    const cplx_t ee = NEAR_LOAD(v[0]), em = NEAR_LOAD(v[1]), mm = NEAR_LOAD(v[2]);
    for (int b = 0; b < NEAR_BATCH; ++b) {
        const cplx_t xj = x[(size_t)b * 2 * nb + col], xm = x[(size_t)b * 2 * nb + nb + col];
        ye[b] = c_fma(ee, xj, c_fma(em, xm, ye[b]));
        yh[b] = c_fma(em, xj, c_fma(mm, xm, yh[b]));
    }
}

inline void near_store(__global cplx_t *y, int g, int nb, const cplx_t ye[NEAR_BATCH], const cplx_t yh[NEAR_BATCH])
{
    for (int b = 0; b < NEAR_BATCH; ++b) {
        y[(size_t)b * 2 * nb + g] = c_add(y[(size_t)b * 2 * nb + g], ye[b]);
        y[(size_t)b * 2 * nb + nb + g] = c_add(y[(size_t)b * 2 * nb + nb + g], yh[b]);
    }
}

/* one orientation o with itself: one work-item per rooftop of orientation o */
__kernel void near_same(const int o, const int N, __global const int2 *offsets, const int noff,
                        __global const near_t *values, __global const cplx_t *x, __global cplx_t *y)
{
    const int nrows = N * (N - 1), nb = 2 * nrows;
    const int row = get_global_id(0);
    if (row >= nrows) return;
    const int2 c = near_coords(o, N, row);
    const int first = near_first(o, N);
    cplx_t ye[NEAR_BATCH], yh[NEAR_BATCH];
    for (int b = 0; b < NEAR_BATCH; ++b) ye[b] = yh[b] = c_new(R(0.0), R(0.0));
    for (int j = 0; j < noff; ++j) {
        const int2 d = offsets[j];
        if (near_valid(o, N, c.x + d.x, c.y + d.y)) {
            const int r = near_row(o, N, c.x + d.x, c.y + d.y);
            near_accumulate(values + ((size_t)j * nrows + row) * 3, x, first + r, nb, ye, yh);
        }
        if ((d.x != 0 || d.y != 0) && near_valid(o, N, c.x - d.x, c.y - d.y)) {
            const int r = near_row(o, N, c.x - d.x, c.y - d.y);
            near_accumulate(values + ((size_t)j * nrows + r) * 3, x, first + r, nb, ye, yh);
        }
    }
    near_store(y, first + row, nb, ye, yh);
}

/* horizontal rows with vertical columns and the transpose: one work-item per rooftop */
__kernel void near_cross(const int N, __global const int2 *offsets, const int noff,
                         __global const near_t *values, __global const cplx_t *x, __global cplx_t *y)
{
    const int nrows = N * (N - 1), nb = 2 * nrows;
    const int g = get_global_id(0);
    if (g >= nb) return;
    const int o = g < nrows ? 0 : 1;
    const int2 c = near_coords(o, N, g - near_first(o, N));
    cplx_t ye[NEAR_BATCH], yh[NEAR_BATCH];
    for (int b = 0; b < NEAR_BATCH; ++b) ye[b] = yh[b] = c_new(R(0.0), R(0.0));
    for (int j = 0; j < noff; ++j) {
        const int2 d = offsets[j];
        if (o == 0) {
            if (near_valid(1, N, c.x + d.x, c.y + d.y))
                near_accumulate(values + ((size_t)j * nrows + g) * 3, x,
                                nrows + near_row(1, N, c.x + d.x, c.y + d.y), nb, ye, yh);
        } else if (near_valid(0, N, c.x - d.x, c.y - d.y)) {
            const int r = near_row(0, N, c.x - d.x, c.y - d.y);
            near_accumulate(values + ((size_t)j * nrows + r) * 3, x, r, nb, ye, yh);
        }
    }
    near_store(y, g, nb, ye, yh);
}
