/* WS-V (Falster's Kirchhoff with ray-traced masking, solver/approx/falster.py): the part of the
 * far-field sums that masking removes, summed directly over the masked nodes of each pixel's
 * masking class (e^{+jωt}):
 *
 *   out_c(pixel) = Σ_{n ∈ masked(class(pixel))} ap_c[n] e^{+jk[s·x_n + (μ_i+μ_o) z_n]},  s = u_i + u_o,
 *
 * for the eight apertures c (2 polarizations × 4). The masked far field is the full transform
 * minus these sums (z: heights about the mid-height, as in the transform).
 */
#include "wb_complex.h"
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
