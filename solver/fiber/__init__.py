"""Wave-optics scattering by fibers: 2.5D boundary elements, Mie series, BCSDF tables.

Specification: shared/design/fiber.md. Conventions: lengths in µm, vacuum wavelength, e^{+jωt},
index m = n - jκ (κ >= 0 is loss), fiber axis ẑ, θ_i measured from the plane normal to the
axis, all angles in radians; cross sections per unit length (µm) normalised by S₀ cosθ_i.
Polarization axis: 0 = "parallel" (BH case I, E in the plane of the axis and the incident
direction), 1 = "perpendicular" (BH case II).

Typical use::

    from wavebrdf.solver.opencl import create_context
    from wavebrdf.solver import fiber

    ctx = create_context()
    shape = fiber.ellipse(0.4, 0.25, segments=96)
    res = fiber.solve_fiber(ctx, shape, 0.5, 1.55 - 0.02j, theta_i=0.5, phi_i=[0.0, 0.3])
    res.dCs_dphi, res.C_ext, res.C_sca, res.C_abs, res.power_balance_error
    table = fiber.bcsdf_table(fiber.FiberBEM(ctx, shape), wavelengths, 1.55, thetas)
    S = wavebrdf.open("out/fiber_ellipse.h5").bcsdf(theta_i, theta_r, phi_i, phi_r, 0.5)  # M₀·N_wave
"""

from wavebrdf.solver.fiber.assembly import BEMQuadrature, FiberAssembler
from wavebrdf.solver.fiber.bcsdf import (
    BCSDFSlice,
    BCSDFTable,
    bcsdf_slices,
    bcsdf_table,
    effective_width,
    longitudinal_cdf,
    longitudinal_m0,
)
from wavebrdf.solver.fiber.evaluator import FiberBCSDF, azimuthal_cdf
from wavebrdf.solver.fiber.bem import FiberBEM, FiberSolution, solve_fiber
from wavebrdf.solver.fiber.hankel import hankel2_01, hankel2_01_cl, hankel2_01_scipy
from wavebrdf.solver.fiber.incidence import POLARIZATIONS, FiberMedia, fiber_media
from wavebrdf.solver.fiber.mie import MieCylinder, MieFiber, mie_cylinder, mie_scattering
from wavebrdf.solver.fiber.results import ScatteringResult
from wavebrdf.solver.fiber.shapes import (
    CrossSection,
    ShapeError,
    circle,
    ellipse,
    load_shape,
    polygon,
    recommended_segments,
    save_shape,
    spline,
)

__all__ = [
    "BCSDFSlice",
    "BCSDFTable",
    "BEMQuadrature",
    "CrossSection",
    "FiberAssembler",
    "FiberBCSDF",
    "FiberBEM",
    "FiberMedia",
    "FiberSolution",
    "MieCylinder",
    "MieFiber",
    "POLARIZATIONS",
    "ScatteringResult",
    "ShapeError",
    "azimuthal_cdf",
    "bcsdf_slices",
    "bcsdf_table",
    "circle",
    "effective_width",
    "ellipse",
    "fiber_media",
    "hankel2_01",
    "hankel2_01_cl",
    "hankel2_01_scipy",
    "load_shape",
    "longitudinal_cdf",
    "longitudinal_m0",
    "mie_cylinder",
    "mie_scattering",
    "polygon",
    "recommended_segments",
    "save_shape",
    "solve_fiber",
    "spline",
]
