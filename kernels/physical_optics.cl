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
 * po_beam_currents (one work-item per node): the same currents summed over the plane waves of the exact
 * Gaussian beam (solver/beams.py), each with its own direction k̂_m and Fresnel coefficients at its own
 * local angle: Δ² Σ_m e^{−j k k̂_m·(r − f)} e^{−jk ω_i·r} currents(k̂_m, E_m), f the focus (the phase
 * e^{+jk ω_i·r} is again left to the transform). On a plane this reflects every plane wave exactly.
 * Output: 12 apertures (pol s|p) × (J'_x, J'_y, J'_z, M_x, M_y, M_z), transformed by the Chebyshev /
 * chirp-z machinery of kernels/kirchhoff.cl into N' = Σ J' e^{+jk(ω_i+ω_o)·r}, L likewise.
 *
 * po_farfield (one work-item per pixel): E_far = (jk/4π) ω_o × (ω_o × N' + L)
 *   = (jk/4π) [ω_o (ω_o·N') − N' + ω_o × L]   (far field E e^{−jkr}/r, Balanis' e^{+jωt} form).
 */
#include "kirchhoff.cl"
#include "wb_beam_waves.h"

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


/* The currents (J' = η₁J, M per unit dx dy; 12: pol s|p × (J'_x, J'_y, J'_z, M_x, M_y, M_z)) at a node
 * of m̃ (m = m̃/|m̃|) from one plane wave of direction k̂ and complex polarization vectors e (2 × 3):
 * the reflected field's where lit and c = −k̂·m > 0, else minus the incident field's. */
inline void po_wave_currents(const real_t *mt, const real_t *m, const real_t *kh, const cplx_t *e, const cplx_t eta,
                             const int lit, cplx_t *cur)
{
    const real_t c = -dot_rr(kh, m);
    if (!lit || c <= R(0.0)) { /* minus the incident field's own currents */
        for (int p = 0; p < 2; ++p) {
            cplx_t ke[3], J[3], M[3];
            cross_rc(kh, e + 3 * p, ke);
            cross_rc(mt, ke, J);
            cross_rc(mt, e + 3 * p, M);
            for (int q = 0; q < 3; ++q) {
                cur[p * 6 + q] = c_scale(J[q], R(-1.0));
                cur[p * 6 + 3 + q] = M[q];
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
        const cplx_t *ep = e + 3 * p;
        const cplx_t es = c_add(c_add(c_scale(ep[0], s[0]), c_scale(ep[1], s[1])), c_scale(ep[2], s[2]));
        const cplx_t epi = c_add(c_add(c_scale(ep[0], pi[0]), c_scale(ep[1], pi[1])), c_scale(ep[2], pi[2]));
        const cplx_t as = c_mul(rs, es), ap = c_mul(rp, epi);
        cplx_t Er[3], Hr[3], J[3], M[3];
        for (int q = 0; q < 3; ++q) Er[q] = c_add(c_scale(as, s[q]), c_scale(ap, pr[q]));
        cross_rc(kr, Er, Hr);
        cross_rc(mt, Hr, J);
        cross_rc(mt, Er, M);
        for (int q = 0; q < 3; ++q) {
            cur[p * 6 + q] = J[q];
            cur[p * 6 + 3 + q] = c_scale(M[q], R(-1.0));
        }
    }
}


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
    cplx_t e[6], cur[12];
    for (int q = 0; q < 6; ++q) e[q] = c_new(polarizations[q], R(0.0));
    po_wave_currents(mt, m, kh, e, eta, lit[gid], cur);
    const cplx_t w = window[gid];
    for (int q = 0; q < 12; ++q) out[q * plane + gid] = c_mul(w, cur[q]);
}


__kernel void po_beam_currents(
    __global const real_t *geometry,   /* (5, nodes) h_x, h_y, x, y, z − z_ref (wb_beam_waves.h) */
    __global const uchar *lit,         /* (nodes) V_i along the beam axis */
    const int nodes,
    const int waves,
    __global const real_t *table,      /* (waves, 7) k̂_m, q_m, φ_m (wb_beam_waves.h) */
    __global const cplx_t *fields,     /* (waves, 2, 3) E_m per beam polarization */
    const cplx_t eta,                  /* n₂/n₁ */
    const real_t area,                 /* Δ² (µm²) */
    __global cplx_t *out)              /* (12, nodes) */
{
    const int gid = get_global_id(0);
    if (gid >= nodes) return;
    real_t mt[3], m[3], r[3], kh[3];
    beam_node(geometry, gid, nodes, mt, m, r);
    const int on = lit[gid];
    cplx_t acc[12], cur[12], e[6];
    for (int q = 0; q < 12; ++q) acc[q] = c_new(R(0.0), R(0.0));
    for (int w = 0; w < waves; ++w) {
        const cplx_t phase = beam_wave(table, w, r, area, kh);
        for (int q = 0; q < 6; ++q) e[q] = fields[6 * w + q];
        po_wave_currents(mt, m, kh, e, eta, on, cur);
        for (int q = 0; q < 12; ++q) acc[q] = c_fma(phase, cur[q], acc[q]);
    }
    for (int q = 0; q < 12; ++q) out[(size_t)q * nodes + gid] = acc[q];
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
