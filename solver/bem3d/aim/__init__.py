"""The Adaptive Integral Method: the PMCHWT operator Z ≈ B + C without the dense matrix, for
10⁵–10⁶ unknowns (bem3d.md §6–§9, docs/aim.md). The driver is bem3d's :class:`BEMSolver`
(``method="aim"``); this package holds the operator and what it is built from.

Modules:

* options        :class:`AIMOptions` (config table ``[model.aim]``), the near-field quadrature
* grid           the uniform 3-D grid of point sources and its FFT sizes
* green          the Green's function sampled on the grid, its spectra, which media go on the grid
* projection     Λ: each rooftop as point sources on its stencil (moment or far-field matching)
* convolution    B = Λᵀ G Λ applied by FFT convolution (OpenCL scatter / Fourier / gather, NumPy twins)
* nearfield      the near pattern, the lattice diagonal storage of C = A − B and its SpMV
* near_assembly  the entries of C: exact element integrals minus the grid's
* near_tables    element-pair tables computed once where pairs share them (repeating geometry, transposes)
* preconditioner the near-field LU (whole or tiled) and the local inverses of the Krylov solve
* flat_circulant the damped flat interface's inverse by 2-D FFTs on a torus (``preconditioner = "flat"``)
* flat_patch     the flat patch's operator by FFTs, solved by inner GMRES steps (``"flat-patch"``; FGMRES)
* operator       :class:`AIMOperator` (B + C, Krylov solve) and :class:`GridPart` (B alone)
* continuation   the flat continuation of the patch edge (``edge = "flat"``)
* farfield       far field of the solved currents from grid point sources by chirp-z transforms
* estimate       :func:`estimate_aim`, memory (held parts + each stage's transient) and time before a run
* budget         :func:`fit_to_budget`, the settings the planner picks to fit the memory a task may use
"""

from wavebrdf.solver.bem3d.aim.continuation import FlatContinuation
from wavebrdf.solver.bem3d.aim.estimate import estimate_aim
from wavebrdf.solver.bem3d.aim.operator import AIMOperator, GridPart
from wavebrdf.solver.bem3d.aim.options import AIM_QUADRATURE, AIMOptions

__all__ = ["AIM_QUADRATURE", "AIMOperator", "AIMOptions", "FlatContinuation", "GridPart", "estimate_aim"]
