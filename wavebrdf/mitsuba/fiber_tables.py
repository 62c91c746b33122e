"""A fiber dataset turned into the tables the ``"wavebrdf_fiber"`` Mitsuba plugin evaluates (NumPy).

Nothing here imports Mitsuba. :func:`load_fiber_tables` reads one sweep case of a fiber dataset
(``jobs/store.py`` layout: ``bcsdf`` = N_wave, ``C_eff``, ``phi_r_cdf``, ``longitudinal_variance``)
and returns :class:`FiberTables`:

* ``hit[c, t, p]``: the probability that a ray meeting the bounding cylinder (width C_b = the
  largest stored C_e) hits the fiber's effective width, C_e/C_b ([P] §6: offset-limited hits),
  in channel c; ``miss[c, t, p]`` = the same for passing through (1 - hit, channel-weighted).
* ``value[c, t, p, r]`` = hit · N_wave (1/rad) at the φ_r bin centres.
  Channels: the dataset's wavelengths ("spectral"); linear sRGB through the dataset's own
  spectrum → XYZ → sRGB path ("rgb", negatives clipped to 0); luminance Y ("mono").
* ``cdf[s, t, p, r]``: φ_r sampling CDFs at the bins' upper edges. Spectral: the stored
  ``phi_r_cdf`` per wavelength (slot s = table wavelength). RGB/mono: one slot, the mixture of
  the stored per-wavelength densities weighted by each wavelength's share of the channel-mean
  ``value`` (so the density is proportional to the channel mean of ``value``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wavebrdf.mitsuba.tables import channel_matrix, open_for_plugin

__all__ = ["FiberTables", "load_fiber_tables"]

logger = logging.getLogger("wavebrdf")


@dataclass
class FiberTables:
    """Angles in radians, widths in µm; axes c (channel), s (sampling slot), t (θ_i), p (φ_i),
    r (φ_r bin, centres r·2π/R)."""

    channels: str
    wavelengths_um: np.ndarray  # (L,)
    theta_i: np.ndarray  # (T,) ascending
    phi_i: np.ndarray  # (P,) bin centres or sorted point samples
    phi_i_binned: bool
    value: np.ndarray  # (C, T, P, R) float32
    hit: np.ndarray  # (C, T, P)
    miss: np.ndarray  # (C, T, P)
    cdf: np.ndarray  # (S, T, P, R) float32
    variance: float
    bounding_width_um: float
    geometric_width_um: float
    diagnostics: dict = field(default_factory=dict)

    @property
    def mirror_theta(self) -> bool:
        """θ_i >= 0 only: N_wave(-θ_i) = N_wave(θ_i) (z → -z symmetry) answers negative θ_i."""
        return bool(np.all(self.theta_i >= 0))

    @property
    def rotation_invariant(self) -> bool:
        """One φ_i (circles): N_wave depends on φ_r − φ_i only; the table holds φ_r for its own
        φ_i (``phi_i[0]``), so a query's φ_r is read at φ_r − (φ_i − phi_i[0])."""
        return self.phi_i.size == 1


def load_fiber_tables(path: str | Path, *, case: int = 0, channels: str = "rgb") -> FiberTables:
    """Read sweep case ``case`` (flat C-order index over the sweep axes) of fiber dataset ``path``."""
    from wavebrdf.solver.fiber.evaluator import FiberBCSDF

    start = time.perf_counter()
    with open_for_plugin(path, "fiber", channels) as ds:
        try:
            ev = FiberBCSDF.from_dataset(ds, case)
        except ValueError as exc:
            raise ValueError(f"[wavebrdf_fiber plugin] {exc}") from None
    lams, theta, phi_i, binned = ev.wavelength_um, ev.theta_i, ev.phi_i, ev.phi_i_binned
    n_wave, c_eff, stored_cdf, c_geom, variance = ev.table, ev.C_eff, ev.cdf, ev.C_geom, ev.variance
    bounding = float(c_eff.max())
    hit = c_eff / bounding  # (L, T, P)
    R = n_wave.shape[-1]
    if channels == "spectral":
        value, hit_c, miss_c, cdf = n_wave * hit[..., None], hit, 1.0 - hit, stored_cdf
    else:
        matrix = channel_matrix(lams, channels)  # (C, L)
        value = np.maximum(np.einsum("cl,ltpr->ctpr", matrix, n_wave * hit[..., None]), 0.0)
        hit_c = np.clip(np.einsum("cl,ltp->ctp", matrix, hit), 0.0, 1.0)
        miss_c = np.clip(np.einsum("cl,ltp->ctp", matrix, 1.0 - hit), 0.0, 1.0)
        # the stored per-λ densities, mixed with weights ∝ each λ's share of the channel-mean value
        density = np.diff(np.concatenate([np.zeros(stored_cdf.shape[:-1] + (1,)), stored_cdf], axis=-1), axis=-1)
        share = matrix.mean(axis=0)[:, None, None] * hit * n_wave.sum(axis=-1)  # (L, T, P)
        share = np.maximum(share, 0.0)
        mixed = np.einsum("ltp,ltpr->tpr", share, density) / np.maximum(share.sum(axis=0), 1e-300)[..., None]
        cdf = np.cumsum(mixed, axis=-1)
        cdf = (cdf / np.where(cdf[..., -1:] > 0, cdf[..., -1:], 1.0))[None]
    cdf = np.ascontiguousarray(cdf, dtype=np.float64)
    cdf[..., -1] = 1.0
    tables = FiberTables(channels=channels, wavelengths_um=lams, theta_i=theta, phi_i=phi_i, phi_i_binned=binned,
                         value=np.ascontiguousarray(value, dtype=np.float32), hit=hit_c, miss=miss_c,
                         cdf=cdf.astype(np.float32), variance=variance, bounding_width_um=bounding,
                         geometric_width_um=float(np.max(c_geom)))
    tables.diagnostics = {
        "wavelengths_um": lams.tolist(), "theta_i_deg": np.rad2deg(theta).round(6).tolist(),
        "phi_i": int(phi_i.size), "phi_r_bins": int(R), "variance": variance,
        "bounding_over_geometric": bounding / tables.geometric_width_um,
        "hit_min": float(hit.min()), "load_s": time.perf_counter() - start,
    }
    logger.info("wavebrdf_fiber tables %s: %s", Path(path).name, tables.diagnostics)
    return tables
