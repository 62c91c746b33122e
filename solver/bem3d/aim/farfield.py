"""Far field of the solved currents from AIM grid point sources, exactly on the output pixels.

The currents J and M = η₀M̃ are projected onto point sources h(p) on an AIM grid by far-field
matching at k₁ over the upper hemisphere (projection.py): Σ_p Λ_p e^{jk₁ r̂·p} reproduces
∫ψ e^{jk₁ r̂·r} dA of every rooftop for all outgoing directions r̂. Then (bem3d.md §9)

    F(r̂) = Σ_p h(p) e^{+jk₁ r̂·p} = Σ_l e^{jk₁ μ z_l} Σ_{i,j} h(x_i, y_j, z_l) e^{jk₁(u x_i + v y_j)}

is evaluated per z plane by two 1-D chirp-z transforms (solver/czt.py, the machinery of the
Kirchhoff model) directly at the projected-hemisphere pixel centres (u, v), and summed over
the planes with the exact phase e^{jk₁μ z_l}. No fixed periodic box, no padding choice and no
interpolation: the only approximation is the projection, whose error against the direct
quadrature sum (bem3d/farfield.py) is measured in the tests (< 1e-3).

E and H follow from F_J, F_M by bem3d/farfield.py's :func:`fields_from_integrals`.
"""

from __future__ import annotations

import logging

import numpy as np

from wavebrdf.solver.bem3d.aim.convolution import projection_matrices
from wavebrdf.solver.bem3d.aim.grid import GridOptions, build_grid
from wavebrdf.solver.bem3d.aim.projection import Projection, project
from wavebrdf.solver.bem3d.farfield import fields_from_integrals
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.bem3d.mesh import BEMMesh
from wavebrdf.solver.czt import ChirpZAxis
from wavebrdf.solver.farfield import ETA0, FarField, HemisphereGrid
from wavebrdf.solver.opencl import fft_workers

logger = logging.getLogger(__name__)

__all__ = ["FARFIELD_STENCIL", "GridFarField"]

FARFIELD_STENCIL = (4, 4, 4)  # with 1.5 S directions, order 3: error ~5e-6 vs the direct sum (docs/aim.md)
FARFIELD_ORDER = 3


class GridFarField:
    """Point-source far field of one mesh at one wavelength on a projected-hemisphere grid.

    ``grid_options``: the AIM grid of the point sources (default: Δ = 1.6 d and a 4 × 4 × 4
    stencil; a z stencil helps even on flat patches: the extra planes fit the grazing
    directions); ``directions`` (default 1.5 S), ``regularization``: far-field matching on the
    upper hemisphere. The chirp-z transforms run on ``solver.opencl.fft_workers()`` threads.
    """

    def __init__(self, mesh: BEMMesh, media: Media, output: HemisphereGrid, *, projection: Projection | None = None,
                 grid_options: GridOptions | None = None, directions: int | None = None,
                 regularization: float = 1e-5):
        self.mesh = mesh
        self.media = media
        self.output = output
        self.workers = fft_workers()
        k1 = media.k0 * media.exterior_index
        self.k = k1
        if projection is None:
            grid = build_grid(mesh, grid_options or GridOptions(stencil=FARFIELD_STENCIL))
            projection = project(mesh, grid, "farfield", k=k1, hemisphere=True, order=FARFIELD_ORDER,
                                 directions=directions or (3 * grid.stencil_size) // 2,
                                 regularization=regularization)
        elif projection.method != "farfield" or not np.isclose(projection.wavenumber[0], k1) or \
                len(projection.wavenumber) != 1:
            raise ValueError("the far field needs point sources far-field matched at the exterior wavenumber alone")
        self.grid = g = projection.grid
        self.projection = projection
        self._mats = projection_matrices(projection, mesh.n_horizontal, 3)  # x, y, z
        res = output.resolution
        s0, ds = -1.0 + 1.0 / res, 2.0 / res
        self.czt = [ChirpZAxis.plan(k1, g.lattice_start[a] * g.spacing[a], g.spacing[a], g.shape[a], s0, ds, res)
                    for a in (0, 1)]
        self.plane_heights = g.axis_coordinates(2)

    def point_sources(self, x: np.ndarray) -> np.ndarray:
        """Grid point sources h (P, 6, n_x, n_y, n_z) of [J_x, J_y, J_z, M_x, M_y, M_z], M = η₀M̃, in
        the projection's precision."""
        x = np.atleast_2d(x)
        nb = self.mesh.n_bases
        shape = self.grid.shape
        dtype = np.result_type(self._mats[0].dtype, np.complex64)
        out = np.empty((len(x), 6) + shape, dtype=dtype)
        for part, (xs, scale) in enumerate(((x[:, :nb], 1.0), (x[:, nb:], ETA0))):
            xs = np.ascontiguousarray(xs.T, dtype=dtype)
            for c, m in enumerate(self._mats):
                out[:, 3 * part + c] = scale * (m @ xs).T.reshape((len(x),) + shape)
        return out

    def radiation_integrals(self, x: np.ndarray, beyond: np.ndarray | None = None) -> np.ndarray:
        """F (P, 6, res, res) = Σ_p h(p) e^{jk₁ r̂·p} at every pixel (zero outside the disk), plus
        ``beyond`` (P, 6, res, res): the integrals of currents off the mesh (a flat continuation's).

        Streamed over the grid's z planes: two chirp-z transforms of one plane at a time, summed
        with the plane's phase e^{jk₁ μ z_l}, so no array holds every plane's transform."""
        h = self.point_sources(x)
        P = len(h)
        nx, ny, nz = self.grid.shape
        res = self.output.resolution
        mu = self.output.mu
        F = np.zeros((P, 6, res, res), dtype=complex)
        for level, z in enumerate(self.plane_heights):
            plane = h[..., level].reshape(P * 6, nx, ny)
            out = self.czt[0](plane, axis=1, workers=self.workers)
            out = self.czt[1](out, axis=2, workers=self.workers).reshape(P, 6, res, res)
            F += out * np.exp(1j * self.k * z * mu)
        if beyond is not None:
            F += beyond
        return np.where(self.output.inside, F, 0.0)

    def fields(self, x: np.ndarray, beyond: np.ndarray | None = None):
        """E, H (P, 3, res, res) on the output grid for solutions x (P, 2N_b) (and ``beyond``, as in
        ``radiation_integrals``)."""
        F = np.moveaxis(self.radiation_integrals(x, beyond), 1, -1)  # (P, res, res, 6)
        E, H = fields_from_integrals(self.media, self.output.directions[None], F[..., :3], F[..., 3:])
        inside = self.output.inside[None, :, :, None]
        return np.moveaxis(np.where(inside, E, 0.0), -1, 1), np.moveaxis(np.where(inside, H, 0.0), -1, 1)

    def farfield(self, x: np.ndarray, *, theta_i: float, phi_i: float, incident_power, diagnostics=None,
                 beyond: np.ndarray | None = None) -> FarField:
        """FarField (rows of ``x`` = polarizations s, p; ``beyond`` as in ``radiation_integrals``)."""
        E, H = self.fields(x, beyond)
        return FarField(grid=self.output, wavelength_um=self.media.wavelength_um,
                        exterior_index=self.media.exterior_index, theta_i=float(theta_i), phi_i=float(phi_i),
                        E=E, H=H, incident_power=incident_power, diagnostics=dict(diagnostics or {}))
