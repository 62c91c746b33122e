/* Geometric-optics path tracing of the bilinear height field (approx.md §3.1 GS, §3.2 GM);
 * solver/approx/raytrace.py is the driver and holds the NumPy twin of every kernel.
 *
 * Equal-power rays: ray k crosses the reference plane z = zref at a point drawn with density
 * |W|^2 = exp(-2 r^2 / w^2) (a rank-1 lattice (R2) sequence, Cranley-Patterson shifted by the seed,
 * mapped by Box-Muller), travelling along -omega_i. Lengths in grid units (wb_heightfield.h).
 *
 * trace_paths   geometry only: for every bounce the local cosine c = omega_in . m and the rotation
 *               (cos 2psi, sin 2psi) from the ray's polarization frame into the facet's s/p frame,
 *               stored as a linked list per ray (the first record of ray k in slot k, deeper ones
 *               allocated with atomic_inc on a counter starting at the ray count: their order in
 *               memory varies, each ray's chain does not); the exit pixel and depth.
 * path_weights  Fresnel (wb_fresnel.h, n - j kappa) and the Mueller matrix along each chain, for
 *               the incident Stokes vectors of s (1, 1, 0, 0) and p (1, -1, 0, 0) polarization: the
 *               final intensity of each. A new index or wavelength only reruns this kernel.
 * visibility    1 where a ray from a surface point toward a direction escapes.
 *
 * Polarization frame: s = normalize(k x m), p = s x k for the propagation direction k (approx.md §1),
 * the incident frame being (e_s, e_s x k) of the IntensityResult convention (e_s perpendicular to
 * the plane of incidence). Stokes (I, Q, U, V) = (|Es|^2 + |Ep|^2, |Es|^2 - |Ep|^2,
 * 2 Re(Es Ep*), 2 Im(Es Ep*)).
 */
#include "wb_types.h"
#include "wb_complex.h"
#include "wb_fresnel.h"
#include "wb_heightfield.h"

#if WB_FP64
#define RT_TINY 1e-12
#else
#define RT_TINY 1e-5f
#endif

#define RT_TRUNCATED (-1) /* the ray still hit the surface after max_depth reflections */
#define RT_LOST (-2)      /* step cap of one segment reached */

/* output pixel of an escaping direction (u = w.x, v = w.y), pixels outside the disk remapped */
inline int rt_pixel(real_t wx, real_t wy, int res, __global const int *remap)
{
    int i = clamp((int)floor((wx + R(1.0)) * R(0.5) * (real_t)res), 0, res - 1);
    int j = clamp((int)floor((wy + R(1.0)) * R(0.5) * (real_t)res), 0, res - 1);
    return remap[i * res + j];
}

/* the hf_surface of the kernel arguments */
#define HF_SURFACE_ARGS                                                                                     \
    __global const real_t *z, __global const real_t *zb, int n, int periodic, int kb, int nb, int max_steps, \
        real_t zmax
#define HF_SURFACE {z, zb, n, periodic, kb, nb, max_steps, zmax}

__kernel void trace_paths(HF_SURFACE_ARGS, real_t cx,
                          real_t cy, real_t sigma, real_t zref, uint shift1, uint shift2, uint step1, uint step2,
                          uint first, real_t wix, real_t wiy, real_t wiz, real_t esx, real_t esy, real_t esz,
                          int max_depth, int res, __global const int *remap, int capacity, __global int *code,
                          __global uchar *depth, __global int *head, __global real_t *rec, __global int *next,
                          volatile __global int *counter)
{
    const int k = get_global_id(0);
    const hf_surface hf = HF_SURFACE;
    const uint index = first + (uint)k;
    /* origin on the reference plane: R2 lattice point -> Gaussian of std sigma per axis, or uniform
     * over the patch (sigma = 0: plane wave) */
    uint q1 = shift1 + index * step1, q2 = shift2 + index * step2;
    real_t u1 = ((real_t)q1 + R(0.5)) * R(2.3283064365386962890625e-10);
    real_t u2 = ((real_t)q2 + R(0.5)) * R(2.3283064365386962890625e-10);
    real_t x0 = u1 * (real_t)n, y0 = u2 * (real_t)n;
    if (sigma > R(0.0)) {
        real_t r = sigma * sqrt(R(-2.0) * log(u1));
        real_t phi = WB_2PI * u2;
        x0 = cx + r * cos(phi);
        y0 = cy + r * sin(phi);
    }
    /* start where the incident ray crosses z = zmax (above every node) */
    real_t lift = (zmax - zref) / wiz;
    hf_point p;
    p.a = hf_locate(x0 + wix * lift, n, periodic, &p.s);
    p.b = hf_locate(y0 + wiy * lift, n, periodic, &p.t);
    p.zr = zmax;
    real_t wx = -wix, wy = -wiy, wz = -wiz;
    real_t sx = esx, sy = esy, sz = esz; /* s vector of the current polarization frame */
    int d = 0, prev = -1, out = RT_LOST;
    head[k] = -1;
    for (;;) {
        real_t hx, hy;
        int status = hf_trace(&hf, wx, wy, wz, d > 0, d > 0, &p, &hx, &hy);
        if (status == HF_ESCAPE) {
            out = rt_pixel(wx, wy, res, remap);
            break;
        }
        if (status == HF_LOST) break;
        if (d == max_depth) {
            out = RT_TRUNCATED;
            break;
        }
        /* reflect at the bilinear normal m = (-hx, -hy, 1)/|.| */
        real_t inv = R(1.0) / sqrt(hx * hx + hy * hy + R(1.0));
        real_t mx = -hx * inv, my = -hy * inv, mz = inv;
        real_t c = clamp(-(wx * mx + wy * my + wz * mz), R(0.0), R(1.0));
        /* facet s vector s_f = k x m (k = w), kept when k is along m */
        real_t fx = wy * mz - wz * my, fy = wz * mx - wx * mz, fz = wx * my - wy * mx;
        real_t fn = sqrt(fx * fx + fy * fy + fz * fz);
        if (fn > RT_TINY) {
            fx /= fn;
            fy /= fn;
            fz /= fn;
        } else {
            fx = sx;
            fy = sy;
            fz = sz;
        }
        /* rotation: cos psi = s.s_f, sin psi = p.s_f with p = s x k */
        real_t px = sy * wz - sz * wy, py = sz * wx - sx * wz, pz = sx * wy - sy * wx;
        real_t cp = sx * fx + sy * fy + sz * fz, sp = px * fx + py * fy + pz * fz;
        real_t nn = cp * cp + sp * sp;
        real_t c2 = (cp * cp - sp * sp) / nn, s2 = R(2.0) * sp * cp / nn;
        /* the first record of ray k is slot k; deeper ones are allocated after the first count slots */
        int slot = d == 0 ? k : atomic_inc(counter);
        if (slot < capacity) {
            rec[3 * slot] = c;
            rec[3 * slot + 1] = c2;
            rec[3 * slot + 2] = s2;
            next[slot] = -1;
            if (prev >= 0)
                next[prev] = slot;
            else
                head[k] = slot;
        }
        prev = slot;
        ++d;
        /* new direction and frame: w + 2c m; s_f made exactly perpendicular to it */
        wx += R(2.0) * c * mx;
        wy += R(2.0) * c * my;
        wz += R(2.0) * c * mz;
        real_t wn = R(1.0) / sqrt(wx * wx + wy * wy + wz * wz);
        wx *= wn;
        wy *= wn;
        wz *= wn;
        real_t fw = fx * wx + fy * wy + fz * wz;
        fx -= fw * wx;
        fy -= fw * wy;
        fz -= fw * wz;
        real_t sn = R(1.0) / sqrt(fx * fx + fy * fy + fz * fz);
        sx = fx * sn;
        sy = fy * sn;
        sz = fz * sn;
    }
    code[k] = out;
    depth[k] = (uchar)d;
}

/* final intensity (s and p incidence) of each ray: Mueller matrices along its chain */
__kernel void path_weights(__global const int *head, __global const real_t *rec, __global const int *next,
                           real_t eta_re, real_t eta_im, __global real_t *weights)
{
    const int k = get_global_id(0);
    cplx_t eta = c_new(eta_re, eta_im);
    /* Stokes of the s and p inputs */
    real_t I0 = R(1.0), Q0 = R(1.0), U0 = R(0.0), V0 = R(0.0);
    real_t I1 = R(1.0), Q1 = R(-1.0), U1 = R(0.0), V1 = R(0.0);
    for (int r = head[k]; r >= 0; r = next[r]) {
        real_t c = rec[3 * r], c2 = rec[3 * r + 1], s2 = rec[3 * r + 2];
        cplx_t rs, rp;
        fresnel_rs_rp(eta, c, &rs, &rp);
        real_t Rs = c_abs2(rs), Rp = c_abs2(rp);
        cplx_t x = c_mul(rs, c_conj(rp));
        real_t sum = R(0.5) * (Rs + Rp), dif = R(0.5) * (Rs - Rp);
        /* rotate into the facet frame, then reflect */
        real_t q = c2 * Q0 + s2 * U0, u = c2 * U0 - s2 * Q0;
        real_t i = sum * I0 + dif * q;
        Q0 = dif * I0 + sum * q;
        I0 = i;
        U0 = x.x * u - x.y * V0;
        V0 = x.y * u + x.x * V0;
        q = c2 * Q1 + s2 * U1;
        u = c2 * U1 - s2 * Q1;
        i = sum * I1 + dif * q;
        Q1 = dif * I1 + sum * q;
        I1 = i;
        U1 = x.x * u - x.y * V1;
        V1 = x.y * u + x.x * V1;
    }
    weights[2 * k] = I0;
    weights[2 * k + 1] = I1;
}

/* out[m * npts + q] = 1 if the ray from the surface point above points[q] (grid units) toward the
 * unit direction dirs[m] (upper hemisphere) escapes, else 0 */
__kernel void visibility(HF_SURFACE_ARGS, __global const real_t *points, int npts, __global const real_t *dirs,
                         __global uchar *out)
{
    const int g = get_global_id(0);
    const hf_surface hf = HF_SURFACE;
    const int m = g / npts, q = g - m * npts;
    hf_point p = hf_surface_point(&hf, points[2 * q], points[2 * q + 1]);
    real_t hx, hy;
    int status = hf_trace(&hf, dirs[3 * m], dirs[3 * m + 1], dirs[3 * m + 2], 1, 0, &p, &hx, &hy);
    out[g] = status == HF_ESCAPE ? 1 : 0;
}
