"""The ``"wavebrdf"`` Mitsuba 3 BSDF: evaluation, importance sampling and pdf of tabulated BRDFs.

One implementation serves every variant: the arithmetic is written once against a
small backend (:class:`_ScalarOps`: Python floats and ``math``; :class:`_JitOps`: Dr.Jit arrays,
``dr.gather``, ``dr.binary_search``), chosen by the variant when the plugin is instantiated.

Directions are in the shading frame (x, y, z) = (s, t, n); u = x, v = y as in the dataset.

* **Which direction is the incidence.** The dataset's θ_i/φ_i point toward the light; a
  computed BRDF is reciprocal (Helmholtz), f(ω_l → ω_v) = f(ω_v → ω_l), up to its numerical
  error. ``eval``, ``sample`` and ``pdf`` all look the tables up with Mitsuba's ``si.wi`` as the
  tabulated incidence and ``wo`` as ω_o (in radiance transport wi is the camera side: by
  reciprocity the table of incidence wi is f as a function of the light direction wo), and
  ``eval`` returns f·cos θ_wo as Mitsuba expects. The integration variable of the renderer (wo)
  is thereby the tables' dense (u, v) axis and the sparse incidence axis is only interpolated at
  the fixed wi: a pixel under a white sky shows the stored albedo of its incidence (exactly at a
  tabulated one), and ``sample`` draws from the same table it evaluates. (Evaluating with the light as incidence
  would integrate the sparse axis; with few, speckled incidences that breaks energy balance.)
* **Interpolation over incidence** (Tables.scheme): components (table k, weight w_k, rotation,
  shift). The shift (default ``interpolation = "shift"``) translates table k in (u, v) so that
  its specular direction −a_k lands on the query's −a: the Harvey–Shack picture, in which the
  scattered lobe moves with the specular direction in direction-cosine space (exact for
  gratings, whose orders move rigidly). The part of a translated table that leaves the disk is
  dropped and the rest scaled by Tables.shift_gain, so that the albedo of the interpolated BRDF
  is the interpolated albedo (never a gain from extrapolation). ``interpolation = "blend"``
  mixes the tables in place (albedo interpolated exactly, lobes not aligned).
* **Over (u, v)**: bilinear between pixel centres; 0 beyond the table's unit disk (no data:
  evanescent directions). **Over λ** (spectral variants): linear between the dataset's
  wavelengths, held constant beyond the first and last (like ``solver/spectrum.py``).
* **Sampling**: component k with probability w_k (``sample1``), then a cell of its
  piecewise-constant table (cells between pixel centres, Tables.pmf) from the row/column CDFs
  and a uniform point in it (``sample2``); mapped back through the component's rotation and
  shift (Jacobian 1 in (u, v)); density in solid angle = Σ_k w_k pmf_k / cell area · cos θ_o,
  which ``pdf`` returns. Points that land outside the unit disk are invalid samples (weight 0).
* **Polarized variants** (``*_spectral_polarized``, ``*_mono_polarized``; a dataset with Jones or
  Mueller matrices): the table's M = f·[1, ratios] (Tables.mueller_ratio, looked up like f,
  without the shift gain) is the Mueller matrix of incidence wi → ω_o = wo in the s/p frames of
  ``solver/polarimetry.py``. In radiance transport light travels wo → wi, so the reciprocal
  path's matrix R Mᵀ R (``polarimetry.reversed_path``) is taken; it is then rotated from the
  tables' frames to Mitsuba's Stokes bases with ``mueller.rotate_mueller_basis``, as Mitsuba's own
  conductors do. The tables hold the matrices in the regular frames of ``polarimetry.regular_axis``
  taken about each table's incidence azimuth (smooth across ω_o's pole, where the dataset's s/p
  frames turn with φ; turning with the incidence as those do), read as the frames about the
  query's azimuth (:meth:`Evaluator.frame`; a θ = 0 table's, fixed, are turned to them:
  :meth:`Evaluator._turned`), and the relation R Mᵀ R holds in them too (each direction has one
  first axis, as incidence and as exitance).
* **Below the horizon and back faces**: zero (a one-sided reflector, like Mitsuba's conductors);
  wrap it in Mitsuba's ``twosided`` BSDF to use the same tables on both sides.
"""

from __future__ import annotations

import bisect
import math
from array import array

import numpy as np

from wavebrdf.mitsuba.tables import ANGLE_TOL_DEG, Tables, cell_edges

__all__ = ["linear_nodes", "make_plugin_class", "pick_interval"]


class _ScalarOps:
    """Scalar variants: Python floats, ``math`` and ``bisect``."""

    jit = False

    def __init__(self, mi):
        self.mi = mi

    def floats(self, values) -> array:
        out = array("f")
        out.frombytes(np.ascontiguousarray(values, dtype=np.float32).ravel().tobytes())
        return out

    def ints(self, values) -> list:
        return [int(x) for x in np.asarray(values).ravel()]

    def gather(self, table, index, active=True):
        return table[index]

    @staticmethod
    def select(cond, a, b):
        return a if cond else b

    @staticmethod
    def floor_int(x):
        return math.floor(x)

    @staticmethod
    def clip(x, lo, hi):
        return lo if x < lo else hi if x > hi else x

    @staticmethod
    def sqrt(x):
        return math.sqrt(x) if x > 0.0 else 0.0

    atan2 = staticmethod(math.atan2)
    maximum = staticmethod(max)

    def index(self, value):
        return int(value)

    def search(self, cdf, base, count, x):
        """Index j in [0, count) with cdf[base + j] <= x < cdf[base + j + 1] (clamped)."""
        j = bisect.bisect_right(cdf, x, base, base + count + 1) - 1 - base
        return 0 if j < 0 else count - 1 if j > count - 1 else j


class _JitOps:
    """JIT variants (llvm_*, cuda_*): Dr.Jit arrays."""

    jit = True

    def __init__(self, mi):
        import drjit as dr

        self.mi, self.dr = mi, dr

    def floats(self, values):
        return self.mi.Float(np.asarray(values, dtype=np.float32).ravel())

    def ints(self, values):
        return self.mi.Int32(np.asarray(values, dtype=np.int32).ravel())

    def gather(self, table, index, active=True):
        dtype = self.mi.Int32 if isinstance(table, self.mi.Int32) else self.mi.Float
        return self.dr.gather(dtype, table, self.mi.UInt32(index), active)

    def select(self, cond, a, b):
        return self.dr.select(cond, a, b)

    def floor_int(self, x):
        return self.mi.Int32(self.dr.floor(x))

    def clip(self, x, lo, hi):
        return self.dr.clip(x, lo, hi)

    def sqrt(self, x):
        return self.dr.sqrt(self.dr.maximum(x, 0.0))

    def atan2(self, y, x):
        return self.dr.atan2(y, x)

    def maximum(self, a, b):
        return self.dr.maximum(a, b)

    def index(self, value):
        return self.mi.Int32(value)

    def search(self, cdf, base, count, x):
        dr, mi = self.dr, self.mi
        base = mi.UInt32(base)
        j = dr.binary_search(0, count, lambda j: dr.gather(mi.Float, cdf, base + j) <= x)
        return dr.clip(mi.Int32(j) - 1, 0, count - 1)


class _Component:
    """One term of the incidence interpolation: table ``k`` with weight ``w``, the rotation
    (cos, sin) taking the query frame to the table frame, and the shift added after it."""

    __slots__ = ("k", "w", "c", "s", "du", "dv")

    def __init__(self, k, w, c, s, du, dv):
        self.k, self.w, self.c, self.s, self.du, self.dv = k, w, c, s, du, dv

    def to_table(self, x, y):
        return self.c * x + self.s * y + self.du, -self.s * x + self.c * y + self.dv

    def from_table(self, x, y):
        x, y = x - self.du, y - self.dv
        return self.c * x - self.s * y, self.s * x + self.c * y


class Evaluator:
    """The tables on one backend: incidence components, f lookup, sampling and pdf."""

    def __init__(self, tables: Tables, ops, shift: bool = True):
        self.t, self.ops, self.shift = tables, ops, shift
        res = tables.resolution
        self.res, self.du = res, tables.pixel
        self.n_tab, self.n_chan = tables.f.shape[:2]
        self.f = ops.floats(tables.f)
        self.pmf = ops.floats(tables.pmf)
        self.row_cdf = ops.floats(tables.row_cdf)
        self.col_cdf = ops.floats(tables.col_cdf)
        self.edges = ops.floats(cell_edges(res))
        self.grid_theta = ops.floats(tables.grid_theta)
        self.grid_phi_ext = ops.floats(np.concatenate([tables.grid_phi - tables.grid_phi[0], [2 * np.pi]]))
        self.grid_index = ops.ints(tables.grid_index)
        a = tables.incident_uv
        self.a_u, self.a_v = ops.floats(a[:, 0]), ops.floats(a[:, 1])
        self.a_np = np.column_stack([a, np.cos(tables.theta)])
        self.wavelengths_nm = ops.floats(tables.wavelengths_um * 1000.0)
        self.ratio = None if tables.mueller_ratio is None else ops.floats(tables.mueller_ratio)
        # θ = 0 tables of anisotropic schemes: their ratio frames are fixed (turned by φ_k), not the query's
        fixed = (tables.theta <= np.deg2rad(ANGLE_TOL_DEG)) & (tables.scheme != "isotropic")
        self.fixed_frames = bool(fixed.any())
        self.fixed = ops.floats(fixed.astype(float))
        self.frame_cos, self.frame_sin = ops.floats(np.cos(tables.phi)), ops.floats(np.sin(tables.phi))
        self.gain = ops.floats(tables.shift_gain)
        self.gain_n = tables.shift_gain.shape[-1]
        self.gain_step = tables.shift_step

    # -- incidence ---------------------------------------------------------------------------
    def components(self, ax, ay, az) -> list[_Component]:
        """Interpolation terms for incidence (ax, ay, az) (local frame, az > 0)."""
        ops, t = self.ops, self.t
        sin_t = ops.sqrt(ax * ax + ay * ay)
        theta = ops.atan2(sin_t, az)
        if t.scheme == "isotropic":
            c, s = self.frame(ax, ay)
            terms = []
            for k, w in self._linear(self.grid_theta, len(t.grid_theta), theta):
                sin_k = ops.gather(self.a_u, k)  # canonical tables: a_k = (sin θ_k, 0)
                du = (sin_t - sin_k) if self.shift else 0.0
                terms.append(_Component(k, w, c, s, du, 0.0))
            return terms
        if t.scheme == "grid":
            return self._grid(ax, ay, theta)
        return self._nearest(ax, ay, az)

    def frame(self, ax, ay):
        """(cos, sin) of the query's incidence azimuth ((1, 0) at the pole): the ratio tables' frames
        are the regular frames taken about it (Tables.mueller_ratio)."""
        ops = self.ops
        sin_t = ops.sqrt(ax * ax + ay * ay)
        safe = ops.maximum(sin_t, 1e-12)
        return ops.select(sin_t > 1e-12, ax / safe, 1.0), ops.select(sin_t > 1e-12, ay / safe, 0.0)

    def _turned(self, values: list, k, frame) -> list:
        """One component's 15 ratio contributions (element-major, channel-minor), from the fixed
        frames of a θ = 0 table (taken about its φ_k) to those about the query's azimuth φ:
        S(2Δ) M S(2Δ), Δ = φ − φ_k (``polarimetry.to_regular_frames``); unchanged for other tables."""
        ops = self.ops
        fixed = ops.gather(self.fixed, k) > 0.5
        cr, sr = ops.gather(self.frame_cos, k), ops.gather(self.frame_sin, k)
        cos_d, sin_d = frame[0] * cr + frame[1] * sr, frame[1] * cr - frame[0] * sr
        C = ops.select(fixed, cos_d * cos_d - sin_d * sin_d, 1.0)
        S = ops.select(fixed, 2.0 * sin_d * cos_d, 0.0)
        n = len(values) // 15
        out = list(values)
        for c in range(n):
            m = [[0.0] + [values[(i - 1) * n + c] for i in range(1, 4)]] + \
                [[values[(4 * r + col - 1) * n + c] for col in range(4)] for r in range(1, 4)]
            t = [m[0], [C * a + S * b for a, b in zip(m[1], m[2])], [C * b - S * a for a, b in zip(m[1], m[2])], m[3]]
            turned = [[row[0], row[1] * C - row[2] * S, row[1] * S + row[2] * C, row[3]] for row in t]
            for i in range(1, 16):
                out[(i - 1) * n + c] = turned[i // 4][i % 4]
        return out

    def _linear(self, grid, n, x):
        return linear_nodes(self.ops, grid, n, x)

    def _shifted(self, k, w, ax, ay):
        ops = self.ops
        if not self.shift:
            return _Component(k, w, 1.0, 0.0, 0.0, 0.0)
        return _Component(k, w, 1.0, 0.0, ax - ops.gather(self.a_u, k), ay - ops.gather(self.a_v, k))

    def _grid(self, ax, ay, theta):
        ops, t = self.ops, self.t
        n_p = len(t.grid_phi)
        rows = self._linear(self.grid_theta, len(t.grid_theta), theta)
        if n_p == 1:
            cols = [(ops.index(0), 1.0)]
        else:
            phi = ops.atan2(ay, ax) - float(t.grid_phi[0])
            phi = phi - 2 * math.pi * ops.floor_int(phi / (2 * math.pi))
            j = ops.search(self.grid_phi_ext, 0, n_p, phi)
            lo, hi = ops.gather(self.grid_phi_ext, j), ops.gather(self.grid_phi_ext, j + 1)
            w = ops.clip((phi - lo) / (hi - lo), 0.0, 1.0)
            nxt = ops.select(j + 1 >= n_p, j + 1 - n_p, j + 1)
            cols = [(j, 1.0 - w), (nxt, w)]
        terms = []
        for r, wr in rows:
            for p, wp in cols:
                k = ops.gather(self.grid_index, r * n_p + p)
                terms.append(self._shifted(k, wr * wp, ax, ay))
        return terms

    def _nearest(self, ax, ay, az):
        ops = self.ops
        best_k, best = ops.index(0), None
        for k, (bu, bv, bz) in enumerate(self.a_np):
            dot = ax * float(bu) + ay * float(bv) + az * float(bz)
            if best is None:
                best = dot
                continue
            better = dot > best
            best_k = ops.select(better, ops.index(k), best_k)
            best = ops.select(better, dot, best)
        return [self._shifted(best_k, 1.0, ax, ay)]

    # -- lookups -------------------------------------------------------------------------------
    def _bilinear(self, x, y):
        """(i0, j0, tx, ty) of table coordinates (x, y): the 2×2 pixel-centre cell."""
        ops, res = self.ops, self.res
        gx = (x + 1.0) / self.du - 0.5
        gy = (y + 1.0) / self.du - 0.5
        i0 = ops.clip(ops.floor_int(gx), 0, res - 2)
        j0 = ops.clip(ops.floor_int(gy), 0, res - 2)
        return i0, j0, ops.clip(gx - i0, 0.0, 1.0), ops.clip(gy - j0, 0.0, 1.0)

    def lookup(self, terms: list[_Component], ox, oy, channel_terms, ratios: bool = False, frame=None) -> list:
        """Σ_k w_k f_k at query ω_o = (ox, oy) for each output channel; ``channel_terms`` lists,
        per output channel, [(table channel index, weight)] (λ interpolation or identity).
        ``ratios``: the Mueller ratio tables instead (channel index e·C + c, all 15 elements of each
        output channel; no shift gain), in the regular frames about ``frame`` (:meth:`frame`)."""
        ops, res, plane = self.ops, self.res, self.res * self.res
        f = self.ratio if ratios else self.f
        n_chan = self.n_chan * 15 if ratios else self.n_chan
        out = [0.0] * len(channel_terms)
        for term in terms:
            x, y = term.to_table(ox, oy)
            inside = x * x + y * y < 1.0  # a table holds no data beyond its disk (evanescent)
            if not ops.jit and not inside:
                continue
            i0, j0, tx, ty = self._bilinear(x, y)
            w = term.w * self._gain(term) if self.shift and not ratios else term.w
            if ops.jit:
                w = ops.select(inside, w, 0.0)
            w00, w10, w01, w11 = w * (1 - tx) * (1 - ty), w * tx * (1 - ty), w * (1 - tx) * ty, w * tx * ty
            base = term.k * (n_chan * plane) + i0 * res + j0
            values = [0.0] * len(channel_terms)
            for n, chans in enumerate(channel_terms):
                for c, wc in chans:
                    b = base + c * plane
                    values[n] = values[n] + wc * (w00 * ops.gather(f, b) + w10 * ops.gather(f, b + res)
                                                  + w01 * ops.gather(f, b + 1) + w11 * ops.gather(f, b + res + 1))
            if ratios and self.fixed_frames:
                if frame is None:
                    raise ValueError("Evaluator.lookup(ratios=True): the query's frame (Evaluator.frame) is needed")
                values = self._turned(values, term.k, frame)
            out = [o + v for o, v in zip(out, values)]
        return out

    def _gain(self, term: _Component):
        """Tables.shift_gain of table k at the term's shift (bilinear on its lattice)."""
        ops, n = self.ops, self.gain_n
        centre = (n - 1) // 2
        gx = term.du / self.gain_step + centre
        gy = term.dv / self.gain_step + centre
        i0 = ops.clip(ops.floor_int(gx), 0, n - 2)
        j0 = ops.clip(ops.floor_int(gy), 0, n - 2)
        tx, ty = ops.clip(gx - i0, 0.0, 1.0), ops.clip(gy - j0, 0.0, 1.0)
        b = term.k * (n * n) + i0 * n + j0
        g = self.gain
        return ((1 - tx) * (1 - ty) * ops.gather(g, b) + tx * (1 - ty) * ops.gather(g, b + n)
                + (1 - tx) * ty * ops.gather(g, b + 1) + tx * ty * ops.gather(g, b + n + 1))

    def spectral_terms(self, wavelengths_nm) -> list:
        """Per Mitsuba wavelength, [(table channel, weight)]: linear in λ, constant beyond the ends."""
        n = len(self.t.wavelengths_um)
        return [self._linear(self.wavelengths_nm, n, lam) for lam in wavelengths_nm]

    def pdf_uv(self, terms: list[_Component], ox, oy):
        """Σ_k w_k pmf_k(cell of ω_o in table k) / cell area (density over the (u, v) plane)."""
        ops, n = self.ops, self.res + 1
        total = 0.0
        for term in terms:
            x, y = term.to_table(ox, oy)
            inside = (x >= -1.0) & (x <= 1.0) & (y >= -1.0) & (y <= 1.0)
            if not ops.jit and not inside:
                continue
            i = ops.clip(ops.floor_int((x + 1.0) / self.du + 0.5), 0, n - 1)
            j = ops.clip(ops.floor_int((y + 1.0) / self.du + 0.5), 0, n - 1)
            area = ((ops.gather(self.edges, i + 1) - ops.gather(self.edges, i))
                    * (ops.gather(self.edges, j + 1) - ops.gather(self.edges, j)))
            p = ops.gather(self.pmf, term.k * (n * n) + i * n + j) / area
            total = total + term.w * (ops.select(inside, p, 0.0) if ops.jit else p)
        return total

    def sample_uv(self, terms: list[_Component], xi1, xi2x, xi2y):
        """A point (u, v) drawn from Σ_k w_k (table k's density), query frame."""
        ops, n = self.ops, self.res + 1
        fields = ("k", "c", "s", "du", "dv")
        picked = {name: getattr(terms[-1], name) for name in fields}
        cumulative, acc = [], 0.0
        for term in terms:
            acc = acc + term.w
            cumulative.append(acc)
        # the first term whose cumulative weight exceeds xi1 (scanned from the back, selects win)
        for term, upper in zip(reversed(terms[:-1]), reversed(cumulative[:-1])):
            take = xi1 < upper
            for name in fields:
                picked[name] = ops.select(take, getattr(term, name), picked[name])
        comp = _Component(picked["k"], 1.0, picked["c"], picked["s"], picked["du"], picked["dv"])
        i, tx = self._pick(self.row_cdf, comp.k * (n + 1), n, xi2x)
        j, ty = self._pick(self.col_cdf, (comp.k * n + i) * (n + 1), n, xi2y)
        x = ops.gather(self.edges, i) + tx * (ops.gather(self.edges, i + 1) - ops.gather(self.edges, i))
        y = ops.gather(self.edges, j) + ty * (ops.gather(self.edges, j + 1) - ops.gather(self.edges, j))
        return comp.from_table(x, y)

    def _pick(self, cdf, base, count, xi):
        return pick_interval(self.ops, cdf, base, count, xi)


def linear_nodes(ops, grid, n, x):
    """[(index, weight)] of linear interpolation at x over sorted ``grid`` (n nodes; clamped)."""
    if n == 1:
        return [(ops.index(0), 1.0)]
    j = ops.search(grid, 0, n - 1, x)
    lo, hi = ops.gather(grid, j), ops.gather(grid, j + 1)
    w = ops.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return [(j, 1.0 - w), (j + 1, w)]


def pick_interval(ops, cdf, base, count, xi):
    """Interval j of the CDF segment cdf[base : base + count + 1] holding xi, and the fraction of
    xi within it (uniform within the cell)."""
    j = ops.search(cdf, base, count, xi)
    lo, hi = ops.gather(cdf, base + j), ops.gather(cdf, base + j + 1)
    return j, ops.clip((xi - lo) / ops.maximum(hi - lo, 1e-30), 0.0, 1.0)


def make_plugin_class(mi, load):
    """The BSDF class for the current Mitsuba variant; ``load(props, channels, polarized)`` returns Tables."""
    import drjit as dr

    variant = mi.variant()
    polarized = "polarized" in variant
    channels = "spectral" if "spectral" in variant else "mono" if "mono" in variant else "rgb"
    ops_type = _ScalarOps if variant.startswith("scalar") else _JitOps

    def _regular_axis(d, c, s):
        """The tables' first Stokes axis of direction d (shading frame): ``polarimetry.regular_axis``
        in the table frame (d turned by (c, s) as ``_Component.to_table`` turns it, without the
        shift), turned back."""
        x, y = c * d.x + s * d.y, -s * d.x + c * d.y
        inv = 1.0 / (1.0 + d.z)
        ax, ay = 1.0 - x * x * inv, -x * y * inv
        return mi.Vector3f(c * ax - s * ay, s * ax + c * ay, -x)

    class WaveBRDF(mi.BSDF):
        """Tabulated wave-optics BRDF from a wavebrdf surface dataset (see wavebrdf.mitsuba)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.tables = load(props, channels, polarized)
            interpolation = props.get("interpolation", "shift")
            if interpolation not in ("shift", "blend"):
                raise ValueError(f"[wavebrdf plugin] interpolation = {interpolation!r}: expected 'shift' or 'blend'")
            self.ev = Evaluator(self.tables, ops_type(mi), shift=interpolation == "shift")
            self.m_flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]

        # what Mitsuba calls -----------------------------------------------------------------
        def _channel_terms(self, si):
            if channels == "spectral":
                return self.ev.spectral_terms([si.wavelengths[n] for n in range(len(si.wavelengths))])
            return [[(c, 1.0)] for c in range(self.ev.n_chan)]

        def _terms(self, si):
            return self.ev.components(si.wi.x, si.wi.y, si.wi.z)

        def _value(self, terms, si, wo, ctx=None):
            """f(incidence wi, ω_o = wo) · cos θ_wo as a Spectrum (not masked); in polarized variants
            the Mueller matrix in Mitsuba's Stokes bases (module docstring)."""
            chans = self._channel_terms(si)
            values = [v * wo.z for v in self.ev.lookup(terms, wo.x, wo.y, chans)]
            if not polarized:
                return mi.Spectrum(*values)
            n = len(chans)
            ratio_terms = [[(e * self.ev.n_chan + c, w) for c, w in terms_c] for e in range(15) for terms_c in chans]
            frame = self.ev.frame(si.wi.x, si.wi.y)  # the tables' frames are taken about wi's azimuth
            ratios = self.ev.lookup(terms, wo.x, wo.y, ratio_terms, ratios=True, frame=frame)
            elements = [values] + [[values[c] * ratios[e * n + c] for c in range(n)] for e in range(15)]
            radiance = ctx is None or ctx.mode == mi.TransportMode.Radiance
            if radiance:  # light wo → wi: the reciprocal path, R Mᵀ R with R = diag(1, 1, −1, 1)
                sign = (1.0, 1.0, -1.0, 1.0)
                elements = [[sign[r] * sign[c] * x for x in elements[4 * c + r]] for r in range(4) for c in range(4)]
            matrix = mi.Spectrum(*[mi.UnpolarizedSpectrum(*e) for e in elements])
            c, s = frame
            axis_wi, axis_wo = _regular_axis(si.wi, c, s), _regular_axis(wo, c, s)
            (light_in, axis_in), (light_out, axis_out) = (((wo, axis_wo), (si.wi, axis_wi)) if radiance
                                                          else ((si.wi, axis_wi), (wo, axis_wo)))
            return mi.mueller.rotate_mueller_basis(matrix, -light_in, axis_in, mi.mueller.stokes_basis(-light_in),
                                                   light_out, axis_out, mi.mueller.stokes_basis(light_out))

        def _density(self, terms, wo):
            return self.ev.pdf_uv(terms, wo.x, wo.y) * wo.z

        def eval(self, ctx, si, wo, active=True):
            active = active & (si.wi.z > 0) & (wo.z > 0)
            if not ops_type.jit:
                return self._value(self._terms(si), si, wo, ctx) if active else mi.Spectrum(0.0)
            return dr.select(active, self._value(self._terms(si), si, wo, ctx), 0.0)

        def pdf(self, ctx, si, wo, active=True):
            active = active & (si.wi.z > 0) & (wo.z > 0)
            if not ops_type.jit:
                return self._density(self._terms(si), wo) if active else 0.0
            return dr.select(active, self._density(self._terms(si), wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            active = active & (si.wi.z > 0) & (wo.z > 0)
            if not ops_type.jit:
                if not active:
                    return mi.Spectrum(0.0), 0.0
                terms = self._terms(si)
                return self._value(terms, si, wo, ctx), self._density(terms, wo)
            terms = self._terms(si)
            return (dr.select(active, self._value(terms, si, wo, ctx), 0.0),
                    dr.select(active, self._density(terms, wo), 0.0))

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs = mi.BSDFSample3f()
            active = active & (si.wi.z > 0)
            if not ops_type.jit and not active:
                return bs, mi.Spectrum(0.0)
            terms = self._terms(si)
            x, y = self.ev.sample_uv(terms, sample1, sample2.x, sample2.y)
            r2 = x * x + y * y
            valid = active & (r2 < 1.0)
            if not ops_type.jit and not valid:
                return bs, mi.Spectrum(0.0)
            wo = mi.Vector3f(x, y, self.ev.ops.sqrt(1.0 - r2))
            valid = valid & (wo.z > 0)
            pdf = self._density(terms, wo)
            value = self._value(terms, si, wo, ctx)
            bs.wo = wo
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            if not ops_type.jit:
                if not pdf > 0:
                    return mi.BSDFSample3f(), mi.Spectrum(0.0)
                bs.pdf = pdf
                return bs, value / pdf
            valid = valid & (pdf > 0)
            bs.pdf = dr.select(valid, pdf, 0.0)
            return bs, dr.select(valid, value / dr.select(valid, pdf, 1.0), 0.0)

        def traverse(self, callback):
            pass

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            d = self.tables.diagnostics
            return (f"WaveBRDF[{d['tables']} tables ({d['scheme']}), {channels}, res {d['resolution']}, "
                    f"λ {d['wavelengths_um'][0]:g}–{d['wavelengths_um'][-1]:g} µm]")

    return WaveBRDF
