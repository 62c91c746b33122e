"""The Model interface and registry: every surface model turns a :class:`SurfaceScene` into a
:class:`~wavebrdf.solver.farfield.FarField`.

Models are registered by name with the module that implements them and are imported lazily, so
``[model] name = "..."`` in a config selects one without importing the others.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

from wavebrdf.solver.farfield import FarField, HemisphereGrid
from wavebrdf.solver.surface import HeightField

__all__ = ["Estimate", "Model", "SurfaceScene", "get_model", "model_names"]


@dataclass(frozen=True)
class SurfaceScene:
    """Physics inputs of one surface simulation (one wavelength, one incident direction).

    Angles in radians; θ_i, φ_i give the direction toward the light. ``index`` is n − jκ of the
    material below the surface at this wavelength. ``z_reference`` is the phase-reference height
    (None: the surface mean; sub-area patches pass the global mean). ``footprint_centre_um`` is
    the beam centre in patch coordinates.
    """

    surface: HeightField
    wavelength_um: float
    index: complex
    theta_i: float
    phi_i: float
    waist_um: float
    grid: HemisphereGrid
    exterior_index: float = 1.0
    beam: str = "exact"
    precision: str = "double"
    z_reference: float | None = None
    footprint_centre_um: tuple[float, float] = (0.0, 0.0)
    options: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Estimate:
    """Predicted cost of one scene: peak memory (bytes) and wall time (s) on a 2-core CPU."""

    memory_bytes: float
    seconds: float
    detail: str = ""


class Model(ABC):
    """A surface scattering model."""

    name: ClassVar[str]
    steerable: ClassVar[bool] = True  # returns coherent fields (beam steering can use them)
    methods: ClassVar[tuple[str, ...]] = ()  # allowed values of [model] method (first = default)

    @abstractmethod
    def farfield(self, ctx, scene: SurfaceScene) -> FarField:
        """Simulate ``scene`` on the OpenCL context ``ctx``."""

    @abstractmethod
    def estimate(self, scene: SurfaceScene) -> Estimate:
        """Memory/time estimate for ``scene`` without running it."""

    def incident_fields(self, scene: SurfaceScene, points):
        """Incident (E, H), each (2 pol, 3, ...), at ``points`` (..., 3) in patch coordinates,
        with the normalisation of this model's FarField incident power (used by beam steering)."""
        raise NotImplementedError(f"model {self.name!r} does not provide incident fields (cannot be steered)")


# name -> "module:ClassName" (imported on first use)
_REGISTRY: dict[str, str] = {
    "kirchhoff": "wavebrdf.solver.approx.kirchhoff:KirchhoffModel",
    "bem": "wavebrdf.solver.bem3d.model:BEMModel",
}


def register(name: str, target: str) -> None:
    """Register model ``name`` implemented by ``"module:ClassName"``."""
    _REGISTRY[name] = target


def model_names() -> tuple[str, ...]:
    return tuple(_REGISTRY)


def get_model(name: str) -> Model:
    """An instance of the model registered as ``name``."""
    if name not in _REGISTRY:
        raise KeyError(f"unknown model {name!r}; available: {', '.join(_REGISTRY)}")
    module, cls = _REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), cls)()
