/* The AIM part B of near pairs, subtracted from the exact entries: C = A - B (solver/bem3d/aim/near_assembly.py).
 *
 * B of a pair uses exactly the sampled grid kernel of the FFT path (aim/green.py lattice_green),
 * given here as a table over the lattice offsets [lo, lo + T) per axis: green (T) and
 * gradient (3, T). Two steps per chunk of row rooftops s (the "sources"):
 *
 * aim_near_potentials  one work-item per (source s, window point w): the grid fields of the
 *   source's stencil charges at the window points p = o_s + wb + w,
 *     FG_c = sum_b g(p - q_b) L^c_s(b)   (c = t, z, d)
 *     FK   = sum_b grad g(p - q_b) x (L^t_s(b) t_s + L^z_s(b) z^)     (3 components)
 *   stored as pot[(s * 6 + f) * nW + w], f = (FG_t, FG_z, FG_d, FK_x, FK_y, FK_z).
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

#define AIM_FIELDS 6

__kernel void aim_near_potentials(__global const int *sources, const int nsrc, __global const int *origins,
                                  const int nb, const int nh, __global const weight_t *W,
                                  const int sx, const int sy, const int sz, const int4 wdim, const int4 wbase,
                                  const int4 tlo, const int4 tdim, __global const cplx_t *green,
                                  __global const cplx_t *gradient, __global cplx_t *pot)
{
    const int nW = wdim.x * wdim.y * wdim.z;
    const size_t gid = get_global_id(0);
    if (gid >= (size_t)nsrc * nW) return;
    const int s = gid / nW, w = gid - (size_t)s * nW;
    const int wz = w % wdim.z, wy = (w / wdim.z) % wdim.y, wx = w / (wdim.z * wdim.y);
    const int g = sources[s];
    const int S = sx * sy * sz;
    const size_t wstride = (size_t)nb * S;
    const int T = tdim.x * tdim.y * tdim.z;
    cplx_t f[AIM_FIELDS];
    for (int i = 0; i < AIM_FIELDS; ++i) f[i] = c_new(R(0.0), R(0.0));
    const int horizontal = g < nh;
    int slot = 0;
    for (int a = 0; a < sx; ++a)
        for (int b = 0; b < sy; ++b)
            for (int c = 0; c < sz; ++c, ++slot) {
                const int dx = wbase.x + wx - a - tlo.x, dy = wbase.y + wy - b - tlo.y, dz = wbase.z + wz - c - tlo.z;
                const int ti = (dx * tdim.y + dy) * tdim.z + dz;
                const cplx_t G = green[ti], Gx = gradient[ti], Gy = gradient[T + ti], Gz = gradient[2 * T + ti];
                const size_t e = (size_t)g * S + slot;
                const weight_t lt = W[e], lz = W[wstride + e], ld = W[2 * wstride + e];
                f[0] = c_add(f[0], aim_wmul(lt, G));
                f[1] = c_add(f[1], aim_wmul(lz, G));
                f[2] = c_add(f[2], aim_wmul(ld, G));
                if (horizontal) { /* v = (lt, 0, lz) */
                    f[3] = c_add(f[3], aim_wmul(lz, Gy));
                    f[4] = c_add(f[4], c_sub(aim_wmul(lt, Gz), aim_wmul(lz, Gx)));
                    f[5] = c_sub(f[5], aim_wmul(lt, Gy));
                } else { /* v = (0, lt, lz) */
                    f[3] = c_add(f[3], c_sub(aim_wmul(lz, Gy), aim_wmul(lt, Gz)));
                    f[4] = c_sub(f[4], aim_wmul(lz, Gx));
                    f[5] = c_add(f[5], aim_wmul(lt, Gx));
                }
            }
    for (int i = 0; i < AIM_FIELDS; ++i) pot[((size_t)s * AIM_FIELDS + i) * nW + w] = f[i];
}

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
    __global const cplx_t *F = pot + (size_t)r * AIM_FIELDS * nW;
    const int fk = ocol == 0 ? 3 : 4; /* K field tested by the in-plane component */
    const int same = orow == ocol;
    cplx_t lvec = c_new(R(0.0), R(0.0)), ldiv = lvec, kk = lvec;
    int slot = 0;
    for (int a = 0; a < sx; ++a)
        for (int b = 0; b < sy; ++b)
            for (int cz = 0; cz < sz; ++cz, ++slot) {
                const int w = ((rx + a) * wdim.y + (ry + b)) * wdim.z + (rz + cz);
                const size_t e = (size_t)gn * S + slot;
                const weight_t lt = W[e], lz = W[wstride + e], ld = W[2 * wstride + e];
                if (same) lvec = c_add(lvec, aim_wmul(lt, F[w]));
                lvec = c_add(lvec, aim_wmul(lz, F[nW + w]));
                ldiv = c_add(ldiv, aim_wmul(ld, F[2 * nW + w]));
                kk = c_add(kk, c_add(aim_wmul(lt, F[fk * nW + w]), aim_wmul(lz, F[5 * nW + w])));
            }
    v[0] = c_sub(v[0], c_add(c_mul(coef[0], lvec), c_mul(coef[1], ldiv)));
    v[1] = c_sub(v[1], c_mul(coef[4], kk));
    v[2] = c_sub(v[2], c_add(c_mul(coef[2], lvec), c_mul(coef[3], ldiv)));
}
