"""Jones and Mueller matrices (solver/polarimetry.py, [output] polarization; docs/dataset.md).

* A flat interface: every model returning coherent fields gives, at the mirror direction, the
  Mueller matrix of the Fresnel coefficients (tests/references.py, written from Born & Wolf and
  Collett; not from wavebrdf) with r_p/r_s scaled by the beam's √(P_s/P_p) (Novotny & Hecht's
  angular spectrum; 1 − 7·10⁻⁵ for the approximate rungs' 30 µm waist at 80°), metal and
  dielectric, 20°, 50° and 80° (the full wave: 20°, 50° and 70°), within 0.5 % of M₀₀; off the plane of incidence only the vector-field models (bem, po) carry
  the polarization, which is why the dataset stores Jones/Mueller matrices from them alone.
* Steered studies answer in the requested direction's incident frame.
* Reciprocity: the full wave's Mueller matrix of the reversed path is R Mᵀ R (the relation the
  Mitsuba plugin relies on in radiance transport), on a rough patch under plane waves.
* One coherent realization does not depolarize (depolarization index 1 in every pixel); the
  speckle average of a rough surface does.
* The dataset: `jones` and `mueller` written, read back (also through xarray), M₀₀ = the BRDF;
  refusals name the key and the model.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
from references import ALUMINIUM_400NM, fresnel_coefficients, fresnel_mueller, gaussian_beam_power_ratio

from wavebrdf.solver.farfield import HemisphereGrid
from wavebrdf.solver.models import SurfaceScene, get_model, model_class, rungs
from wavebrdf.solver.polarimetry import depolarization_index, jones, mueller, reversed_path, to_regular_frames
from wavebrdf.solver.surface import generate

logger = logging.getLogger(__name__)

LAMBDA = 0.4
GLASS = 1.5
MATERIALS = {"glass": GLASS, "aluminium": ALUMINIUM_400NM}
COHERENT = [n for n in rungs("height_field") if model_class(n).capabilities.returns == "fields"]
TOLERANCE = 0.005  # of M00, every element (issue 32's bar)

# A flat patch whose beam spreads over λ/(πw) ≈ 4 mrad (the approximate rungs). The full wave
# needs its own patch and a waist of a few λ, whose s and p beams carry different powers toward
# grazing: the reference is Fresnel's Mueller matrix with r_p/r_s scaled by √(P_s/P_p) of that beam
# (tests/references.py, from the beam's definition). Toward grazing the light cone cuts the beam's
# spectrum unless the waist grows (3·10⁻⁴ of it at 70° for 3.6 µm, 7.7 % at 80° for 6 µm), and the
# mirror direction is read from a grid fine enough for the lobe: a 256² grid's bilinear reading of
# the exact far field misses by 0.86 % at 80° (docs/dataset.md, 'toward grazing'). The full wave
# is tested at 20°, 50°, 70° and 80° (8.4 GiB).
FLAT = dict(cells=810, size_um=162.0, waist_um=30.0, resolution=768, options=None)
_CONTINUED = {"method": "aim", "aim": {"edge": "flat"}}
FLAT_BEM = {20.0: dict(cells=72, size_um=2.4, waist_um=0.6, resolution=128, options=_CONTINUED),
            50.0: dict(cells=144, size_um=4.8, waist_um=1.2, resolution=256, options=_CONTINUED),
            70.0: dict(cells=48, size_um=2.4, waist_um=3.6, resolution=256, options=_CONTINUED),
            80.0: dict(cells=48, size_um=2.4, waist_um=6.0, resolution=1024, options=_CONTINUED)}


def _flat_cases():
    cases = []
    for name in COHERENT:
        for material in MATERIALS:
            if name == "bem":  # CI: glass at 20° (8 s each)
                cases.append((name, material, 20.0) if material == "glass" else
                             pytest.param(name, material, 20.0, marks=pytest.mark.slow))
                cases += [pytest.param(name, material, angle, marks=pytest.mark.slow) for angle in (50.0, 70.0, 80.0)]
                continue
            cases += [(name, material, angle) for angle in (20.0, 50.0, 80.0)]
    return cases


def _at_mirror(M: np.ndarray, grid: HemisphereGrid, theta: float, phi: float = 0.0) -> np.ndarray:
    """M (4, 4, res, res) bilinear at the mirror direction −sin θ (cos φ, sin φ) of (θ_i, φ_i)."""
    g = (-np.sin(theta) * np.array([np.cos(phi), np.sin(phi)]) + 1.0) * grid.resolution / 2.0 - 0.5
    (i, j), (a, b) = np.floor(g).astype(int), g - np.floor(g)
    return ((1 - a) * (1 - b) * M[:, :, i, j] + a * (1 - b) * M[:, :, i + 1, j] + (1 - a) * b * M[:, :, i, j + 1]
            + a * b * M[:, :, i + 1, j + 1])


def _scene(surface, cfg, index, theta, phi, beam="exact"):
    return SurfaceScene(surface=surface, wavelength_um=LAMBDA, index=complex(index), theta_i=float(theta),
                        phi_i=float(phi), waist_um=cfg.get("waist_um"), grid=HemisphereGrid(cfg["resolution"]),
                        beam=beam)


@pytest.mark.parametrize("name,material,theta_deg", _flat_cases())
def test_flat_mueller_equals_fresnel(cl_ctx, name, material, theta_deg):
    cfg = FLAT_BEM[theta_deg] if name == "bem" else FLAT
    model = get_model(name, cfg["options"])
    theta = np.deg2rad(theta_deg)
    index = MATERIALS[material]
    field = model.run(cl_ctx, _scene(generate("flat", cells=cfg["cells"], size_um=cfg["size_um"]), cfg, index, theta, 0.0))
    M = _at_mirror(mueller(jones(field)), field.grid, theta)
    r_s, r_p = fresnel_coefficients(1.0, index, theta)
    expected = fresnel_mueller(r_s, r_p / np.sqrt(gaussian_beam_power_ratio(LAMBDA, cfg["waist_um"], theta)))
    measured, reference = M / M[0, 0], expected / expected[0, 0]
    worst = float(np.max(np.abs(measured - reference)))
    logger.info("%s %s %g°: normalized Mueller at the mirror direction\n%s\nFresnel\n%s\nworst %.2e", name, material,
                theta_deg, np.round(measured, 5), np.round(reference, 5), worst)
    assert worst <= TOLERANCE, f"{name} {material} {theta_deg}°: Mueller off by {worst:.3g} of M00"


@pytest.mark.parametrize("name", [n for n in COHERENT if model_class(n).capabilities.vector_fields])
def test_vector_models_carry_the_polarization_around_the_pole(cl_ctx, name):
    """Normal incidence on flat glass: the reflected lobe straddles the pole, where the s/p frames of
    neighbouring pixels differ by up to 180°. A vector far field, seen in the regular frames
    (solver/polarimetry.py ``to_regular_frames``), is Fresnel's diag(1, 1, −1, −1)·R in every
    lobe pixel (M00-weighted mean within 0.005); a scalar rung (E_s on φ̂_o, E_p on θ̂_o) is not,
    which is why the dataset refuses it for Jones/Mueller output (checked on ghs)."""
    def regular(model_name, cfg):
        field = get_model(model_name, cfg["options"]).run(
            cl_ctx, _scene(generate("flat", cells=cfg["cells"], size_um=cfg["size_um"]), cfg, GLASS, 0.0, 0.0))
        U, V = field.grid.uv
        M = to_regular_frames(mueller(jones(field)), U, V, 0.0)
        lobe = field.grid.inside & (M[0, 0] > 1e-2 * M[0, 0].max())
        weight = M[0, 0][lobe]
        normalized = M[:, :, lobe] / weight
        return np.sum(normalized * weight, axis=-1) / np.sum(weight), int(lobe.sum())

    expected = np.diag([1.0, 1.0, -1.0, -1.0])
    mean, pixels = regular(name, FLAT_BEM[20.0] if name == "bem" else FLAT)
    error = float(np.max(np.abs(mean - expected)))
    scalar, _ = regular("ghs", FLAT)
    logger.info("%s: %d lobe pixels, regular-frame M/M00 off diag(1, 1, −1, −1) by %.2e (ghs: %.2f)", name, pixels,
                error, np.max(np.abs(scalar - expected)))
    assert pixels >= 4 and error < TOLERANCE
    assert np.max(np.abs(scalar - expected)) > 0.1


def test_flat_mueller_sign_conventions():
    """The reference itself: a perfect conductor at normal incidence keeps linear polarization
    (M = diag(1, 1, −1, −1) in frames whose p axes are mirrored), and aluminium's phase delay
    gives M23 = Im(r_s r_p*) ≠ 0 at 60° (the element a wrong V convention flips)."""
    M = fresnel_mueller(np.array(-1.0), np.array(1.0))
    assert np.allclose(M, np.diag([1.0, 1.0, -1.0, -1.0]))
    r_s, r_p = fresnel_coefficients(1.0, ALUMINIUM_400NM, np.deg2rad(60.0))
    field = np.array([[-r_s, 0], [0, -r_p]])[:, :, None]  # J = −diag(r_s, r_p) (solver/polarimetry.py)
    assert np.allclose(mueller(field)[..., 0], fresnel_mueller(r_s, r_p), atol=1e-12)
    assert abs(fresnel_mueller(r_s, r_p)[2, 3]) > 0.05


RECIPROCITY_PAIRS_DEG = [((15.0, 0.0), (35.0, 160.0)), ((30.0, 60.0), (50.0, 220.0))]


def test_full_wave_mueller_is_reciprocal(cl_ctx):
    """M(ω_o → ω_i) = R M(ω_i → ω_o)ᵀ R to rounding (measured 4e-15 of M₀₀): the dense PMCHWT
    amplitudes under plane waves are reciprocal (tests/test_models.py)."""
    cfg = dict(resolution=32)
    grid = HemisphereGrid(cfg["resolution"])
    surface = generate("gaussian", cells=16, size_um=0.8, seed=11, rms_height_um=0.04, correlation_um=0.2)
    model = get_model("bem", {"method": "dense"})

    def pixel(theta_deg, phi_deg):
        u = np.sin(np.deg2rad(theta_deg)) * np.array([np.cos(np.deg2rad(phi_deg)), np.sin(np.deg2rad(phi_deg))])
        return tuple(int(np.argmin(np.abs(grid.u - c))) for c in u)

    def direction(p):
        u, v = grid.u[p[0]], grid.u[p[1]]
        return np.arcsin(np.hypot(u, v)), np.arctan2(v, u)

    worst = 0.0
    for a_deg, b_deg in RECIPROCITY_PAIRS_DEG:
        a, b = pixel(*a_deg), pixel(*b_deg)
        matrices = []
        for src, dst in ((a, b), (b, a)):
            theta, phi = direction(src)
            field = model.run(cl_ctx, _scene(surface, cfg, ALUMINIUM_400NM, theta, phi, beam="plane"))
            matrices.append(mueller(jones(field))[:, :, dst[0], dst[1]])
        forward, backward = matrices
        error = float(np.max(np.abs(backward - reversed_path(forward))) / forward[0, 0])
        unrelated = float(np.max(np.abs(backward - forward)) / forward[0, 0])
        logger.info("pixels %s ↔ %s: |M_ba − R M_abᵀ R| = %.3g M00 (|M_ba − M_ab| = %.3g M00)", a, b, error, unrelated)
        worst = max(worst, error)
        assert unrelated > 3 * error, "the pair does not tell the reversed-path relation from M_ab itself"
    assert worst < 1e-9, f"reciprocity of the Mueller matrix off by {worst:.3g} of M00"


def test_coherent_realization_does_not_depolarize_and_its_speckle_average_does(cl_ctx):
    """PO on rough glass (σ = 0.3 µm, ℓ = 1 µm: facets tilted ±0.4 rad turn the local planes of
    incidence), 60°: DI = 1 in every pixel of the one realization (a property of a Mueller matrix
    made from one Jones matrix, checked here through the model's fields), while its speckle average
    (5×5-pixel boxes, Δu = 0.08 > the speckle size λ/(πw) ≈ 0.055) depolarizes (measured 0.981,
    M₀₀-weighted)."""
    cfg = dict(resolution=128, waist_um=2.3)
    surface = generate("gaussian", cells=400, size_um=12.5, seed=7, rms_height_um=0.3, correlation_um=1.0)
    field = get_model("po").run(cl_ctx, _scene(surface, cfg, GLASS, np.deg2rad(60.0), 0.0))
    M = mueller(jones(field))
    inside = field.grid.inside & (M[0, 0] > 1e-3 * M[0, 0].max())
    di = depolarization_index(M)[inside]
    assert np.allclose(di, 1.0, atol=1e-9), f"a single coherent realization depolarizes: DI {di.min():.6g}"
    from scipy.ndimage import uniform_filter

    averaged = np.stack([[uniform_filter(np.where(field.grid.inside, M[i, j], 0.0), 5) for j in range(4)]
                         for i in range(4)])
    weight = M[0, 0][inside]
    di_avg = float(np.sum(depolarization_index(averaged)[inside] * weight) / np.sum(weight))
    logger.info("depolarization index of the speckle average, M00-weighted: %.4f", di_avg)
    assert di_avg < 0.99


# --- the dataset --------------------------------------------------------------------------


def _config(tmp_path, polarization, model="po"):
    return {"study": {"name": f"pol_{polarization}", "output": str(tmp_path / f"pol_{polarization}.h5")},
            "surface": {"generator": "gaussian", "size_um": 6.0, "cells": 120, "rms_height_um": 0.05,
                        "correlation_um": 1.0, "seed": 3},
            "material": {"name": "aluminium"},
            "illumination": {"wavelengths_um": [0.5, 0.6], "directions_deg": [[0, 0], [40, 30]], "waist_um": 1.2},
            "model": {"name": model}, "output": {"resolution": 64, "polarization": polarization}}


def test_dataset_stores_jones_and_mueller(tmp_path):
    import xarray as xr

    import wavebrdf

    paths = {}
    for kind in ("jones", "mueller"):
        wavebrdf.run(_config(tmp_path, kind)).close()
        paths[kind] = tmp_path / f"pol_{kind}.h5"
    with wavebrdf.open(paths["jones"]) as a, wavebrdf.open(paths["mueller"]) as b:
        assert (a.polarimetry, b.polarimetry) == ("jones", "mueller")
        J = a.jones()
        assert J.shape == (2, 2, 2, 2, 64, 64) and np.iscomplexobj(J)
        Ma, Mb = a.mueller(), b.mueller()
        assert Ma.shape == Mb.shape == (2, 2, 4, 4, 64, 64)
        scale = np.nanmax(Mb[:, :, 0, 0])
        assert np.nanmax(np.abs(Ma - Mb)) <= 1e-5 * scale
        assert np.nanmax(np.abs(Mb[:, :, 0, 0] - b.brdf)) <= 1e-5 * scale  # M00 is the unpolarized BRDF
        assert np.array_equal(np.isnan(Mb[:, :, 0, 0]), np.isnan(b.brdf))
        with pytest.raises(Exception, match="polarization = \"jones\""):
            b.jones()
    x = xr.open_dataset(paths["jones"], engine="h5netcdf")
    assert x["jones"].dims[-5:] == ("polarization_out", "polarization", "u", "v", "complex")
    y = xr.open_dataset(paths["mueller"], engine="h5netcdf")
    assert list(y["stokes_in"].values) == ["I", "Q", "U", "V"]


def test_polarimetry_refusals(tmp_path):
    import wavebrdf
    from wavebrdf.jobs.errors import ConfigError

    with pytest.raises(ConfigError, match=r"\[output\] polarization = \"jones\": model 'gs' returns intensity"):
        wavebrdf.run(_config(tmp_path, "jones", model="gs"))
    with pytest.raises(ConfigError, match=r"model 'kirchhoff' returns scalar fields.*vector-field models bem, po"):
        wavebrdf.run(_config(tmp_path, "mueller", model="kirchhoff"))
    with pytest.raises(ConfigError, match=r"\[sweep\] output.polarization: cannot be swept \(every case must store the same variables\)"):
        wavebrdf.run({**_config(tmp_path, "jones", model="po"), "sweep": {"output.polarization": ["jones", "intensity"]}})
    with pytest.raises(ConfigError, match=r"\[output\] polarization = 'stokes'|polarization.*stokes"):
        wavebrdf.run(_config(tmp_path, "stokes"))


@pytest.mark.parametrize("incidence", ["beam", "footprint"])
def test_steered_figures_are_in_the_requested_incident_frame(tmp_path, incidence):
    """Steered synthesis sums patch fields excited with the basic direction's ê_s, ê_p; every stored
    figure (s and p BRDFs, Jones, Mueller) must answer for the requested direction's frame. Flat
    glass, basic direction the normal, requested (8°, 90°), (12°, 45°) and (12°, 90°), at the mirror
    direction. po lit by the exact beam reflects each plane wave at its own angle: M/M00 is Fresnel's
    at θ_i within 0.015 and the s/p BRDF ratio Fresnel's within 4 % (measured 0.0056, 0.0006, 0.013
    and +1.1 %, −0.03 %, +2.6 %: the synthesis at 0.66× its aliasing limit with a waist of λ; the
    basic frame's s is the requested p at φ_i = 90°, where s/p read in the basic frame is R_p/R_s,
    −11 % at 8°). po lit
    by the footprint keeps the basic direction's Fresnel factors (warned), so its figures are those
    of normal incidence carried to ω_i: M/M00 within 0.005 of Fresnel's at 0° (measured ≤ 0.0016),
    s/p 1 within 0.5 %. M00 is the unpolarized BRDF in every pixel (the plain projections of one
    frame on the other, not orthogonal, would lose 1–3 % of it)."""
    import warnings

    import wavebrdf

    res = 256
    config = {"study": {"name": "steered", "output": str(tmp_path / "steered.h5")},
              "surface": {"generator": "flat", "size_um": 3.7, "cells": 74}, "material": {"n": GLASS},
              "illumination": {"wavelengths_um": [0.5], "directions_deg": [[8, 90], [12, 45], [12, 90]],
                               "waist_um": 0.5},
              "model": {"name": "po", "incidence": incidence},
              "output": {"resolution": res, "polarization": "mueller", "per_polarization": True},
              "steering": {"patches": [3, 3], "patch_size_um": 2.7}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the small waist's spread, and the footprint's kept Fresnel factors
        with wavebrdf.run(config) as ds:
            M, coords, brdf, brdf_sp = ds.mueller((0,)), ds.coords, ds.brdf[0], np.asarray(ds["brdf_sp"])[0]
            assert np.allclose(ds["theta_basic"], 0.0)
    unpolarized_error = np.nanmax(np.abs(M[:, 0, 0] - brdf)) / np.nanmax(brdf)
    logger.info("steered, po lit by the %s: max |M00 − brdf| = %.2e of the peak", incidence, unpolarized_error)
    assert unpolarized_error <= 1e-5
    grid = HemisphereGrid(res)
    for k in range(3):
        theta, phi = np.deg2rad(coords["theta_i"][k]), np.deg2rad(coords["phi_i"][k])
        at = _at_mirror(M[k].astype(float), grid, theta, phi)
        fresnel_at = theta if incidence == "beam" else 0.0
        rs, rp = fresnel_coefficients(1.0, GLASS, fresnel_at)
        expected = fresnel_mueller(rs, rp)
        error = float(np.max(np.abs(at / at[0, 0] - expected / expected[0, 0])))
        s_at, p_at = (float(_at_mirror(brdf_sp[k, i][None, None].astype(float), grid, theta, phi)[0, 0]) for i in (0, 1))
        ratio_error = (s_at / p_at) / (abs(rs) ** 2 / abs(rp) ** 2) - 1.0
        logger.info("(%g°, %g°): max |M/M00 − Fresnel at %.0f°| = %.3g; s/p %.4f, off Fresnel's by %+.4f",
                    coords["theta_i"][k], coords["phi_i"][k], np.rad2deg(fresnel_at), error, s_at / p_at, ratio_error)
        assert error < (0.015 if incidence == "beam" else 0.005)
        assert abs(ratio_error) < (0.04 if incidence == "beam" else 0.005)


def test_auto_picks_a_vector_rung_for_polarimetry_after_a_choice_for_intensities():
    """auto caches its choice per scene in the process; a study storing Jones matrices must not get
    the scalar rung chosen for the same scene without them (one process, two studies)."""
    import dataclasses

    # smooth enough that the rule fitted to today's trade table picks a scalar rung (ohs) for intensities
    surface = generate("gaussian", cells=200, size_um=20.0, seed=3, rms_height_um=0.01, correlation_um=2.0)
    scene = SurfaceScene(surface=surface, wavelength_um=0.5, index=1.5 + 0j, theta_i=0.3, phi_i=0.0, waist_um=5.0,
                         grid=HemisphereGrid(64))
    auto = get_model("auto")
    plain = auto.choice(scene).model
    polarimetric = auto.choice(dataclasses.replace(scene, polarimetric=True)).model
    assert not model_class(plain).capabilities.vector_fields, "the scene no longer tells the two apart"
    assert model_class(polarimetric).capabilities.vector_fields, polarimetric


def test_steered_frame_changes_agree_to_second_order_in_the_offset():
    """The beam's inverse of the projected frames and the footprint's rotation of the basic frame
    are the same map to first order in the offset, the identity without one, and the rotation is
    orthogonal: basic (40°, 10°), requested 1°–8° away."""
    from wavebrdf.solver.polarimetry import steered_frame_change

    basic = (np.deg2rad(40.0), np.deg2rad(10.0))
    assert np.allclose(steered_frame_change(basic, basic, beam=True), np.eye(2), atol=1e-14)
    assert np.allclose(steered_frame_change(basic, basic, beam=False), np.eye(2), atol=1e-14)
    gaps = []
    for offset_deg in (1.0, 2.0, 4.0, 8.0):
        stated = (np.deg2rad(40.0 + offset_deg * 0.6), np.deg2rad(10.0 + offset_deg))
        rotation = steered_frame_change(basic, stated, beam=False)
        assert np.allclose(rotation @ rotation.T, np.eye(2), atol=1e-13)
        gaps.append(float(np.max(np.abs(steered_frame_change(basic, stated, beam=True) - rotation))))
    slopes = np.diff(np.log(gaps)) / np.log(2.0)
    logger.info("|inverse − rotation| at offsets 1, 2, 4, 8°: %s (log-log slopes %s)", np.round(gaps, 6), np.round(slopes, 2))
    assert np.all(slopes > 1.8) and gaps[0] < 1e-3


def _responses_to(grid, J_exc, power, direction_rad, centre_um=(0.0, 0.0, 0.0)):
    """A FarField whose response to excitation a (the models' ŝ, −p̂, incident powers ``power``)
    is the Jones column J_exc[:, a] (per pixel), for a source centred at ``centre_um``."""
    from wavebrdf.solver.farfield import ETA0, FarField
    from wavebrdf.solver.polarimetry import outgoing_frames

    s_out, p_out = outgoing_frames(*grid.uv)
    amplitude = np.zeros((2,) + grid.mu.shape)
    for a in range(2):
        amplitude[a][grid.inside] = np.sqrt(2.0 * ETA0 * power[a] * grid.mu[grid.inside])
    E = np.stack([(1.0, -1.0)[a] * amplitude[a][..., None] * (J_exc[0, a][..., None] * s_out
                                                                + J_exc[1, a][..., None] * p_out)
                  for a in range(2)])  # (a, i, j, xyz)
    k = 2 * np.pi / 0.5
    out = np.stack([grid.uv[0], grid.uv[1], grid.mu], axis=-1)
    E = E * np.exp(-1j * k * (out @ np.asarray(centre_um)))[None, ..., None]  # the source's far-field phase
    return FarField(grid=grid, wavelength_um=0.5, exterior_index=1.0, theta_i=float(direction_rad[0]),
                    phi_i=float(direction_rad[1]), E=np.moveaxis(E, -1, 1), incident_power=np.asarray(power))


def _excited_by(J, basic, stated, beam):
    """The responses to the basic direction's polarizations of a surface whose Jones matrix in the
    stated direction's frame is J: exact beams carry â_exc projected on the plane normal to ω_i
    (J v̂_a, v̂_a the projection's stated components, normalized); footprint rungs answer J Tᵀ with
    T the rotation carrying the frames."""
    from wavebrdf.solver.polarimetry import incident_frame, steered_frame_change

    if beam:
        projected = np.array(incident_frame(*basic)) @ np.array(incident_frame(*stated)).T
        V = projected / np.linalg.norm(projected, axis=1, keepdims=True)
    else:
        V = steered_frame_change(tuple(basic), tuple(stated), beam=False)
    return np.einsum("bcij,ac->baij", J, V)


def test_in_stated_frame_recovers_a_known_jones_matrix():
    """Fields built from a known Jones matrix J (random per pixel, in the stated frame (37°, 31°))
    as the responses to another direction's (29°, 17°) polarizations, per unit power of incident
    powers 2 and 3 W (``_excited_by``): ``in_stated_frame`` then ``jones`` give J back to rounding
    for exact beams and footprints (the models' −p̂ excitation and the powers included)."""
    from wavebrdf.solver.polarimetry import in_stated_frame

    grid = HemisphereGrid(16)
    rng = np.random.default_rng(5)
    J = rng.normal(size=(2, 2, 16, 16)) + 1j * rng.normal(size=(2, 2, 16, 16))
    basic, stated = np.deg2rad([29.0, 17.0]), np.deg2rad([37.0, 31.0])
    power = np.array([2.0, 3.0])
    for beam in (True, False):
        field = _responses_to(grid, _excited_by(J, basic, stated, beam), power, stated)
        recovered = jones(in_stated_frame(field, tuple(basic), beam=beam))
        error = np.max(np.abs(recovered - J)[:, :, grid.inside]) / np.max(np.abs(J))
        logger.info("beam %s: max |J recovered − J| = %.2e of max |J|", beam, error)
        assert error < 1e-12


def test_a_synthesis_of_mixed_rungs_changes_each_patchs_frame_by_its_own_rung():
    """``auto`` in a steered study may run one patch with an exact beam (bem) and its neighbour
    with a footprint rung (kirchhoff), each normalized by its own kind of summed beam: patch (0, 0)
    answers the stated direction's Jones matrix J₀ through the exact beams' projection per unit of
    powers (2, 3) W, patch (1, 0) J₁ through the footprint's rotation per unit of (4, 5) W. The
    synthesis in the stated frame is Σ e^{+jk p·ω_i} J_p to rounding. The construction takes the
    footprint's rotation from ``steered_frame_change`` itself (the known-Jones test above and the
    flat-surface steering tests check the changes): this checks the grouping, the powers and the
    sum. One frame change for both patches misses by the two changes' difference (6·10⁻³ of the
    largest element at this 8°–14° offset, second order in it), one power for both by 1 − √(P₀/P₁)."""
    from wavebrdf.jobs.steering import PatchLayout, RungGroup, synthesize_in_stated_frame

    grid = HemisphereGrid(16)
    rng = np.random.default_rng(6)
    basic, stated = np.deg2rad([29.0, 17.0]), np.deg2rad([37.0, 31.0])
    layout = PatchLayout((2, 1), 2.0, 0.8)
    omega_i = np.array([np.sin(stated[0]) * np.cos(stated[1]), np.sin(stated[0]) * np.sin(stated[1]),
                        np.cos(stated[0])])
    k = 2 * np.pi / 0.5
    out = np.stack([grid.uv[0], grid.uv[1], grid.mu], axis=-1)
    patches = {(0, 0): (True, np.array([2.0, 3.0])), (1, 0): (False, np.array([4.0, 5.0]))}
    fields, expected = {}, 0.0
    for patch, (beam, power) in patches.items():
        J = rng.normal(size=(2, 2, 16, 16)) + 1j * rng.normal(size=(2, 2, 16, 16))
        centre = layout.centre(patch)
        fields[patch] = _responses_to(grid, _excited_by(J, basic, stated, beam), power, stated, centre)
        if beam:  # bem's far fields carry H, the footprint rungs' do not
            fields[patch] = dataclasses.replace(fields[patch], H=np.zeros_like(fields[patch].E))
        expected = expected + np.exp(1j * k * float(centre @ omega_i)) * np.exp(-1j * k * (out @ centre)) * J

    def error(beams, powers):
        groups = [RungGroup({p: fields[p]}, beams[p], powers[p]) for p in patches]
        J = jones(synthesize_in_stated_frame(groups, layout, *stated, tuple(basic)))
        return np.max(np.abs(J - expected)[:, :, grid.inside]) / np.max(np.abs(expected))

    beams, powers = {p: b for p, (b, _) in patches.items()}, {p: w for p, (_, w) in patches.items()}
    right = error(beams, powers)
    wrong = {"all exact": error({p: True for p in patches}, powers),
             "all footprint": error({p: False for p in patches}, powers),
             "one power": error(beams, {p: powers[(0, 0)] for p in patches})}
    logger.info("max |J − Σ J_p| / max: own frames and powers %.2e; %s", right,
                {name: f"{e:.2e}" for name, e in wrong.items()})
    assert right < 1e-12 and min(wrong.values()) > 1e-3
