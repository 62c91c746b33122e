/* 2.5D PMCHWT matrix of a fiber cross section (fiber.md §3, §4).
 *
 * Host side and NumPy reference with matching names: wavebrdf.solver.fiber.assembly
 * (fiber_pair_moments / fiber_assemble and their *_reference twins).
 *
 * Geometry: closed polygon, nodes P_e (counter-clockwise), element e = [P_e, P_{e+1 mod N}],
 * length D_e, unit tangent t_e. Local hats on an element: L_0 = 1 - s (start node), L_1 = s.
 * Green's function G = H0^(2)(k_rho R)/(4j); h = dG/dR = (j k_rho/4) H1^(2)(k_rho R).
 *
 * Kernel fiber_pair_moments: one work-item per unordered element pair (a <= b); for each medium p
 *   I^{ab}  = int_a int_b L_alpha L_beta G_p
 *   Kz^{ab} = int_a int_b L_alpha L_beta h_p z.(R^ x t_b),  R = rho_a - rho_b
 * written for both orders (a,b) and (b,a): I is symmetric, Kz(b,a) is computed from the same
 * kernel values. Far pairs: Q_FAR x Q_FAR Gauss. Near pairs (centre distance < near_factor *
 * max(D_a, D_b), which includes self and adjacent pairs): G = G_s - ln(R)/(2 pi) and
 * h = h_s - 1/(2 pi R); the smooth parts by Q_NEAR x Q_NEAR Gauss, the singular parts integrated
 * in closed form over the source element for every outer Gauss point.
 *
 * Build defines: Q_FAR, Q_NEAR (Gauss orders), WB_FP64.
 */
#include "hankel.h"

#define WB_INV_2PI R(0.15915494309189533577)

typedef struct {
    real2_t p;   /* start node */
    real2_t t;   /* unit tangent */
    real_t len;
} element_t;

inline element_t fiber_element(__global const real2_t *nodes, int e, int n)
{
    element_t el;
    el.p = nodes[e];
    const real2_t d = nodes[(e + 1) % n] - el.p;
    el.len = hypot(d.x, d.y);
    el.t = d / el.len;
    return el;
}

/* z.(v x t) for in-plane vectors */
inline real_t cross_z(real2_t v, real2_t t) { return v.x * t.y - v.y * t.x; }

/* G and h at distance R (> 0) in a medium of transverse wavenumber k */
inline void green_and_gradient(cplx_t k, real_t dist, cplx_t *g, cplx_t *h)
{
    cplx_t h0, h1;
    hankel2_01(c_scale(k, dist), &h0, &h1);
    *g = c_new(R(0.25) * h0.y, R(-0.25) * h0.x);            /* -j H0 / 4 */
    const cplx_t jk = c_new(R(-0.25) * k.y, R(0.25) * k.x);  /* j k / 4 */
    *h = c_mul(jk, h1);
}

/* Smooth parts G_s = G + ln(R)/(2 pi) and h_s = h + 1/(2 pi R); R = 0 gives their limits. */
inline void green_smooth(cplx_t k, real_t dist, cplx_t *gs, cplx_t *hs)
{
    const cplx_t z = c_scale(k, dist);
    if (c_abs(z) >= HANKEL_SERIES_MAX) {
        green_and_gradient(k, dist, gs, hs);
        gs->x += WB_INV_2PI * log(dist);
        hs->x += WB_INV_2PI / dist;
        return;
    }
    cplx_t j0m1, j1, y0r, y1r;
    bessel01_series(z, &j0m1, &j1, &y0r, &y1r);
    const cplx_t j0 = c_new(R(1.0) + j0m1.x, j0m1.y);
    const cplx_t log_half_k = c_log(c_scale(k, R(0.5)));
    const real_t log_r = dist > R(0.0) ? log(dist) : R(0.0);  /* multiplies terms that vanish at 0 */
    /* G_s = J0/(4j) - (1/2pi) ln(k/2) J0 - y0r/4 - (1/2pi) ln R (J0 - 1) */
    cplx_t g = c_new(R(0.25) * j0.y, R(-0.25) * j0.x);
    g = c_sub(g, c_scale(c_mul(log_half_k, j0), WB_INV_2PI));
    g = c_sub(g, c_scale(y0r, R(0.25)));
    g = c_sub(g, c_scale(j0m1, WB_INV_2PI * log_r));
    *gs = g;
    /* h_s = (j k/4) J1 + (k/4) [(2/pi)(ln(k/2) + ln R) J1 + y1r] */
    const cplx_t log_half_z = c_new(log_half_k.x + log_r, log_half_k.y);
    const cplx_t bracket = c_add(c_scale(c_mul(log_half_z, j1), WB_2_OVER_PI), y1r);
    const cplx_t jk = c_new(R(-0.25) * k.y, R(0.25) * k.x);
    *hs = c_add(c_mul(jk, j1), c_mul(c_scale(k, R(0.25)), bracket));
}

/* Local coordinates of point x relative to element el: along = (x - P).t, perp = z.((x - P) x t);
 * the element spans u in [u_s, u_e] = [-along, len - along] measured from the foot point. */

/* int_el L_beta ln R ds' (beta = 0: start hat, 1: end hat), closed form (fiber.md §4) */
inline real2_t log_moments(real2_t x, element_t el)
{
    const real2_t rel = x - el.p;
    const real_t u0 = dot(rel, el.t);
    const real_t h = fabs(cross_z(rel, el.t));
    const real_t ue = el.len - u0, us = -u0;
    const real_t re2 = ue * ue + h * h, rs2 = us * us + h * h;
    const real_t lre = re2 > R(0.0) ? R(0.5) * log(re2) : R(0.0);
    const real_t lrs = rs2 > R(0.0) ? R(0.5) * log(rs2) : R(0.0);
    /* F0(u) = u ln r - u + h atan(u/h); the atan difference written as one atan2 */
    real_t i0 = ue * lre - us * lrs - (ue - us);
    if (h > R(0.0)) i0 += h * atan2(h * (ue - us), h * h + ue * us);
    /* F1(u) = r^2 ln r / 2 - u^2/4;  int s' ln R = [F1] + u0 I0 */
    const real_t i1 = R(0.5) * (re2 * lre - rs2 * lrs) - R(0.25) * (ue * ue - us * us) + u0 * i0;
    return (real2_t)(i0 - i1 / el.len, i1 / el.len);
}

/* int_el L_beta d / R^2 ds' with d = z.((x - P) x t) (static double-layer kernel), closed form */
inline real2_t static_moments(real2_t x, element_t el)
{
    const real2_t rel = x - el.p;
    const real_t u0 = dot(rel, el.t);
    const real_t d = cross_z(rel, el.t);
    const real_t ue = el.len - u0, us = -u0;
    const real_t j0 = atan2(d * (ue - us), d * d + ue * us);
    const real_t re2 = ue * ue + d * d, rs2 = us * us + d * d;
    const real_t j1 = (d != R(0.0) ? R(0.5) * d * log(re2 / rs2) : R(0.0)) + u0 * j0;
    return (real2_t)(j0 - j1 / el.len, j1 / el.len);
}

/* Tensor Gauss rule (q points per element) over elements a and b, accumulating for both media
 *   I^{ab}  += L_alpha L_beta g,   Kz^{ab} += L_alpha L_beta h z.(R^ x t_b),
 *   Kz^{ba} += L_beta L_alpha h z.(-R^ x t_a)   (R = rho_a - rho_b),
 * with (g, h) = (G, dG/dR) for far pairs or their smooth parts (G_s, h_s) for near pairs. */
inline void accumulate_tensor(element_t ea, element_t eb, __constant real2_t *rule, const int q,
                              const int smooth, const int self, __constant cplx_t *krho,
                              cplx_t ii[2][4], cplx_t kab[2][4], cplx_t kba[2][4])
{
    for (int i = 0; i < q; ++i) {
        const real2_t qa = rule[i];
        const real2_t ra = ea.p + (qa.x * ea.len) * ea.t;
        const real_t la[2] = {R(1.0) - qa.x, qa.x};
        for (int j = 0; j < q; ++j) {
            const real2_t qb = rule[j];
            const real2_t rvec = ra - (eb.p + (qb.x * eb.len) * eb.t);
            const real_t dist = hypot(rvec.x, rvec.y);
            const real_t lb[2] = {R(1.0) - qb.x, qb.x};
            const real_t w = qa.y * qb.y * ea.len * eb.len;
            const int use_k = !self && dist > R(0.0);   /* K vanishes on the self element */
            const real_t cb = use_k ? cross_z(rvec, eb.t) / dist : R(0.0);
            const real_t ca = use_k ? -cross_z(rvec, ea.t) / dist : R(0.0);
            for (int p = 0; p < 2; ++p) {
                cplx_t g, h;
                if (smooth)
                    green_smooth(krho[p], dist, &g, &h);
                else
                    green_and_gradient(krho[p], dist, &g, &h);
                for (int al = 0; al < 2; ++al)
                    for (int be = 0; be < 2; ++be) {
                        const real_t ww = w * la[al] * lb[be];
                        ii[p][2 * al + be] = c_fma(g, c_new(ww, R(0.0)), ii[p][2 * al + be]);
                        kab[p][2 * al + be] = c_fma(h, c_new(ww * cb, R(0.0)), kab[p][2 * al + be]);
                        kba[p][2 * be + al] = c_fma(h, c_new(ww * ca, R(0.0)), kba[p][2 * be + al]);
                    }
            }
        }
    }
}

#define MOM_INDEX(p, a, b, n) ((((p) * (n) + (a)) * (n) + (b)) * 4)

__kernel void fiber_pair_moments(__global const real2_t *nodes, __constant cplx_t *krho,
                                 __constant real2_t *gl_far, __constant real2_t *gl_near,
                                 const int n, const real_t near_factor,
                                 __global cplx_t *mom_i, __global cplx_t *mom_k)
{
    const int a = get_global_id(0), b = get_global_id(1);
    if (a >= n || b >= n || a > b) return;
    const element_t ea = fiber_element(nodes, a, n), eb = fiber_element(nodes, b, n);
    const real2_t ca = ea.p + R(0.5) * ea.len * ea.t, cb = eb.p + R(0.5) * eb.len * eb.t;
    const real2_t dc = ca - cb;
    const int near = hypot(dc.x, dc.y) < near_factor * fmax(ea.len, eb.len);
    const int self = (a == b);

    cplx_t ii[2][4], kab[2][4], kba[2][4];   /* [medium][2 alpha + beta] */
    for (int p = 0; p < 2; ++p)
        for (int q = 0; q < 4; ++q) {
            ii[p][q] = c_new(R(0.0), R(0.0));
            kab[p][q] = c_new(R(0.0), R(0.0));
            kba[p][q] = c_new(R(0.0), R(0.0));
        }

    if (!near) {
        accumulate_tensor(ea, eb, gl_far, Q_FAR, 0, self, krho, ii, kab, kba);
    } else {
        /* singular parts (medium independent): -ln R/(2 pi) and -d/(2 pi R^2) */
        real_t ilog[4] = {R(0.0), R(0.0), R(0.0), R(0.0)};
        real_t sab[4] = {R(0.0), R(0.0), R(0.0), R(0.0)};
        real_t sba[4] = {R(0.0), R(0.0), R(0.0), R(0.0)};
        for (int i = 0; i < Q_NEAR; ++i) {
            const real2_t qa = gl_near[i];
            const real2_t ra = ea.p + (qa.x * ea.len) * ea.t;
            const real_t la[2] = {R(1.0) - qa.x, qa.x};
            const real_t w = qa.y * ea.len;
            const real2_t lm = log_moments(ra, eb);
            const real2_t sm = self ? (real2_t)(R(0.0), R(0.0)) : static_moments(ra, eb);
            for (int al = 0; al < 2; ++al) {
                ilog[2 * al + 0] += w * la[al] * lm.x;
                ilog[2 * al + 1] += w * la[al] * lm.y;
                sab[2 * al + 0] += w * la[al] * sm.x;
                sab[2 * al + 1] += w * la[al] * sm.y;
            }
            if (!self) {  /* outer point on b, inner analytic over a */
                const real2_t rb = eb.p + (qa.x * eb.len) * eb.t;
                const real2_t smb = static_moments(rb, ea);
                const real_t wb = qa.y * eb.len;
                for (int be = 0; be < 2; ++be) {
                    sba[2 * be + 0] += wb * la[be] * smb.x;
                    sba[2 * be + 1] += wb * la[be] * smb.y;
                }
            }
        }
        for (int p = 0; p < 2; ++p)
            for (int q = 0; q < 4; ++q) {
                ii[p][q] = c_new(-WB_INV_2PI * ilog[q], R(0.0));
                kab[p][q] = c_new(-WB_INV_2PI * sab[q], R(0.0));
                kba[p][q] = c_new(-WB_INV_2PI * sba[q], R(0.0));
            }
        /* smooth parts */
        accumulate_tensor(ea, eb, gl_near, Q_NEAR, 1, self, krho, ii, kab, kba);
    }

    for (int p = 0; p < 2; ++p) {
        const int ab = MOM_INDEX(p, a, b, n), ba = MOM_INDEX(p, b, a, n);
        for (int al = 0; al < 2; ++al)
            for (int be = 0; be < 2; ++be) {
                mom_i[ab + 2 * al + be] = ii[p][2 * al + be];
                mom_i[ba + 2 * be + al] = ii[p][2 * al + be];
                mom_k[ab + 2 * al + be] = kab[p][2 * al + be];
                if (!self) mom_k[ba + 2 * be + al] = kba[p][2 * be + al];
            }
    }
}

/* Matrix of one (test node i, source node j) pair: 16 entries of the 4N x 4N system.
 * Rows [E_t, E_z, eta0 H_t, eta0 H_z] tested with hats; columns [J~_t, J~_z, M_t, M_z].
 * coef (per medium p, 4 values): 1/k_p^2, k_rho,p^2/k_p^2, mu_r,p, eps_r,p. */
__kernel void fiber_assemble(__global const real2_t *nodes, __global const cplx_t *mom_i,
                             __global const cplx_t *mom_k, __constant cplx_t *coef,
                             const real_t k0, const real_t kz, const int n, __global cplx_t *zmat)
{
    const int i = get_global_id(0), j = get_global_id(1);
    if (i >= n || j >= n) return;
    cplx_t ltt_e = c_new(R(0.0), R(0.0)), ltz_e = ltt_e, lzt_e = ltt_e, lzz_e = ltt_e;
    cplx_t ltt_h = ltt_e, ltz_h = ltt_e, lzt_h = ltt_e, lzz_h = ltt_e;
    cplx_t ktt = ltt_e, ktz = ltt_e, kzt = ltt_e;
    for (int al = 0; al < 2; ++al) {
        const int a = al == 0 ? i : (i + n - 1) % n;
        const real_t sa = al == 0 ? R(-1.0) : R(1.0);
        const element_t ea = fiber_element(nodes, a, n);
        for (int be = 0; be < 2; ++be) {
            const int b = be == 0 ? j : (j + n - 1) % n;
            const real_t sb = be == 0 ? R(-1.0) : R(1.0);
            const element_t eb = fiber_element(nodes, b, n);
            const real_t tt = dot(ea.t, eb.t);
            const real_t tzt = -cross_z(ea.t, eb.t);   /* t_a . (z x t_b) */
            for (int p = 0; p < 2; ++p) {
                const int ab = MOM_INDEX(p, a, b, n);
                const cplx_t iab = mom_i[ab + 2 * al + be];
                const cplx_t irow = c_add(mom_i[ab + 2 * al], mom_i[ab + 2 * al + 1]);
                const cplx_t icol = c_add(mom_i[ab + be], mom_i[ab + 2 + be]);
                const cplx_t itot = c_add(c_add(mom_i[ab], mom_i[ab + 1]), c_add(mom_i[ab + 2], mom_i[ab + 3]));
                const cplx_t inv_k2 = coef[4 * p], kr2_k2 = coef[4 * p + 1];
                const cplx_t mu = coef[4 * p + 2], eps = coef[4 * p + 3];
                /* L operator, integrated by parts (fiber.md §3 table) */
                const cplx_t ltt = c_sub(c_scale(iab, tt), c_mul(inv_k2, c_scale(itot, sa * sb / (ea.len * eb.len))));
                const cplx_t jkz_k2 = c_mul(c_new(R(0.0), kz), inv_k2);
                const cplx_t ltz = c_mul(jkz_k2, c_scale(icol, -sa / ea.len));
                const cplx_t lzt = c_mul(jkz_k2, c_scale(irow, sb / eb.len));
                const cplx_t lzz = c_mul(kr2_k2, iab);
                ltt_e = c_fma(mu, ltt, ltt_e);  ltt_h = c_fma(eps, ltt, ltt_h);
                ltz_e = c_fma(mu, ltz, ltz_e);  ltz_h = c_fma(eps, ltz, ltz_h);
                lzt_e = c_fma(mu, lzt, lzt_e);  lzt_h = c_fma(eps, lzt, lzt_h);
                lzz_e = c_fma(mu, lzz, lzz_e);  lzz_h = c_fma(eps, lzz, lzz_h);
                /* K operator: K^tt = j kz [t_a.(z x t_b)] I, K^tz = Kz(b,a)^T, K^zt = Kz(a,b) */
                ktt = c_add(ktt, c_mul(c_new(R(0.0), kz * tzt), iab));
                ktz = c_add(ktz, mom_k[MOM_INDEX(p, b, a, n) + 2 * be + al]);
                kzt = c_add(kzt, mom_k[ab + 2 * al + be]);
            }
        }
    }
    const cplx_t jk0 = c_new(R(0.0), k0);
    const cplx_t zero = c_new(R(0.0), R(0.0));
    const size_t nn = 4 * (size_t)n;
    const size_t r0 = (size_t)i, c0 = (size_t)j;
    /* E_t row */
    zmat[(r0) * nn + c0] = c_mul(jk0, ltt_e);
    zmat[(r0) * nn + c0 + n] = c_mul(jk0, ltz_e);
    zmat[(r0) * nn + c0 + 2 * n] = ktt;
    zmat[(r0) * nn + c0 + 3 * n] = ktz;
    /* E_z row */
    zmat[(r0 + n) * nn + c0] = c_mul(jk0, lzt_e);
    zmat[(r0 + n) * nn + c0 + n] = c_mul(jk0, lzz_e);
    zmat[(r0 + n) * nn + c0 + 2 * n] = kzt;
    zmat[(r0 + n) * nn + c0 + 3 * n] = zero;
    /* eta0 H_t row */
    zmat[(r0 + 2 * n) * nn + c0] = c_scale(ktt, R(-1.0));
    zmat[(r0 + 2 * n) * nn + c0 + n] = c_scale(ktz, R(-1.0));
    zmat[(r0 + 2 * n) * nn + c0 + 2 * n] = c_mul(jk0, ltt_h);
    zmat[(r0 + 2 * n) * nn + c0 + 3 * n] = c_mul(jk0, ltz_h);
    /* eta0 H_z row */
    zmat[(r0 + 3 * n) * nn + c0] = c_scale(kzt, R(-1.0));
    zmat[(r0 + 3 * n) * nn + c0 + n] = zero;
    zmat[(r0 + 3 * n) * nn + c0 + 2 * n] = c_mul(jk0, lzt_h);
    zmat[(r0 + 3 * n) * nn + c0 + 3 * n] = c_mul(jk0, lzz_h);
}
