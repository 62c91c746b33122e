"""Full-wave 3D solver: PMCHWT boundary elements on height fields (bem3d.md; docs/bem3d.md).

Public entry points:

* :func:`bem_farfield` — one simulation (surface, wavelength, index, incident direction, beam)
  → :class:`~wavebrdf.solver.farfield.FarField` (model "bem", method "dense");
* :class:`DenseBEM` — assemble and factorize once, then any number of directions/beams;
* :func:`estimate_dense` — unknowns, memory and flops of the dense path for planning;
* :class:`BEMWarning` and its subclasses — the situations that are reported, not hidden.

Modules: mesh (elements, rooftops, unknown ordering), quadrature (Gauss–Legendre, singular
transforms, order rules), elements (element-pair integrals: OpenCL + NumPy twins), assembly
(basis-pair entries for any list of pairs, dense Z), excitation (right-hand sides, surface
currents), farfield (radiated far field), dense (LU solve), media, checks (warnings).
"""

from wavebrdf.solver.bem3d.checks import (
    BEMWarning,
    FootprintWarning,
    MaterialWarning,
    ResolutionWarning,
    SolverWarning,
)
from wavebrdf.solver.bem3d.dense import DenseBEM, DenseTooLarge, bem_farfield, estimate_dense
from wavebrdf.solver.bem3d.quadrature import QuadratureOptions

__all__ = [
    "BEMWarning",
    "DenseBEM",
    "DenseTooLarge",
    "FootprintWarning",
    "MaterialWarning",
    "QuadratureOptions",
    "ResolutionWarning",
    "SolverWarning",
    "bem_farfield",
    "estimate_dense",
]
