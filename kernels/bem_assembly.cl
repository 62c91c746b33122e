/* PMCHWT matrix entries of basis-function pairs from element-pair tables (assembly.py).
 *
 * A rooftop g has two halves sigma = 0, 1 on elements elem[g][sigma] (local indices into the
 * table block) with slots slot[g][sigma] in 0..3 (divergence sign -,+,-,+). For a pair (m, n):
 *   L_vec,i = sum_{sigma,tau} T_i[A,B].Lvec[a][b],  L_div,i = sum s_a s_b T_i[A,B].Ldiv,
 *   K_i = sum T_i[A,B].K[a][b],  A = elem[m][sigma], B = elem[n][tau], a/b the slots,
 * and T = tables[pair_map[A * n_source + B]] (33 complex per medium, elements.py layout); a
 * code -1 - r in pair_map: row r holds the table of (B, A), read with the slots swapped (the
 * Galerkin symmetry: Lvec[b][a], K[b][a], Ldiv; aim/near_tables.py).
 * Outputs (scaled PMCHWT, media.py):
 *   ee = sum_i ee_vec[i] L_vec,i + ee_div[i] L_div,i,   mm likewise,   em = eta0 sum_i K_i.
 * bem_basis_block: all (row, col) of a block, entry = row * ncols + col.
 * bem_basis_list:  an explicit list of (row, col) pairs (sparse near-field lists).
 * NumPy twin: basis_entries_numpy in assembly.py.
 */
#include "wb_complex.h"

#define BEM_TABLE 33
#ifndef BEM_SEGMENT
#define BEM_SEGMENT 64
#endif

inline real_t bem_slot_sign(int a) { return (a & 1) ? R(1.0) : R(-1.0); }

inline void bem_basis_entry(__global const cplx_t *tables, __global const int *pair_map,
                            const int n_source, int2 row_elem, int2 row_slot, int2 col_elem,
                            int2 col_slot, __constant const cplx_t *coef, cplx_t *ee, cplx_t *mm,
                            cplx_t *em)
{
    /* coef: ee_vec[2], ee_div[2], mm_vec[2], mm_div[2], em */
    cplx_t lv[2] = {c_new(R(0.0), R(0.0)), c_new(R(0.0), R(0.0))};
    cplx_t ld[2] = {c_new(R(0.0), R(0.0)), c_new(R(0.0), R(0.0))};
    cplx_t kk = c_new(R(0.0), R(0.0));
    const int re[2] = {row_elem.x, row_elem.y}, rs[2] = {row_slot.x, row_slot.y};
    const int ce[2] = {col_elem.x, col_elem.y}, cs[2] = {col_slot.x, col_slot.y};
    for (int s = 0; s < 2; ++s) {
        for (int t = 0; t < 2; ++t) {
            /* code r: table row r; -1 - r: row r holds the pair's other order, read transposed */
            const int code = pair_map[re[s] * n_source + ce[t]];
            __global const cplx_t *tab = tables + 2 * BEM_TABLE * (code < 0 ? -1 - code : code);
            const int ab = code < 0 ? 4 * cs[t] + rs[s] : 4 * rs[s] + cs[t];
            const real_t sign = bem_slot_sign(rs[s]) * bem_slot_sign(cs[t]);
            for (int m = 0; m < 2; ++m) {
                lv[m] = c_add(lv[m], tab[m * BEM_TABLE + ab]);
                ld[m] = c_add(ld[m], c_scale(tab[m * BEM_TABLE + 16], sign));
                kk = c_add(kk, tab[m * BEM_TABLE + 17 + ab]);
            }
        }
    }
    cplx_t e = c_new(R(0.0), R(0.0)), h = c_new(R(0.0), R(0.0));
    for (int m = 0; m < 2; ++m) {
        e = c_add(e, c_add(c_mul(coef[0 + m], lv[m]), c_mul(coef[2 + m], ld[m])));
        h = c_add(h, c_add(c_mul(coef[4 + m], lv[m]), c_mul(coef[6 + m], ld[m])));
    }
    *ee = e;
    *mm = h;
    *em = c_mul(coef[8], kk);
}

__kernel void bem_basis_block(__global const cplx_t *tables, __global const int *pair_map,
                              const int n_source, __global const int2 *row_elem,
                              __global const int2 *row_slot, __global const int2 *col_elem,
                              __global const int2 *col_slot, const int nrows, const int ncols,
                              __constant const cplx_t *coef, __global cplx_t *ee,
                              __global cplx_t *mm, __global cplx_t *em)
{
    /* one work-item per row and column segment of BEM_SEGMENT entries */
    const int segments = (ncols + BEM_SEGMENT - 1) / BEM_SEGMENT;
    const int gid = get_global_id(0);
    if (gid >= nrows * segments) return;
    const int i = gid / segments;
    const int j0 = (gid - i * segments) * BEM_SEGMENT;
    const int j1 = min(j0 + BEM_SEGMENT, ncols);
    const int2 re = row_elem[i], rs = row_slot[i];
    for (int j = j0; j < j1; ++j) {
        cplx_t e, h, k;
        bem_basis_entry(tables, pair_map, n_source, re, rs, col_elem[j], col_slot[j], coef, &e, &h, &k);
        const size_t o = (size_t)i * ncols + j;
        ee[o] = e;
        mm[o] = h;
        em[o] = k;
    }
}

__kernel void bem_basis_list(__global const cplx_t *tables, __global const int *pair_map,
                             const int n_source, __global const int2 *row_elem,
                             __global const int2 *row_slot, __global const int2 *col_elem,
                             __global const int2 *col_slot, __global const int *rows,
                             __global const int *cols, const int nentries,
                             __constant const cplx_t *coef, __global cplx_t *ee,
                             __global cplx_t *mm, __global cplx_t *em)
{
    const int p = get_global_id(0);
    if (p >= nentries) return;
    const int i = rows[p], j = cols[p];
    cplx_t e, h, k;
    bem_basis_entry(tables, pair_map, n_source, row_elem[i], row_slot[i], col_elem[j],
                    col_slot[j], coef, &e, &h, &k);
    ee[p] = e;
    mm[p] = h;
    em[p] = k;
}
