"""Example scene: a wavebrdf material on a sphere or a tilted plate under a procedural sky.

World frame: z up. The environment is computed here (no downloads): a sky whose radiance grows
from the zenith to the horizon, a darker ground below it and a sun-like Gaussian spot. Mitsuba's
``envmap`` is a latitude–longitude image with +y up (row = acos(y)/π, column =
atan2(x, −z)/2π in its own frame); it is rotated by +90° about x so that its +y is the world +z.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from wavebrdf.jobs.store import Dataset
from wavebrdf.jobs.study_kinds import STUDY_KINDS, study_kind
from wavebrdf.mitsuba.bsdfs import fiber_radius, fiber_tables_for, register, require_mitsuba, tables_for
from wavebrdf.mitsuba.fiber_scene import GEOMETRIC_RADIUS, write_fiber_wisp

__all__ = ["DEFAULT_SUN", "default_variant", "environment", "llvm_usable", "render_scene", "scene_dict", "tone_map"]

DEFAULT_SUN = {"elevation_deg": 38.0, "azimuth_deg": -125.0, "radius_deg": 2.0, "radiance": 1500.0}


def _env_directions(height: int) -> np.ndarray:
    """World directions (height, 2·height, 3) of the envmap pixel centres."""
    width = 2 * height
    theta = (np.arange(height) + 0.5) / height * np.pi
    phi = (np.arange(width) + 0.5) / width * 2 * np.pi
    T, P = np.meshgrid(theta, phi, indexing="ij")
    local = np.stack([np.sin(T) * np.sin(P), np.cos(T), -np.sin(T) * np.cos(P)], axis=-1)
    # rotation by +90° about x: (x, y, z) -> (x, -z, y)
    return np.stack([local[..., 0], -local[..., 2], local[..., 1]], axis=-1)


def environment(height: int = 256, *, sun: dict | None = DEFAULT_SUN, zenith=(0.25, 0.42, 0.95),
                horizon=(0.95, 0.95, 1.0), ground=(0.30, 0.26, 0.22)) -> np.ndarray:
    """Linear-RGB radiance image (height, 2·height, 3), float32, in Mitsuba's envmap layout.

    ``sun``: dict(elevation_deg, azimuth_deg (from +x toward +y), radius_deg (Gaussian 1/e
    radius), radiance (peak)); None for sky only.
    """
    d = _env_directions(height)
    z = d[..., 2]
    up = np.clip(z, 0.0, 1.0)[..., None]
    sky = np.asarray(horizon) + (np.asarray(zenith) - np.asarray(horizon)) * np.sqrt(up)
    fade = np.clip(z / 0.05 + 1.0, 0.0, 1.0)[..., None]  # soft horizon line
    rgb = fade * np.where(z[..., None] > 0, sky, np.asarray(horizon)) + (1 - fade) * np.asarray(ground)
    if sun:
        el, az = np.deg2rad(sun["elevation_deg"]), np.deg2rad(sun["azimuth_deg"])
        s = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        angle = np.arccos(np.clip(d @ s, -1.0, 1.0))
        spot = sun["radiance"] * np.exp(-((angle / np.deg2rad(sun["radius_deg"])) ** 2))
        rgb = rgb + spot[..., None] * np.array([1.0, 0.95, 0.85])
    return rgb.astype(np.float32)


def tone_map(rgb: np.ndarray, white: float = 16.0) -> np.ndarray:
    """Extended Reinhard on luminance, L' = L (1 + L/white²) / (1 + L), chromaticity kept (sun
    highlights are hundreds of times the sky); values ≥ ``white`` map to 1."""
    rgb = np.clip(np.asarray(rgb, dtype=np.float64), 0.0, None)
    lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
    scale = np.where(lum > 0, (1.0 + lum / white**2) / (1.0 + lum), 1.0)
    return np.clip(rgb * scale[..., None], 0.0, 1.0)


def scene_dict(bsdf: dict, *, scene: str = "sphere", resolution: int = 256, spp: int = 64,
               env: np.ndarray | None = None, hide_emitters: bool = False, seed: int = 0,
               sampler: str = "multijitter", curves: str | Path | None = None) -> dict:
    """Mitsuba scene dict: ``bsdf`` on a unit sphere or a square plate (side 1.7) tilted 62°
    toward the camera and turned −25° about the vertical (the sun's highlight in a corner), or
    on the B-spline curves of the file ``curves`` ("fibers", see :mod:`.fiber_scene`),
    perspective camera, the environment ``env`` (default :func:`environment`), direct lighting
    (path tracer, max_depth 2: the objects are convex; for fibers ``volpath`` with max_depth 24,
    whose shadow rays pass through the fibers' Null component, eval_null_transmission, instead
    of stopping at the bounding cylinders), RGBA film (alpha = coverage), box pixel filter;
    ``sampler``: a Mitsuba sampler ("multijitter" stratifies: give a square spp)."""
    mi = require_mitsuba()
    if scene not in ("sphere", "plate", "fibers"):
        raise ValueError(f"scene = {scene!r}: expected 'sphere', 'plate' or 'fibers'")
    T = mi.ScalarTransform4f
    env = environment() if env is None else env
    if scene == "fibers":
        shape = {"type": "bsplinecurve", "filename": str(curves), "bsdf": bsdf}
    else:
        shape = {"type": "sphere", "bsdf": bsdf} if scene == "sphere" else \
            {"type": "rectangle", "to_world": T().rotate([0, 0, 1], -25).rotate([1, 0, 0], 62).scale(0.85),
             "bsdf": bsdf}
    return {
        "type": "scene",
        "integrator": {"type": "volpath" if scene == "fibers" else "path", "max_depth": 24 if scene == "fibers" else 2,
                       "hide_emitters": hide_emitters},
        "sensor": {
            "type": "perspective",
            "fov": 30.0,
            "to_world": T().look_at(origin=[0, -4.4, 0.5], target=[0, 0, 0], up=[0, 0, 1]),
            "sampler": {"type": sampler, "sample_count": int(spp), "seed": int(seed)},
            "film": {"type": "hdrfilm", "width": int(resolution), "height": int(resolution),
                     "pixel_format": "rgba", "rfilter": {"type": "box"}},
        },
        "emitter": {"type": "envmap", "bitmap": mi.Bitmap(env), "to_world": T().rotate([1, 0, 0], 90)},
        "object": shape,
    }


LLVM_MIN = (17, 0, 0)  # drjit 1.5 kernels use llvm.minimum, which older x86 back ends abort on


def llvm_usable() -> bool:
    """Whether Dr.Jit found a libLLVM recent enough for Mitsuba's llvm_* variants."""
    import drjit as dr

    try:
        return bool(dr.has_backend(dr.JitBackend.LLVM)) and tuple(dr.detail.llvm_version()) >= LLVM_MIN
    except Exception:  # noqa: BLE001 - no LLVM backend at all
        return False


def default_variant(spectral: bool = False) -> str:
    """llvm_ad_rgb/llvm_ad_spectral when :func:`llvm_usable`, else scalar_rgb/scalar_spectral."""
    kind = "spectral" if spectral else "rgb"
    return f"llvm_ad_{kind}" if llvm_usable() else f"scalar_{kind}"


def render_scene(dataset, scene: str = "sphere", out: str | Path | None = None, *, spp: int | None = None,
                 resolution: int | None = None, variant: str | None = None, case: int = 0,
                 smooth_sigma: float | None = None, env: np.ndarray | None = None, seed: int = 0,
                 exposure: float = 1.5, tonemap: bool = True) -> dict:
    """Render the material of ``dataset`` on ``scene`` ("sphere" or "plate" for a surface dataset,
    "fibers" for a fiber dataset: a wisp of 48 B-spline fibers with the ``"wavebrdf_fiber"``
    BSDF) and write ``out`` (PNG, sRGB, default ``<dataset stem>_<scene>.png``).

    ``variant``: a Mitsuba variant (default :func:`default_variant`: llvm_ad_rgb when a libLLVM
    >= 17 is found, else scalar_rgb, where the Python plugin runs once per sample: ~10⁴
    samples/s). Defaults: 256² pixels × 64 spp in JIT variants, 128² × 16 in scalar ones.
    The PNG is ``exposure`` × the linear image, through :func:`tone_map` (``tonemap=True``) or
    clipped, then sRGB-encoded. Returns {"image": linear RGBA array (res, res, 4), "path",
    "variant", "load_s", "render_s", "diagnostics"}.
    """
    mi = require_mitsuba()
    variant = variant or default_variant()
    scalar = variant.startswith("scalar")
    spp = spp or (16 if scalar else 64)
    resolution = resolution or (128 if scalar else 256)
    mi.set_variant(variant)
    register()
    channels = "spectral" if "spectral" in variant else "mono" if "mono" in variant else "rgb"
    start = time.perf_counter()
    with Dataset(dataset) as ds:
        kind = study_kind(ds.kind)
    shows = next((k for k in STUDY_KINDS.values() if scene in k.scenes), kind)  # another: scene_dict names them
    if shows is not kind:
        raise ValueError(f"{dataset}: scene = {scene!r} needs a {shows.name} dataset ({kind.name} datasets render "
                         f"with --scene {' or '.join(kind.scenes)})")
    return _RENDER[kind.plugin](dataset, scene, out, spp=spp, resolution=resolution, channels=channels, case=case,
                                env=env, seed=seed, exposure=exposure, tonemap=tonemap, start=start, variant=variant,
                                smooth_sigma=smooth_sigma)


def _render_surface(dataset, scene, out, *, spp, resolution, channels, case, env, seed, exposure, tonemap, start,
                    variant, smooth_sigma) -> dict:
    """A "sphere" or "plate" scene with the ``"wavebrdf"`` BSDF."""
    mi = require_mitsuba()
    # the plugin's own tables, loaded here first: a dataset the variant cannot take is refused in
    # one line rather than from inside Mitsuba's scene parser
    tables = tables_for(dataset, channels=channels, case=case, smooth_sigma=smooth_sigma,
                        polarized="polarized" in variant)
    bsdf = {"type": "wavebrdf", "filename": str(Path(dataset).resolve()), "case": int(case)}
    if smooth_sigma is not None:
        bsdf["smooth_sigma"] = float(smooth_sigma)
    scn = mi.load_dict(scene_dict(bsdf, scene=scene, resolution=resolution, spp=spp, env=env, seed=seed))
    load_s = time.perf_counter() - start
    return _finish(scn, dataset, scene, out, exposure, tonemap, variant, load_s, tables.diagnostics)


def _finish(scn, dataset, scene, out, exposure, tonemap, variant, load_s, diagnostics) -> dict:
    """Render ``scn``, write the PNG, return render_scene's dict."""
    mi = require_mitsuba()
    start = time.perf_counter()
    image = np.array(mi.render(scn))
    render_s = time.perf_counter() - start
    out = Path(out) if out else Path(dataset).with_name(f"{Path(dataset).stem}_{scene}.png")
    out.parent.mkdir(parents=True, exist_ok=True)
    rgb = tone_map(image[..., :3] * exposure) if tonemap else np.clip(image[..., :3] * exposure, 0.0, None)
    mi.util.write_bitmap(str(out), np.ascontiguousarray(rgb, dtype=np.float32), write_async=False)
    return {"image": image, "path": out, "variant": variant, "load_s": load_s, "render_s": render_s,
            "diagnostics": diagnostics}


def _render_fibers(dataset, scene, out, *, spp, resolution, channels, case, env, seed, exposure, tonemap, start,
                   variant, smooth_sigma=None) -> dict:
    """The "fibers" scene: a wisp of B-spline fibers with the ``"wavebrdf_fiber"`` BSDF (the
    curves' radius is the dataset's bounding width, :func:`wavebrdf.mitsuba.fiber_radius`), lit
    by the environment, which camera rays do not show (black background)."""
    import tempfile

    mi = require_mitsuba()
    tables = fiber_tables_for(dataset, channels=channels, case=case)
    bsdf = {"type": "wavebrdf_fiber", "filename": str(Path(dataset).resolve()), "case": int(case)}
    with tempfile.TemporaryDirectory() as tmp:
        curves = write_fiber_wisp(Path(tmp) / "wisp.txt", fiber_radius(dataset, GEOMETRIC_RADIUS, case))
        scn = mi.load_dict(scene_dict(bsdf, scene=scene, resolution=resolution, spp=spp, env=env, seed=seed,
                                      curves=curves, hide_emitters=True))  # thin fibers read best on black
    load_s = time.perf_counter() - start
    return _finish(scn, dataset, scene, out, exposure, tonemap, variant, load_s, tables.diagnostics)


_RENDER = {"wavebrdf": _render_surface, "wavebrdf_fiber": _render_fibers}  # the renderer of each kind's plugin
