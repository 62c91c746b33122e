"""The Model seam: every scattering model is one class registered here by name.

A model owns

* ``name`` — the ``[model] name`` of configs; ``summary`` — one line for users (``wavebrdf
  models``): what it computes, in plain words (the docstrings are for developers);
* ``Options`` — a frozen dataclass of its settings (solver/options.py), parsed by the config layer
  from the keys of ``[model]`` besides ``name``/``precision`` and from ``[model.<name>]``;
  unknown keys and bad values are refused at load;
* ``capabilities`` — what it takes (a height field, a fiber cross section, surface statistics)
  and returns (coherent fields, intensities, fiber tables; polarization-resolved or not;
  steerable; reciprocal), enforced by config and plan before anything runs;
* :meth:`Model.estimate` — memory and time of one scene, without running it;
* :meth:`Model.run` — one scene → a result: a :class:`~wavebrdf.solver.farfield.FarField`
  (coherent) or :class:`~wavebrdf.solver.farfield.IntensityResult` for surfaces, both
  :class:`~wavebrdf.solver.farfield.BRDFResult`; a :class:`FiberResult` for fibers.

Adding a model is one module with one such class plus one line in ``_REGISTRY`` below
(docs/architecture.md, "How to add a model"). Models are imported on first use, so selecting one
never imports the others. An instance holds its options and may keep what one scene built for
the next (an operator, a factorization): the batch layer keeps one instance per worker process
and model configuration (jobs/tasks.py ``ModelPool``).
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import warnings
from abc import ABC, abstractmethod
from collections.abc import Set
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.footprint import footprint_edge_warning, gaussian_edge_fraction
from wavebrdf.solver.options import NoOptions, parse_options
from wavebrdf.solver.precision import Precision
from wavebrdf.solver.surface import HeightField
from wavebrdf.solver.validity import ValidityWarning, check_sampling, waist_spread

__all__ = [
    "Capabilities",
    "Estimate",
    "FiberResult",
    "FiberScene",
    "Model",
    "ModelsWith",
    "SurfaceScene",
    "get_model",
    "model_class",
    "model_names",
    "register",
    "rung_order",
    "rungs",
]

@dataclass(frozen=True)
class Capabilities:
    """What a model takes and returns; config and plan enforce it before anything runs.

    takes       "height_field" (a bilinear height field) | "cross_section" (a fiber cross
                section) | "statistics" (surface statistics, no realization)
    returns     "fields" (coherent FarField) | "intensity" (IntensityResult) | "fiber_table"
    polarized   resolves s and p (else both polarizations carry the same values)
    steerable   its fields can be synthesized by beam steering (coherent, with incident_fields)
    reciprocal  claims f(ω_i, ω_o) = f(ω_o, ω_i) (checked by the conformance suite)
    conserves_energy   claims albedo ≤ 1 for κ ≥ 0 at every angle (models that do not, e.g.
                Kirchhoff without shadowing at grazing angles, report the excess instead)
    spot_checks measures its own choice on sampled tasks of a study: the plan adds "check" tasks
                (``plan_spot_checks``, ``spot_check``, ``run_checked``; jobs/spot_checks.py)
    rung        its place on the ladder of surface rungs, from the cheapest (0) to the most accurate
                (docs/approx.md): ``wavebrdf compare`` lists models in this order and takes the
                highest that fits as its reference; None: not ranked (below every rung)
    vector_fields  its FarField is the full vector far field (cross-polarization, the turn between the
                planes of incidence and exitance), so Jones and Mueller matrices are meaningful in every
                direction; scalar rungs put E_s on φ̂_o and E_p on θ̂_o (diagonal Jones matrices)
    single_scattering  its paths end after one reflection, so it misses the energy of longer paths
                (``auto`` never predicts its error below the scene's multiple-bounce share)
    picks_rung  it runs, per scene, a rung it picks among the registered models (``auto``): it is
                not itself a rung that ``compare`` lists or ``auto`` picks
    """

    INPUTS: ClassVar[tuple[str, ...]] = ("height_field", "cross_section", "statistics")
    OUTPUTS: ClassVar[tuple[str, ...]] = ("fields", "intensity", "fiber_table")

    takes: str
    returns: str
    polarized: bool = True
    steerable: bool = False
    reciprocal: bool = False
    conserves_energy: bool = False
    spot_checks: bool = False
    rung: int | None = None
    single_scattering: bool = False
    vector_fields: bool = False
    picks_rung: bool = False

    def __post_init__(self):
        if self.takes not in self.INPUTS:
            raise ValueError(f"Capabilities.takes must be one of {self.INPUTS}, got {self.takes!r}")
        if self.returns not in self.OUTPUTS:
            raise ValueError(f"Capabilities.returns must be one of {self.OUTPUTS}, got {self.returns!r}")
        if self.steerable and self.returns != "fields":
            raise ValueError("only models returning coherent fields can be steerable")
        if self.vector_fields and self.returns != "fields":
            raise ValueError("only models returning coherent fields can return vector fields")


@dataclass(frozen=True)
class SurfaceScene:
    """Physics inputs of one surface simulation (one wavelength, one incident direction).

    Angles in radians; θ_i, φ_i give the direction toward the light. ``index`` is n − jκ of the
    material below the surface at this wavelength. ``z_reference`` is the phase-reference height
    (None: the surface mean; sub-area patches pass the global mean). ``footprint_centre_um`` is
    the beam centre in patch coordinates. ``precision``: the task's :class:`~wavebrdf.solver.precision.Precision`
    (kernels and FFTs; given as its word it is typed here, once).
    ``memory_budget_bytes``: the memory one task may use ([run] memory_gb or the node's, over the
    tasks at once; None: not limited), which models that can trade time for memory fit.
    ``coherent``: the result must be a coherent FarField (a steered sub-area, summed with others).
    ``polarimetric``: the result must be a vector FarField (the study stores Jones or Mueller matrices).
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
    precision: Precision = Precision.DOUBLE
    z_reference: float | None = None
    footprint_centre_um: tuple[float, float] = (0.0, 0.0)
    memory_budget_bytes: float | None = None
    coherent: bool = False
    polarimetric: bool = False

    def __post_init__(self):
        object.__setattr__(self, "precision", Precision(self.precision))


@dataclass(frozen=True)
class FiberScene:
    """Physics inputs of one fiber solve: one wavelength and one θ_i, every φ_i at once.

    ``cross_section``: a :class:`~wavebrdf.solver.fiber.CrossSection` (µm); θ_i (radians) from
    the plane normal to the axis. φ_i is either ``phi_i`` (point samples, radians) or, when it
    is None, ``phi_i_bins`` box-averaged bins over [0, 2π) (fiber.md §14.8); ``phi_r_bins`` bins
    of the outgoing azimuth. ``radius_um``: the circle's radius for models that need it (Mie).
    ``shape``: what the cross section was made from (``[fiber] shape``: "circle", "ellipse",
    "polygon"); ``meshed``: its nodes are a mesh chosen for it (``[fiber] segments``, or a polygon's
    own points), not an outline of a smooth shape (360 nodes) that models needing no mesh read.
    ``precision`` as for surface scenes.
    """

    cross_section: object
    wavelength_um: float
    index: complex
    theta_i: float
    phi_i: tuple[float, ...] | None
    phi_i_bins: int
    phi_r_bins: int
    radius_um: float | None = None
    precision: Precision = Precision.DOUBLE
    shape: str = "polygon"
    meshed: bool = True

    def __post_init__(self):
        object.__setattr__(self, "precision", Precision(self.precision))


@dataclass
class FiberResult:
    """One fiber solve: dC_s/dφ (2 polarizations, P φ_i, R φ_r bins; µm/rad) and the cross
    sections C_ext, C_sca, C_abs (2, P) in µm, normalised by S₀ cos θ_i (fiber.md §6)."""

    dCs_dphi: np.ndarray
    C_ext: np.ndarray
    C_sca: np.ndarray
    C_abs: np.ndarray
    diagnostics: dict = field(default_factory=dict)

    def arrays(self) -> dict[str, np.ndarray]:
        return {"dCs_dphi": self.dCs_dphi, "C_ext": self.C_ext, "C_sca": self.C_sca, "C_abs": self.C_abs}

    @property
    def power_balance_error(self) -> np.ndarray:
        from wavebrdf.solver.fiber.results import power_balance_error

        return power_balance_error(self.C_ext, self.C_sca, self.C_abs)


@dataclass(frozen=True)
class Estimate:
    """Predicted cost of one scene: peak memory (bytes) and wall time (s) on a 2-core CPU."""

    memory_bytes: float
    seconds: float
    detail: str = ""
    # the time when the worker has just solved the same surface at the previous wavelength (a set-up
    # part kept, a warm start; solver/bem3d/aim/estimate.py); None: ``seconds`` then too
    following_seconds: float | None = None
    # device side, checked by `wavebrdf plan`/`run` against the device (None: not reported)
    device_bytes: float | None = None  # device memory held at once
    largest_buffer_bytes: float | None = None  # the largest single device buffer (max allocation)


class Model(ABC):
    """A scattering model: options, capabilities, estimate and run (see the module docstring).

    Sampling validity: ``sampling`` names what the model's figure depends on
    (:data:`~wavebrdf.solver.validity.SAMPLING_FLAGS`: the node lattice against λ, point-sampled
    output pixels, a realization against its ensemble). Every subclass's :meth:`run` and
    :meth:`check` go through :meth:`validity` on surface scenes: a refusal is a ValueError, each
    warning a :class:`~wavebrdf.solver.validity.ValidityWarning` (which the batch layer records in
    the task table's warnings), unless ``run_warns_itself``: every warning of :meth:`validity` is
    raised by the model's run itself (the full wave's solver, in its own category; ``auto``'s rung),
    and the seam applies only the refusals.
    """

    name: ClassVar[str]
    summary: ClassVar[str] = ""  # what ``wavebrdf models`` says it computes
    capabilities: ClassVar[Capabilities]
    Options: ClassVar[type] = NoOptions
    sampling: ClassVar[frozenset[str]] = frozenset()
    run_warns_itself: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        for method in ("run", "check"):
            own = cls.__dict__.get(method)
            if own is not None and not getattr(own, "_sampling_checked", False):
                setattr(cls, method, _through_validity(own, method == "run"))

    def __init__(self, options=None):
        self.options = parse_options(self.Options, options, f"model.{self.name}")

    @abstractmethod
    def run(self, ctx, scene):
        """Simulate ``scene`` on the OpenCL context ``ctx`` (a BRDFResult or a FiberResult)."""

    @abstractmethod
    def estimate(self, scene) -> Estimate:
        """Memory/time estimate for ``scene`` without running it."""

    def check(self, scene) -> None:
        """Refuse (ValueError naming the config key) a scene these options cannot simulate; called
        by the config layer on each case before anything runs. Default: the sampling refusals of
        :meth:`validity` only."""
        self.validity(scene)

    def validity(self, scene) -> list[str]:
        """The sampling validity of ``scene`` without running it (``wavebrdf plan`` can show it):
        raises ValueError where the figure would be wrong, returns the warnings it would carry."""
        if not isinstance(scene, SurfaceScene):
            return []
        return check_sampling(self.name, self.sampling, scene)

    def steered_fresnel(self) -> str | None:
        """Where the figure's Fresnel factors are taken when they follow the incident direction ω_i
        rather than each plane wave of the beam: "incidence" (at ω_i) or "half vector" (of ω_i and
        ω_o). A steered synthesis (jobs/steering.py) then keeps the basic direction in them. None:
        per plane wave (the full wave), or no Fresnel factors to keep."""
        return None

    def waist_remedy(self) -> str | None:
        """What removes the footprint's angular-spread error from this model's albedo besides a
        wider waist, as its run's :func:`~wavebrdf.solver.validity.check_waist` names it; None where
        its run has no such error to predict (rays, renormalized or beam-lit rungs, the full wave)."""
        return None

    def foreseen_warnings(self, scene) -> list[str]:
        """What ``plan`` shows for ``scene`` before anything runs: the warnings of :meth:`validity`
        and of the run-time checks that need no run (the footprint's spread,
        :func:`~wavebrdf.solver.validity.waist_spread`; for the rungs that sum over the footprint on
        the nodes, its amplitude at the patch edge, :func:`~wavebrdf.solver.footprint.
        footprint_edge_warning`), in the words the run will use."""
        found = list(self.validity(scene))
        if not isinstance(scene, SurfaceScene):
            return found
        remedy = self.waist_remedy()
        if remedy is not None:
            _, message = waist_spread(scene, self.name, remedy)
            found += [message] if message else []
        if "lattice" in self.sampling and scene.waist_um is not None:  # the node sum weighs the footprint W
            edge = gaussian_edge_fraction(scene.surface, scene.waist_um, scene.footprint_centre_um)
            message = footprint_edge_warning(edge, scene.surface.size_um)
            found += [message] if message else []
        return found

    def incident_fields(self, scene: SurfaceScene, points):
        """Incident (E, H), each (2 pol, 3, ...), at ``points`` (..., 3) in patch coordinates,
        with the normalisation of this model's FarField incident power (steerable models)."""
        raise NotImplementedError(f"model {self.name!r} does not provide incident fields (cannot be steered)")

    def release(self) -> None:
        """Free what the instance keeps between scenes (operators, factorizations)."""


def _through_validity(method, warn: bool):
    """``method`` (a subclass's run or check) preceded by :meth:`Model.validity`; ``warn``: issue
    its warnings (run, unless the model's ``run_warns_itself``) rather than only its refusals (check)."""

    @functools.wraps(method)
    def checked(self, *args, **kwargs):
        scene = args[-1] if args else kwargs.get("scene")
        for message in self.validity(scene):
            if warn and not self.run_warns_itself:
                warnings.warn(message, ValidityWarning, stacklevel=2)
        return method(self, *args, **kwargs)

    checked._sampling_checked = True
    return checked


# name -> "module:ClassName" (imported on first use)
_REGISTRY: dict[str, str] = {
    "kirchhoff": "wavebrdf.solver.approx.kirchhoff:KirchhoffModel",
    "bem": "wavebrdf.solver.bem3d.model:BEMModel",
    "fiber-bem": "wavebrdf.solver.fiber.model:FiberBEMModel",
    "mie": "wavebrdf.solver.fiber.model:MieModel",
    "po": "wavebrdf.solver.approx.physical_optics:POModel",
    "ghs": "wavebrdf.solver.approx.harvey_shack:GHSModel",
    "ohs": "wavebrdf.solver.approx.harvey_shack:OHSModel",
    "gs": "wavebrdf.solver.approx.geometric:GSModel",
    "gm": "wavebrdf.solver.approx.geometric:GMModel",
    "stam": "wavebrdf.solver.approx.stam:StamModel",
    "ws-v": "wavebrdf.solver.approx.falster:WSVModel",
    "wm": "wavebrdf.solver.approx.falster:WMModel",
    "auto": "wavebrdf.solver.auto:AutoModel",
}


def register(name: str, target: str) -> None:
    """Register model ``name`` implemented by ``"module:ClassName"`` (plugins, tests)."""
    _REGISTRY[name] = target


def model_names(takes: str | None = None) -> tuple[str, ...]:
    """Registered model names (only those taking ``takes`` when given)."""
    if takes is None:
        return tuple(_REGISTRY)
    return tuple(n for n in _REGISTRY if model_class(n).capabilities.takes == takes)


def model_class(name: str) -> type[Model]:
    """The class registered as ``name`` (imported on first use)."""
    if name not in _REGISTRY:
        raise KeyError(f"unknown model {name!r}; available: {', '.join(_REGISTRY)}")
    module, cls = _REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), cls)


def rungs(takes: str | None = None) -> tuple[str, ...]:
    """Registered models taking ``takes`` (all when None) that are rungs themselves, not pickers of
    rungs (:attr:`Capabilities.picks_rung`)."""
    return tuple(n for n in model_names(takes) if not model_class(n).capabilities.picks_rung)


def rung_order(name: str) -> int:
    """The place of model ``name`` on the ladder (:attr:`Capabilities.rung`), -1 when it is not
    ranked: the key that sorts models from the cheapest rung to the most accurate."""
    rung = model_class(name).capabilities.rung
    return -1 if rung is None else rung


class ModelsWith(Set):
    """The registered models whose capability ``flag`` is true, as a set of names read from the
    registry when asked: ``name in ModelsWith("single_scattering")`` imports only that model
    (unregistered names are not in it), iterating imports every model."""

    def __init__(self, flag: str):
        if flag not in {f.name for f in dataclasses.fields(Capabilities)}:
            raise ValueError(f"Capabilities has no flag {flag!r}")
        self.flag = flag

    def __contains__(self, name) -> bool:
        return isinstance(name, str) and name in _REGISTRY and bool(getattr(model_class(name).capabilities, self.flag))

    def __iter__(self):
        return (name for name in tuple(_REGISTRY) if name in self)

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def __repr__(self) -> str:
        return f"ModelsWith({self.flag!r})"


def get_model(name: str, options=None) -> Model:
    """An instance of the model registered as ``name`` with ``options`` (its Options dataclass,
    a mapping parsed into it, or None for the defaults)."""
    return model_class(name)(options)
