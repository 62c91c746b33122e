/* Near-field correction C x on the rooftop lattice (solver/bem3d/aim/nearfield.py, NearMatrix).
 *
 * Both orientations live on one lattice of rows of pitch P >= N + max|a| (zero pad sites after
 * the N sites of each row) with Gy zero guard rows above and below: rooftop (x, y) of either
 * orientation sits at site (Gy + y) P + x (near_index.h gives the rooftop ranges; sites without
 * a rooftop hold zeros). An offset (a, b) of the pattern is then one constant shift a + P b, and
 * a shifted read never leaves the zero pads and guards. Rows are grouped in tiles of T rows.
 *
 * Values, per block, real storage type near_s: (n_offsets, tiles, 3, 2, T, P) = offset j, tile,
 * [ee, em, mm] x [re, im], row in tile, site in row; zero where the column lies outside the
 * patch and at pad, guard and empty sites. HH and VV keep the upper half of the offsets, HV all
 * offsets from horizontal rows to vertical columns. Lattice vectors X (input) and Y (output):
 * (NEAR_BATCH, 2 orientations, 2 [J, M] or [E, H], 2 [re, im], tiles T P) of real_t.
 *
 * Z is complex-symmetric, so a stored pair (row m, column n = m + s) acts twice:
 *   forward     Y_E[m] += ee X_J[n] + em X_M[n],   Y_H[m] += em X_J[n] + mm X_M[n]
 *   transposed  the same with m and n exchanged, the values read at the row m = n - s.
 * near_tiles fills the rows of one orientation o, one tile of rows and one range of sites per
 * work-item (no atomics): its own block forward and transposed, then the cross block forward
 * (o = 0: values at the row, X_V at row + s) or transposed (o = 1: values and X_H at row - s).
 * The loops run offset by offset over the tile, so each offset's values stream as 6
 * contiguous runs of T P reals (hardware prefetch; docs/aim.md), and Y accumulates in memory
 * (a tile of Y stays in cache). The right-hand sides take turns over the tile within each
 * offset: the offset's values come from memory once and from cache for the next right-hand
 * side, and only one right-hand side's rows of X and Y need the cache (docs/aim.md). On CPUs
 * a work-item takes a whole row width in WB_VW-lane vectors (wb_vcomplex.h), on GPUs one site
 * (WB_VW = 1).
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

/* Y += C_pair X for one stored slice, one right-hand side and WB_VW sites: v at [ee re] (component
   c, part r at v + (2c + r) cs); x and y at [J re] / [E re] of one orientation (parts at + plane) */
inline void near_pair(__global const near_s *v, const int cs, __global const real_t *x, __global real_t *y,
                      const size_t plane)
{
    const vcplx_t ee = vc_new(VLOAD(v), VLOAD(v + cs));
    const vcplx_t em = vc_new(VLOAD(v + 2 * cs), VLOAD(v + 3 * cs));
    const vcplx_t mm = vc_new(VLOAD(v + 4 * cs), VLOAD(v + 5 * cs));
    const vcplx_t xj = vc_new(VLOAD(x), VLOAD(x + plane));
    const vcplx_t xm = vc_new(VLOAD(x + 2 * plane), VLOAD(x + 3 * plane));
    const vcplx_t ye = vc_fma(ee, xj, vc_fma(em, xm, vc_new(VLOAD(y), VLOAD(y + plane))));
    const vcplx_t yh = vc_fma(em, xj, vc_fma(mm, xm, vc_new(VLOAD(y + 2 * plane), VLOAD(y + 3 * plane))));
    VSTORE(ye.re, y);
    VSTORE(ye.im, y + plane);
    VSTORE(yh.re, y + 2 * plane);
    VSTORE(yh.im, y + 3 * plane);
}

/* the values of offset j at lattice row r, site 0 */
inline __global const near_s *near_values(__global const near_s *v, const int j, const int r, const int tiles,
                                          const int T, const int P)
{
    return v + (((size_t)j * tiles + r / T) * 6 * T + r % T) * (size_t)P;
}

/* global size (tiles, ceil(N / (WB_VW xvectors))): rows [first_row, first_row + N) of one orientation */
__kernel void near_tiles(const int o, const int N, const int P, const int T, const int tiles, const int first_row,
                         const int xvectors, __global const int2 *same_ab, const int nsame, __global const near_s *same,
                         __global const int2 *cross_ab, const int ncross, __global const near_s *cross,
                         __global const real_t *X, __global real_t *Y)
{
    const int t = get_global_id(0);
    const int r0 = max(t * T, first_row), r1 = min((t + 1) * T, first_row + N);
    const int x0 = get_global_id(1) * xvectors * WB_VW, x1 = min(x0 + xvectors * WB_VW, N);
    if (r0 >= r1 || x0 >= x1) return;
    const size_t plane = (size_t)tiles * T * P;
    const int cs = T * P;
    __global const real_t *Xown = X + 4 * plane * o, *Xother = X + 4 * plane * (1 - o);
    __global real_t *Yown = Y + 4 * plane * o;
    for (int j = 0; j < nsame; ++j) {
        const int2 ab = same_ab[j];
        const int s = ab.x + P * ab.y;
        for (int b = 0; b < NEAR_BATCH; ++b) {
            const size_t rhs = (size_t)b * 8 * plane;
            for (int r = r0; r < r1; ++r) {
                __global const near_s *v = near_values(same, j, r, tiles, T, P);
                const size_t m = (size_t)r * P + rhs;
                for (int x = x0; x < x1; x += WB_VW) near_pair(v + x, cs, Xown + m + s + x, Yown + m + x, plane);
            }
            if (s == 0) continue;
            for (int r = r0; r < r1; ++r) {
                __global const near_s *v = near_values(same, j, r - ab.y, tiles, T, P) - ab.x;
                const size_t m = (size_t)r * P + rhs;
                for (int x = x0; x < x1; x += WB_VW) near_pair(v + x, cs, Xown + m - s + x, Yown + m + x, plane);
            }
        }
    }
    for (int j = 0; j < ncross; ++j) {
        const int2 ab = cross_ab[j];
        const int s = ab.x + P * ab.y;
        for (int b = 0; b < NEAR_BATCH; ++b) {
            const size_t rhs = (size_t)b * 8 * plane;
            for (int r = r0; r < r1; ++r) {
                __global const near_s *v = o == 0 ? near_values(cross, j, r, tiles, T, P)
                                                  : near_values(cross, j, r - ab.y, tiles, T, P) - ab.x;
                const size_t m = (size_t)r * P + rhs;
                __global const real_t *xc = Xother + m + (o == 0 ? s : -s);
                for (int x = x0; x < x1; x += WB_VW) near_pair(v + x, cs, xc + x, Yown + m + x, plane);
            }
        }
    }
}

/* lattice site of rooftop g (0 <= g < 2 N (N - 1)) and its orientation o */
inline size_t near_site(const int N, const int P, const int first_row, const int g, int *o)
{
    const int nrows = N * (N - 1);
    *o = g < nrows ? 0 : 1;
    const int2 c = near_coords(*o, N, g - near_first(*o, N));
    return (size_t)(first_row + c.y) * P + c.x;
}

/* to_lattice = 1: lattice X <- x at the sites of the rooftops; 0: y += lattice Y there, then Y <- 0 */
__kernel void near_move(const int to_lattice, const int N, const int P, const int first_row, const int L,
                        __global real_t *lattice, __global cplx_t *v)
{
    const int nb = 2 * N * (N - 1);
    const int g = get_global_id(0);
    if (g >= nb) return;
    int o;
    const size_t p = near_site(N, P, first_row, g, &o);
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
