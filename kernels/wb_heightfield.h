/* Exact ray traversal of the bilinear height field (approx.md §3.1); solver/approx/raytrace.py
 * (_trace_numpy) is the host twin, with the same arithmetic.
 *
 * Grid units: lengths divided by the node spacing d, x and y measured from the patch corner (node
 * i at X = i), heights z/d; z[i * (n + 1) + j] with row i <-> x. Between nodes the surface is the
 * bilinear interpolant of the four corner heights of each cell. Border (cells outside [0, n)^2):
 *   periodic  the period-n continuation of nodes 0..n-1 (node n is taken as node 0; equal for
 *             generated periodic surfaces); cell indices are kept in [0, n);
 *   clamp     node indices clamped to [0, n]: the edge heights extended outward (beyond an edge the
 *             surface is constant along the outward normal, beyond a corner it is the corner height);
 *             a ray beyond an edge moving away from the patch crosses no cell boundary along that axis.
 *
 * A ray is followed cell by cell (2-D DDA of its xy projection) in cell-local coordinates
 * (s, t) in [0, 1]^2, with its height Z and the gap g = Z - h. Within a cell g is a quadratic in
 * the ray parameter tau (exact for the bilinear patch), and the gap at the exit of one cell is
 * carried as the gap at the entry of the next, so a crossing between cells is never lost to
 * rounding. A ray that starts on the surface (a reflected or a visibility ray) starts with g = 0
 * exactly: the root at tau = 0 is excluded by construction, not by an epsilon; a reflected ray
 * leaves its facet (dg/dtau >= 0 in its start cell). An upgoing ray above the highest node escapes.
 * Blocks of kb x kb cells inside the patch carry their highest node (zb): a ray that stays above
 * it across the block skips the block's cells (its gap is then recomputed at the next cell, where
 * it is positive).
 */
#ifndef WB_HEIGHTFIELD_H
#define WB_HEIGHTFIELD_H
#include "wb_types.h"

#define HF_HIT 0
#define HF_ESCAPE 1
#define HF_LOST 2      /* step cap reached (reported, never hidden) */
#define HF_BIG R(1e30) /* "no boundary" distance along an axis the ray does not move on */

/* the traced surface (host: solver/approx/raytrace.py GridSurface) */
typedef struct {
    __global const real_t *z;  /* (n+1)^2 node heights, grid units */
    __global const real_t *zb; /* nb^2 block maxima (nb = ceil(n / kb)) */
    int n, periodic, kb, nb, max_steps;
    real_t zmax;
} hf_surface;

/* a point of a ray: cell (a, b), position (s, t) in it, height zr */
typedef struct {
    int a, b;
    real_t s, t, zr;
} hf_point;

/* bilinear coefficients of cell (a, b): h(s, t) = A + B s + C t + D s t */
inline void hf_cell(const hf_surface *hf, int a, int b, real_t *A, real_t *B, real_t *C, real_t *D)
{
    const int n = hf->n;
    int i0, i1, j0, j1;
    if (hf->periodic) {
        i0 = a;
        j0 = b;
        i1 = a + 1 == n ? 0 : a + 1;
        j1 = b + 1 == n ? 0 : b + 1;
    } else {
        i0 = clamp(a, 0, n);
        j0 = clamp(b, 0, n);
        i1 = clamp(a + 1, 0, n);
        j1 = clamp(b + 1, 0, n);
    }
    __global const real_t *z = hf->z;
    real_t c00 = z[i0 * (n + 1) + j0], c10 = z[i1 * (n + 1) + j0];
    real_t c01 = z[i0 * (n + 1) + j1], c11 = z[i1 * (n + 1) + j1];
    *A = c00;
    *B = c10 - c00;
    *C = c01 - c00;
    *D = (c11 - c10) - (c01 - c00);
}

/* periodic: cell indices back into [0, n) after a step */
inline int hf_wrap(int a, int n, int periodic)
{
    if (!periodic) return a;
    return a >= n ? a - n : (a < 0 ? a + n : a);
}

/* the cell of grid coordinate x (periodic: wrapped into [0, n)) and the position in it */
inline int hf_locate(real_t x, int n, int periodic, real_t *s)
{
    if (periodic) x -= (real_t)n * floor(x / (real_t)n);
    real_t f = floor(x);
    *s = clamp(x - f, R(0.0), R(1.0));
    return hf_wrap((int)f, n, periodic);
}

/* the point of the surface above grid position (x, y) */
inline hf_point hf_surface_point(const hf_surface *hf, real_t x, real_t y)
{
    hf_point p;
    p.a = hf_locate(x, hf->n, hf->periodic, &p.s);
    p.b = hf_locate(y, hf->n, hf->periodic, &p.t);
    real_t A, B, C, D;
    hf_cell(hf, p.a, p.b, &A, &B, &C, &D);
    p.zr = A + B * p.s + C * p.t + D * p.s * p.t;
    return p;
}

/* first root in [0, L] of gamma + beta tau + alpha tau^2 once a crossing is known to lie there */
inline real_t hf_root(real_t alpha, real_t beta, real_t gamma, real_t L)
{
    real_t tau;
    if (alpha == R(0.0)) {
        tau = -gamma / beta;
    } else {
        real_t disc = fmax(beta * beta - R(4.0) * alpha * gamma, R(0.0));
        real_t q = R(-0.5) * (beta + copysign(sqrt(disc), beta));
        real_t r1 = q / alpha;
        real_t r2 = (q != R(0.0)) ? gamma / q : r1;
        real_t lo = fmin(r1, r2), hi = fmax(r1, r2);
        tau = (lo > R(0.0)) ? lo : hi;
    }
    return clamp(tau, R(0.0), L);
}

/* distance to the exit of an interval [0, size] from x along direction w (inverse iw) */
inline real_t hf_exit(real_t x, real_t size, real_t w, real_t iw)
{
    return w > R(0.0) ? (size - x) * iw : (w < R(0.0) ? -x * iw : HF_BIG);
}

/* after moving L along w from x in [0, size] (cell offset c0 of the interval): the new cell and
 * position; crossing: the exit is through this axis (onto the next interval) */
inline int hf_advance(real_t x, real_t size, int c0, real_t w, real_t L, int crossing, real_t *s)
{
    if (crossing) {
        *s = w > R(0.0) ? R(0.0) : R(1.0);
        return w > R(0.0) ? c0 + (int)size : c0 - 1;
    }
    real_t y = x + w * L;
    real_t c = clamp(floor(y), R(0.0), size - R(1.0));
    *s = clamp(y - c, R(0.0), R(1.0));
    return c0 + (int)c;
}

/* Trace from *p along the unit direction (wx, wy, wz). on_surface: *p lies on the surface (gap 0);
 * leaving: the ray leaves the facet at *p (a reflected ray). Returns HF_HIT (*p = the hit point on
 * the surface, (*hx, *hy) = the surface gradient there), HF_ESCAPE or HF_LOST. */
inline int hf_trace(const hf_surface *hf, real_t wx, real_t wy, real_t wz, int on_surface, int leaving, hf_point *p,
                    real_t *hx, real_t *hy)
{
    const int n = hf->n, periodic = hf->periodic, kb = hf->kb;
    const real_t zmax = hf->zmax;
    const real_t ix = wx != R(0.0) ? R(1.0) / wx : R(0.0), iy = wy != R(0.0) ? R(1.0) / wy : R(0.0);
    int a = p->a, b = p->b;
    real_t s = p->s, t = p->t, zr = p->zr;
    real_t gamma = R(0.0);
    int have_gamma = on_surface;
    int first = 1;
    for (int step = 0; step < hf->max_steps; ++step) {
        if (wz >= R(0.0) && zr >= zmax) return HF_ESCAPE;
        if (kb > 1 && a >= 0 && a < n && b >= 0 && b < n) {
            /* block skip: the ray stays above the block's highest node until it leaves the block */
            int ja = a / kb, jb = b / kb;
            real_t top = hf->zb[ja * hf->nb + jb];
            if (zr > top) {
                real_t xa = (real_t)(a - ja * kb) + s, yb = (real_t)(b - jb * kb) + t;
                real_t sa = (real_t)min(kb, n - ja * kb), sb = (real_t)min(kb, n - jb * kb);
                real_t bx = hf_exit(xa, sa, wx, ix), by = hf_exit(yb, sb, wy, iy);
                real_t LB = fmin(bx, by);
                if (zr + wz * LB > top) {
                    a = hf_wrap(hf_advance(xa, sa, ja * kb, wx, LB, bx <= by, &s), n, periodic);
                    b = hf_wrap(hf_advance(yb, sb, jb * kb, wy, LB, by <= bx, &t), n, periodic);
                    zr += wz * LB;
                    have_gamma = 0;
                    first = 0;
                    continue;
                }
            }
        }
        real_t A, B, C, D;
        hf_cell(hf, a, b, &A, &B, &C, &D);
        if (!have_gamma) {
            gamma = zr - (A + B * s + C * t + D * s * t);
            have_gamma = 1;
        }
        real_t lx = hf_exit(s, R(1.0), wx, ix), ly = hf_exit(t, R(1.0), wy, iy);
        if (!periodic) { /* beyond an edge, moving away: the extended surface is the same in every cell */
            if ((a >= n && wx >= R(0.0)) || (a < 0 && wx <= R(0.0))) lx = HF_BIG;
            if ((b >= n && wy >= R(0.0)) || (b < 0 && wy <= R(0.0))) ly = HF_BIG;
        }
        real_t L = fmin(lx, ly);
        real_t beta = wz - (B + D * t) * wx - (C + D * s) * wy;
        real_t alpha = -D * wx * wy;
        if (first && leaving) beta = fmax(beta, R(0.0));
        real_t gexit = gamma + L * (beta + L * alpha);
        if (L > R(0.0)) { /* a cell the ray only touches at its boundary is not traversed */
            int hit = 0;
            real_t tau = R(0.0);
            if (gamma < R(0.0) || (gamma == R(0.0) && (beta < R(0.0) || (beta == R(0.0) && alpha < R(0.0))))) {
                hit = 1;
            } else if (gexit < R(0.0)) {
                hit = 1;
                tau = hf_root(alpha, beta, gamma, L);
            } else if (alpha > R(0.0)) {
                real_t tv = -beta / (R(2.0) * alpha);
                if (tv > R(0.0) && tv < L && gamma + tv * (beta + tv * alpha) < R(0.0)) {
                    hit = 1;
                    tau = hf_root(alpha, beta, gamma, L);
                }
            }
            if (hit) {
                real_t sh = clamp(s + wx * tau, R(0.0), R(1.0));
                real_t th = clamp(t + wy * tau, R(0.0), R(1.0));
                p->a = a;
                p->b = b;
                p->s = sh;
                p->t = th;
                p->zr = A + B * sh + C * th + D * sh * th;
                *hx = B + D * th;
                *hy = C + D * sh;
                return HF_HIT;
            }
        }
        first = 0;
        zr += wz * L;
        if (wz >= R(0.0) && zr >= zmax) return HF_ESCAPE;
        gamma = gexit;
        a = hf_wrap(hf_advance(s, R(1.0), a, wx, L, lx <= ly, &s), n, periodic);
        b = hf_wrap(hf_advance(t, R(1.0), b, wy, L, ly <= lx, &t), n, periodic);
    }
    return HF_LOST;
}

#endif
