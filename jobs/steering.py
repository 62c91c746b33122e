"""Beam steering (bem3d.md §10): dense incident directions from sub-area simulations.

1. **Basic directions.** The projected incidence disk is tiled by hexagons of circumradius
   R ≤ sin(λ_min/(π w)) (flat-topped lattice, centres inside the unit disk). Each requested
   direction belongs to the hexagon whose centre is nearest; the hexagon's basic direction is its
   centre, except that outer hexagons use the middle of the zenith range they cover, capped at
   80° (§10.1).
2. **Sub-areas.** M_x × M_y overlapping patches of side L_sub, shifted by s (default: the waist)
   so that the Gaussian footprints sum to a flat top; patch (a, b) is centred at
   p_ab = s·(a − (M_x−1)/2, b − (M_y−1)/2) in global coordinates and is cut from the global
   height field with the global mean as z reference. The global surface may be rectangular
   (the reference simulator's ``-x ≠ -y``: :class:`GlobalSurface`, used only to cut square
   patches from; every model sees square :class:`HeightField` patches). Each patch is simulated once per
   (wavelength, basic direction); its FarField is translated to global coordinates
   (e^{+jk p·ω_o}).
3. **Synthesis** of a requested ω_i: E = Σ a_ab E_ab with a_ab = e^{+jk p_ab·ω_i} (same for H);
   the incident power is that of the summed beams, a_ab·beam(x − p_ab), evaluated on the flat
   plane z = 0 of the global surface (§10.3). The patch beams carry the basic direction's ŝ, p̂; the
   synthesis answers the requested direction's (``polarimetry.in_stated_frame``), so its s, p,
   Jones and Mueller figures are all in ω_i's frame. The result is valid while the steering offset
   |u_i − u_b| stays well inside the beam divergence λ/(π w): beyond it the array factor's
   grating lobes (spacing λ/s in direction cosine) alias the BRDF.

Nothing here is model-specific: models provide FarFields and their incident fields
(:meth:`wavebrdf.solver.models.Model.incident_fields`); only steerable models
(``Capabilities.steerable``) are accepted in a ``[steering]`` study. :func:`synthesize_task`
and :func:`estimate_synthesis` are the "synth" task kind of jobs/tasks.py.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from wavebrdf.jobs.parts import SYNTHESIS_FRAME
from wavebrdf.solver.farfield import FarField
from wavebrdf.solver.metrics import direction_to_u
from wavebrdf.solver.models import Estimate
from wavebrdf.solver.polarimetry import in_stated_frame
from wavebrdf.solver.validity import ValidityWarning, steered_fresnel_warning
from wavebrdf.solver.surface import GaussianEnsemble, HeightField, SurfaceError, checked_heights, generate

__all__ = [
    "GRAZING_CAP_DEG",
    "GlobalSurface",
    "HexagonTiling",
    "PatchLayout",
    "aliasing_limit",
    "estimate_synthesis",
    "synthesize",
    "synthesize_task",
    "synthesized_incident_power",
    "surface_sides_um",
]

GRAZING_CAP_DEG = 80.0


def aliasing_limit(wavelength_um: float, waist_um: float, exterior_index: float = 1.0) -> float:
    """The footprint's angular spread λ₁/(π w) (radians), whose sine is the steering offset (in
    direction cosines) where aliasing sets in."""
    return wavelength_um / exterior_index / (np.pi * waist_um)


@dataclass(frozen=True)
class HexagonTiling:
    """Hexagon territories of circumradius ``radius`` in the projected disk."""

    radius: float

    @classmethod
    def for_beam(cls, wavelength_min_um: float, waist_um: float, exterior_index: float = 1.0,
                 fill: float = 0.97) -> "HexagonTiling":
        """The largest safe radius, shrunk by ``fill``: R = fill · sin(λ_min/(π w))."""
        return cls(fill * np.sin(aliasing_limit(wavelength_min_um, waist_um, exterior_index)))

    @property
    def centres(self) -> np.ndarray:
        """(K, 2) hexagon centres inside the unit disk, (0, 0) first."""
        r = self.radius
        a1 = np.array([1.5 * r, np.sqrt(3) / 2 * r])
        a2 = np.array([0.0, np.sqrt(3) * r])
        n = int(np.ceil(2.0 / r)) + 2
        i, j = np.meshgrid(np.arange(-n, n + 1), np.arange(-n, n + 1), indexing="ij")
        pts = i.reshape(-1, 1) * a1 + j.reshape(-1, 1) * a2
        pts = pts[np.sum(pts**2, axis=1) <= 1.0]
        order = np.lexsort((np.arctan2(pts[:, 1], pts[:, 0]), np.round(np.hypot(*pts.T), 12)))
        return pts[order]

    def basic_direction(self, centre: np.ndarray) -> tuple[float, float]:
        """(θ_b, φ_b) in radians of the hexagon with ``centre`` (§10.1)."""
        rho = float(np.hypot(*centre))
        phi = float(np.arctan2(centre[1], centre[0])) % (2 * np.pi)
        if rho <= self.radius:
            return float(np.arcsin(rho)), phi
        cap = np.sin(np.deg2rad(GRAZING_CAP_DEG))
        theta = 0.5 * (np.arcsin(rho - self.radius) + np.arcsin(min(rho + self.radius, cap)))
        return float(theta), phi

    def assign(self, directions_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For (n, 2) requested (θ, φ): the index of each one's basic direction (into the
        returned list) and the (K_used, 2) basic directions (θ_b, φ_b) actually needed."""
        centres = self.centres
        theta, phi = np.asarray(directions_rad, dtype=float).T
        proj = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi)], axis=1)
        nearest = np.argmin(np.sum((proj[:, None, :] - centres[None]) ** 2, axis=2), axis=1)
        used, which = np.unique(nearest, return_inverse=True)
        basics = np.array([self.basic_direction(centres[c]) for c in used])
        return which, basics


def surface_sides_um(surface) -> tuple[float, float]:
    """(L_x, L_y) of a square :class:`HeightField` or a rectangular :class:`GlobalSurface` (µm)."""
    sides = getattr(surface, "sides_um", None)
    return tuple(map(float, sides)) if sides is not None else (float(surface.size_um), float(surface.size_um))


@dataclass(frozen=True)
class GlobalSurface:
    """A rectangular global surface for steering: corner heights ``z`` (µm, shape (N_x+1, N_y+1),
    row index ↔ x, column ↔ y as in :class:`HeightField`) on L_x × L_y = ``sides_um``, centred on
    the origin, with square cells d = L_x/N_x = L_y/N_y.

    Only :class:`PatchLayout` uses it: it cuts square patches (HeightFields) from it; the models
    never see it. It offers what the steering layer and the dataset writer read from a global
    surface: ``z``, ``spacing_um``, ``size_um`` (L_x: the side along the rows, so that
    spacing = size_um / (rows − 1) as for a square field), :meth:`statistics`, ``parameters``,
    ``ensemble``. Square inputs stay :class:`HeightField`.
    """

    z: np.ndarray
    sides_um: tuple[float, float]
    ensemble: GaussianEnsemble | None = field(default=None, compare=False)
    parameters: dict | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        z = checked_heights(self.z, square=False)
        sides = tuple(float(v) for v in self.sides_um)
        if len(sides) != 2 or not all(np.isfinite(v) and v > 0 for v in sides):
            raise SurfaceError(f"surface size_um must be [L_x, L_y] with two numbers > 0, got {self.sides_um!r}")
        dx, dy = sides[0] / (z.shape[0] - 1), sides[1] / (z.shape[1] - 1)
        if abs(dx - dy) > 1e-9 * max(dx, dy):
            raise SurfaceError(f"cells must be square: size_um = [{sides[0]:g}, {sides[1]:g}] over "
                               f"{z.shape[0] - 1}x{z.shape[1] - 1} cells gives spacings {dx:.6g} (x) and "
                               f"{dy:.6g} (y) µm")
        object.__setattr__(self, "z", z)
        object.__setattr__(self, "sides_um", sides)

    @classmethod
    def generated(cls, name: str, *, cells: tuple[int, int], sides_um: tuple[float, float], seed: int = 0,
                  **params) -> "GlobalSurface":
        """Generator ``name`` (solver/surface.py) on the square of the longer side at the same
        spacing, cropped to N_x × N_y cells from its corner (−L/2, −L/2). The crop keeps the
        generator's ensemble; it is no longer periodic along the cropped axis."""
        nx, ny = (int(c) for c in cells)
        side, n = (sides_um[0], nx) if nx >= ny else (sides_um[1], ny)
        square = generate(name, cells=n, size_um=float(side), seed=seed, **params)
        recorded = dict(square.parameters or {})
        recorded.update({"cells": [nx, ny], "size_um": [float(sides_um[0]), float(sides_um[1])],
                         "generated_square_cells": n, "periodic": ""})
        return cls(square.z[: nx + 1, : ny + 1].copy(), (float(sides_um[0]), float(sides_um[1])),
                   ensemble=square.ensemble, parameters=recorded)

    @property
    def size_um(self) -> float:
        """L_x (µm), the side along the rows (the dataset stores it with the x/y node scales)."""
        return self.sides_um[0]

    @property
    def cells(self) -> tuple[int, int]:
        """(N_x, N_y)."""
        return self.z.shape[0] - 1, self.z.shape[1] - 1

    @property
    def spacing_um(self) -> float:
        return self.sides_um[0] / (self.z.shape[0] - 1)

    @property
    def x(self) -> np.ndarray:
        return -0.5 * self.sides_um[0] + self.spacing_um * np.arange(self.z.shape[0])

    @property
    def y(self) -> np.ndarray:
        return -0.5 * self.sides_um[1] + self.spacing_um * np.arange(self.z.shape[1])

    def statistics(self) -> dict[str, float]:
        """As :meth:`HeightField.statistics` for a non-periodic field: rms height and
        peak-to-valley of the nodes, rms / max slope of the bilinear surface (cell centres), and
        the 1/e lengths of the linear (zero-padded) autocorrelation along x and y (µm; NaN where
        it does not fall to 1/e within half the side)."""
        z, d = self.z, self.spacing_um
        zx = 0.5 * (z[1:, 1:] + z[1:, :-1] - z[:-1, 1:] - z[:-1, :-1]) / d
        zy = 0.5 * (z[1:, 1:] - z[1:, :-1] + z[:-1, 1:] - z[:-1, :-1]) / d
        slope = np.hypot(zx, zy)
        h = z - z.mean()
        lengths = []
        for axis in (0, 1):
            n = 2 * h.shape[axis]
            spectrum = np.fft.rfft(h, n=n, axis=axis)
            acf = np.fft.irfft(np.abs(spectrum) ** 2, n=n, axis=axis).sum(axis=1 - axis)
            half = acf[: (h.shape[axis] - 1) // 2 + 1]
            lengths.append(_one_over_e_length(half, d))
        return {
            "rms_height_um": float(np.sqrt(np.mean(h**2))),
            "peak_to_valley_um": float(np.ptp(h)),
            "rms_slope": float(np.sqrt(np.mean(slope**2))),
            "max_slope": float(slope.max()),
            "correlation_length_x_um": lengths[0],
            "correlation_length_y_um": lengths[1],
        }


def _one_over_e_length(acf: np.ndarray, spacing_um: float) -> float:
    """Lag (µm) where ``acf``/``acf[0]`` first falls to 1/e, linearly interpolated; NaN if never."""
    if not acf[0] > 0:
        return float("nan")
    values = acf / acf[0]
    below = np.nonzero(values <= np.exp(-1.0))[0]
    if below.size == 0:
        return float("nan")
    i = int(below[0])
    return float((i - 1 + (values[i - 1] - np.exp(-1.0)) / (values[i - 1] - values[i])) * spacing_um)


@dataclass(frozen=True)
class PatchLayout:
    """M_x × M_y sub-areas of side ``patch_size_um`` shifted by ``shift_um`` on a global surface
    (square :class:`HeightField` or rectangular :class:`GlobalSurface`), centred on it, moved by
    ``offset_um`` (µm): :meth:`for_surface` moves it by −d/2 along an axis where the centred
    layout would leave half a cell over on each side, so that patch nodes are surface nodes."""

    counts: tuple[int, int]
    patch_size_um: float
    shift_um: float
    offset_um: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        if len(self.counts) != 2 or any(isinstance(m, bool) or not isinstance(m, (int, np.integer))
                                        for m in self.counts):
            raise ValueError(f"steering.patches must be two integers [mx, my], got {list(self.counts)}")
        if min(self.counts) < 1:
            raise ValueError(f"steering.patches must be >= 1 in each direction, got {self.counts}")
        if not (self.patch_size_um > 0 and self.shift_um > 0):
            raise ValueError("steering.patch_size_um and shift_um must be > 0")
        object.__setattr__(self, "counts", (int(self.counts[0]), int(self.counts[1])))

    @staticmethod
    def _fitting(side_um: float, patch_size_um: float, shift_um: float, axis: str) -> int:
        m = int(np.floor((side_um - patch_size_um) / shift_um + 1e-9)) + 1
        if m < 1:
            raise ValueError(f"steering.patch_size_um = {patch_size_um:g} does not fit on the {side_um:g} µm "
                             f"side of the surface along {axis}")
        return m

    @classmethod
    def auto(cls, global_size_um, patch_size_um: float, shift_um: float) -> "PatchLayout":
        """As many patches per side as fit on the global surface (``global_size_um``: L, or
        (L_x, L_y) for a rectangle)."""
        sides = np.broadcast_to(np.asarray(global_size_um, dtype=float), (2,))
        return cls(tuple(cls._fitting(float(s), patch_size_um, shift_um, a) for s, a in zip(sides, "xy")),
                   patch_size_um, shift_um)

    @classmethod
    def for_surface(cls, surface, patches, patch_size_um: float, shift_um: float) -> "PatchLayout":
        """The layout of ``[steering] patches`` on ``surface``: ``"auto"`` (as many as fit along
        each axis), or [mx, my] where either may be ``"auto"``."""
        sides = surface_sides_um(surface)
        wanted = ("auto", "auto") if patches == "auto" else tuple(patches)
        counts = tuple(cls._fitting(side, patch_size_um, shift_um, axis) if m == "auto" else m
                       for m, side, axis in zip(wanted, sides, "xy"))
        layout = cls(counts, patch_size_um, shift_um)
        starts, d = layout._starts(surface)  # nodes left over before patch 0: k/2 for whole-cell sizes
        offset = tuple(-0.5 * d if abs(s - round(s)) > 1e-6 and abs(2 * s - round(2 * s)) < 1e-6 else 0.0
                       for s in starts)
        return cls(counts, patch_size_um, shift_um, offset)

    @property
    def indices(self) -> list[tuple[int, int]]:
        return [(a, b) for a in range(self.counts[0]) for b in range(self.counts[1])]

    def centre(self, patch: tuple[int, int]) -> np.ndarray:
        """Patch centre p_ab (µm, global coordinates, z = 0)."""
        a, b = patch
        mx, my = self.counts
        return np.array([self.offset_um[0] + self.shift_um * (a - (mx - 1) / 2),
                         self.offset_um[1] + self.shift_um * (b - (my - 1) / 2), 0.0])

    @property
    def spans_um(self) -> tuple[float, float]:
        """Extent (x, y) the patches cover (µm)."""
        return tuple(self.patch_size_um + (m - 1) * self.shift_um for m in self.counts)

    @property
    def span_um(self) -> float:
        """The longer of :attr:`spans_um`."""
        return max(self.spans_um)

    def _starts(self, surface) -> tuple[list[float], float]:
        """First node (fractional index) of patch (0, 0) along x and y, and the spacing."""
        d = surface.spacing_um
        return [((side - span) / 2 + off) / d
                for side, span, off in zip(surface_sides_um(surface), self.spans_um, self.offset_um)], d

    def check(self, surface) -> None:
        """Raise ValueError unless every patch lies on ``surface`` on whole grid cells."""
        d = surface.spacing_um
        for name, value in (("patch_size_um", self.patch_size_um), ("shift_um", self.shift_um)):
            if abs(value / d - round(value / d)) > 1e-6:
                raise ValueError(
                    f"steering.{name} = {value} is not a multiple of the surface spacing {d:g} µm"
                )
        sides = surface_sides_um(surface)
        for axis, side, span, m in zip("xy", sides, self.spans_um, self.counts):
            if span > side + 1e-9:
                what = (f"{side:g} µm surface" if sides[0] == sides[1]
                        else f"{side:g} µm side of the surface along {axis}")
                raise ValueError(
                    f"{self.counts[0]}x{self.counts[1]} patches of {self.patch_size_um} µm shifted by "
                    f"{self.shift_um} µm span {span:g} µm along {axis}, more than the {what}"
                )
        starts, _ = self._starts(surface)
        for axis, start, side, span in zip("xy", starts, sides, self.spans_um):
            if abs(start - round(start)) > 1e-6 or start < -1e-6:
                raise ValueError(
                    f"the patches span {span:g} µm along {axis} on the {side:g} µm side: placed as given they "
                    f"start {start * d:g} µm after its edge, not a whole number of cells of {d:g} µm, so the "
                    "patches' nodes would fall between the surface's (PatchLayout.for_surface places them)"
                )

    def cut(self, surface, patch: tuple[int, int]) -> HeightField:
        """The patch's square height field (local coordinates centred on p_ab; heights unchanged)
        from a square or rectangular global ``surface``: nodes
        [s_x + a·shift, s_x + a·shift + n] × [s_y + b·shift, ...] with n = patch/d and s the
        margin of the centred layout (:meth:`check` guarantees whole cells)."""
        starts, d = self._starts(surface)
        cells = int(round(self.patch_size_um / d))
        shift = int(round(self.shift_um / d))
        i0, j0 = (int(round(s)) + k * shift for s, k in zip(starts, patch))
        z = surface.z[i0 : i0 + cells + 1, j0 : j0 + cells + 1]
        if z.shape != (cells + 1, cells + 1):
            raise ValueError(f"patch {tuple(patch)} does not lie on the surface (layout {self.counts})")
        centre = self.centre(patch)
        return HeightField(z.copy(), self.patch_size_um, origin_um=(float(centre[0]), float(centre[1])))


def synthesize(patch_fields: dict, layout: PatchLayout, theta_i: float, phi_i: float,
               incident_power: np.ndarray) -> FarField:
    """Σ_ab e^{+jk p_ab·ω_i} E_ab for FarFields already translated to global coordinates."""
    first = next(iter(patch_fields.values()))
    k = first.wavenumber
    omega_i = np.array([np.sin(theta_i) * np.cos(phi_i), np.sin(theta_i) * np.sin(phi_i), np.cos(theta_i)])
    E = np.zeros_like(first.E)
    H = None if first.H is None else np.zeros_like(first.H)
    for patch, ff in patch_fields.items():
        weight = np.exp(1j * k * float(layout.centre(patch) @ omega_i))
        E += weight * ff.E
        if H is not None:
            H += weight * ff.H
    return FarField(
        grid=first.grid, wavelength_um=first.wavelength_um, exterior_index=first.exterior_index,
        theta_i=theta_i, phi_i=phi_i, E=E, H=H, incident_power=incident_power,
        diagnostics={"patches": len(patch_fields)},
    )


@dataclass(frozen=True)
class RungGroup:
    """The patch fields one rung computed for a synthesis, whether its patch beams are exact
    (True: bem, po lit by the beam) or locally plane footprints (False), and the incident power
    (W, per polarization) of the summed patch beams of that rung's kind (``synthesized_incident_power``)."""

    patch_fields: dict
    exact_beam: bool
    incident_power: np.ndarray


def synthesize_in_stated_frame(groups: list[RungGroup], layout: PatchLayout, theta_i: float, phi_i: float,
                               excited_rad: tuple[float, float]) -> FarField:
    """:func:`synthesize` answering the requested direction's s and p, per unit incident power:
    the patch beams carry the excited (basic) direction's polarizations; each rung's sub-areas are
    summed, divided by the power of its own kind of summed beam and carried to the requested frame
    by its own frame change (``polarimetry.steered_frame_change``: the exact beams' projection or
    the footprints' rotation), then the groups are added (in the first group's power). One group:
    a single rung; several: ``auto`` with mixed rungs."""
    parts = [in_stated_frame(synthesize(g.patch_fields, layout, theta_i, phi_i, g.incident_power), excited_rad,
                             beam=g.exact_beam) for g in groups]
    total = parts[0]
    for part in parts[1:]:
        scale = float(np.sqrt(total.incident_power[0] / part.incident_power[0]))  # both powers equal per part
        total.E += scale * part.E
        # H where every rung gave it (bem does; the footprint rungs and po do not)
        total.H = None if total.H is None or part.H is None else total.H + scale * part.H
    total.diagnostics["patches"] = sum(len(g.patch_fields) for g in groups)
    return total


def synthesized_incident_power(incident_fields, layout: PatchLayout, spacing_um: float, wavelength_um: float,
                               exterior_index: float, theta_i: float, phi_i: float) -> np.ndarray:
    """Φ_i (per polarization) of Σ_ab a_ab·beam(x − p_ab) through the plane z = 0.

    ``incident_fields(points)`` returns the basic-direction beam of one patch (patch-local
    coordinates, (…, 3) points) as (E, H), each (2, 3, …). The beam is evaluated once on a grid
    of cell centres covering the patch, then shifted (whole cells) and summed with the phases.
    """
    d = spacing_um
    n_patch = int(round(layout.patch_size_um / d))
    shift = int(round(layout.shift_um / d))
    local = (np.arange(n_patch) + 0.5) * d - layout.patch_size_um / 2
    X, Y = np.meshgrid(local, local, indexing="ij")
    E_b, H_b = incident_fields(np.stack([X, Y, np.zeros_like(X)], axis=-1))
    k = 2 * np.pi * exterior_index / wavelength_um
    omega_i = np.array([np.sin(theta_i) * np.cos(phi_i), np.sin(theta_i) * np.sin(phi_i), np.cos(theta_i)])
    mx, my = layout.counts
    E = np.zeros(E_b.shape[:2] + (n_patch + (mx - 1) * shift, n_patch + (my - 1) * shift), dtype=complex)
    H = np.zeros_like(E)
    for a, b in layout.indices:
        weight = np.exp(1j * k * float(layout.centre((a, b)) @ omega_i))
        sl = (slice(None), slice(None), slice(a * shift, a * shift + n_patch), slice(b * shift, b * shift + n_patch))
        E[sl] += weight * E_b
        H[sl] += weight * H_b
    S_z = 0.5 * np.real(E[:, 0] * np.conj(H[:, 1]) - E[:, 1] * np.conj(H[:, 0]))
    return d * d * np.sum(np.abs(S_z), axis=(-2, -1))


def synthesize_task(ctx, plan, task, pool, parts) -> FarField:
    """The far field of a requested direction from the saved patch fields of its basic direction,
    with the incident power of the summed patch beams (the "synth" task kind)."""
    st = plan.steering[task.case]
    model = pool.get(plan.model_spec(task))
    fields = {tuple(p.patch): parts.load_farfield(p) for p in (plan.tasks[i] for i in task.depends)}
    basic_scene = plan.scene(task, basic=task.basic)
    theta, phi = plan.direction_rad(task)
    by_rung = {}
    for patch, patch_field in fields.items():
        rung = _patch_rung(model, patch_field)
        by_rung.setdefault(rung.name, (rung, {}))[1][patch] = patch_field
    groups = [RungGroup(group, rung.steered_fresnel() is None, synthesized_incident_power(
        lambda pts, rung=rung: rung.incident_fields(basic_scene, pts), st.layout, basic_scene.surface.spacing_um,
        basic_scene.wavelength_um, basic_scene.exterior_index, theta, phi)) for _, (rung, group) in sorted(by_rung.items())]
    kept = _kept_fresnel(model, fields)
    ff = synthesize_in_stated_frame(groups, st.layout, theta, phi, (basic_scene.theta_i, basic_scene.phi_i))
    ff.diagnostics["polarization_frame"] = SYNTHESIS_FRAME
    offset = float(np.hypot(*(direction_to_u(theta, phi) - direction_to_u(basic_scene.theta_i, basic_scene.phi_i))))
    limit = np.sin(aliasing_limit(basic_scene.wavelength_um, basic_scene.waist_um, basic_scene.exterior_index))
    ff.diagnostics.update(steering_offset=offset, steering_offset_over_limit=offset / limit)
    name = plan.model_spec(task).name
    if offset > limit:
        warnings.warn(f"{name}: steered {offset:.3g} in direction cosines from its basic direction, "
                      f"{offset / limit:.2f}× the aliasing limit sin(λ₁/(πw)) = {limit:.3g} at λ = "
                      f"{basic_scene.wavelength_um:g} µm: grating lobes of the patch array carry part of the power "
                      "(a flat mirror lost 55 % to them at 1.6×, docs/batch.md); use a smaller [steering] "
                      "hexagon_fill", ValidityWarning, stacklevel=2)
    if kept is not None:
        said = steered_fresnel_warning(name, kept, basic_scene, theta, phi, stored_polarizations(plan.study))
        if said:
            warnings.warn(said, ValidityWarning, stacklevel=2)
    return ff


def _patch_rung(model, patch_field: FarField):
    """The model that computed one patch field: under ``auto``, the rung named in its diagnostics."""
    name = patch_field.diagnostics.get("model")
    if not model.capabilities.picks_rung or name in (None, model.name):
        return model
    return model.rung(name)


def _kept_fresnel(model, fields: dict) -> str | None:
    """Where the patch fields' rungs take their Fresnel factors (``Model.steered_fresnel``;
    under ``auto`` each patch's own rung), "incidence" first."""
    kinds = {_patch_rung(model, ff).steered_fresnel() for ff in fields.values()} - {None}
    return "incidence" if "incidence" in kinds else next(iter(kinds), None)


def stored_polarizations(study) -> tuple[str, ...]:
    """The incident polarizations whose figures a study stores: its [illumination] polarization,
    and s and p too with per-polarization or polarimetric outputs."""
    stored = (study.illumination.polarization,)
    if study.output_options.per_polarization or study.output_options.polarization != "intensity":
        stored += ("s", "p")
    return tuple(dict.fromkeys(stored))


def estimate_synthesis(plan, task) -> Estimate:
    """Reading and summing the patch far fields of one requested direction."""
    res = plan.grid.resolution
    n = len(task.depends)
    field_bytes = 2 * 6 * 16.0 * res * res
    return Estimate(3 * field_bytes + 100e6, 2e-8 * n * res * res + 0.05 * n, f"sum of {n} patch fields")
