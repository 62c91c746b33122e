"""Full-wave 3D solver: PMCHWT boundary elements on height fields (bem3d.md; docs/bem3d.md, docs/aim.md).

Public entry points:

* :func:`bem_farfield` — one simulation (surface, wavelength, index, incident direction, beam)
  → :class:`~wavebrdf.solver.farfield.FarField` (model "bem", method "dense" or "aim");
* :class:`BEMSolver` — build the operator once (dense LU or AIM), then any number of
  directions/beams;
* :func:`estimate_dense`, :func:`estimate_aim` — unknowns, memory and time for planning;
* :class:`AIMOptions`, :class:`QuadratureOptions` — the settings;
* :class:`BEMWarning` and its subclasses, :class:`FootprintWarning` — the situations that are
  reported, not hidden.

Modules:

* mesh        bilinear elements, rooftops, the unknown ordering and the rooftop index spaces
* media       wavenumbers and PMCHWT coefficients of the exterior and the material
* quadrature  Gauss–Legendre, singular transforms, order rules (QuadratureOptions)
* elements    element-pair integrals (OpenCL + NumPy twins)
* assembly    basis-pair entries for any list of pairs, the dense Z
* excitation  beams on the patch: right-hand sides, surface currents, power into the material
* farfield    far field by the direct quadrature sum, radiated power, E and H from the integrals
* checks      warnings (material, resolution, footprint, solver)
* dense       DenseOperator: assembly + LU + solve; estimate_dense, DenseTooLarge
* driver      BEMSolver, the one driver (excitation → solve → radiation → diagnostics); bem_farfield
* aim/        the Adaptive Integral Method: options, grid, green, projection, convolution,
              nearfield, near_assembly, preconditioner, operator, continuation, farfield,
              estimate (see aim/__init__.py)
* model       the registry adapter (``[model] name = "bem"``)
"""

from wavebrdf.solver.bem3d.aim.estimate import estimate_aim
from wavebrdf.solver.bem3d.aim.options import AIMOptions
from wavebrdf.solver.bem3d.checks import (
    BEMWarning,
    FootprintWarning,
    MaterialWarning,
    ResolutionWarning,
    SolverWarning,
)
from wavebrdf.solver.bem3d.dense import DenseTooLarge, estimate_dense
from wavebrdf.solver.bem3d.driver import BEMSolver, bem_farfield
from wavebrdf.solver.bem3d.quadrature import QuadratureOptions

__all__ = [
    "AIMOptions",
    "BEMSolver",
    "BEMWarning",
    "DenseTooLarge",
    "FootprintWarning",
    "MaterialWarning",
    "QuadratureOptions",
    "ResolutionWarning",
    "SolverWarning",
    "bem_farfield",
    "estimate_aim",
    "estimate_dense",
]
