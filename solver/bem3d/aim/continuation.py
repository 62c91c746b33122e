"""Flat continuation: the surface goes on as the flat interface beyond the patch border.

A patch solve pins the currents to zero at the patch border (bem3d.md §14.7), so the beam must
have decayed there (margin ≥ 2.5 w). With the flat continuation the surface is the patch inside
and the flat interface z = 0 outside, and the currents outside the patch are those of the flat
interface under the same beam, known in closed form (every plane wave of the exact beam with its
Fresnel reflection). Only the patch's rooftops are unknowns. On the rooftop lattice of a large
flat mesh around the patch (the *extended* mesh, reaching where the beam's flux is below
``FLUX_LEFT``), the rooftops split into S (the patch's own, solved) and F (all others, fixed at
the flat-interface coefficients c_F), and the patch rows read

    Z_SS x_S = b_S − Z_SF c_F.

Z_SS is the patch's AIM operator. Z_SF c_F comes in two parts, both independent of the patch
solve: the rooftops of F within ``near_cells`` + 2 cells of the patch (the *ring*) through a full
AIM operator (near + grid) of the patch grown by that margin, and the rest through the grid part
alone of the extended mesh (those pairs lie beyond the near radius, where the AIM operator is
its grid part). The far field is that of x_S on the patch plus that of c_F on the whole plane
outside it (``radiation_beyond``: the whole plane's flat-interface currents in closed form, less
the patch rooftops' share), so the extended mesh's edge does not cut the far field.

Flat-interface currents (exterior side, normal n̂ = ẑ): J = ẑ × H, M = E × ẑ (unknowns J and
M̃ = M/η₀, mesh.py), with E, H the incident plus Fresnel-reflected fields at z = 0. On a flat
element a rooftop of coefficient c carries J·t̂ = 4c/d across its shared edge (mesh.py: the
half-basis weight 1 + u is 2 there and |r_u| = d/2), so c = d J·t̂ / 4 at the edge midpoint for
each plane wave, divided by the rooftop's form factor at its transverse wavevector (the Galerkin
solution's amplitude: ``rooftop_form_factor``).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from wavebrdf.solver.bem3d.aim.operator import AIMOperator, GridPart
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh, embedded_bases, unknown_indices
from wavebrdf.solver.farfield import ETA0
from wavebrdf.solver.surface import HeightField

__all__ = ["FLUX_LEFT", "FlatContinuation", "border_height", "check_flat_border", "embedded_mesh",
           "flat_interface_coefficients", "flat_interface_integrals", "flat_rooftop_integrals", "flux_beyond",
           "rooftop_form_factor"]

FLUX_LEFT = 1e-6  # beam flux (relative) allowed to fall outside the extended mesh
PHASE_BLOCK_BYTES = 64 * 2**20  # phases of one block of directions in flat_rooftop_integrals
BORDER_TOLERANCE = 0.05  # largest |border height − continuation plane| in cells d


def flat_interface_coefficients(mesh: BEMMesh, beam, media: Media) -> np.ndarray:
    """Rooftop coefficients [J | M̃] (2, 2N_b) of the flat-interface currents on ``mesh`` (taken
    as flat at z = 0): the exact ``beam`` and its Fresnel reflection (``ExactGaussianBeam.fields``
    with ``interface_index``), each plane wave over the form factor of the rooftops it is held on."""
    nb = mesh.n_bases
    d = mesh.spacing_um
    centres = mesh.basis_centres.copy()
    centres[:, 2] = 0.0
    horizontal = np.arange(nb) < mesh.n_horizontal
    kx, ky = beam.plane_waves["kvec"][:, 0], beam.plane_waves["kvec"][:, 1]
    z = np.array([0.0, 0.0, 1.0])
    x = np.empty((2, 2 * nb), dtype=complex)
    for rows, axis, form in ((horizontal, 0, rooftop_form_factor(kx, ky, d)),
                             (~horizontal, 1, rooftop_form_factor(ky, kx, d))):
        E, H = beam.fields(centres[rows], interface_index=complex(media.index), weights=1.0 / form)
        x[:, :nb][:, rows] = 0.25 * d * np.cross(z, H)[..., axis]
        x[:, nb:][:, rows] = 0.25 * d * np.cross(E, z)[..., axis] / ETA0
    return x


def flat_interface_integrals(beam, media: Media, kx, ky) -> np.ndarray:
    """Radiation integrals [F_J | F_M] (2, ..., 6), M = η₀M̃ (aim/farfield.py), of the flat-interface
    currents on the whole plane z = 0 under the continuous exact ``beam``, toward the outgoing
    directions of transverse wavevector (κx, κy) = k₁ r̂_t: the plane integral of J e^{jκ·ρ} picks the
    currents' spectral density, F = (2π)² (ẑ × Ĥ, Ê × ẑ)(κ) (``ExactGaussianBeam.interface_spectrum``)."""
    E, H = beam.interface_spectrum(kx, ky, complex(media.index))
    z = np.array([0.0, 0.0, 1.0])
    return (2.0 * np.pi) ** 2 * np.concatenate([np.cross(z, H), np.cross(E, z)], axis=-1)


def flat_rooftop_integrals(mesh: BEMMesh, x: np.ndarray, kx: np.ndarray, ky: np.ndarray, *,
                           separable: bool = False) -> np.ndarray:
    """Radiation integrals [F_J | F_M] (P, ..., 6), M = η₀M̃, of rooftop coefficients ``x`` (P, 2N_b)
    laid on ``mesh``'s lattice flat at z = 0: a rooftop of coefficient c at edge midpoint r_n
    radiates 4cd·(its form factor)·e^{jκ·r_n} along its current (``flat_interface_coefficients``).
    Toward (κx[i], κy[i]) (any shape); with ``separable``, toward the grid κx[i] × κy[j] (1-D
    axes, output (P, n_x, n_y, 6)) by two matrix products per component."""
    x = np.atleast_2d(x)
    nb, d = mesh.n_bases, mesh.spacing_um
    centres = mesh.basis_centres[:, :2]
    kx, ky = np.asarray(kx, dtype=float), np.asarray(ky, dtype=float)
    shape = (kx.size, ky.size) if separable else np.broadcast_shapes(kx.shape, ky.shape)
    out = np.zeros((len(x),) + shape + (6,), dtype=complex)
    horizontal = np.arange(nb) < mesh.n_horizontal
    for rows, axis in ((horizontal, 0), (~horizontal, 1)):
        r = centres[rows]
        if separable:
            form = rooftop_form_factor(*((kx[:, None], ky[None, :]) if axis == 0 else (ky[None, :], kx[:, None])), d)
            ux, ix = np.unique(r[:, 0], return_inverse=True)
            uy, iy = np.unique(r[:, 1], return_inverse=True)
            ex = np.exp(1j * np.outer(kx, ux))
            ey = np.exp(1j * np.outer(uy, ky))
        else:
            form = rooftop_form_factor(*((kx, ky) if axis == 0 else (ky, kx)), d)
        for part, offset in ((0, 0), (1, nb)):
            c = 4.0 * d * x[:, offset:offset + nb][:, rows] * (ETA0 if part else 1.0)
            if separable:
                lattice = np.zeros((len(x), len(ux), len(uy)), dtype=complex)
                lattice[:, ix, iy] = c
                summed = ex @ lattice @ ey
            else:
                summed = _phase_sums(kx, ky, r, c, shape)
            out[..., 3 * part + axis] = summed * form
    return out


def _phase_sums(kx, ky, points: np.ndarray, c: np.ndarray, shape) -> np.ndarray:
    """Σ_n c[p, n] e^{j(κx x_n + κy y_n)} (P, *shape), over blocks of directions of about
    PHASE_BLOCK_BYTES of phases."""
    KX, KY = (np.broadcast_to(k, shape).ravel() for k in (kx, ky))
    out = np.empty((len(c), KX.size), dtype=complex)
    block = max(1, PHASE_BLOCK_BYTES // (16 * max(1, len(points))))
    for s in range(0, KX.size, block):
        phase = np.exp(1j * (np.outer(KX[s:s + block], points[:, 0]) + np.outer(KY[s:s + block], points[:, 1])))
        out[:, s:s + block] = c @ phase.T
    return out.reshape((len(c),) + tuple(shape))


def rooftop_form_factor(k_along, k_across, spacing_um: float) -> np.ndarray:
    """Fourier transform of a flat rooftop relative to its value at κ = 0: sinc²(k_along d/2)
    sinc(k_across d/2) (a hat of half-width d along its current, a box of width d across it).

    The Galerkin currents of a plane wave of transverse wavevector κ on a flat rooftop mesh are its
    samples divided by this factor (they radiate the plane wave's amplitude); bare samples radiate
    it times the factor, 1 − (k_along² / 12 + k_across² / 24) d² toward grazing."""
    along = np.sinc(np.asarray(k_along) * spacing_um / (2 * np.pi))
    return along**2 * np.sinc(np.asarray(k_across) * spacing_um / (2 * np.pi))


def _border(z: np.ndarray) -> np.ndarray:
    """The corner heights on the border of a height grid, each once."""
    return np.concatenate([z[0], z[-1], z[1:-1, 0], z[1:-1, -1]])


def border_height(surface: HeightField) -> float:
    """Mean height of the patch border (µm): the plane the flat continuation goes on in."""
    return float(np.mean(_border(surface.z)))


def check_flat_border(heights: np.ndarray, spacing_um: float) -> None:
    """ValueError unless the border of ``heights`` (µm, relative to the continuation plane) lies
    in that plane within BORDER_TOLERANCE cells."""
    worst = float(np.max(np.abs(_border(heights))))
    if worst > BORDER_TOLERANCE * spacing_um:
        raise ValueError(
            f"aim.edge = 'flat' continues the surface as a plane at the patch border, but the border "
            f"heights leave that plane by up to {worst:.4g} µm (> {BORDER_TOLERANCE:g} d = "
            f"{BORDER_TOLERANCE * spacing_um:.4g} µm): use a patch whose border is flat, or aim.edge = 'pinned'")


def embedded_mesh(mesh: BEMMesh, margin: int) -> BEMMesh:
    """``mesh`` grown by ``margin`` flat cells on every side, at its reference height."""
    z0 = mesh.heights
    n = mesh.cells + 2 * margin
    z = np.zeros((n + 1, n + 1))
    z[margin : margin + mesh.cells + 1, margin : margin + mesh.cells + 1] = z0
    s = mesh.surface
    return BEMMesh(HeightField(z, n * s.spacing_um, s.origin_um), z_reference=0.0)


def extended_margin(mesh: BEMMesh, beam, minimum: int) -> int:
    """Cells to add on every side so that the beam's flux beyond the extended mesh is ≤ FLUX_LEFT
    (a Gaussian footprint of radius w about the focus: e^{−2R²/w²} at radius R, then checked)."""
    L, d = mesh.surface.size_um, mesh.spacing_um
    reach = beam.waist_um * math.sqrt(0.5 * math.log(1.0 / FLUX_LEFT)) + float(np.max(np.abs(beam.focus_um[:2])))
    margin = max(minimum, math.ceil((reach - 0.5 * L) / d))
    while beam.outside_fraction(L + 2 * margin * d) > FLUX_LEFT:
        margin = math.ceil(1.1 * margin) + 1
    return margin


def flux_beyond(beam, extent_um: float) -> float:
    """Share of one exact ``beam``'s incident flux crossing z = focus outside the extended mesh, a
    square of side ``extent_um`` about the patch centre: measured outside the largest square about
    the focus within it, for the same beam with a lattice period of ≥ 2.8 extents, so that its
    periodic copies do not fill the square (the margin's own check, ``extended_margin``, stops at
    the period where the tails of a beam cut by the light cone reach it)."""
    inside = extent_um - 2.0 * float(np.max(np.abs(beam.focus_um[:2])))
    return max(0.0, replace(beam, patch_size_um=4.0 * extent_um).outside_fraction(inside))


class FlatContinuation:
    """The fixed currents of a patch with flat continuation and their field on the patch rooftops,
    for one patch mesh, wavelength, material and AIM options (see the module docstring).

    ``mesh``'s heights must be relative to the continuation plane (``border_height``) and its
    border must lie in it (within BORDER_TOLERANCE cells), else ValueError.
    """

    def __init__(self, ctx, mesh: BEMMesh, media: Media, options, *, quadrature=None):
        t0 = time.perf_counter()
        check_flat_border(mesh.heights, mesh.spacing_um)
        self.ctx, self.mesh, self.media, self.options = ctx, mesh, media, options
        self.ring_cells = math.ceil(options.near_cells) + 2
        self.ring_mesh = embedded_mesh(mesh, self.ring_cells)
        # the ring's static tables are not kept for another wavelength (only the patch's are)
        self.ring_operator = AIMOperator(ctx, self.ring_mesh, media,
                                         replace(options, preconditioner="none", reuse_setup=False),
                                         quadrature=quadrature)
        self._patch_in_ring = embedded_bases(mesh.cells, self.ring_cells)
        self._extended: dict = {}
        self.setup_s = time.perf_counter() - t0

    def extended(self, margin: int):
        """(mesh, grid part, patch rooftops in it, ring-mesh rooftops in it) for ``margin`` cells."""
        if margin not in self._extended:
            ext = embedded_mesh(self.mesh, margin)
            self._extended = {margin: (ext, GridPart.build(self.ctx, ext, self.media, self.options),
                                       embedded_bases(self.mesh.cells, margin),
                                       embedded_bases(self.ring_mesh.cells, margin - self.ring_cells))}
        return self._extended[margin]

    def margin(self, beam) -> int:
        """Cells of flat interface around the patch that carry the beam's currents (≥ the ring)."""
        return extended_margin(self.mesh, beam, self.ring_cells + 2)

    def fixed_currents(self, beam, margin: int) -> tuple[np.ndarray, np.ndarray]:
        """(c_F on the extended mesh of ``margin`` cells with zeros on the patch rooftops (2, 2N_b,ext),
        Z_SF c_F on the patch rooftops (2, 2N_b)) for ``beam`` (an exact beam whose period covers
        the extended mesh)."""
        ext, grid_part, patch, ring = self.extended(margin)
        nb_ext, nb_ring = ext.n_bases, self.ring_mesh.n_bases
        c = flat_interface_coefficients(ext, beam, self.media)
        c[:, unknown_indices(patch, nb_ext)] = 0.0
        # ring rooftops: near + grid through the ring mesh's operator
        op = self.ring_operator
        y_ring = op.matvec(c[:, unknown_indices(ring, nb_ext)].astype(op.dtype))
        op.base.release_work()
        # the rest: grid part of the extended mesh (beyond the near radius of every patch rooftop)
        outer = c.copy()
        outer[:, unknown_indices(ring, nb_ext)] = 0.0
        y_outer = grid_part.base.apply(outer.astype(grid_part.base.complex))
        grid_part.base.release_work()  # one product per direction: its arrays are not worth keeping
        field = (y_ring[:, unknown_indices(self._patch_in_ring, nb_ring)]
                 + y_outer[:, unknown_indices(patch, nb_ext)])
        return c, field.astype(complex)

    def radiation_beyond(self, beam, kx, ky, *, separable: bool = False) -> np.ndarray:
        """Radiation integrals [F_J | F_M] (2, ..., 6) of the continued currents, every rooftop
        but the patch's on the whole plane, toward (κx, κy) (``flat_rooftop_integrals``' shapes): the
        whole plane's in closed form less the patch rooftops' flat-interface coefficients'. No
        mesh truncates them, so their far field does not depend on the margin."""
        KX, KY = np.meshgrid(kx, ky, indexing="ij") if separable else (kx, ky)
        whole = flat_interface_integrals(beam, self.media, KX, KY)
        own = flat_interface_coefficients(self.mesh, beam, self.media)
        return whole - flat_rooftop_integrals(self.mesh, own, kx, ky, separable=separable)

    def bytes(self) -> int:
        """Memory held: the ring operator and the extended mesh's grid part."""
        total = self.ring_operator.bytes()
        for _, grid_part, _, _ in self._extended.values():
            total += grid_part.base.bytes()
        return int(total)
