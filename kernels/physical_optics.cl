/* Vector physical optics, first order (approx.md §3.6), e^{+jωt}, index n − jκ.
 *
 * po_currents (one work-item per node): the tangent-plane currents of the footprint plane wave
 * E_i = W e^{+jk ω_i·r} ê (k̂ = −ω_i; the phase e^{+jk ω_i·r} is left to the transform):
 *   local frame (approx.md §1): ŝ = k̂×m/|k̂×m| (any unit vector ⟂ m at normal local incidence),
 *   p̂_i = ŝ×k̂, k̂_r = k̂ − 2(k̂·m)m, p̂_r = ŝ×k̂_r; Fresnel r_s, r_p at c = ω_i·m (wb_fresnel.h);
 *   E_r = r_s (ê·ŝ) ŝ + r_p (ê·p̂_i) p̂_r,   η₁H = k̂×ê + k̂_r×E_r  (η₁ = η₀/n₁),
 *   J' dS = η₁ J dS = m̃ × η₁(H_i + H_r) dx dy,   M dS = −m̃ × (E_i + E_r) dx dy,
 * with m̃ = (−h_x, −h_y, 1) and the aperture Δ² W; unlit nodes (lit = 0, or c ≤ 0) carry none.
 * The incident field's currents on every node are subtracted (they radiate nothing upward for a
 * Maxwell field; the footprint's radiate only its ∇W leak): lit nodes keep the reflected part
 * m̃ × η₁H_r, −m̃ × E_r, unlit ones carry −m̃ × η₁H_i, m̃ × E_i.
 * Output: 12 apertures (pol s|p) × (J'_x, J'_y, J'_z, M_x, M_y, M_z), transformed by the Chebyshev /
 * chirp-z machinery of kernels/kirchhoff.cl into N' = Σ J' e^{+jk(ω_i+ω_o)·r}, L likewise.
 *
 * po_farfield (one work-item per pixel): E_far = (jk/4π) ω_o × (ω_o × N' + L)
 *   = (jk/4π) [ω_o (ω_o·N') − N' + ω_o × L]   (far field E e^{−jkr}/r, Balanis' e^{+jωt} form).
 */
#include "kirchhoff.cl"

/* a × b for real a and complex b */
inline void cross_rc(const real_t *a, const cplx_t *b, cplx_t *out)
{
    out[0] = c_sub(c_scale(b[2], a[1]), c_scale(b[1], a[2]));
    out[1] = c_sub(c_scale(b[0], a[2]), c_scale(b[2], a[0]));
    out[2] = c_sub(c_scale(b[1], a[0]), c_scale(b[0], a[1]));
}

inline void cross_rr(const real_t *a, const real_t *b, real_t *out)
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

inline real_t dot_rr(const real_t *a, const real_t *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }


__kernel void po_currents(
    __global const real_t *slopes,    /* (2, na·nb) h_x, h_y at the nodes */
    __global const cplx_t *window,    /* (na·nb) Δ² W */
    __global const uchar *lit,        /* (na·nb) V_i (ray-traced or 1) */
    const int nodes,
    const real_t wx, const real_t wy, const real_t wz,   /* ω_i */
    __global const real_t *polarizations,                /* (2, 3) ê_s, ê_p */
    const cplx_t eta,                                    /* n₂/n₁ */
    __global cplx_t *out)             /* (12, na·nb) */
{
    const int gid = get_global_id(0);
    if (gid >= nodes) return;
    const size_t plane = (size_t)nodes;
    const real_t mt[3] = {-slopes[gid], -slopes[plane + gid], R(1.0)}; /* m̃ */
    const real_t inv = R(1.0) / sqrt(dot_rr(mt, mt));
    const real_t m[3] = {mt[0] * inv, mt[1] * inv, mt[2] * inv};
    const real_t kh[3] = {-wx, -wy, -wz};                                /* k̂ */
    const real_t c = -dot_rr(kh, m);                                   /* ω_i·m */
    const cplx_t w = window[gid];
    if (!lit[gid] || c <= R(0.0)) { /* minus the incident field's own currents */
        for (int p = 0; p < 2; ++p) {
            const real_t e[3] = {polarizations[3 * p], polarizations[3 * p + 1], polarizations[3 * p + 2]};
            real_t ke[3], J[3], M[3];
            cross_rr(kh, e, ke);
            cross_rr(mt, ke, J);
            cross_rr(mt, e, M);
            for (int q = 0; q < 3; ++q) {
                out[(p * 6 + q) * plane + gid] = c_scale(w, -J[q]);
                out[(p * 6 + 3 + q) * plane + gid] = c_scale(w, M[q]);
            }
        }
        return;
    }
    real_t s[3];
    cross_rr(kh, m, s);
    real_t s2 = dot_rr(s, s);
    if (s2 < R(1e-24)) { /* normal local incidence: any unit vector ⟂ m (r_s = −r_p there) */
        const real_t a[3] = {fabs(m[0]) < R(0.9) ? R(1.0) : R(0.0), fabs(m[0]) < R(0.9) ? R(0.0) : R(1.0), R(0.0)};
        cross_rr(m, a, s);
        s2 = dot_rr(s, s);
    }
    const real_t sn = R(1.0) / sqrt(s2);
    s[0] *= sn; s[1] *= sn; s[2] *= sn;
    real_t pi[3], kr[3], pr[3];
    cross_rr(s, kh, pi);
    for (int q = 0; q < 3; ++q) kr[q] = kh[q] + R(2.0) * c * m[q];
    cross_rr(s, kr, pr);
    cplx_t rs, rp;
    fresnel_rs_rp(eta, c, &rs, &rp);
    for (int p = 0; p < 2; ++p) {
        const real_t e[3] = {polarizations[3 * p], polarizations[3 * p + 1], polarizations[3 * p + 2]};
        const real_t es = dot_rr(e, s), ep = dot_rr(e, pi);
        cplx_t Er[3], Hr[3];
        for (int q = 0; q < 3; ++q) Er[q] = c_add(c_scale(rs, es * s[q]), c_scale(rp, ep * pr[q]));
        cross_rc(kr, Er, Hr);
        cplx_t J[3], M[3];
        cross_rc(mt, Hr, J);
        cross_rc(mt, Er, M);
        for (int q = 0; q < 3; ++q) {
            out[(p * 6 + q) * plane + gid] = c_mul(w, J[q]);
            out[(p * 6 + 3 + q) * plane + gid] = c_mul(w, c_scale(M[q], R(-1.0)));
        }
    }
}


__kernel void po_farfield(
    __global const cplx_t *acc,       /* (12, res, res) Σ_n T_n A_n per aperture (post factors not applied) */
    __global const cplx_t *post_x,    /* (res) */
    __global const cplx_t *post_y,    /* (res) */
    const int res,
    const real_t k, const real_t mu_i,
    const real_t dz_ref,              /* mid-height − reference height, µm */
    __global cplx_t *E)               /* (2 pol, 3, res, res) */
{
    const int gid = get_global_id(0);
    int i, j;
    real_t u, v, rho2, mu_o;
    if (gid >= res * res || !disk_pixel(E, gid, res, &i, &j, &u, &v, &rho2, &mu_o)) return;
    const size_t plane = (size_t)res * res;
    const real_t o[3] = {u, v, mu_o};
    /* common factor (jk/4π) · post · e^{jk(μ_i+μ_o) dz_ref} */
    cplx_t f = c_mul(c_mul(post_x[i], post_y[j]), c_expj(k * (mu_i + mu_o) * dz_ref));
    f = c_mul(f, c_new(R(0.0), k * WB_INV_4PI));
    for (int p = 0; p < 2; ++p) {
        cplx_t N[3], L[3], oxL[3];
        for (int q = 0; q < 3; ++q) {
            N[q] = acc[(p * 6 + q) * plane + gid];
            L[q] = acc[(p * 6 + 3 + q) * plane + gid];
        }
        const cplx_t on = c_add(c_add(c_scale(N[0], o[0]), c_scale(N[1], o[1])), c_scale(N[2], o[2]));
        cross_rc(o, L, oxL);
        for (int q = 0; q < 3; ++q)
            E[(p * 3 + q) * plane + gid] = c_mul(f, c_add(c_sub(c_scale(on, o[q]), N[q]), oxL[q]));
    }
}
