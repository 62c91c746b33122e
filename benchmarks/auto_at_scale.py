"""``auto`` where users work: a reduced steered study at the reference simulator's discretization
and waist regime, run end to end all-full-wave and with ``auto`` (its spot checks included), each
with ``wavebrdf run`` in a child process, CPU measured from the children's resource usage.

    .venv/bin/python benchmarks/auto_at_scale.py bumpy        # rough Al bumps, rms slope ~0.14: auto simplifies
    .venv/bin/python benchmarks/auto_at_scale.py pits         # spherical pits at λ scale: auto must choose BEM
    .venv/bin/python benchmarks/auto_at_scale.py brushed      # brushed Al, rms slope 0.13, anisotropic: a second low slope
    .venv/bin/python benchmarks/auto_at_scale.py glass-oblique    # rough glass at θ_i 40°, two azimuths
    .venv/bin/python benchmarks/auto_at_scale.py brushed-oblique --tolerance 0.1    # along and across the grooves
    .venv/bin/python benchmarks/auto_at_scale.py brushed-oblique-50 --tolerance 0.07
    .venv/bin/python benchmarks/auto_at_scale.py brushed-direct --tolerance 0.1     # the same, one patch, no steering
    .venv/bin/python benchmarks/auto_at_scale.py glass-single --one-task --tolerance 0.2   # each λ its own study: the rule
    .venv/bin/python benchmarks/auto_at_scale.py bumpy --tolerance 0.05 0.01 --keep out/auto_at_scale
    .venv/bin/python benchmarks/auto_at_scale.py single       # one-task studies at waist 5λ: rule vs measured
    .venv/bin/python benchmarks/auto_at_scale.py single --rule-only   # the rule's predictions alone
    .venv/bin/python benchmarks/auto_at_scale.py single --material gold --wavelength 0.6 --scenes smooth bumpy

Regime (unless said below): 2 × 2 sub-areas of 5.4 µm at d = 0.03 µm (≤ λ/16 at λ ≥ 0.48 µm; 129 600
cells, ~130 000 unknowns each), shifted by the waist 1.5 µm (≥ 2.5 λ), the reference's aluminium
``wvl.txt``, exact beams, normal incidence plus the reference's four neighbouring ``wi.txt``
directions (one basic direction), 256² output. ``bumpy``: 3 wavelengths (0.5, 0.55, 0.6 µm): 12
patch solves. ``brushed``: 3 wavelengths (0.5, 0.58, 0.66 µm): 12 patch solves. ``pits``: 1 wavelength
(0.5 µm): 4 patch solves. ``glass-oblique``: glass (the catalogue's), θ_i 40° at φ_i 0° and 60°
instead of the reference's directions, 3 wavelengths (0.45, 0.55, 0.65 µm): 24 patch solves.
``brushed-oblique``: grooves along x lit at θ_i 40° along them (φ_i 0°) and across them (90°), 2
wavelengths (0.5, 0.6 µm): 16 patch solves; ``brushed-oblique-50``: the same at 50° along them.
``brushed-direct``: no steering, the 5.4 µm surface of 180² cells (one sub-area's size) lit
directly at θ_i 40° along and across its grooves, 2 wavelengths: 4 tasks. ``glass-single``: the
glass-oblique surface on one such patch, lit directly at θ_i 34° (glass-oblique's steered basic
θ_i), λ 0.45 and 0.65 µm. ``--one-task``: every (λ, direction) of a study without steering run as
a study of its own, all-full-wave and with ``auto``: one task has no spot checks, so ``auto`` takes
the rule's choice and its escalation check (the reason is printed).

``single``: three one-task scenes not in the trade table (smooth, bumpy, steep), aluminium at
λ = 0.5 µm, waist 2.5 µm (5 λ), θ_i = 20°, 9 µm patches at d = 0.05 µm (λ/10; |k₂|d = 3.9 ≤ 4), 256²
output: every rung and AIM BEM (``compare_scenes``), the rule's predicted error of each rung beside
its measured error, and the rung ``auto`` (the rule: one task has no spot checks) picks;
``--material``, ``--wavelength`` and ``--scenes`` change the material (a catalogue name), λ and
which of the three run (the same patches and waist).

Printed per direction and wavelength: the speckle-averaged relative L2 over the lobe of the
``auto`` dataset's BRDF against the all-full-wave one (per polarization and unpolarized, raw
beside), the rungs ``auto`` ran per patch task, and the CPU of each run (user + system of the
``wavebrdf run`` child) with their ratio.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import NamedTuple

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

ALUMINIUM = 'file = "{root}/configs/data/aluminium_wvl.txt"'
REFERENCE_DIRECTIONS = 'directions_file = "{root}/configs/data/reference_subareas_wi.txt"\nangles = "rad"'

# the surface's extent and [steering] table
STEERED = ("size_um = 6.9\ncells = 230", "[steering]\npatches = [2, 2]\npatch_size_um = 5.4\nshift_um = 1.5\n")
DIRECT = ("size_um = 5.4\ncells = 180", "")  # one sub-area of the steered studies, lit directly


class Study(NamedTuple):
    """One study of the benchmark, as TOML snippets (``{root}``: the repository)."""

    surface: str  # the [surface] table without its extent
    wavelengths: list[float]  # µm
    material: str  # the [material] table
    directions: str  # the [illumination] directions
    layout: tuple[str, str] = STEERED  # the surface's extent and the [steering] table


BRUSHED_X = ('generator = "brushed"\nrms_height_um = 0.035\ncorrelation_um = [2.5, 0.45]\nangle_deg = 0.0\n'
             'seed = 31')  # grooves along x

SURFACES = {
    "bumpy": Study('generator = "gaussian"\nrms_height_um = 0.1\ncorrelation_um = 1.0\nseed = 7', [0.5, 0.55, 0.6],
                   ALUMINIUM, REFERENCE_DIRECTIONS),
    "pits": Study('generator = "spherical-pits"\nradius_um = 0.45\ndepth_um = 0.3\nperiod_um = 1.15', [0.5],
                  ALUMINIUM, REFERENCE_DIRECTIONS),
    # a second low-slope surface, anisotropic (rms slope 0.13: the 230² realization's statistics()), other wavelengths
    "brushed": Study('generator = "brushed"\nrms_height_um = 0.06\ncorrelation_um = [2.0, 0.8]\nangle_deg = 30.0\n'
                     'seed = 9', [0.5, 0.58, 0.66], ALUMINIUM, REFERENCE_DIRECTIONS),
    # a dielectric lit obliquely: glass, θ_i 40° at two azimuths, other wavelengths
    "glass-oblique": Study('generator = "gaussian"\nrms_height_um = 0.08\ncorrelation_um = 0.9\nseed = 23',
                           [0.45, 0.55, 0.65], 'name = "glass"', "directions_deg = [[40, 0], [40, 60]]"),
    # an anisotropic surface lit obliquely along its grooves (listed first) and across them: the
    # tangent-plane rungs' error depends on the azimuth (rms slope 0.11, 0.16 across the grooves)
    "brushed-oblique": Study(BRUSHED_X, [0.5, 0.6], ALUMINIUM, "directions_deg = [[40, 0], [40, 90]]"),
    # the same, more oblique along the grooves than across them
    "brushed-oblique-50": Study(BRUSHED_X, [0.5, 0.6], ALUMINIUM, "directions_deg = [[50, 0], [40, 90]]"),
    # one sub-area's size lit directly (no steering) at θ_i 40° along its grooves (listed first) and across them
    "brushed-direct": Study(BRUSHED_X, [0.5, 0.6], ALUMINIUM, "directions_deg = [[40, 0], [40, 90]]", DIRECT),
    # glass-oblique's surface on one patch at its steered basic θ_i: with --one-task, the rule's path on a dielectric
    "glass-single": Study('generator = "gaussian"\nrms_height_um = 0.08\ncorrelation_um = 0.9\nseed = 23',
                          [0.45, 0.65], 'name = "glass"', "directions_deg = [[34, 0]]", DIRECT),
}

STUDY = """[study]
name = "{name}"
output = "{name}.h5"
[surface]
{surface}
{extent}
[material]
{material}
[illumination]
wavelengths_um = {wavelengths}
{directions}
waist_um = 1.5
beam = "exact"
[model]
{model}
[output]
resolution = 256
per_polarization = true
{steering}"""


def run_study(folder: Path, name: str, study: Study, model: str) -> dict:
    """``wavebrdf run`` of one study (a ``SURFACES`` entry) in a child process: its CPU seconds (user +
    system), wall time."""
    extent, steering = study.layout
    config = folder / f"{name}.toml"
    config.write_text(STUDY.format(name=name, surface=study.surface, wavelengths=study.wavelengths, model=model,
                                   root=ROOT, material=study.material.format(root=ROOT),
                                   directions=study.directions.format(root=ROOT), extent=extent, steering=steering))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "wavebrdf", "run", str(config), "--no-render", "-q"],
                          cwd=folder, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{name}: wavebrdf run failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"name": name, "cpu_s": cpu, "wall_s": wall, "path": folder / f"{name}.h5", "log": done.stdout + done.stderr}


def compare(auto_path: Path, bem_path: Path) -> list[dict]:
    """Per (wavelength, direction): the auto dataset's errors against the all-BEM one."""
    from wavebrdf.solver.farfield import HemisphereGrid
    from wavebrdf.solver.metrics import speckle_errors, speckle_sigma_u

    rows = []
    with h5py.File(auto_path) as a, h5py.File(bem_path) as b:
        lams, theta, phi = b["wavelength_um"][()], b["theta_i"][()], b["phi_i"][()]
        grid = HemisphereGrid(a["brdf_sp"].shape[-1])
        for w, lam in enumerate(lams):
            for d in range(len(theta)):
                errors = speckle_errors(a["brdf_sp"][w, d], b["brdf_sp"][w, d], grid, speckle_sigma_u(lam, 1.5, grid))
                rows.append({"wavelength_um": float(lam), "theta_i": float(theta[d]), "phi_i": float(phi[d]),
                             "albedo_auto": float(a["albedo"][w, d]), "albedo_bem": float(b["albedo"][w, d]), **errors})
    return rows


def rungs(path: Path) -> dict[str, int]:
    with h5py.File(path) as h5:
        kinds = [k.decode() for k in h5["tasks/kind"][()]]
        models = [m.decode() for m in h5["tasks/model"][()]]
    out = {}
    for kind, model in zip(kinds, models):
        if kind in ("patch", "direct", "check"):
            out[f"{kind}:{model}"] = out.get(f"{kind}:{model}", 0) + 1
    return out


SINGLE = {  # not in the trade table: new generators' parameters, seeds, waist and patch
    "smooth": ("gaussian", dict(rms_height_um=0.01, correlation_um=1.2, seed=41)),
    "bumpy": ("gaussian", dict(rms_height_um=0.1, correlation_um=1.0, seed=42)),
    "steep": ("hemispheres", dict(radius_um=0.5, fill=0.3, placement="random", seed=43)),
}


def single_task_studies(tolerances: list[float], rule_only: bool = False, material: str | None = None,
                        wavelength_um: float = 0.5, names: list[str] | None = None) -> int:
    """The one-task scenes of ``SINGLE`` (or those ``names``) through every rung and BEM, with the
    rule's predictions (``rule_only``: the predictions and picks alone, no rung run); ``material``
    a catalogue name instead of the reference's aluminium ``wvl.txt``, at ``wavelength_um``."""
    from wavebrdf.jobs.compare import compare_scenes
    from wavebrdf.solver.auto import REFERENCE, candidate_models, choose, default_rule, measure_scene, table_error
    from wavebrdf.solver.farfield import HemisphereGrid
    from wavebrdf.solver.materials import Material
    from wavebrdf.solver.models import SurfaceScene
    from wavebrdf.solver.surface import generate

    lam = wavelength_um
    catalogue = Material.from_name(material) if material else Material.from_file(ROOT / "configs" / "data" / "aluminium_wvl.txt")
    index = complex(catalogue.index(lam))
    print(f"material {material or 'aluminium (wvl.txt)'}: n = {index:.4g} at λ {lam:g} µm", flush=True)
    scenes = []
    for label, (generator, params) in SINGLE.items():
        if names and label not in names:
            continue
        params = dict(params)
        seed = params.pop("seed")
        surface = generate(generator, cells=180, size_um=9.0, seed=seed, **params)
        scenes.append((label, SurfaceScene(surface, lam, index, np.deg2rad(20.0), 0.0, 2.5, HemisphereGrid(256))))
    rungs = sorted({n for _, scene in scenes for n in candidate_models(scene)} - {REFERENCE})
    if rule_only:
        return print_rule(scenes, rungs, tolerances)
    comparison = compare_scenes(scenes, rungs + [REFERENCE], {REFERENCE: {"method": "aim"}}, reference=REFERENCE,
                                progress=lambda what: print(f"  running {what}", flush=True))
    rule = default_rule()
    print("| scene | rms slope | rung | predicted | measured (speckle-avg, worst of s, p, unpolarized) | raw | CPU (s) |")
    print("|---|---|---|---|---|---|---|")
    for label, scene in scenes:
        features = measure_scene(scene)
        rows = {r["model"]: r for r in comparison.rows if r["scene"] == label}
        for name, row in sorted(rows.items(), key=lambda kv: kv[1].get("cpu_s", np.inf)):
            print(f"| {label} | {features.rms_slope:.3g} | {name} | {rule.predict(name, features):.3g} | "
                  f"{table_error(row):.3g} | {row.get('rel_l2', np.nan):.3g} | {row.get('cpu_s', np.nan):.3g} |")
        for tolerance in tolerances:
            picked = choose(scene, tolerance, rule, features).model
            within = sorted((r["cpu_s"], m) for m, r in rows.items() if table_error(r) <= tolerance)
            measured = 0.0 if picked == REFERENCE else table_error(rows[picked])
            print(f"{label}, tolerance {tolerance:g}: auto picks {picked} (measured {measured:.3g}); "
                  f"cheapest measured within: {within[0][1] if within else REFERENCE}")
    return 0


def print_rule(scenes, rungs: list[str], tolerances: list[float]) -> int:
    """The rule's predicted error of each rung and its pick per tolerance, on each scene."""
    from wavebrdf.solver.auto import choose, default_rule, measure_scene

    rule = default_rule()
    print("| scene | features | " + " | ".join(rungs) + " | " + " | ".join(f"picks at {t:g}" for t in tolerances) + " |")
    print("|---|---|" + "---|" * (len(rungs) + len(tolerances)))
    for label, scene in scenes:
        features = measure_scene(scene)
        picks = [choose(scene, t, rule, features).model for t in tolerances]
        print(f"| {label} | {features.describe()} | " + " | ".join(f"{rule.predict(n, features):.3g}" for n in rungs) +
              " | " + " | ".join(picks) + " |")
    return 0


def one_task_studies(name: str, study: Study) -> list[tuple[str, Study]]:
    """``study`` split into a study per (wavelength, direction), each named by them: one task each,
    so ``auto`` takes the rule's choice and its escalation check. Only a study without steering
    whose directions are listed (``directions_deg``)."""
    import tomllib

    if study.layout[1]:
        raise SystemExit(f"--one-task: {name} is steered (its sub-areas are tasks of one direction); take a study "
                         "without [steering]")
    directions = tomllib.loads(study.directions).get("directions_deg")
    if directions is None:
        raise SystemExit(f"--one-task: {name} takes its directions from a file ({study.directions!r}); it needs "
                         "directions_deg")
    return [(f"{lam:g}um_{theta:g}_{phi:g}", study._replace(wavelengths=[lam], directions=f"directions_deg = [[{theta}, {phi}]]"))
            for lam in study.wavelengths for theta, phi in directions]


def measure(folder: Path, label: str, study: Study, tolerances: list[float], explain: bool = False) -> dict:
    """``study`` all-full-wave and with ``auto`` at each tolerance: CPU, rungs, the errors of the
    ``auto`` dataset against the all-full-wave one (printed; ``explain``: each task's rung and reason)."""
    from wavebrdf.solver.metrics import worst_speckle_error

    bem = run_study(folder, f"bem{label}", study, 'name = "bem"\nmethod = "aim"')
    print(f"all-BEM{label}: {bem['cpu_s']:.0f} CPU-s, {bem['wall_s']:.0f} s wall; {rungs(bem['path'])}", flush=True)
    summary = {"bem_cpu_s": bem["cpu_s"], "bem_wall_s": bem["wall_s"], "auto": []}
    for tolerance in tolerances:
        auto = run_study(folder, f"auto_{tolerance:g}{label}", study, f'name = "auto"\ntolerance = {tolerance}')
        rows = compare(auto["path"], bem["path"])
        worst = max(worst_speckle_error(r) for r in rows)
        print(f"\nauto{label}, tolerance {tolerance:g}: {auto['cpu_s']:.0f} CPU-s, {auto['wall_s']:.0f} s wall; all-BEM / auto "
              f"CPU {bem['cpu_s'] / auto['cpu_s']:.2f}x; rungs {rungs(auto['path'])}; worst error vs all-BEM {worst:.3g}")
        if explain:
            with h5py.File(auto["path"]) as h5:
                for model, reason in zip(h5["tasks/model"][()], h5["tasks/model_reason"][()]):
                    print(f"  {model.decode()}: {reason.decode()}")
        print("| λ (µm) | θ_i (°) | φ_i (°) | s | p | unpolarized | raw | albedo auto | albedo BEM |")
        print("|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['wavelength_um']:.3g} | {r['theta_i']:.2f} | {r['phi_i']:.0f} | {r['s']:.3g} | {r['p']:.3g} | "
                  f"{r['unpolarized']:.3g} | {r['raw']:.3g} | {r['albedo_auto']:.4f} | {r['albedo_bem']:.4f} |")
        summary["auto"].append({"tolerance": tolerance, "cpu_s": auto["cpu_s"], "wall_s": auto["wall_s"],
                                "ratio": bem["cpu_s"] / auto["cpu_s"], "worst_error": worst, "rungs": rungs(auto["path"]),
                                "rows": rows})
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("surface", choices=sorted(SURFACES) + ["single"])
    parser.add_argument("--tolerance", type=float, nargs="+", default=[0.05, 0.01])
    parser.add_argument("--keep", type=Path, default=ROOT / "out" / "auto_at_scale")
    parser.add_argument("--rule-only", action="store_true",
                        help="single: print the rule's predictions and picks only (no rung or BEM run)")
    parser.add_argument("--material", help="single: a catalogue material (default: the reference's aluminium wvl.txt)")
    parser.add_argument("--wavelength", type=float, default=0.5, help="single: λ in µm (0.5)")
    parser.add_argument("--scenes", nargs="+", choices=sorted(SINGLE), help="single: these scenes only (default: all)")
    parser.add_argument("--one-task", action="store_true",
                        help="run each (λ, direction) of a study without steering as a study of its own (the rule's "
                             "path: one task has no spot checks)")
    args = parser.parse_args(argv)
    if args.surface == "single":
        return single_task_studies(args.tolerance, args.rule_only, args.material, args.wavelength, args.scenes)
    folder = args.keep / args.surface
    folder.mkdir(parents=True, exist_ok=True)
    study = SURFACES[args.surface]
    if args.one_task:
        summary = {"surface": args.surface, "one_task": {label: measure(folder, f"_{label}", one, args.tolerance, True)
                                                         for label, one in one_task_studies(args.surface, study)}}
    else:
        summary = {"surface": args.surface, **measure(folder, "", study, args.tolerance)}
    (folder / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
