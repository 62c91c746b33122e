"""Gaussian illumination footprint shared by the surface models; the warning when it reaches the
patch edge.

Every surface model illuminates the patch with the footprint of the full-wave beam (bem3d.md §8):
amplitude W(r) = exp(−|r − c|²/w²) on the surface nodes (patch coordinates, µm). A footprint that
has not decayed at the patch border makes the result depend on the patch edge; the models say so
with :class:`FootprintWarning` instead of hiding it.
"""

from __future__ import annotations

import numpy as np

from wavebrdf.solver.surface import HeightField

__all__ = ["EDGE_AMPLITUDE", "FootprintWarning", "edge_fraction", "gaussian_footprint"]

EDGE_AMPLITUDE = 1e-3  # footprint amplitude at the patch edge (relative to its peak) above which models warn


class FootprintWarning(UserWarning):
    """The illumination footprint is not contained in the patch (edge truncation, e.g. grazing incidence)."""


def gaussian_footprint(surface: HeightField, waist_um: float, centre_um=(0.0, 0.0)) -> np.ndarray:
    """Footprint amplitude exp(−|x − c|²/w²) on the surface nodes (patch coordinates, µm)."""
    if not (np.isfinite(waist_um) and waist_um > 0):
        raise ValueError(f"illumination.waist_um must be > 0, got {waist_um!r}")
    X, Y = np.meshgrid(surface.x - centre_um[0], surface.y - centre_um[1], indexing="ij")
    return np.exp(-(X**2 + Y**2) / waist_um**2)


def edge_fraction(window: np.ndarray) -> float:
    """Largest footprint magnitude on the border of a node array, relative to its peak."""
    magnitude = np.abs(window)
    edge = max(magnitude[0].max(), magnitude[-1].max(), magnitude[:, 0].max(), magnitude[:, -1].max())
    return float(edge / magnitude.max())
