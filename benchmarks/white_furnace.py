"""White furnace of a surface dataset's renderer outputs: the albedo per θ_i of the "wavebrdf"
plugin and of the dataset's RGL export (Mitsuba's ``measured``), each Σ eval/cos θ_o Δu Δv over
512² directions at the dataset's wavelengths (llvm_ad_spectral), against the dataset's stored
albedo; means over the wavelengths, as the table of docs/export.md.

    .venv/bin/wavebrdf run configs/render_ready.toml --set 'study.output="render_ready.h5"' --no-render
    nice .venv/bin/python -m benchmarks.white_furnace render_ready.h5

Needs Mitsuba's llvm variants (libLLVM >= 17). An isotropic dataset (exported with --isotropic).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from wavebrdf.jobs.cli import main as export_main

DIRECTIONS = 512


def albedo(bsdf, theta_deg: float, wavelengths_um, mi, dr) -> np.ndarray:
    """Σ eval/cos θ_o Δu Δv over DIRECTIONS² pixel centres inside the disk, per wavelength (incidence
    at φ_i = 0)."""
    c = (np.arange(DIRECTIONS) + 0.5) / DIRECTIONS * 2.0 - 1.0
    u, v = (x.ravel() for x in np.meshgrid(c, c, indexing="ij"))
    keep = u**2 + v**2 < 1.0
    u, v = u[keep], v[keep]
    mu = np.sqrt(1.0 - u**2 - v**2)
    out = []
    for first in range(0, len(wavelengths_um), 4):  # Mitsuba's spectral variants carry 4 wavelengths
        chosen = list(range(first, min(first + 4, len(wavelengths_um))))
        padded = chosen + [chosen[-1]] * (4 - len(chosen))
        si = dr.zeros(mi.SurfaceInteraction3f, len(u))
        si.wi = mi.Vector3f(float(np.sin(np.deg2rad(theta_deg))), 0.0, float(np.cos(np.deg2rad(theta_deg))))
        si.wavelengths = mi.Spectrum(*[mi.Float(np.full(len(u), wavelengths_um[n] * 1000.0)) for n in padded])
        value = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(mi.Float(u), mi.Float(v), mi.Float(mu))))
        out += list(((value.reshape(4, -1) / mu).sum(axis=1) * (2.0 / DIRECTIONS) ** 2)[:len(chosen)])
    return np.array(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--thetas", default="0,20,40,50,60,70,80,85", help="θ_i (degrees) among the dataset's")
    args = parser.parse_args(argv)
    import drjit as dr
    import h5py
    import mitsuba as mi

    mi.set_variant("llvm_ad_spectral")
    import wavebrdf.mitsuba as wm

    wm.register()
    from wavebrdf.jobs.store import Dataset
    from wavebrdf.mitsuba.tables import case_config, isotropy_from_config

    with Dataset(args.dataset) as ds:
        isotropic, why = isotropy_from_config(case_config(ds.config))
    if not isotropic:
        raise SystemExit(f"{args.dataset}: not declared isotropic ({why}); this furnace reads tables at φ_i = 0 "
                         "averaged over azimuth")
    with h5py.File(args.dataset, "r") as h5:
        stored, thetas, wavelengths = h5["albedo"][()], h5["theta_i"][()], h5["wavelength_um"][()]
    stored = stored.reshape(-1, *stored.shape[-2:])[0]  # (λ, incidence) of the first sweep case
    with tempfile.TemporaryDirectory() as folder:
        file = Path(folder) / "furnace.bsdf"
        if export_main(["export", str(args.dataset), "-o", str(file), "--isotropic"]) != 0:
            raise SystemExit(f"wavebrdf export {args.dataset} failed")
        bsdfs = {"file": mi.load_dict({"type": "measured", "filename": str(file)}),
                 "plugin": mi.load_dict({"type": "wavebrdf", "filename": str(args.dataset), "isotropic": True})}
        print("| θ_i | dataset | file (`measured`) | `\"wavebrdf\"` plugin | file − dataset | plugin − dataset | "
              "file − plugin |\n|---|---|---|---|---|---|---|")
        for theta in (float(t) for t in args.thetas.split(",")):
            matches = np.flatnonzero(np.isclose(thetas, theta))
            if not len(matches):
                raise SystemExit(f"--thetas: {theta:g}° is not among the dataset's θ_i {thetas.tolist()}")
            dataset = stored[:, matches[0]]
            got = {name: albedo(bsdf, theta, wavelengths, mi, dr) for name, bsdf in bsdfs.items()}
            f, p = got["file"], got["plugin"]
            print(f"| {theta:g}° | {dataset.mean():.4f} | {f.mean():.4f} | {p.mean():.4f} | "
                  f"{100 * np.mean(f / dataset - 1):+.2f} % | {100 * np.mean(p / dataset - 1):+.2f} % | "
                  f"{100 * np.mean(f / p - 1):+.2f} % |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
