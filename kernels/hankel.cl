/* Evaluate H0^(2), H1^(2) at an array of complex arguments (one work-item per argument).
 * Host wrapper and NumPy reference: wavebrdf.solver.fiber.hankel (hankel2_01_cl, hankel2_01). */
#include "hankel.h"

__kernel void hankel2_eval(__global const cplx_t *z, __global cplx_t *h0, __global cplx_t *h1,
                           const int n)
{
    const int gid = get_global_id(0);
    if (gid >= n) return;
    cplx_t a, b;
    hankel2_01(z[gid], &a, &b);
    h0[gid] = a;
    h1[gid] = b;
}
