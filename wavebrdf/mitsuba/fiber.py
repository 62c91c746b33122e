"""The ``"wavebrdf_fiber"`` Mitsuba 3 BSDF: the full wave-optics fiber BCSDF of a fiber dataset on
cylinders and B-spline curves (seed 004 §5–6: S = M₀(θ_i, θ_r; v) · N_wave(λ, θ_i, φ_i, φ_r)).

Same backends as the surface plugin (``plugin._ScalarOps`` / ``plugin._JitOps``). Conventions:

* **Fiber frame.** Mitsuba's ``cylinder`` and ``bsplinecurve`` put dp_du around the fiber and
  dp_dv along it, so in the shading frame (s, t, n) = (x, y, z) the fiber axis is t (local y).
  θ = asin(ω·t) is measured from the normal plane; the azimuth around the axis is
  φ = 2π·u + atan2(ω·s, ω·n): the hit's normal sits at cross-section angle 2π·u, so φ is fixed
  to the cross section (φ = 0 along the shape's u = 0 normal), not to the hit point. Circular
  fibers depend on φ_r - φ_i only. (``linearcurve`` has no dp_du: unsupported.)
* **Which direction is the incidence.** As in the surface plugin, Mitsuba's ``si.wi`` (the
  camera side) is the tabulated incidence and ``wo`` the outgoing direction (reciprocity), so
  a hit scatters exactly the tabulated distribution of its incidence and ``sample`` draws from it.
* **Effective width** ([P] §5.1, §6). The scene's cylinder is the bounding width C_b (the
  largest stored C_e); a ray that meets it hits the fiber with probability C_e(λ, θ_wi, φ_wi)/C_b
  (the offset-limited hit of [P], randomised over the offset) and otherwise passes straight
  through: a ``Null`` component (wo = -wi, weight ``miss``). Back faces (rays inside the bounding
  cylinder, e.g. leaving it after a forward scatter) are pure pass-through. So a scene's
  cylinders must have radius C_b/2 in the scene's units of the fiber (``bounding_over_geometric``
  × the geometric radius; :func:`wavebrdf.mitsuba.fiber_radius`).
* **Value.** ``eval`` returns hit · M₀ · N_wave (1/sr): Mitsuba's cosine-weighted BSDF is the
  BCSDF's density per solid angle of ω_o (∫ M₀ N_wave dω_o = C_sca/C_ext); no extra cosine.
  N_wave is interpolated like ``FiberBCSDF`` (linear in θ_i, φ_i, φ_r, λ; |θ_i| by z-symmetry).
* **Sampling.** Null with probability P_null = the channel mean of ``miss``; otherwise an
  interpolation corner (θ_i, φ_i, and in spectral variants the table wavelengths around the
  hero wavelength) with its weight, a φ_r bin from the stored CDF and a uniform φ_r in it, and
  θ_r by inverting d'Eon's M₀ exactly (d'Eon et al. 2013, as in pbrt-v3's hair model:
  cos ϑ = 1 + v ln(ξ + (1-ξ)e^{-2/v}), sinθ_r = -cos ϑ sinθ_i + sin ϑ cos(2πξ') cosθ_i). ``pdf``
  = (1 - P_null) · M₀ · p_φ with p_φ the mixture of the corners' piecewise-constant φ_r densities.
"""

from __future__ import annotations

import math

import numpy as np

from wavebrdf.mitsuba.fiber_tables import FiberTables
from wavebrdf.mitsuba.plugin import _JitOps, _ScalarOps, linear_nodes, pick_interval

__all__ = ["FiberEvaluator", "make_fiber_plugin_class"]

TWO_PI = 2.0 * math.pi
SERIES_MAX = 15.0  # log I₀: power series up to here, the asymptotic series beyond
SERIES_TERMS = 40


class _ScalarMath(_ScalarOps):
    exp = staticmethod(math.exp)
    cos = staticmethod(math.cos)
    sin = staticmethod(math.sin)

    @staticmethod
    def log(x):
        return math.log(x) if x > 0 else -math.inf

    @staticmethod
    def asin(x):
        return math.asin(max(-1.0, min(1.0, x)))

    @staticmethod
    def mod_int(i, n):
        return i % n


class _JitMath(_JitOps):
    def exp(self, x):
        return self.dr.exp(x)

    def log(self, x):
        return self.dr.log(x)

    def cos(self, x):
        return self.dr.cos(x)

    def sin(self, x):
        return self.dr.sin(x)

    def asin(self, x):
        return self.dr.asin(self.dr.clip(x, -1.0, 1.0))

    def mod_int(self, i, n):
        return i - n * self.mi.Int32(self.dr.floor(self.mi.Float(i) / n))


class FiberEvaluator:
    """The fiber tables on one backend: interpolation, M₀, sampling and densities."""

    def __init__(self, tables: FiberTables, ops, variance: float | None = None):
        self.t, self.ops = tables, ops
        self.C, self.T, self.P, self.R = tables.value.shape
        self.S = tables.cdf.shape[0]
        self.dphi = TWO_PI / self.R
        self.value = ops.floats(tables.value)
        self.hit = ops.floats(tables.hit)
        self.miss = ops.floats(tables.miss)
        cdf = np.concatenate([np.zeros(tables.cdf.shape[:-1] + (1,)), tables.cdf], axis=-1)
        self.cdf = ops.floats(cdf)  # (S, T, P, R + 1)
        self.theta = ops.floats(tables.theta_i)
        self.phi = ops.floats(tables.phi_i)
        self.wavelengths_nm = ops.floats(tables.wavelengths_um * 1000.0)
        self.v = float(tables.variance if variance is None else variance)
        if not self.v > 0:
            raise ValueError(f"[wavebrdf_fiber plugin] variance = {self.v!r}: must be > 0 (rad²)")
        self.log_norm = -math.log(self.v) - 1.0 / self.v - math.log1p(-math.exp(-2.0 / self.v))
        self.e2v = math.exp(-2.0 / self.v)

    # -- directions ------------------------------------------------------------------------------
    def angles(self, w, alpha):
        """(sinθ, cosθ, φ) of local direction w: axis = local y, φ = α + atan2(w.x, w.z)."""
        ops = self.ops
        s = ops.clip(w.y, -1.0, 1.0)
        return s, ops.sqrt(1.0 - s * s), alpha + ops.atan2(w.x, w.z)

    def direction(self, sin_t, cos_t, phi, alpha):
        """Local (x, y, z) of the direction (θ, φ)."""
        psi = phi - alpha
        ops = self.ops
        return cos_t * ops.sin(psi), sin_t, cos_t * ops.cos(psi)

    # -- interpolation ---------------------------------------------------------------------------
    def corners(self, sin_i, phi_i):
        """[(t, p, w)]: the (θ_i, φ_i) interpolation corners of the incidence."""
        ops, t = self.ops, self.t
        theta = ops.asin(sin_i)
        if t.mirror_theta:
            theta = ops.select(theta < 0, -theta, theta)
        ts = linear_nodes(ops, self.theta, self.T, theta)
        if self.P == 1:
            ps = [(ops.index(0), 1.0)]
        elif t.phi_i_binned:
            x = phi_i / (TWO_PI / self.P)
            f = ops.floor_int(x)
            w = x - f
            i0 = ops.mod_int(f, self.P)
            ps = [(i0, 1.0 - w), (ops.mod_int(i0 + 1, self.P), w)]
        else:
            ps = linear_nodes(ops, self.phi, self.P, phi_i)
        return [(ti, pi, wt * wp) for ti, wt in ts for pi, wp in ps]

    def channel_terms(self, wavelengths_nm):
        """Per output channel, [(table channel, weight)]: spectral = linear in λ (clamped)."""
        if self.t.channels == "spectral":
            return [linear_nodes(self.ops, self.wavelengths_nm, self.C, lam) for lam in wavelengths_nm]
        return [[(c, 1.0)] for c in range(self.C)]

    def slots(self, hero_nm):
        """[(sampling slot, weight)]: spectral = the table wavelengths around the hero wavelength."""
        if self.S == 1:
            return [(self.ops.index(0), 1.0)]
        return linear_nodes(self.ops, self.wavelengths_nm, self.S, hero_nm)

    def relative(self, phi_i, phi_r):
        return phi_r - (phi_i - float(self.t.phi_i[0])) if self.t.rotation_invariant else phi_r

    def _bins(self, phi):
        """Nodes (r0, r1, w) between φ_r bin centres, periodic."""
        ops = self.ops
        x = phi / self.dphi
        f = ops.floor_int(x)
        w = x - f
        r0 = ops.mod_int(f, self.R)
        return r0, ops.mod_int(r0 + 1, self.R), w

    def _incidence_sum(self, table, corners, chans):
        ops = self.ops
        out = []
        for terms in chans:
            acc = 0.0
            for c, wc in terms:
                for ti, pi, w in corners:
                    acc = acc + wc * w * ops.gather(table, (c * self.T + ti) * self.P + pi)
            out.append(acc)
        return out

    def hit_miss(self, corners, chans):
        return self._incidence_sum(self.hit, corners, chans), self._incidence_sum(self.miss, corners, chans)

    def azimuthal(self, corners, chans, phi_rel):
        """Per channel, hit · N_wave interpolated (1/rad)."""
        ops = self.ops
        r0, r1, wr = self._bins(phi_rel)
        out = []
        for terms in chans:
            acc = 0.0
            for c, wc in terms:
                for ti, pi, w in corners:
                    base = ((c * self.T + ti) * self.P + pi) * self.R
                    acc = acc + wc * w * ((1.0 - wr) * ops.gather(self.value, base + r0)
                                          + wr * ops.gather(self.value, base + r1))
            out.append(acc)
        return out

    def m0(self, sin_i, cos_i, sin_r, cos_r):
        """d'Eon's M₀ (1/rad) in the log domain (∫ M₀ cosθ_r dθ_r = 1)."""
        ops, v = self.ops, self.v
        a = ops.maximum(cos_i * cos_r / v, 0.0)
        b = sin_i * sin_r / v
        small = ops.clip(a, 0.0, SERIES_MAX)
        q, term, series = small * small / 4.0, 1.0, 1.0
        for k in range(1, SERIES_TERMS + 1):
            term = term * q / (k * k)
            series = series + term
        big = ops.maximum(a, SERIES_MAX)
        x = 1.0 / big
        poly = 1.0 + x * (1.0 / 8 + x * (9.0 / 128 + x * (225.0 / 3072 + x * 11025.0 / 98304)))
        log_i0 = ops.select(a <= SERIES_MAX, ops.log(series),
                            big - 0.5 * ops.log(TWO_PI * big) + ops.log(poly))
        return ops.exp(log_i0 - b + self.log_norm)

    def sample_theta(self, sin_i, cos_i, u1, u2):
        """(sinθ_r, cosθ_r) with density M₀(θ_i, θ_r) cosθ_r over θ_r (exact inversion)."""
        ops, v = self.ops, self.v
        u1 = ops.clip(u1, 1e-7, 1.0)
        cos_t = ops.clip(1.0 + v * ops.log(u1 + (1.0 - u1) * self.e2v), -1.0, 1.0)
        sin_t = ops.sqrt(1.0 - cos_t * cos_t)
        sin_r = ops.clip(-cos_t * sin_i + sin_t * ops.cos(TWO_PI * u2) * cos_i, -1.0, 1.0)
        return sin_r, ops.sqrt(1.0 - sin_r * sin_r)

    def phi_density(self, corners, slots, phi_rel):
        """p_φ(φ_rel) (1/rad): the mixture of the corners' piecewise-constant CDF densities."""
        ops = self.ops
        x = phi_rel / self.dphi + 0.5
        r = ops.mod_int(ops.floor_int(x), self.R)
        acc = 0.0
        for s, ws in slots:
            for ti, pi, w in corners:
                base = ((s * self.T + ti) * self.P + pi) * (self.R + 1)
                acc = acc + ws * w * (ops.gather(self.cdf, base + r + 1) - ops.gather(self.cdf, base + r))
        return acc / self.dphi

    def sample_phi(self, corners, slots, u_pick, u_bin):
        """(φ_rel, leftover uniform): a component by weight, then a bin and a point in it."""
        ops = self.ops
        base = left = None
        cum = 0.0
        for s, ws in slots:  # the last component whose cumulative start is <= u_pick
            for ti, pi, w in corners:
                w = ws * w
                b = ((s * self.T + ti) * self.P + pi) * (self.R + 1)
                frac = ops.clip((u_pick - cum) / ops.maximum(w, 1e-12), 0.0, 1.0)
                if base is None:
                    base, left = b, frac
                elif ops.jit:
                    take = (u_pick >= cum) & (w > 0)
                    base, left = ops.select(take, b, base), ops.select(take, frac, left)
                elif u_pick >= cum and w > 0:
                    base, left = b, frac
                cum = cum + w
        j, f = pick_interval(ops, self.cdf, base, self.R, u_bin)
        return (j - 0.5 + f) * self.dphi, left


def make_fiber_plugin_class(mi, load):
    """The BSDF class for the current Mitsuba variant; ``load(props, channels)`` returns
    (FiberTables, variance or None)."""
    import drjit as dr

    variant = mi.variant()
    polarized = "polarized" in variant
    channels = "spectral" if "spectral" in variant else "mono" if "mono" in variant else "rgb"
    ops_type = _ScalarMath if variant.startswith("scalar") else _JitMath
    jit = ops_type.jit

    class WaveFiber(mi.BSDF):
        """Tabulated wave-optics fiber BCSDF from a wavebrdf fiber dataset (see wavebrdf.mitsuba.fiber)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            if polarized:
                raise ValueError(f"the wavebrdf_fiber plugin supports unpolarized variants; {variant!r} is polarized "
                                 "(fiber datasets hold cross sections per polarization, no Mueller matrices)")
            tables, variance = load(props, channels)
            self.tables = tables
            self.ev = FiberEvaluator(tables, ops_type(mi), variance)
            glossy = (mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.FrontSide
                      | mi.BSDFFlags.BackSide)
            null = mi.BSDFFlags.Null | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            self.m_components = [glossy, null]
            self.m_flags = glossy | null

        # -- shared pieces ---------------------------------------------------------------------
        def _wavelengths(self, si):
            return [si.wavelengths[n] for n in range(len(si.wavelengths))] if channels == "spectral" else []

        def _setup(self, si):
            """Everything that depends on the incidence only."""
            ev = self.ev
            alpha = TWO_PI * si.uv.x
            sin_i, cos_i, phi_i = ev.angles(si.wi, alpha)
            lams = self._wavelengths(si)
            chans = ev.channel_terms(lams)
            corners = ev.corners(sin_i, phi_i)
            slots = ev.slots(lams[0] if lams else 0.0)
            hit, miss = ev.hit_miss(corners, chans)
            p_null = ev.ops.clip(sum(miss) / len(miss), 0.0, 1.0)
            return dict(alpha=alpha, sin_i=sin_i, cos_i=cos_i, phi_i=phi_i, chans=chans, corners=corners,
                        slots=slots, miss=miss, p_null=p_null)

        def _value_pdf(self, g, wo):
            ev = self.ev
            sin_r, cos_r, phi_r = ev.angles(wo, g["alpha"])
            rel = ev.relative(g["phi_i"], phi_r)
            m0 = ev.m0(g["sin_i"], g["cos_i"], sin_r, cos_r)
            values = [m0 * n for n in ev.azimuthal(g["corners"], g["chans"], rel)]
            pdf = (1.0 - g["p_null"]) * m0 * ev.phi_density(g["corners"], g["slots"], rel)
            return mi.Spectrum(*values), pdf

        # -- what Mitsuba calls ----------------------------------------------------------------
        def eval(self, ctx, si, wo, active=True):
            active = active & (si.wi.z > 0)
            if not jit:
                return self._value_pdf(self._setup(si), wo)[0] if active else mi.Spectrum(0.0)
            return dr.select(active, self._value_pdf(self._setup(si), wo)[0], 0.0)

        def pdf(self, ctx, si, wo, active=True):
            active = active & (si.wi.z > 0)
            if not jit:
                return self._value_pdf(self._setup(si), wo)[1] if active else 0.0
            return dr.select(active, self._value_pdf(self._setup(si), wo)[1], 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            active = active & (si.wi.z > 0)
            if not jit:
                return self._value_pdf(self._setup(si), wo) if active else (mi.Spectrum(0.0), 0.0)
            value, pdf = self._value_pdf(self._setup(si), wo)
            return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

        def eval_null_transmission(self, si, active=True):
            front = si.wi.z > 0
            if not jit:
                return mi.Spectrum(*self._setup(si)["miss"]) if front else mi.Spectrum(1.0)
            return dr.select(front, mi.Spectrum(*self._setup(si)["miss"]), 1.0)

        def _null(self, si, weight, pdf):
            bs = mi.BSDFSample3f()
            bs.wo = -si.wi
            bs.eta = 1.0
            bs.pdf = pdf
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.Null)
            bs.sampled_component = mi.UInt32(1)
            return bs, weight

        def sample(self, ctx, si, sample1, sample2, active=True):
            ev, ops = self.ev, self.ev.ops
            front = si.wi.z > 0
            if not jit and not front:
                return self._null(si, mi.Spectrum(1.0), 1.0)
            g = self._setup(si)
            p_null = g["p_null"]
            null = sample1 < p_null
            null_weight = mi.Spectrum(*[m / ops.maximum(p_null, 1e-12) for m in g["miss"]])
            if not jit and null:
                return self._null(si, null_weight, p_null)
            u = ops.clip((sample1 - p_null) / ops.maximum(1.0 - p_null, 1e-12), 0.0, 1.0 - 1e-7)
            rel, u2 = ev.sample_phi(g["corners"], g["slots"], u, sample2.x)
            phi_r = rel + (g["phi_i"] - float(self.tables.phi_i[0])) if self.tables.rotation_invariant else rel
            sin_r, cos_r = ev.sample_theta(g["sin_i"], g["cos_i"], sample2.y, u2)
            wo = mi.Vector3f(*ev.direction(sin_r, cos_r, phi_r, g["alpha"]))
            value, pdf = self._value_pdf(g, wo)
            bs = mi.BSDFSample3f()
            bs.wo = wo
            bs.eta = 1.0
            bs.sampled_component = mi.UInt32(0)
            if not jit:
                if not pdf > 0:
                    return mi.BSDFSample3f(), mi.Spectrum(0.0)
                bs.pdf = pdf
                bs.sampled_type = mi.UInt32(+(mi.BSDFFlags.GlossyReflection if wo.z >= 0
                                              else mi.BSDFFlags.GlossyTransmission))
                return bs, value / pdf
            valid = active & front & (pdf > 0)
            weight = dr.select(valid, value / dr.select(valid, pdf, 1.0), 0.0)
            bs.pdf = dr.select(valid, pdf, 0.0)
            bs.sampled_type = dr.select(wo.z >= 0, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                        mi.UInt32(+mi.BSDFFlags.GlossyTransmission))
            nbs, nweight = self._null(si, null_weight, p_null)
            back_bs, back_weight = self._null(si, mi.Spectrum(1.0), mi.Float(1.0))
            take_null = active & front & null
            for name in ("wo", "pdf", "sampled_type", "sampled_component"):
                setattr(bs, name, dr.select(take_null, getattr(nbs, name), getattr(bs, name)))
                setattr(bs, name, dr.select(active & ~front, getattr(back_bs, name), getattr(bs, name)))
            weight = dr.select(take_null, nweight, weight)
            weight = dr.select(active & ~front, back_weight, weight)
            return bs, dr.select(active, weight, 0.0)

        def to_string(self):
            d = self.tables.diagnostics
            return (f"WaveFiber[{channels}, λ {d['wavelengths_um'][0]:g}–{d['wavelengths_um'][-1]:g} µm, "
                    f"θ_i {d['theta_i_deg']}, {d['phi_i']} φ_i, {d['phi_r_bins']} φ_r bins, v = {self.ev.v:g}]")

    return WaveFiber
