"""Whose convergence a trade-table reference misses: the scene's sampling or the full-wave solver's.

``rung`` runs a cheap rung (physical optics by default) on a config's hardest scene with its surface
generated at several cells (benchmarks/trade.py ``surface_at``: the table's convergence refinement):
where the cheap rung's BRDF settles as d falls, the height field itself converges and what a
full-wave pair still changes is the solver's discretization. ``pair`` splits a stored full-wave pair
(``trade.py --finer-pair``, or the table's own check) into the specular cone and the rest. ``mesh``
solves the config's surface kind on a patch small enough for the dense LU, dense and by AIM, on its
mesh and on that mesh subdivided by 2 (the same bilinear surface): where both methods move alike
between the meshes, and a tighter element quadrature moves neither, what changes is the Galerkin
discretization itself. All on the unpolarized BRDFs speckle-averaged as the table compares them
(metrics.blur by the footprint's spread λ/(π w)). docs/aim.md: the steep hemispheres at waist 2.5 µm.

    .venv/bin/python benchmarks/sampling_convergence.py rung configs/compare/trade/al_waist2.5/steep_hemispheres.toml \
        --cells 180 240 270 360 540 720 1080
    .venv/bin/python benchmarks/sampling_convergence.py pair configs/compare/trade/al_waist2.5/steep_hemispheres.toml 240
    .venv/bin/python benchmarks/sampling_convergence.py mesh configs/compare/trade/al_waist2.5/steep_hemispheres.toml \
        --size 1.8 --cells 24 --waist 0.4
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # trade.py: the table's scenes, surfaces and stored pairs

import trade  # noqa: E402

CONE_SIGMAS = 2.0  # the specular cone's radius in blur widths
TIGHT_QUADRATURE = {"tolerance": 1e-9, "static_order": 14, "min_order": 4, "max_order": 24}  # against 1e-6, 8, 2, 12


def _speckle_averaged(brdf_sp: np.ndarray, scene) -> np.ndarray:
    """The unpolarized BRDF of (s, p) slices (2, res, res), blurred as the table's metric blurs it (0 off the disk)."""
    from wavebrdf.solver.metrics import blur

    return np.nan_to_num(blur(np.mean(brdf_sp, axis=0), scene.grid, trade._speckle_sigma(scene)))


def _specular_cone(scene, lobe: np.ndarray) -> np.ndarray:
    """Lobe pixels within CONE_SIGMAS blur widths of the scene's mirror direction (−u of ω_i)."""
    from wavebrdf.solver.metrics import direction_to_u

    U, V = scene.grid.uv
    mirror = -direction_to_u(scene.theta_i, scene.phi_i)
    return lobe & (np.hypot(U - mirror[0], V - mirror[1]) <= CONE_SIGMAS * trade._speckle_sigma(scene))


def _rung_options(path: Path, model: str):
    """The config's options of ``model`` as a comparison takes them, or None (the model's defaults)."""
    from wavebrdf.jobs.compare import compare_options
    from wavebrdf.jobs.config import load_config

    return compare_options(load_config(path).cases[0]).get(model)


def rung_convergence(path: Path, model: str, cells: list[int]) -> list[dict]:
    """``model`` on the config's hardest scene at each of ``cells`` (ascending): per mesh its CPU,
    the relative L2 against the finest and against the next finer, and its specular cone's power
    over the finest one's (speckle-averaged, unpolarized, over the finest one's lobe)."""
    from wavebrdf.jobs.compare import MeasuringProcess
    from wavebrdf.solver.metrics import lobe_mask, relative_l2

    cells = sorted(set(cells))
    if len(cells) < 2:
        raise SystemExit("--cells: give at least two meshes")
    label, scene = trade.hardest_scene(path)
    options = _rung_options(path, model)
    runs = {}
    with MeasuringProcess() as process:
        for n in cells:
            at = dataclasses.replace(scene, surface=trade.surface_at(scene.surface, n))
            m = process.measure(model, options, at, label)
            if m.failure:
                raise SystemExit(f"{model} at {n}² cells failed: {m.failure}")
            runs[n] = (at.surface.spacing_um, m.cpu_s, _speckle_averaged(m.brdf, scene))
            print(f"  {model} at {n}²: {m.cpu_s:.1f} CPU-s", file=sys.stderr, flush=True)
    finest = runs[cells[-1]][2]
    cone = _specular_cone(scene, lobe_mask(finest, scene.grid))
    rows = []
    for n, finer in zip(cells, cells[1:] + [None]):
        d, cpu, f = runs[n]
        rows.append({"scene": label, "cells": n, "d_um": d, "cpu_s": cpu,
                     "vs_finest": float(relative_l2(f, finest, scene.grid)),
                     "vs_next": None if finer is None else float(relative_l2(f, runs[finer][2], scene.grid)),
                     "cone_power": float(f[cone].sum() / finest[cone].sum())})
    return rows


def pair_split(path: Path, cells: int, fine_cells: int | None = None) -> dict:
    """Where the stored full-wave pair (``cells`` against ``fine_cells``, default 1.5× ``cells``)
    differs: over the fine one's lobe, the relative L2, the share of the squared difference within
    the specular cone, and the coarse/fine reflected power inside and outside it."""
    from wavebrdf.jobs.config import load_config
    from wavebrdf.solver.metrics import lobe_mask

    label, scene = trade.hardest_scene(path)
    fine_cells = fine_cells or int(round(trade.REFINEMENT * cells))
    study = load_config(path).cases[0].name
    stored = trade.pair_path(study, cells, fine_cells)
    if not stored.is_file() and cells == scene.surface.cells:
        stored = trade.WORK / f"{study}_converged.h5"
    if not stored.is_file():
        raise SystemExit(f"no stored pair {cells}² → {fine_cells}² for {path}: run benchmarks/trade.py "
                         f"--finer-pair {path} {cells} first")
    fine, coarse, attrs = trade._read_refinement(stored, label)
    if int(attrs["cells"]) != fine_cells or fine.brdf is None or coarse.brdf is None:
        raise SystemExit(f"{stored.name}: holds {attrs['cells']}² (failure: {attrs['failure'] or 'none'}), "
                         f"not a finished {fine_cells}² solve")
    f, c = _speckle_averaged(fine.brdf, scene), _speckle_averaged(coarse.brdf, scene)
    lobe = lobe_mask(f, scene.grid)
    cone = _specular_cone(scene, lobe)
    squared = np.where(lobe, (c - f) ** 2, 0.0)
    return {"scene": label, "file": stored.name, "cells": cells, "fine_cells": fine_cells,
            "relative_l2": float(np.sqrt(squared.sum() / np.sum(np.where(lobe, f**2, 0.0)))),
            "cone_share": float(squared[cone].sum() / squared.sum()),
            "cone_power": float(c[cone].sum() / f[cone].sum()),
            "rest_power": float(c[lobe & ~cone].sum() / f[lobe & ~cone].sum())}


def small_surface(surface, size_um: float, cells: int):
    """``surface``'s generator, seed and own parameters at ``cells`` on a ``size_um`` patch
    (:func:`~wavebrdf.solver.surface.generate_like`)."""
    from wavebrdf.solver.surface import SurfaceError, generate_like

    try:
        return generate_like(surface, cells, size_um)
    except SurfaceError as exc:  # no generator, or a period the small patch does not hold
        raise SystemExit(f"mesh: {exc} (the small patch is the config's surface generated at --size and --cells)") from None


def mesh_pairs(path: Path, size_um: float, cells: int, waist_um: float, tight: bool = True) -> dict:
    """The config's surface generator at ``cells`` on a ``size_um`` patch, its hardest scene's
    wavelength, material and incidence at ``waist_um``: the BRDF dense (the Galerkin matrix, LU)
    and by AIM (``fit_memory`` off), on the mesh and on it subdivided by 2; with ``tight`` the dense
    one again with TIGHT_QUADRATURE. Relative L2 (speckle-averaged, unpolarized) of each method's
    coarse mesh against its fine one, of AIM against dense on each mesh, and of the default
    quadrature against the tight one; each solve's CPU seconds."""
    import time

    from wavebrdf.solver.bem3d.driver import bem_farfield
    from wavebrdf.solver.metrics import relative_l2
    from wavebrdf.solver.opencl import create_context
    from wavebrdf.solver.surface import subdivided

    _, scene = trade.hardest_scene(path)
    coarse = small_surface(scene.surface, size_um, cells)
    small = dataclasses.replace(scene, surface=coarse, waist_um=waist_um)
    ctx = create_context()
    brdf, cpu = {}, {}
    runs = [("dense", "coarse", coarse, {}), ("dense", "fine", subdivided(coarse, 2), {}),
            ("aim", "coarse", coarse, {"aim": {"fit_memory": False}}),
            ("aim", "fine", subdivided(coarse, 2), {"aim": {"fit_memory": False}})]
    if tight:
        runs.append(("dense tight", "coarse", coarse, {"quadrature": TIGHT_QUADRATURE}))
    for method, mesh, surface, extra in runs:
        start = time.process_time()
        ff = bem_farfield(ctx, surface, small.wavelength_um, small.index, small.theta_i, small.phi_i, waist_um,
                          small.grid, method=method.split()[0], exterior_index=small.exterior_index, **extra)
        cpu[method, mesh] = time.process_time() - start
        brdf[method, mesh] = _speckle_averaged(ff.brdf(), small)
        print(f"  {method} on {surface.cells}²: {cpu[method, mesh]:.1f} CPU-s", file=sys.stderr, flush=True)
    rel = lambda a, b: float(relative_l2(brdf[a], brdf[b], small.grid))  # noqa: E731
    out = {"cells": cells, "size_um": size_um, "waist_um": waist_um, "cpu_s": {" ".join(k): v for k, v in cpu.items()},
           "dense_pair": rel(("dense", "coarse"), ("dense", "fine")),
           "aim_pair": rel(("aim", "coarse"), ("aim", "fine")),
           "aim_vs_dense": {m: rel(("aim", m), ("dense", m)) for m in ("coarse", "fine")}}
    if tight:
        out["quadrature"] = rel(("dense", "coarse"), ("dense tight", "coarse"))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rung = sub.add_parser("rung", help="a cheap rung on the config's surface at several cells")
    rung.add_argument("config", type=Path)
    rung.add_argument("--model", default="po", help="the rung (po)")
    rung.add_argument("--cells", type=int, nargs="+", required=True)
    pair = sub.add_parser("pair", help="where a stored full-wave convergence pair differs")
    pair.add_argument("config", type=Path)
    pair.add_argument("cells", type=int)
    pair.add_argument("--fine", type=int, default=None, help="the fine mesh's cells (default 1.5× CELLS)")
    mesh = sub.add_parser("mesh", help="dense and AIM on a small patch of the config's surface kind, on its "
                                       "mesh and subdivided by 2")
    mesh.add_argument("config", type=Path)
    mesh.add_argument("--size", type=float, required=True, help="the patch side (µm)")
    mesh.add_argument("--cells", type=int, required=True, help="cells a side N (the dense LU at 2N: about 16 N² unknowns; 24 takes 3.8 GB)")
    mesh.add_argument("--waist", type=float, required=True, help="the beam waist (µm)")
    mesh.add_argument("--no-tight", action="store_true", help="skip the dense solve with the tight quadrature")
    args = parser.parse_args(argv)
    if args.command == "rung":
        rows = rung_convergence(args.config, args.model, args.cells)
        print(f"{rows[0]['scene']}, {args.model}; relative L2 speckle-averaged (unpolarized); specular cone "
              f"{CONE_SIGMAS:g} blur widths")
        print("| cells | d (µm) | CPU (s) | vs the next finer | vs the finest | cone power / the finest's |")
        print("|---|---|---|---|---|---|")
        for r in rows:
            nxt = "—" if r["vs_next"] is None else f"{r['vs_next']:.4f}"
            print(f"| {r['cells']} | {r['d_um']:.4g} | {r['cpu_s']:.1f} | {nxt} | {r['vs_finest']:.4f} | "
                  f"{r['cone_power']:.4f} |")
    elif args.command == "mesh":
        r = mesh_pairs(args.config, args.size, args.cells, args.waist, not args.no_tight)
        print(f"{args.config}: {r['cells']}² cells on {r['size_um']:g} µm (d = {r['size_um'] / r['cells']:.4g} µm), "
              f"waist {r['waist_um']:g} µm, and subdivided by 2")
        print(f"  coarse against fine: dense {r['dense_pair']:.4f}, AIM {r['aim_pair']:.4f}")
        print(f"  AIM against dense: {r['aim_vs_dense']['coarse']:.2e} (coarse), {r['aim_vs_dense']['fine']:.2e} (fine)")
        if "quadrature" in r:
            print(f"  dense, default quadrature against the tight one: {r['quadrature']:.2e}")
        print("  CPU (s): " + ", ".join(f"{k} {v:.1f}" for k, v in r["cpu_s"].items()))
    else:
        r = pair_split(args.config, args.cells, args.fine)
        print(f"{r['scene']}: {r['file']} ({r['cells']}² against {r['fine_cells']}²)")
        print(f"  relative L2 (speckle-averaged, unpolarized) {r['relative_l2']:.4f}; share of the squared "
              f"difference in the specular cone ({CONE_SIGMAS:g} blur widths) {r['cone_share']:.3f}")
        print(f"  reflected power coarse / fine: in the cone {r['cone_power']:.4f}, outside it {r['rest_power']:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
