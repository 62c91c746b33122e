"""Beam steering (bem3d.md §10): dense incident directions from sub-area simulations.

1. **Basic directions.** The projected incidence disk is tiled by hexagons of circumradius
   R ≤ sin(λ_min/(π w)) (flat-topped lattice, centres inside the unit disk). Each requested
   direction belongs to the hexagon whose centre is nearest; the hexagon's basic direction is its
   centre, except that outer hexagons use the middle of the zenith range they cover, capped at
   80° (§10.1).
2. **Sub-areas.** M_x × M_y overlapping patches of side L_sub, shifted by s (default: the waist)
   so that the Gaussian footprints sum to a flat top; patch (a, b) is centred at
   p_ab = s·(a − (M_x−1)/2, b − (M_y−1)/2) in global coordinates and is cut from the global
   height field with the global mean as z reference. Each patch is simulated once per
   (wavelength, basic direction); its FarField is translated to global coordinates
   (e^{+jk p·ω_o}).
3. **Synthesis** of a requested ω_i: E = Σ a_ab E_ab with a_ab = e^{+jk p_ab·ω_i} (same for H);
   the incident power is that of the summed beams, a_ab·beam(x − p_ab), evaluated on the flat
   plane z = 0 of the global surface (§10.3). The result is valid while the steering offset
   |u_i − u_b| stays well inside the beam divergence λ/(π w): beyond it the array factor's
   grating lobes (spacing λ/s in direction cosine) alias the BRDF.

Nothing here is model-specific: models provide FarFields and their incident fields
(:meth:`wavebrdf.solver.models.Model.incident_fields`); only steerable models
(``Capabilities.steerable``) are accepted in a ``[steering]`` study. :func:`synthesize_task`
and :func:`estimate_synthesis` are the "synth" task kind of jobs/tasks.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wavebrdf.solver.farfield import FarField
from wavebrdf.solver.models import Estimate
from wavebrdf.solver.surface import HeightField

__all__ = [
    "GRAZING_CAP_DEG",
    "HexagonTiling",
    "PatchLayout",
    "aliasing_limit",
    "estimate_synthesis",
    "synthesize",
    "synthesize_task",
    "synthesized_incident_power",
]

GRAZING_CAP_DEG = 80.0


def aliasing_limit(wavelength_um: float, waist_um: float, exterior_index: float = 1.0) -> float:
    """Steering offset (direction cosine) where aliasing sets in: λ₁/(π w)."""
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


@dataclass(frozen=True)
class PatchLayout:
    """M_x × M_y sub-areas of side ``patch_size_um`` shifted by ``shift_um`` on a global surface."""

    counts: tuple[int, int]
    patch_size_um: float
    shift_um: float

    def __post_init__(self):
        if min(self.counts) < 1:
            raise ValueError(f"steering.patches must be >= 1 in each direction, got {self.counts}")
        if not (self.patch_size_um > 0 and self.shift_um > 0):
            raise ValueError("steering.patch_size_um and shift_um must be > 0")

    @classmethod
    def auto(cls, global_size_um: float, patch_size_um: float, shift_um: float) -> "PatchLayout":
        """As many patches per side as fit on the global surface."""
        m = int(np.floor((global_size_um - patch_size_um) / shift_um + 1e-9)) + 1
        if m < 1:
            raise ValueError(
                f"steering.patch_size_um = {patch_size_um} does not fit on the {global_size_um} µm surface"
            )
        return cls((m, m), patch_size_um, shift_um)

    @property
    def indices(self) -> list[tuple[int, int]]:
        return [(a, b) for a in range(self.counts[0]) for b in range(self.counts[1])]

    def centre(self, patch: tuple[int, int]) -> np.ndarray:
        """Patch centre p_ab (µm, global coordinates, z = 0)."""
        a, b = patch
        mx, my = self.counts
        return np.array([self.shift_um * (a - (mx - 1) / 2), self.shift_um * (b - (my - 1) / 2), 0.0])

    @property
    def span_um(self) -> float:
        """Side of the square the patches cover."""
        return self.patch_size_um + (max(self.counts) - 1) * self.shift_um

    def check(self, surface: HeightField) -> None:
        """Raise ValueError unless every patch lies on ``surface`` on whole grid cells."""
        d = surface.spacing_um
        for name, value in (("patch_size_um", self.patch_size_um), ("shift_um", self.shift_um)):
            if abs(value / d - round(value / d)) > 1e-6:
                raise ValueError(
                    f"steering.{name} = {value} is not a multiple of the surface spacing {d:g} µm"
                )
        if self.span_um > surface.size_um + 1e-9:
            raise ValueError(
                f"{self.counts[0]}x{self.counts[1]} patches of {self.patch_size_um} µm shifted by "
                f"{self.shift_um} µm span {self.span_um:g} µm, more than the {surface.size_um:g} µm surface"
            )

    def cut(self, surface: HeightField, patch: tuple[int, int]) -> HeightField:
        """The patch's height field (local coordinates centred on p_ab; heights unchanged)."""
        d = surface.spacing_um
        cells = int(round(self.patch_size_um / d))
        centre = self.centre(patch)
        start = [int(round((c + surface.size_um / 2 - self.patch_size_um / 2) / d)) for c in centre[:2]]
        z = surface.z[start[0] : start[0] + cells + 1, start[1] : start[1] + cells + 1]
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
    n_global = n_patch + (max(mx, my) - 1) * shift
    E = np.zeros(E_b.shape[:2] + (n_global, n_global), dtype=complex)
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
    power = synthesized_incident_power(
        lambda pts: model.incident_fields(basic_scene, pts), st.layout, basic_scene.surface.spacing_um,
        basic_scene.wavelength_um, basic_scene.exterior_index, theta, phi,
    )
    ff = synthesize(fields, st.layout, theta, phi, power)
    ff.diagnostics["steering_offset"] = float(np.hypot(
        *(np.sin(theta) * np.array([np.cos(phi), np.sin(phi)])
          - np.sin(basic_scene.theta_i) * np.array([np.cos(basic_scene.phi_i), np.sin(basic_scene.phi_i)]))))
    return ff


def estimate_synthesis(plan, task) -> Estimate:
    """Reading and summing the patch far fields of one requested direction."""
    res = plan.grid.resolution
    n = len(task.depends)
    field_bytes = 2 * 6 * 16.0 * res * res
    return Estimate(3 * field_bytes + 100e6, 2e-8 * n * res * res + 0.05 * n, f"sum of {n} patch fields")
