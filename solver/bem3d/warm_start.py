"""Initial guesses across wavelengths: the previous solution of the same surface and incidence.

A study solves each surface (or steering sub-area) at every wavelength, and the planner keeps a
patch's wavelengths consecutive in one worker (jobs/plan.py, jobs/scheduler.py). Neighbouring
wavelengths' currents are close once the incident phase is moved along: the surface currents
follow the incident field's phase e^{+j k₁ ω_i·r} (e^{+jωt}; the beam propagates along −ω_i,
k₁ = 2π n₁/λ), so a solution x' at k₁' moves to k₁ as x' · e^{+j (k₁ − k₁') ω_i·r} at each
rooftop's centre. With the two previous solutions x', x'' (at k₁', k₁'') the guess is their
linear extrapolation in k₁ after the move, x̃' + t (x̃' − x̃''), t = (k₁ − k₁')/(k₁' − k₁'')
(taken for 0 ≤ t ≤ :data:`MAX_EXTRAPOLATION`, else x̃' alone). The Krylov solve then scales the
guess by least squares per polarization and drops it where it does not lower the residual
(solver/krylov.py), so a guess changes a result only within the Krylov tolerance.

Measured (docs/aim.md, rough aluminium, 1.6 µm patch, λ 0.400 → 0.412 → 0.424 µm, the third
solve's ‖b − α Z x̃‖/‖b‖): 0.029 unmoved, 0.016 moved, 0.0028 extrapolated at normal incidence;
0.070, 0.018, 0.007 at θ_i = 30°.

:class:`WarmStarts` holds one worker's previous solutions: the last two per (surface, incidence)
key, all of one surface (a solution of another surface evicts them), at most ``max_bytes`` in
all (the oldest keys go first), stored in complex64 (a guess needs no more).
"""

from __future__ import annotations

from collections import OrderedDict
from typing import NamedTuple

import numpy as np

from wavebrdf.solver.bem3d.mesh import BEMMesh

__all__ = ["WARM_START_BYTES", "WarmStarts", "incident_phase", "surface_key"]

WARM_START_BYTES = 256 * 2**20  # one 10⁶-unknown solution of both polarizations is 16 MiB
MAX_EXTRAPOLATION = 2.0  # the step to the new k₁ at most twice the last one


def surface_key(mesh: BEMMesh, *extra) -> tuple:
    """What makes two solves' unknowns the same currents: the mesh geometry (``BEMMesh.digest``:
    heights with the reference subtracted, their shape, the size) and ``extra`` (exterior index,
    precision, ...)."""
    return (*mesh.digest, *extra)


def incident_phase(mesh: BEMMesh, dk: float, theta_i: float, phi_i: float) -> np.ndarray:
    """e^{+j dk ω_i·r} at every unknown (J then M̃ of each rooftop centre), shape (2N_b,); ``dk``
    (µm⁻¹) the change of the exterior wavenumber, (θ_i, φ_i) toward the light (radians)."""
    omega = np.array([np.sin(theta_i) * np.cos(phi_i), np.sin(theta_i) * np.sin(phi_i), np.cos(theta_i)])
    phase = np.exp(1j * dk * (mesh.basis_centres @ omega))
    return np.concatenate([phase, phase])


class _Kept(NamedTuple):
    wavenumber: float  # k₁ (µm⁻¹) of the solve
    wavelength_um: float
    x: np.ndarray  # (P, 2N_b) complex64


class WarmStarts:
    """Previous solutions by (surface key, incidence key); see the module docstring."""

    def __init__(self, max_bytes: float = WARM_START_BYTES):
        if not max_bytes >= 0:
            raise ValueError(f"warm starts: max_bytes must be >= 0, got {max_bytes!r}")
        self.max_bytes = float(max_bytes)
        self._kept: OrderedDict[tuple, list[_Kept]] = OrderedDict()  # oldest key first, per key oldest first

    def __len__(self) -> int:
        return len(self._kept)

    def bytes(self) -> int:
        return sum(k.x.nbytes for kept in self._kept.values() for k in kept)

    def clear(self) -> None:
        self._kept.clear()

    def guess(self, surface: tuple, incidence: tuple, mesh: BEMMesh, wavenumber: float, theta_i: float,
              phi_i: float) -> tuple[np.ndarray, tuple[float, ...]] | None:
        """(initial guess (P, 2N_b), the wavelengths (µm) it comes from) for a solve at exterior
        wavenumber ``wavenumber`` (µm⁻¹) and incidence (θ_i, φ_i) (radians), or None when
        nothing of this key is kept."""
        kept = self._kept.get((surface, incidence))
        if not kept or kept[-1].x.shape[1] != 2 * mesh.n_bases:
            return None

        def moved(k: _Kept) -> np.ndarray:
            return k.x * incident_phase(mesh, wavenumber - k.wavenumber, theta_i, phi_i)[None, :]

        last = moved(kept[-1])
        if len(kept) == 2:
            t = (wavenumber - kept[-1].wavenumber) / (kept[-1].wavenumber - kept[0].wavenumber)
            if 0.0 <= t <= MAX_EXTRAPOLATION:
                return last + t * (last - moved(kept[0])), (kept[0].wavelength_um, kept[-1].wavelength_um)
        return last, (kept[-1].wavelength_um,)

    def keep(self, surface: tuple, incidence: tuple, wavenumber: float, wavelength_um: float,
             x: np.ndarray) -> None:
        """Keep ``x`` (P, 2N_b), solved at exterior wavenumber ``wavenumber``, for the next solves
        of this key (with the key's previous solution at another wavenumber); evicts every other
        surface's solutions, then the oldest keys beyond ``max_bytes``."""
        for key in [k for k in self._kept if k[0] != surface]:
            del self._kept[key]
        x = np.asarray(x, dtype=np.complex64)
        key = (surface, incidence)
        previous = [k for k in self._kept.pop(key, []) if k.wavenumber != wavenumber and k.x.shape == x.shape]
        kept = previous[-1:] + [_Kept(float(wavenumber), float(wavelength_um), x.copy())]
        self._kept[key] = kept
        while self.bytes() > self.max_bytes and self._kept:
            oldest = next(iter(self._kept))
            if oldest == key and len(self._kept[key]) == 2:
                self._kept[key] = self._kept[key][1:]  # the newest solution alone may still fit
            else:
                del self._kept[oldest]
