/* Projection weights of the AIM stencils (solver/bem3d/aim/projection.py): real for moment matching,
 * complex for far-field matching (build define AIM_COMPLEX_W = 0 | 1).
 * weight_t is the stored type; aim_wmul(w, z) = w z for a complex z.
 */
#ifndef AIM_WEIGHTS_H
#define AIM_WEIGHTS_H
#include "wb_complex.h"

#ifndef AIM_COMPLEX_W
#define AIM_COMPLEX_W 0
#endif

#if AIM_COMPLEX_W
typedef cplx_t weight_t;
inline cplx_t aim_wmul(weight_t w, cplx_t z) { return c_mul(w, z); }
#else
typedef real_t weight_t;
inline cplx_t aim_wmul(weight_t w, cplx_t z) { return c_scale(z, w); }
#endif

#endif
