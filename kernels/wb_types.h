/* Precision and constants shared by every wavebrdf kernel.
 *
 * Build option -D WB_FP64=1 (double, the default) or -D WB_FP64=0 (single, a measured user
 * choice). Kernel bodies use real_t / cplx_t only, never float or double directly.
 */
#ifndef WB_TYPES_H
#define WB_TYPES_H

#ifndef WB_FP64
#define WB_FP64 1
#endif

#if WB_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real_t;
typedef double2 real2_t;
#define R(x) (x)
#else
typedef float real_t;
typedef float2 real2_t;
#define R(x) (x##f)
#endif

#define WB_PI    R(3.14159265358979323846)
#define WB_2PI   R(6.28318530717958647692)
#define WB_INV_4PI R(0.07957747154594766788)
#define WB_ETA0  R(376.730313412)   /* free-space impedance, ohm */

#endif
