/* The AIM part B of near pairs, subtracted from the exact entries: C = A - B (solver/bem3d/aim/near_assembly.py).
 *
 * B of a pair uses exactly the sampled grid kernel of the FFT path (aim/green.py lattice_green).
 * The host computes the grid fields of each row rooftop s (the "source") of a chunk of nrows at
 * the window points p = o_s + wb + w (one BLAS product: near_assembly.py window_kernels), in
 * three arrays of pot, row-major per source:
 *   Pt (nrows, 3, nW) = L^t_s * (g, d1 g, d2 g), (d1, d2) = (dy, dz) horizontal, (dz, dx) vertical;
 *   Pz (nrows, 3, nW) = L^z_s * (g, dx g, dy g);
 *   Pd (nrows, nW)    = L^d_s * g,
 * so FG_t = Pt[0], FG_z = Pz[0], FG_d = Pd, and FK = sum_b grad g(p - q_b) x (L^t_s t_s + L^z_s z^):
 *   horizontal (t = x^): FK_x = Pz[2], FK_y = Pt[2] - Pz[1], FK_z = -Pt[1];
 *   vertical (t = y^):   FK_x = Pz[2] - Pt[1], FK_y = -Pz[1], FK_z = Pt[2].
 * aim_near_correct     one work-item per stored pair (row r, offset j) of the chunk: the test
 *   rooftop n (the column) reads the fields over its stencil,
 *     Lvec = [same orientation] sum L^t_n FG_t + sum L^z_n FG_z,  Ldiv = sum L^d_n FG_d,
 *     K = sum L^t_n FK_{x or y} + L^z_n FK_z,
 *   and subtracts ee_vec Lvec + ee_div Ldiv, eta0 K, mm_vec Lvec + mm_div Ldiv from the staged
 *   (noff, nrows, 3) entries [ee, em, mm]. B is symmetric, so B(n, s) = B(s, n).
 * NumPy twin: near_base_numpy in aim/near_assembly.py (the explicit S x S double sum).
 */
#include "aim_weights.h"
#include "near_index.h"

/* orow, ocol: orientations of rows and columns; offsets (a, b): column = row + (a, b); rows: the
   block-local row of each chunk position r (its potentials are pot[r]); values (noff, nrows, 3) */
__kernel void aim_near_correct(const int orow, const int ocol, const int N, __global const int2 *offsets,
                               const int noff, __global const int *rows, const int nrows, __global const int *origins,
                               const int nb, __global const weight_t *W, const int sx, const int sy, const int sz,
                               const int4 wdim, const int4 wbase, __global const cplx_t *pot,
                               __constant const cplx_t *coef, __global cplx_t *values)
{
    /* coef: ee_vec, ee_div, mm_vec, mm_div, em */
    const size_t gid = get_global_id(0);
    if (gid >= (size_t)noff * nrows) return;
    /* the offsets of one row are adjacent work-items: they read the same row's potentials (cache) */
    const int r = gid / noff, j = gid - (size_t)r * noff;
    const int2 c = near_coords(orow, N, rows[r]);
    const int2 d = offsets[j];
    if (!near_valid(ocol, N, c.x + d.x, c.y + d.y)) return;
    const int gs = near_first(orow, N) + rows[r];
    const int gn = near_first(ocol, N) + near_row(ocol, N, c.x + d.x, c.y + d.y);
    const int S = sx * sy * sz;
    const size_t wstride = (size_t)nb * S;
    const int nW = wdim.x * wdim.y * wdim.z;
    const int rx = origins[3 * gn] - origins[3 * gs] - wbase.x;
    const int ry = origins[3 * gn + 1] - origins[3 * gs + 1] - wbase.y;
    const int rz = origins[3 * gn + 2] - origins[3 * gs + 2] - wbase.z;
    __global cplx_t *v = values + ((size_t)j * nrows + r) * 3;
    if (rx < 0 || ry < 0 || rz < 0 || rx + sx > wdim.x || ry + sy > wdim.y || rz + sz > wdim.z) {
        v[0] = v[1] = v[2] = c_new(NAN, NAN); /* the window does not cover the pair: an error */
        return;
    }
    __global const cplx_t *Pt = pot + (size_t)r * 3 * nW;
    __global const cplx_t *Pz = pot + ((size_t)nrows + r) * 3 * nW;
    __global const cplx_t *Pd = pot + (size_t)nrows * 6 * nW + (size_t)r * nW;
    const int same = orow == ocol;
    cplx_t lvec = c_new(R(0.0), R(0.0)), ldiv = lvec, kk = lvec;
    int slot = 0;
    for (int a = 0; a < sx; ++a)
        for (int b = 0; b < sy; ++b)
            for (int cz = 0; cz < sz; ++cz, ++slot) {
                const int w = ((rx + a) * wdim.y + (ry + b)) * wdim.z + (rz + cz);
                const size_t e = (size_t)gn * S + slot;
                const weight_t lt = W[e], lz = W[wstride + e], ld = W[2 * wstride + e];
                if (same) lvec = c_add(lvec, aim_wmul(lt, Pt[w]));
                lvec = c_add(lvec, aim_wmul(lz, Pz[w]));
                ldiv = c_add(ldiv, aim_wmul(ld, Pd[w]));
                /* the K field along the column's tangent (x^ for ocol 0, y^ for 1) and along z^ */
                cplx_t fk, fz;
                if (orow == 0) {
                    fk = ocol == 0 ? Pz[2 * nW + w] : c_sub(Pt[2 * nW + w], Pz[nW + w]);
                    fz = -Pt[nW + w];
                } else {
                    fk = ocol == 0 ? c_sub(Pz[2 * nW + w], Pt[nW + w]) : -Pz[nW + w];
                    fz = Pt[2 * nW + w];
                }
                kk = c_add(kk, c_add(aim_wmul(lt, fk), aim_wmul(lz, fz)));
            }
    v[0] = c_sub(v[0], c_add(c_mul(coef[0], lvec), c_mul(coef[1], ldiv)));
    v[1] = c_sub(v[1], c_mul(coef[4], kk));
    v[2] = c_sub(v[2], c_add(c_mul(coef[2], lvec), c_mul(coef[3], ldiv)));
}
