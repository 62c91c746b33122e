/* WS-V (Falster's Kirchhoff with ray-traced masking, solver/approx/falster.py): the part of the
 * far-field sums that masking removes, summed directly over the masked nodes of each pixel's
 * masking class (e^{+jωt}):
 *
 *   out_c(pixel) = Σ_{n ∈ masked(class(pixel))} ap_c[n] e^{+jk[s·x_n + (μ_i+μ_o) z_n]},  s = u_i + u_o,
 *
 * for the eight apertures c (2 polarizations × 4). The masked far field is the full transform
 * minus these sums (z: heights about the mid-height, as in the transform).
 *
 * wsv_beam_sums (one work-item per node): the sums over the plane waves m of the exact beam that
 * the apertures lit by it are made of (falster.py _beam_apertures, its NumPy twin), per beam
 * polarization p: with w = A_m Δ² e^{j(φ_m − q_m·r)}, c_m = m̃·ω_m and ρ the wave's local
 * reflection (modulus √(w_s|r_s|² + (1 − w_s)|r_p|²), w_s = |E_m·ŝ|²/(|ŝ|²|E_m|²), ŝ = k̂_m × m,
 * ½ at normal local incidence; the phase of r_s for p = 0, of r_p for p = 1; r at cos θ = c_m/|m̃|):
 *   lit0 = Σ_lit c_m w (ρ − 1),  lit1 = Σ_lit w (ρ + 1),  free0 = Σ c_m w,  free1 = Σ w,
 * a wave lighting the node where lit (V_i of the beam axis) and c_m > 0.
 */
#include "wb_complex.h"
#include "wb_beam_waves.h"
#include "wb_fresnel.h"
#include "wb_hemisphere.h"

#define APERTURES 8

__kernel void wsv_masked_sum(
    __global const int *pixel_class,   /* (res*res) masking class of each pixel, -1 outside the disk */
    __global const int *class_start,   /* (classes + 1) offsets into class_nodes */
    __global const int *class_nodes,   /* masked node indices of every class, concatenated */
    __global const real_t *x,          /* (nodes) node x, µm */
    __global const real_t *y,          /* (nodes) node y, µm */
    __global const real_t *z,          /* (nodes) height − mid-height, µm */
    __global const cplx_t *ap,         /* (APERTURES, nodes) apertures, Δ² W included */
    const int res, const int nodes,
    const real_t k, const real_t ux_i, const real_t uy_i, const real_t mu_i,
    __global cplx_t *out)              /* (APERTURES, res*res) */
{
    const int gid = get_global_id(0);
    if (gid >= res * res) return;
    const size_t plane = (size_t)res * res;
    cplx_t acc[APERTURES];
    for (int c = 0; c < APERTURES; ++c) acc[c] = c_new(R(0.0), R(0.0));
    const int cls = pixel_class[gid];
    if (cls >= 0) {
        const real_t u = pixel_coordinate(gid / res, res), v = pixel_coordinate(gid % res, res);
        const real_t mu_o = sqrt(fmax(R(1.0) - u * u - v * v, R(0.0)));
        const real_t sx = k * (ux_i + u), sy = k * (uy_i + v), sz = k * (mu_i + mu_o);
        for (int m = class_start[cls]; m < class_start[cls + 1]; ++m) {
            const int n = class_nodes[m];
            const cplx_t e = c_expj(sx * x[n] + sy * y[n] + sz * z[n]);
            for (int c = 0; c < APERTURES; ++c) acc[c] = c_fma(ap[(size_t)c * nodes + n], e, acc[c]);
        }
    }
    for (int c = 0; c < APERTURES; ++c) out[c * plane + gid] = acc[c];
}


__kernel void wsv_beam_sums(
    __global const real_t *geometry,    /* (5, nodes) h_x, h_y, x, y, z − z_ref (wb_beam_waves.h) */
    __global const uchar *lit,          /* (nodes) V_i of the beam axis */
    const int nodes,
    const int waves,
    __global const real_t *table,       /* (waves, 7) k̂_m, q_m, φ_m (wb_beam_waves.h) */
    __global const cplx_t *fields,      /* (waves, 2, 3) E_m per beam polarization */
    __global const cplx_t *scalars,     /* (waves, 2) scalar amplitudes A_m */
    __global const real_t *power,       /* (waves, 2) |E_m|² */
    const cplx_t eta,                   /* n₂/n₁ */
    const real_t area,                  /* Δ² (µm²) */
    __global cplx_t *out)               /* (8, nodes): per pol p the rows 4p..4p+3 = lit0, lit1, free0, free1 */
{
    const int gid = get_global_id(0);
    if (gid >= nodes) return;
    real_t mt[3], m[3], r[3], kh[3];
    beam_node(geometry, gid, nodes, mt, m, r);
    const real_t norm = sqrt(mt[0] * mt[0] + mt[1] * mt[1] + R(1.0));
    const int on_axis = lit[gid];
    cplx_t acc[8];
    for (int c = 0; c < 8; ++c) acc[c] = c_new(R(0.0), R(0.0));
    for (int w = 0; w < waves; ++w) {
        const cplx_t phase = beam_wave(table, w, r, area, kh);
        const real_t c_m = -(mt[0] * kh[0] + mt[1] * kh[1] + mt[2] * kh[2]);  /* m̃·ω_m, ω_m = −k̂_m */
        const int on = on_axis && c_m > R(0.0);
        cplx_t rs = c_new(R(0.0), R(0.0)), rp = c_new(R(0.0), R(0.0));
        real_t s[3] = {R(0.0), R(0.0), R(0.0)}, s2 = R(0.0);
        if (on) {
            fresnel_rs_rp(eta, fmin(fmax(c_m / norm, R(0.0)), R(1.0)), &rs, &rp);
            s[0] = kh[1] * m[2] - kh[2] * m[1];
            s[1] = kh[2] * m[0] - kh[0] * m[2];
            s[2] = kh[0] * m[1] - kh[1] * m[0];
            s2 = s[0] * s[0] + s[1] * s[1] + s[2] * s[2];
        }
        for (int p = 0; p < 2; ++p) {
            const cplx_t weight = c_mul(phase, scalars[2 * w + p]);
            acc[4 * p + 2] = c_fma(weight, c_new(c_m, R(0.0)), acc[4 * p + 2]);
            acc[4 * p + 3] = c_add(acc[4 * p + 3], weight);
            if (!on) continue;
            __global const cplx_t *E = fields + 6 * w + 3 * p;
            const cplx_t along = c_add(c_add(c_scale(E[0], s[0]), c_scale(E[1], s[1])), c_scale(E[2], s[2]));
            const real_t scale = s2 * power[2 * w + p];
            const real_t share = s2 > R(1e-24) && scale > R(0.0) ? c_abs2(along) / scale : R(0.5);
            const real_t size = sqrt(share * c_abs2(rs) + (R(1.0) - share) * c_abs2(rp));
            const cplx_t pass = p == 0 ? rs : rp;
            const real_t pass_size = c_abs(pass);
            const cplx_t rho = pass_size > R(0.0) ? c_scale(pass, size / pass_size) : c_new(size, R(0.0));
            acc[4 * p] = c_fma(c_scale(weight, c_m), c_sub(rho, c_new(R(1.0), R(0.0))), acc[4 * p]);
            acc[4 * p + 1] = c_fma(weight, c_add(rho, c_new(R(1.0), R(0.0))), acc[4 * p + 1]);
        }
    }
    for (int c = 0; c < 8; ++c) out[(size_t)c * nodes + gid] = acc[c];
}
