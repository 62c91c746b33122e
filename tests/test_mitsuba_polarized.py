"""The "wavebrdf" plugin in Mitsuba's polarized variants against Mitsuba's own polarized conductor.

A flat interface computed by PO (θ_i every 5° to 85°, Jones matrices stored; waist 12 µm, so
its albedo is Fresnel's within ~0.2 % to 80°) renders, through our
plugin, the Stokes images S0…S3 that Mitsuba's ``conductor`` (its own polarized Fresnel, a delta
reflection) renders in the same variant, where the sphere is hit at ≤ 80°: a sphere under a uniform unpolarized sky (hidden: only the sphere is measured), one bounce
(``stokes`` integrator around ``path``). Aluminium (n, κ at 0.55 µm) and glass (n = 1.5, κ = 0:
the conductor plugin with k = 0 is a dielectric's reflection, without the transmission Mitsuba's
``dielectric`` would add). The metric per Stokes component k is Σ|ours_k − Mitsuba_k| / Σ Mitsuba_0
against the noise of two renders with other seeds. Unpolarized light sees only the first column
of M, which is the same for the reversed path of a mirror; so two direct tests of ``eval`` follow:
the matrix at the mirror direction from the normal to 70° against Mitsuba's own polarized Fresnel
in its bases (the pole, where the dataset's s/p frames are singular), and the reversed path of a
rough full-wave patch, whose Mueller matrix is not symmetric, against the dataset's own matrix of
the reversed incidence.
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
                  "surface": {"generator": "flat", "size_um": 80.0, "cells": 800},
                  "material": {"n": n, "kappa": kappa},
                  "illumination": {"wavelengths_um": [0.55], "waist_um": 12.0,
                                   "directions_deg": {"theta": {"start": 0, "stop": 85, "count": 18}, "phi": 0}},
                  "model": {"name": "po"}, "output": {"resolution": 256, "polarization": "jones"}}
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


_VARIANTS = [("llvm_ad_spectral_polarized", 64, 128), ("llvm_ad_mono_polarized", 48, 128),
             ("scalar_spectral_polarized", 12, 16)]
_CI_LLVM = {("aluminium", "llvm_ad_spectral_polarized"), ("glass", "llvm_ad_mono_polarized")}  # each llvm variant once


@pytest.mark.parametrize("material,variant,resolution,spp", [
    (m, *v) if v[0].startswith("scalar") or (m, v[0]) in _CI_LLVM else pytest.param(m, *v, marks=pytest.mark.slow)
    for v in _VARIANTS for m in MATERIALS])
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


def test_polarized_variant_needs_polarimetry(tmp_path, capsys):
    config = {"study": {"name": "flat_plain", "output": str(tmp_path / "plain.h5")},
              "surface": {"generator": "flat", "size_um": 8.0, "cells": 80}, "material": {"n": 1.5},
              "illumination": {"wavelengths_um": [0.55], "waist_um": 1.5, "directions_deg": [[0, 0], [40, 0]]},
              "model": {"name": "po"}, "output": {"resolution": 32}}
    wavebrdf.run(config).close()
    with pytest.raises(Exception, match=r"polarization = \\?\"jones\\?\""):
        _render("llvm_ad_spectral_polarized", {"type": "wavebrdf", "filename": str(tmp_path / "plain.h5")}, 1, 8, 1)
    from wavebrdf.jobs.cli import main  # `wavebrdf render --scene` says it in one line, exit 2, no traceback

    capsys.readouterr()
    assert main(["render", str(tmp_path / "plain.h5"), "--scene", "sphere", "--variant", "scalar_spectral_polarized",
                 "--spp", "1", "--resolution", "8"]) == 2
    err = capsys.readouterr().err
    assert "polarization = \"jones\"" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err


def _matrix(M) -> np.ndarray:
    """A scalar variant's Mueller matrix (first wavelength) as a 4×4 array."""
    return np.array([[float(np.ravel(M[i][j])[0]) for j in range(4)] for i in range(4)])


def _mitsuba_reflection(variant: str, cos_theta: float, eta: complex, light_in, light_out):
    """Mitsuba's own polarized specular reflection in its Stokes bases, built as conductor.cpp builds
    it (light arrives along −light_in and leaves along light_out)."""
    import drjit as dr

    mi.set_variant(variant)
    F = mi.mueller.specular_reflection(float(cos_theta), dr.scalar.Complex2f(eta.real, -abs(eta.imag)))
    n = mi.ScalarVector3f(0, 0, 1)
    s_in, s_out = dr.cross(n, -light_in), dr.cross(n, light_out)
    if dr.norm(s_in) < 1e-9:
        s_in = s_out = mi.ScalarVector3f(1, 0, 0)
    s_in, s_out = dr.normalize(s_in), dr.normalize(s_out)
    return np.array(mi.mueller.rotate_mueller_basis(F, -light_in, s_in, mi.mueller.stokes_basis(-light_in), light_out,
                                                    s_out, mi.mueller.stokes_basis(light_out)))


@pytest.mark.parametrize("mode", ["Radiance", "Importance"])
def test_eval_is_mitsubas_polarized_fresnel_at_the_mirror_direction(flat_datasets, mode):
    """The plugin's Mueller matrix at ω_o = mirror(ω_i), normalized by M00, equals Mitsuba's
    specular_reflection rotated into its Stokes bases, from the normal (where the dataset's s/p
    frames are singular) to 70°, in both transport directions."""
    variant = "scalar_spectral_polarized"
    mi.set_variant(variant)
    from wavebrdf.mitsuba.bsdfs import register

    register()
    bsdf = mi.load_dict({"type": "wavebrdf", "filename": str(flat_datasets["glass"])})
    ctx = mi.BSDFContext(getattr(mi.TransportMode, mode))
    worst = 0.0
    for theta_deg in (0.0, 2.0, 10.0, 45.0, 70.0):
        t, p = np.deg2rad(theta_deg), np.deg2rad(30.0)
        wi = mi.ScalarVector3f(np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t))
        wo = mi.ScalarVector3f(-wi.x, -wi.y, wi.z)
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(wi)
        si.wavelengths = [550.0] * 4
        ours = _matrix(bsdf.eval(ctx, si, mi.Vector3f(wo)))
        light_in, light_out = (wo, wi) if mode == "Radiance" else (wi, wo)
        ref = _mitsuba_reflection(variant, np.cos(t), complex(MATERIALS["glass"][0], -MATERIALS["glass"][1]),
                                  light_in, light_out)
        error = float(np.max(np.abs(ours / ours[0, 0] - ref / ref[0, 0])))
        logger.info("%s θ=%g°: max |M/M00 − Mitsuba's| = %.2e", mode, theta_deg, error)
        worst = max(worst, error)
    assert worst < 0.01


def _pixel_direction(res: int, theta_deg: float, phi_deg: float) -> tuple[float, float, np.ndarray]:
    """(θ, φ) in degrees and the unit vector of the pixel centre nearest to (θ, φ) on a res² grid."""
    centres = 2.0 * (np.arange(res) + 0.5) / res - 1.0
    u, v = (centres[np.argmin(np.abs(centres - c))] for c in
            np.sin(np.deg2rad(theta_deg)) * np.array([np.cos(np.deg2rad(phi_deg)), np.sin(np.deg2rad(phi_deg))]))
    w = np.sqrt(1.0 - u * u - v * v)
    return float(np.rad2deg(np.arcsin(np.hypot(u, v)))), float(np.rad2deg(np.arctan2(v, u))), np.array([u, v, w])


def test_eval_takes_the_reversed_path_of_a_reciprocal_surface(tmp_path):
    """A rough aluminium patch under plane waves, solved by the full wave (exactly reciprocal), at two
    pixel-centre directions A and B. In radiance transport the plugin evaluates light from B seen
    from A with the table of incidence A (its reversed path); that must be the dataset's own
    Mueller matrix of incidence B at pixel A, taken from its s/p frames (ŝ = φ̂ of each direction)
    to Mitsuba's Stokes bases by Mitsuba's rotate_mueller_basis. Importance transport reads the
    table of A as is. M is not symmetric here, so a missing or misplaced transpose shows."""
    import drjit as dr

    res = 32
    (ta, pa, a), (tb, pb, b) = _pixel_direction(res, 15.0, 0.0), _pixel_direction(res, 35.0, 160.0)
    config = {"study": {"name": "reciprocal", "output": str(tmp_path / "reciprocal.h5")},
              "surface": {"generator": "gaussian", "size_um": 0.8, "cells": 16, "rms_height_um": 0.04,
                          "correlation_um": 0.2, "seed": 11},
              "material": {"n": 0.46582, "kappa": 4.7119},
              "illumination": {"wavelengths_um": [0.4], "directions_deg": [[ta, pa], [tb, pb]], "beam": "plane",
                                   "waist_um": 0.4},
              "model": {"name": "bem", "method": "dense"},
              "output": {"resolution": res, "polarization": "mueller"}}
    with wavebrdf.run(config) as ds:
        M = ds.mueller((0,))  # (incidence, 4, 4, res, res), s/p frames

    def pixel(d):
        return tuple(int(np.floor((c + 1.0) / 2.0 * res)) for c in d[:2])

    def s_axis(d):
        rho = np.hypot(d[0], d[1])
        return mi.ScalarVector3f(-d[1] / rho, d[0] / rho, 0.0)

    variant = "scalar_spectral_polarized"
    mi.set_variant(variant)
    from wavebrdf.mitsuba.bsdfs import register

    register()
    bsdf = mi.load_dict({"type": "wavebrdf", "filename": str(tmp_path / "reciprocal.h5"), "smooth_sigma": 0.0,
                         "isotropic": False})
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*a)
    si.wavelengths = [400.0] * 4
    A, B = mi.ScalarVector3f(*a), mi.ScalarVector3f(*b)
    for mode, incidence, light_in, light_out in (("Radiance", 1, B, A), ("Importance", 0, A, B)):
        stored = M[incidence][(slice(None), slice(None)) + pixel(np.array(light_out))]
        expected = np.array(mi.mueller.rotate_mueller_basis(
            mi.ScalarMatrix4f(stored.astype(float)), -light_in, s_axis(np.array(light_in)),
            mi.mueller.stokes_basis(-light_in), light_out, s_axis(np.array(light_out)),
            mi.mueller.stokes_basis(light_out)))
        ours = _matrix(bsdf.eval(mi.BSDFContext(getattr(mi.TransportMode, mode)), si, mi.Vector3f(*b))) / b[2]
        error = float(np.max(np.abs(ours - expected)) / expected[0, 0])
        asymmetry = float(np.max(np.abs(expected - expected.T)) / expected[0, 0])
        logger.info("%s: |plugin − dataset| = %.2e M00 (the matrix's own asymmetry %.2f M00)", mode, error, asymmetry)
        assert error < 1e-3, f"{mode}: the plugin's Mueller matrix is off by {error:.3g} of M00"
        assert asymmetry > 0.05
    assert dr is not None


def _query(bsdf, variant: str, wavelength_nm: float, theta_deg: float, phi_deg: float, wo, mode: str = "Importance"):
    """The plugin's Mueller matrix (4×4, first wavelength) for incidence (θ, φ) and outgoing ``wo``."""
    t, p = np.deg2rad(theta_deg), np.deg2rad(phi_deg)
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(float(np.sin(t) * np.cos(p)), float(np.sin(t) * np.sin(p)), float(np.cos(t)))
    if "spectral" in variant:
        si.wavelengths = [wavelength_nm] * 4
    return _matrix(bsdf.eval(mi.BSDFContext(getattr(mi.TransportMode, mode)), si, mi.Vector3f(*(float(x) for x in wo))))


def test_anisotropic_tables_blend_in_the_querys_frames(tmp_path):
    """Tables on a θ × φ grid (``isotropic = false``: the "grid" scheme) blend neighbouring φ_k. (a)
    Flat glass at φ_i every 90°: between the nodes (φ = 45°, 130°) at the mirror direction M/M00 is
    Mitsuba's Fresnel within 0.002 at the tabulated θ 30° and 60° (blended in frames fixed to x̂,
    where a flat surface's matrix turns with φ_i, it would be off by a large share of M00). (b) A
    glass sinusoidal grating (period 0.7 µm along x, amplitude 0.1 µm, λ 0.55 µm: anisotropic, and
    its order +1 polarizes, M01/M00 ≈ 0.28 under PO): just off the normal at φ = 45° the matrix in
    that order is the normal-incidence table's, within 0.01 of M00 (that table's frames do not turn
    with the query's azimuth, so the plugin turns them; left unturned, the query's frames would read
    it turned by 90° in Q, U, M01 moved to M02); in a scalar and a JIT (llvm) variant."""
    variant = "scalar_spectral_polarized"
    flat = {"study": {"name": "grid_flat", "output": str(tmp_path / "grid_flat.h5")},
            "surface": {"generator": "flat", "size_um": 30.0, "cells": 150}, "material": {"n": 1.5},
            "illumination": {"wavelengths_um": [0.55], "waist_um": 5.0,
                             "directions_deg": {"theta": [0, 30, 60], "phi": [0, 90, 180, 270]}},
            "model": {"name": "po"}, "output": {"resolution": 128, "polarization": "jones"}}
    grating = {"study": {"name": "grid_grating", "output": str(tmp_path / "grid_grating.h5")},
               "surface": {"generator": "sinusoid", "size_um": 12.0, "cells": 120, "amplitude_um": 0.1,
                           "period_um": 0.7},
               "material": {"n": 1.5},
               "illumination": {"wavelengths_um": [0.55], "waist_um": 3.0,
                                "directions_deg": {"theta": [0, 20], "phi": [0, 90, 180, 270]}},
               "model": {"name": "po"}, "output": {"resolution": 128, "polarization": "jones"}}
    for config in (flat, grating):
        wavebrdf.run(config).close()
    mi.set_variant(variant)
    from wavebrdf.mitsuba.bsdfs import register

    register()
    bsdf = mi.load_dict({"type": "wavebrdf", "filename": flat["study"]["output"], "isotropic": False})
    worst = 0.0
    for mode in ("Radiance", "Importance"):
        for theta_deg in (30.0, 60.0):
            for phi_deg in (45.0, 130.0):
                t, p = np.deg2rad(theta_deg), np.deg2rad(phi_deg)
                wi = mi.ScalarVector3f(np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t))
                wo = mi.ScalarVector3f(-wi.x, -wi.y, wi.z)
                ours = _query(bsdf, variant, 550.0, theta_deg, phi_deg, wo, mode)
                light_in, light_out = (wo, wi) if mode == "Radiance" else (wi, wo)
                ref = _mitsuba_reflection(variant, np.cos(t), complex(1.5, 0.0), light_in, light_out)
                error = float(np.max(np.abs(ours / ours[0, 0] - ref / ref[0, 0])))
                logger.info("flat glass, grid, %s (%g°, %g°): max |M/M00 − Mitsuba's| = %.2e", mode, theta_deg,
                            phi_deg, error)
                worst = max(worst, error)
    assert worst < 0.002
    sine = 0.55 / 0.7
    order = np.array([sine, 0.0, np.sqrt(1.0 - sine**2)])  # order +1 at normal incidence
    for variant in ("scalar_spectral_polarized", "llvm_ad_mono_polarized"):
        mi.set_variant(variant)
        register()
        bsdf = mi.load_dict({"type": "wavebrdf", "filename": grating["study"]["output"], "isotropic": False})
        at_pole = _query(bsdf, variant, 550.0, 0.0, 0.0, order)
        near = _query(bsdf, variant, 550.0, 0.01, 45.0, order)
        polarizing = abs(at_pole[0, 1] / at_pole[0, 0])
        error = float(np.max(np.abs(near / near[0, 0] - at_pole / at_pole[0, 0])))
        logger.info("%s, grating, order +1: at the pole M/M00 = %s; just off it at φ 45°: off by %.2e (polarizing "
                    "%.2f)", variant, np.round(at_pole / at_pole[0, 0], 3).tolist(), error, polarizing)
        assert polarizing > 0.1 and error < 0.01
