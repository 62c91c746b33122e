"""The "wavebrdf" plugin in Mitsuba's polarized variants against Mitsuba's own polarized conductor.

A flat interface computed by GHS (θ_i every 5° to 85°, Jones matrices stored; its albedo is
Fresnel's at any waist, where PO's drifts by ~1 % at 80° with this 6 µm waist) renders, through our
plugin, the Stokes images S0…S3 that Mitsuba's ``conductor`` (its own polarized Fresnel, a delta
reflection) renders in the same variant, where the sphere is hit at ≤ 80°: a sphere under a uniform unpolarized sky (hidden: only the sphere is measured), one bounce
(``stokes`` integrator around ``path``). Aluminium (n, κ at 0.55 µm) and glass (n = 1.5, κ = 0:
the conductor plugin with k = 0 is a dielectric's reflection, without the transmission Mitsuba's
``dielectric`` would add). The metric per Stokes component k is Σ|ours_k − Mitsuba_k| / Σ Mitsuba_0
against the noise of two renders with other seeds; a wrong frame, a wrong sign of U, or a missing
reciprocal transpose moves S1/S2 by their own size (≈ 5–40 % of S0 here), far above the noise.
"""

from __future__ import annotations

import logging

import mitsuba as mi  # the `render` extra; missing = a failure, as every reference package
import numpy as np
import pytest

import wavebrdf

logger = logging.getLogger(__name__)

MATERIALS = {"aluminium": (0.96, 6.69), "glass": (1.5, 0.0)}  # n, κ (constant over λ)
FOV_DEG = 30.0
RIM_DEG = 80.0  # compared up to this incidence on the sphere: the tables end at 85°, the delta Fresnel rises to 1 at 90°
STOKES_CHANNELS = 3  # the stokes integrator writes S0…S3 as three colour channels each, after the nested image


@pytest.fixture(scope="module")
def flat_datasets(tmp_path_factory):
    folder = tmp_path_factory.mktemp("flat_polarized")
    out = {}
    for material, (n, kappa) in MATERIALS.items():
        config = {"study": {"name": f"flat_{material}", "output": str(folder / f"flat_{material}.h5")},
                  "surface": {"generator": "flat", "size_um": 40.0, "cells": 400},
                  "material": {"n": n, "kappa": kappa},
                  "illumination": {"wavelengths_um": [0.55], "waist_um": 6.0,
                                   "directions_deg": {"theta": {"start": 0, "stop": 85, "count": 18}, "phi": 0}},
                  "model": {"name": "ghs"}, "output": {"resolution": 128, "polarization": "jones"}}
        wavebrdf.run(config).close()
        out[material] = folder / f"flat_{material}.h5"
    return out


def _render(variant: str, bsdf: dict, seed: int, resolution: int, spp: int) -> np.ndarray:
    mi.set_variant(variant)
    from wavebrdf.mitsuba.bsdfs import register

    register()
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "stokes", "integrator": {"type": "path", "max_depth": 2, "hide_emitters": True}},
        "sensor": {"type": "perspective", "fov": FOV_DEG,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, -6, 3], target=[0, 0, 0], up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                            "pixel_format": "rgb" if "spectral" in variant else "luminance"},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "emitter": {"type": "constant", "radiance": {"type": "spectrum", "value": 1.0}},
        "shape": {"type": "sphere", "radius": 1.0, "bsdf": bsdf}})
    image = np.array(mi.render(scene, seed=seed), dtype=float)
    stokes = image[..., image.shape[-1] - 4 * STOKES_CHANNELS:]
    return stokes.reshape(stokes.shape[:-1] + (4, STOKES_CHANNELS)).sum(axis=-1)  # (H, W, 4)


def _below(resolution: int, theta_max_deg: float) -> np.ndarray:
    """Pixels whose ray meets the sphere at an incidence angle ≤ θ_max: the sphere sits on the
    optical axis at distance D = √45, so a ray at angle α off the axis meets it at sin θ = D sin α
    (unit radius), α = atan(r tan(fov/2)) with r the pixel centre's distance from the image centre
    in half-widths."""
    c = (np.arange(resolution) + 0.5) / resolution * 2.0 - 1.0
    r = np.hypot(*np.meshgrid(c, c, indexing="ij"))
    alpha = np.arctan(r * np.tan(np.deg2rad(FOV_DEG) / 2))
    return np.sqrt(45.0) * np.sin(alpha) <= np.sin(np.deg2rad(theta_max_deg))


@pytest.mark.parametrize("variant,resolution,spp", [("llvm_ad_spectral_polarized", 64, 128),
                                                    ("llvm_ad_mono_polarized", 48, 128),
                                                    ("scalar_spectral_polarized", 12, 16)])
@pytest.mark.parametrize("material", list(MATERIALS))
def test_polarized_plugin_matches_mitsuba_conductor(flat_datasets, material, variant, resolution, spp):
    n, kappa = MATERIALS[material]
    ours = [_render(variant, {"type": "wavebrdf", "filename": str(flat_datasets[material])}, seed, resolution, spp)
            for seed in (1, 2)]
    theirs = [_render(variant, {"type": "conductor", "eta": n, "k": kappa}, seed, resolution, spp) for seed in (3, 4)]
    inside = _below(resolution, RIM_DEG)
    ours, theirs = [o[inside] for o in ours], [t[inside] for t in theirs]
    total = theirs[0][..., 0].sum()
    for k in range(3):
        metric = np.abs(ours[0][..., k] - theirs[0][..., k]).sum() / total
        noise = np.hypot(np.abs(ours[0][..., k] - ours[1][..., k]).sum(),
                         np.abs(theirs[0][..., k] - theirs[1][..., k]).sum()) / np.sqrt(2) / total
        size = np.abs(theirs[0][..., k]).sum() / total
        logger.info("%s %s S%d: Σ|ours − mitsuba|/ΣS0 = %.4f, noise %.4f (|S%d|/S0 = %.3f)", variant, material, k,
                    metric, noise, k, size)
        assert metric <= 1.3 * noise + 0.002, f"{variant} {material} S{k}: {metric:.4f} vs noise {noise:.4f}"
    circular = np.abs(ours[0][..., 3]).sum() / total
    assert circular < 1e-4, f"one reflection of unpolarized light made circular polarization: {circular:.3g}"
    if material == "glass":  # the test can tell: S1 is far above the noise
        assert np.abs(theirs[0][..., 1]).sum() / total > 0.1


def test_polarized_variant_needs_polarimetry(tmp_path):
    config = {"study": {"name": "flat_plain", "output": str(tmp_path / "plain.h5")},
              "surface": {"generator": "flat", "size_um": 8.0, "cells": 80}, "material": {"n": 1.5},
              "illumination": {"wavelengths_um": [0.55], "waist_um": 1.5, "directions_deg": [[0, 0], [40, 0]]},
              "model": {"name": "po"}, "output": {"resolution": 32}}
    wavebrdf.run(config).close()
    with pytest.raises(Exception, match=r"polarization = \\?\"jones\\?\""):
        _render("llvm_ad_spectral_polarized", {"type": "wavebrdf", "filename": str(tmp_path / "plain.h5")}, 1, 8, 1)
