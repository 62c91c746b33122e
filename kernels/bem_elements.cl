/* BEM element-pair integrals on bilinear quadrilaterals (solver/bem3d/elements.py).
 *
 * For a test element A and a source element B, over (u,v), (u',v') in [-1,1]^2 (J cancels):
 *   Lvec[a][b] = int int c_a c'_b (t_a . t'_b) G
 *   Ldiv       = int int G                      (times s_a s_b per slot pair, done later)
 *   K[a][b]    = int int c_a c'_b gradG . (t'_b x t_a)
 * slots a, b = 0..3: c = (1-u, 1+u, 1-v, 1+v), t = (r_u, r_u, r_v, r_v).
 * One table = 33 complex numbers per medium: [Lvec (a*4+b) | Ldiv | K (a*4+b)].
 *
 * Element geometry: 8 reals per element (x_c, y_c, z00, z10, z01, z11, -, -); h = d/2.
 * Media: k1 (exterior), k2 (interior, k2 = k0 (n - j kappa)).
 * Each work-item integrates WB_VW pairs at once, one per vector lane (wb_vcomplex.h).
 *
 * bem_regular_pairs   tensor Gauss-Legendre of `order` points per dimension, full kernel.
 * bem_singular_pairs  a list of 4-D points (a1, a2, b1, b2, w) on the canonical squares
 *                     (Duffy / Sauter-Schwab maps, quadrature.py) oriented per element by a
 *                     3-bit code; BEM_KIND (build define) = BEM_FULL | BEM_REMAINDER | BEM_STATIC.
 *                     BEM_STATIC writes 33 reals per pair (1/(4 pi R) parts, k-independent);
 *                     BEM_MEDIUM (define, 0 or 1) integrates one medium alone at the rule's
 *                     order, when the media need different orders.
 * NumPy twins: regular_pairs_numpy, singular_pairs_numpy in elements.py.
 */
#include "bem_green.h"

#ifndef BEM_KIND
#define BEM_KIND BEM_FULL
#endif
#define BEM_TABLE 33

typedef struct {
    vreal_t xc, yc, z00, z10, z01, z11;
} bem_element;

typedef struct {
    vreal_t x, y, z; /* position */
    vreal_t zu, zv;  /* r_u = (h, 0, zu), r_v = (0, h, zv) */
} bem_point;

/* geometry of the elements index[first + lane] (lanes past n repeat the last pair) */
inline bem_element bem_load(__global const real_t *geom, __global const int *index, int first, int n)
{
    bem_element e;
    for (int i = 0; i < WB_VW; ++i) {
        __global const real_t *g = geom + 8 * index[min(first + i, n - 1)];
        VLANE(e.xc, i) = g[0];
        VLANE(e.yc, i) = g[1];
        VLANE(e.z00, i) = g[2];
        VLANE(e.z10, i) = g[3];
        VLANE(e.z01, i) = g[4];
        VLANE(e.z11, i) = g[5];
    }
    return e;
}

inline bem_point bem_eval(bem_element g, vreal_t u, vreal_t v, real_t h)
{
    bem_point p;
    p.x = g.xc + h * u;
    p.y = g.yc + h * v;
    p.z = g.z00 + g.z10 * u + g.z01 * v + g.z11 * u * v;
    p.zu = g.z10 + g.z11 * v;
    p.zv = g.z01 + g.z11 * u;
    return p;
}

/* T[i][j] = t_i . t'_j and Q[i][j] = R . (t'_j x t_i) for t = (r_u, r_v) = ((h,0,zu), (0,h,zv)):
 *   r'_u x r_u = (0, h (zu' - zu), 0)        r'_v x r_u = (h zu, h zv', -h^2)
 *   r'_u x r_v = (-h zu', -h zv, h^2)        r'_v x r_v = (h (zv - zv'), 0, 0)            */
inline void bem_tangent_products(bem_point A, bem_point B, real_t h, vreal_t rx, vreal_t ry,
                                 vreal_t rz, vreal_t T[2][2], vreal_t Q[2][2])
{
    const real_t hh = h * h;
    T[0][0] = hh + A.zu * B.zu;
    T[0][1] = A.zu * B.zv;
    T[1][0] = A.zv * B.zu;
    T[1][1] = hh + A.zv * B.zv;
    Q[0][0] = h * ry * (B.zu - A.zu);
    Q[0][1] = h * (rx * A.zu + ry * B.zv - h * rz);
    Q[1][0] = h * (h * rz - rx * B.zu - ry * A.zv);
    Q[1][1] = h * rx * (A.zv - B.zv);
}

inline void bem_slot_weights(vreal_t u, vreal_t v, vreal_t c[4])
{
    c[0] = R(1.0) - u;
    c[1] = R(1.0) + u;
    c[2] = R(1.0) - v;
    c[3] = R(1.0) + v;
}

/* write the tables of the lanes that hold real pairs, nmed media from medium m0 of the two each
 * pair stores: out[(pair * 2 + m0 + m) * 33 + i] */
inline void bem_store(__global cplx_t *out, int first, int n, int m0, int nmed, vcplx_t lv[][16],
                      vcplx_t ld[], vcplx_t kk[][16])
{
    for (int i = 0; i < WB_VW; ++i) {
        if (first + i >= n) break;
        for (int m = 0; m < nmed; ++m) {
            __global cplx_t *o = out + ((first + i) * 2 + m0 + m) * BEM_TABLE;
            for (int j = 0; j < 16; ++j) {
                o[j] = vc_lane(lv[m][j], i);
                o[17 + j] = vc_lane(kk[m][j], i);
            }
            o[16] = vc_lane(ld[m], i);
        }
    }
}

__kernel void bem_regular_pairs(__global const real_t *geom, const real_t h,
                                __global const int *test, __global const int *source,
                                const int npairs, __global const real_t *nodes,
                                __global const real_t *weights, const int order,
                                const cplx_t k1, const cplx_t k2, __global cplx_t *out)
{
    const int first = get_global_id(0) * WB_VW;
    if (first >= npairs) return;
    const bem_element gA = bem_load(geom, test, first, npairs);
    const bem_element gB = bem_load(geom, source, first, npairs);
    const cplx_t ks[2] = {k1, k2};
    const real_t hh = h * h;

    vcplx_t lv[2][16], kk[2][16], ld[2];
    for (int m = 0; m < 2; ++m) {
        ld[m] = vc_zero();
        for (int i = 0; i < 16; ++i) lv[m][i] = kk[m][i] = vc_zero();
    }
    for (int ia = 0; ia < order; ++ia) {
        for (int ja = 0; ja < order; ++ja) {
            const real_t ua = nodes[ia], va = nodes[ja];
            const real_t wa = weights[ia] * weights[ja];
            const bem_point A = bem_eval(gA, (vreal_t)(ua), (vreal_t)(va), h);
            /* per medium: moments sum w' g {1, u', v', u'v'} (they give L_vec and L_div) and
               the K partial sums [tangent of a][slot b] */
            vcplx_t mo[2][4], pk[2][2][4];
            for (int m = 0; m < 2; ++m) {
                for (int i = 0; i < 4; ++i) mo[m][i] = vc_zero();
                for (int t = 0; t < 2; ++t)
                    for (int b = 0; b < 4; ++b) pk[m][t][b] = vc_zero();
            }
            for (int ib = 0; ib < order; ++ib) {
                for (int jb = 0; jb < order; ++jb) {
                    const real_t ub = nodes[ib], vb = nodes[jb];
                    const real_t wb = weights[ib] * weights[jb];
                    const bem_point B = bem_eval(gB, (vreal_t)(ub), (vreal_t)(vb), h);
                    const vreal_t rx = A.x - B.x, ry = A.y - B.y, rz = A.z - B.z;
                    const vreal_t r = sqrt(rx * rx + ry * ry + rz * rz);
                    const vreal_t inv_r = R(1.0) / r;
                    vreal_t T[2][2], Q[2][2];
                    bem_tangent_products(A, B, h, rx, ry, rz, T, Q);
                    const real_t cb[4] = {R(1.0) - ub, R(1.0) + ub, R(1.0) - vb, R(1.0) + vb};
                    vreal_t cq[2][4];
                    for (int t = 0; t < 2; ++t)
                        for (int b = 0; b < 4; ++b) cq[t][b] = (wb * cb[b]) * Q[t][b >> 1];
                    const real_t mw[4] = {wb, wb * ub, wb * vb, wb * ub * vb};
                    for (int m = 0; m < 2; ++m) {
                        vcplx_t g, gk;
                        bem_green(BEM_FULL, ks[m], r, inv_r, &g, &gk);
                        for (int i = 0; i < 4; ++i) mo[m][i] = vc_fma_real(g, (vreal_t)(mw[i]), mo[m][i]);
                        for (int t = 0; t < 2; ++t)
                            for (int b = 0; b < 4; ++b) pk[m][t][b] = vc_fma_real(gk, cq[t][b], pk[m][t][b]);
                    }
                }
            }
            vreal_t ca[4];
            bem_slot_weights((vreal_t)(ua), (vreal_t)(va), ca);
            const vreal_t at[2] = {A.zu, A.zv};
            for (int m = 0; m < 2; ++m) {
                const vcplx_t M0 = mo[m][0], M1 = mo[m][1], M2 = mo[m][2], M3 = mo[m][3];
                /* S_b = sum g c'_b ; Z_b = sum g c'_b z'_{t(b)}, zu' = z10'+z11' v', zv' = z01'+z11' u' */
                const vcplx_t S[4] = {vc_sub(M0, M1), vc_add(M0, M1), vc_sub(M0, M2), vc_add(M0, M2)};
                const vcplx_t Z[4] = {
                    vc_add(vc_scale(vc_sub(M0, M1), gB.z10), vc_scale(vc_sub(M2, M3), gB.z11)),
                    vc_add(vc_scale(vc_add(M0, M1), gB.z10), vc_scale(vc_add(M2, M3), gB.z11)),
                    vc_add(vc_scale(vc_sub(M0, M2), gB.z01), vc_scale(vc_sub(M1, M3), gB.z11)),
                    vc_add(vc_scale(vc_add(M0, M2), gB.z01), vc_scale(vc_add(M1, M3), gB.z11))};
                ld[m] = vc_fma_real(M0, (vreal_t)(wa), ld[m]);
                for (int a = 0; a < 4; ++a) {
                    const int t = a >> 1;
                    const vreal_t s = wa * ca[a];
                    for (int b = 0; b < 4; ++b) {
                        /* sum g c'_b t_a.t'_b = h^2 [t(a) == t(b)] S_b + z_{t(a)} Z_b */
                        vcplx_t pv = vc_scale(Z[b], at[t]);
                        if (t == (b >> 1)) pv = vc_fma_real(S[b], (vreal_t)(hh), pv);
                        lv[m][4 * a + b] = vc_fma_real(pv, s, lv[m][4 * a + b]);
                        kk[m][4 * a + b] = vc_fma_real(pk[m][t][b], s, kk[m][4 * a + b]);
                    }
                }
            }
        }
    }
    bem_store(out, first, npairs, 0, 2, lv, ld, kk);
}

/* per-lane affine map of canonical (p1, p2) to (u, v) = c0 + c1 p1 + c2 p2, from 3-bit codes:
 * bit 0 swap (u from p2, v from p1), bit 1 flip u (u = 1 - 2p), bit 2 flip v */
typedef struct {
    vreal_t u0, u1, u2, v0, v1, v2;
} bem_orientation;

inline bem_orientation bem_orientations(__global const int *code, int first, int n)
{
    bem_orientation o;
    for (int i = 0; i < WB_VW; ++i) {
        const int c = code[min(first + i, n - 1)];
        const real_t su = (c & 2) ? R(-2.0) : R(2.0), sv = (c & 4) ? R(-2.0) : R(2.0);
        VLANE(o.u0, i) = (c & 2) ? R(1.0) : R(-1.0);
        VLANE(o.v0, i) = (c & 4) ? R(1.0) : R(-1.0);
        VLANE(o.u1, i) = (c & 1) ? R(0.0) : su;
        VLANE(o.u2, i) = (c & 1) ? su : R(0.0);
        VLANE(o.v1, i) = (c & 1) ? sv : R(0.0);
        VLANE(o.v2, i) = (c & 1) ? R(0.0) : sv;
    }
    return o;
}

#ifndef BEM_MEDIUM
#define BEM_MEDIUM -1 /* both media; 0 or 1: that medium alone (its own order), the other's table untouched */
#endif
#if BEM_KIND == BEM_STATIC || BEM_MEDIUM >= 0
#define BEM_NMED 1
#else
#define BEM_NMED 2
#endif
#define BEM_FIRST_MEDIUM (BEM_MEDIUM > 0 ? 1 : 0)

__kernel void bem_singular_pairs(__global const real_t *geom, const real_t h,
                                 __global const int *test, __global const int *source,
                                 __global const int *code_test, __global const int *code_source,
                                 const int npairs, __global const real_t *rule, const int npoints,
                                 const cplx_t k1, const cplx_t k2, __global real_t *out)
{
    const int first = get_global_id(0) * WB_VW;
    if (first >= npairs) return;
    const bem_element gA = bem_load(geom, test, first, npairs);
    const bem_element gB = bem_load(geom, source, first, npairs);
    const bem_orientation oA = bem_orientations(code_test, first, npairs);
    const bem_orientation oB = bem_orientations(code_source, first, npairs);
    const cplx_t ks[2] = {BEM_FIRST_MEDIUM ? k2 : k1, k2};

    vcplx_t lv[BEM_NMED][16], kk[BEM_NMED][16], ld[BEM_NMED];
    for (int m = 0; m < BEM_NMED; ++m) {
        ld[m] = vc_zero();
        for (int i = 0; i < 16; ++i) lv[m][i] = kk[m][i] = vc_zero();
    }
    for (int q = 0; q < npoints; ++q) {
        __global const real_t *pt = rule + 5 * q;
        const vreal_t ua = oA.u0 + oA.u1 * pt[0] + oA.u2 * pt[1];
        const vreal_t va = oA.v0 + oA.v1 * pt[0] + oA.v2 * pt[1];
        const vreal_t ub = oB.u0 + oB.u1 * pt[2] + oB.u2 * pt[3];
        const vreal_t vb = oB.v0 + oB.v1 * pt[2] + oB.v2 * pt[3];
        const real_t w = R(16.0) * pt[4];
        const bem_point A = bem_eval(gA, ua, va, h);
        const bem_point B = bem_eval(gB, ub, vb, h);
        const vreal_t rx = A.x - B.x, ry = A.y - B.y, rz = A.z - B.z;
        const vreal_t r = sqrt(rx * rx + ry * ry + rz * rz);
        const vreal_t inv_r = R(1.0) / r;
        vreal_t T[2][2], Q[2][2], ca[4], cb[4];
        bem_tangent_products(A, B, h, rx, ry, rz, T, Q);
        bem_slot_weights(ua, va, ca);
        bem_slot_weights(ub, vb, cb);
        vreal_t cT[16], cQ[16];
        for (int a = 0; a < 4; ++a)
            for (int b = 0; b < 4; ++b) {
                const vreal_t cc = w * ca[a] * cb[b];
                cT[4 * a + b] = cc * T[a >> 1][b >> 1];
                cQ[4 * a + b] = cc * Q[a >> 1][b >> 1];
            }
        for (int m = 0; m < BEM_NMED; ++m) {
            vcplx_t g, gk;
#if BEM_KIND == BEM_STATIC
            g = vc_new(WB_INV_4PI * inv_r, (vreal_t)(R(0.0)));
            gk = vc_new(-WB_INV_4PI * inv_r * inv_r * inv_r, (vreal_t)(R(0.0)));
#else
            bem_green(BEM_KIND, ks[m], r, inv_r, &g, &gk);
#endif
            ld[m] = vc_fma_real(g, (vreal_t)(w), ld[m]);
            for (int i = 0; i < 16; ++i) {
                lv[m][i] = vc_fma_real(g, cT[i], lv[m][i]);
                kk[m][i] = vc_fma_real(gk, cQ[i], kk[m][i]);
            }
        }
    }
#if BEM_KIND == BEM_STATIC
    for (int i = 0; i < WB_VW; ++i) {
        if (first + i >= npairs) break;
        __global real_t *o = out + (first + i) * BEM_TABLE;
        for (int j = 0; j < 16; ++j) {
            o[j] = VLANE(lv[0][j].re, i);
            o[17 + j] = VLANE(kk[0][j].re, i);
        }
        o[16] = VLANE(ld[0].re, i);
    }
#else
    bem_store((__global cplx_t *)out, first, npairs, BEM_FIRST_MEDIUM, BEM_NMED, lv, ld, kk);
#endif
}
