/* The full-wave solver's exact beam as the approximate wave rungs' incident field
 * (solver/beams.py BeamWaves; kernels po_beam_currents and wsv_beam_sums).
 *
 * geometry (5, nodes): h_x, h_y, x, y, z − z_ref (µm) of every node; table (waves, 7): per plane
 * wave k̂_m, q_m = k k̂_m + k ω_i and φ_m = k k̂_m·f, so that wave m at node r relative to the rungs'
 * transform phase e^{+jk ω_i·r} is e^{j(φ_m − q_m·r)} (e^{+jωt}, µm).
 */
#ifndef WB_BEAM_WAVES_H
#define WB_BEAM_WAVES_H
#include "wb_complex.h"

#define BEAM_TABLE_ROW 7

/* node gid of `nodes`: m̃ = (−h_x, −h_y, 1), its unit vector m and its position r */
inline void beam_node(__global const real_t *geometry, const int gid, const int nodes, real_t *mt, real_t *m, real_t *r)
{
    const size_t plane = (size_t)nodes;
    mt[0] = -geometry[gid];
    mt[1] = -geometry[plane + gid];
    mt[2] = R(1.0);
    const real_t inv = R(1.0) / sqrt(mt[0] * mt[0] + mt[1] * mt[1] + R(1.0));
    for (int q = 0; q < 3; ++q) {
        m[q] = mt[q] * inv;
        r[q] = geometry[(2 + q) * plane + gid];
    }
}

/* wave w of the table: its direction k̂ and Δ² e^{j(φ_w − q_w·r)} */
inline cplx_t beam_wave(__global const real_t *table, const int w, const real_t *r, const real_t area, real_t *k_hat)
{
    __global const real_t *row = table + BEAM_TABLE_ROW * w;
    for (int q = 0; q < 3; ++q) k_hat[q] = row[q];
    return c_scale(c_expj(row[6] - (row[3] * r[0] + row[4] * r[1] + row[5] * r[2])), area);
}

#endif
