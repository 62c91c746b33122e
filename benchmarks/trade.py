"""The speed/accuracy trade table of record: every scene of ``configs/compare/trade/<suite>/*.toml``
through every rung that fits it, against the full-wave reference (AIM BEM), each reference shown
converged in the mesh, aggregated into ``docs/trade.md``, ``docs/images/trade_<suite>.png``,
``solver/data/trade.csv`` (the data ``model = "auto"`` fits its rule to),
``solver/data/trade_convergence.csv`` and ``solver/data/trade_finer_pairs.csv`` (the refinements
beside the table's spacing, finer or coarser, ``--finer-pair``).

    .venv/bin/python benchmarks/trade.py              # resumes: scenes already compared are reused
    .venv/bin/python benchmarks/trade.py --force      # recompute every scene
    .venv/bin/python benchmarks/trade.py --rerun po    # po again everywhere, the other BRDFs as stored

Suites (one folder each; the regime in every config's second line): aluminium and glass at waist
0.6 µm (≈ λ) on 4 µm patches, aluminium at waist 2.5 µm (5 λ at 0.5 µm, the reference
simulator's) on 9 µm patches, all at d = 0.05 µm (λ/10 at 0.5 µm; |k₂|d ≤ 4 on aluminium).

Each scene's comparison is written to ``out/trade/<study>_compare.*`` (``wavebrdf compare``'s
files) as soon as it finishes, and each convergence solve (with the coarse reference it is
measured against) to ``out/trade/<study>_converged.h5``, so an interrupted regeneration loses at
most the solve it was on. A ``--finer-pair`` keeps each of its two solves the moment it is made
(``out/trade/<study>_bem_<digest>.h5``, :func:`keep_solve`: the digest covers the scene, its
surface and the BEM options): a fine solve that dies does not take the coarse one along, and a
config moved to the pair's spacing with the same fixed BEM options (``fit_memory = false``) takes
that solve as its reference instead of solving again; its time and memory are then the pair's
process's (``--force`` solves again; deleting the file forgets it). The errors of the table are
recomputed from the stored BRDFs (unpolarized and per incident polarization, raw and
speckle-averaged), so every column comes from one definition (``jobs.compare.comparison_metrics``).

The committed tables are the record that outlives ``out/``: a config whose comparison is not in
``out/trade`` keeps its rows of ``solver/data/trade.csv`` (and of ``trade_convergence.csv`` and
``trade_finer_pairs.csv``) as long
as its content is unchanged (``config_digest``: the parsed TOML, comments and the output path
left out), and the end-to-end ``auto`` runs are kept in ``benchmarks/results/trade_auto.csv`` per
(scene, tolerance, rung picked). So a fresh clone adds a new scene config by measuring that config
alone; ``--force`` re-measures everything.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import functools
import hashlib
import json
import logging
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SUITE = ROOT / "configs" / "compare" / "trade"
WORK = ROOT / "out" / "trade"
AUTO_RUNS = ROOT / "benchmarks" / "results" / "trade_auto.csv"  # auto run end to end per scene and tolerance
REFINEMENT = 1.5  # the convergence solve's cells per side / the table's (d → d/1.5: λ/10 → λ/15)
CONVERGENCE_SHARE = 1 / 3  # a reference serves tolerances at least this many times its convergence figure
FINE_MEMORY_SHARE = 0.8  # of this machine's RAM the finer solve may need with the table's settings (else no LU)
LU_FILL_GROWTH = 1.3  # the near LU's fill grows with the block (docs/aim.md: 13.1 → 16.6 over 4× the unknowns)
SWEEP = (0.01, 0.02, 0.05, 0.1, 0.2, 0.25)  # tolerances of the summary tables (0.1–0.25: above auto's VALIDATED_TOLERANCE)
SUITES = {  # folder → the regime, as the tables print it
    "al_waist0.6": "aluminium, waist 0.6 µm (≈ λ), 4 µm patch, 80² cells (the steep hemispheres 120², d = λ/15: at "
                   "λ/10 their reference did not converge to ⅓ of 0.05; at λ/15 it does unpolarized and in s, not in "
                   "p: it serves ≥ 0.062), λ 0.5 & 0.7 µm, θ_i 0° & 60°",
    "al_waist2.5": "aluminium, waist 2.5 µm (5 λ at 0.5 µm: the reference simulator's), 9 µm patch, 180² cells (the spherical "
                   "pits 270², d = λ/15, converged to ⅓ of 0.05 unpolarized and in p, not in s: it serves ≥ "
                   "0.064; the corner cubes and the steep hemispheres 360², d = λ/20 = 0.025 µm, the reference "
                   "simulator's spacing: at λ/10 their references did not converge to ⅓ of 0.05 — 0.0303 "
                   "and 0.027 against the scene rebuilt at 270²; the hemispheres' reference does not converge by "
                   "refinement within reach: 240² against 360² differ by 0.0277, as 180² against 270² — the full "
                   "wave's discretization along the walls, whose cells span √(2 r d) up them, not the height field, "
                   "on which physical optics has settled to 0.007 at 360² —, and their 360² reference's own check "
                   "against 540², 1.16·10⁶ unknowns, converges too slowly to run here (docs/aim.md), so that "
                   "reference serves tolerances ≥ ≈ 0.08, while every cheaper rung is ≥ 0.25 off it), "
                   "λ 0.5 µm (the bumpy surface: 0.4 & 0.7 µm, 6.25 λ & 3.6 λ), θ_i 0° & 30° (the steep "
                   "hemispheres: 0° only, one solve being ≈ 2,000 CPU-s)",
    "glass_waist0.6": "glass (n = 1.5), waist 0.6 µm (≈ λ), 4 µm patch, 80² cells (the corner cubes 120², d = λ/15: "
                      "at λ/10 their reference did not converge to ⅓ of 0.05), λ 0.5 & 0.7 µm, θ_i 0° & 60° "
                      "(the dielectric: the seven scene kinds at waist ≈ λ only), and three more random surfaces "
                      "(smooth, moderate, brushed) at θ_i 30° only, between normal incidence and Brewster's angle",
}
COLUMNS = ("suite", "config", "config_digest", "scene", "model", "wall_s", "cpu_s", "peak_mb", "albedo",
           "albedo_diff", "rel_l2", "rel_l2_smooth", "rel_l2_s", "rel_l2_smooth_s", "rel_l2_p", "rel_l2_smooth_p",
           "misplaced", "peak_offset_deg", "retro", "failure")
CONVERGENCE_COLUMNS = ("suite", "config", "config_digest", "scene", "spacing_um", "fine_spacing_um", "cells",
                       "fine_cells", "cpu_s", "fine_cpu_s", "fine_peak_mb", "fine_settings", "rel_l2", "rel_l2_smooth",
                       "rel_l2_smooth_s", "rel_l2_smooth_p", "failure")
PAIR_COLUMNS = ("suite", "config_digest", "scene", "refinement", "cells", "fine_cells", "spacing_um", "fine_spacing_um", "cpu_s",
                "fine_cpu_s", "fine_peak_mb", "fine_settings", "rel_l2", "rel_l2_smooth", "rel_l2_smooth_s",
                "rel_l2_smooth_p", "failure")
AUTO_COLUMNS = ("suite", "scene", "config_digest", "tolerance", "picked", "ran", "error", "error_s", "error_p",
                "cpu_s")


def suite_configs() -> list[Path]:
    """Every scene config of every suite folder, suite by suite."""
    return sorted(p for suite in SUITES for p in (SUITE / suite).glob("*.toml"))


@functools.cache
def _stem(path: Path) -> Path:
    from wavebrdf.jobs.config import load_config

    return WORK / f"{load_config(path).cases[0].name}_compare"


def _stored(path: Path) -> Path:
    """The config's comparison file (``Comparison.write``'s .h5)."""
    return WORK / f"{_stem(path).name}.h5"


@functools.cache
def config_digest(path: Path) -> str:
    """What a config measures, as 12 hex digits: its parsed TOML without the output path (comments,
    layout and the file's folder do not change a measurement)."""
    data = tomllib.loads(Path(path).read_text())
    data.get("study", {}).pop("output", None)
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:12]


def _read_csv(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@dataclasses.dataclass
class Record:
    """The committed tables, by config digest: what a regeneration keeps for a config whose
    comparison, convergence solve or auto run is not in ``out/trade``."""

    rows: dict[str, list[dict]]
    convergence: dict[str, dict]
    auto: dict[tuple[str, float, str], dict]  # (scene, tolerance, rung picked) → the run
    pairs: list[dict] = dataclasses.field(default_factory=list)  # finer_pair rows (trade_finer_pairs.csv)

    @classmethod
    def read(cls) -> "Record":
        from wavebrdf.solver.auto import TRADE_TABLE

        rows: dict[str, list[dict]] = {}
        for row in _read_csv(TRADE_TABLE):
            rows.setdefault(row.get("config_digest", ""), []).append(row)
        convergence = {r.get("config_digest", ""): r for r in _read_csv(TRADE_TABLE.with_name("trade_convergence.csv"))
                       if not r["failure"]}
        auto = {(r["scene"], float(r["tolerance"]), r["picked"]): r for r in _read_csv(AUTO_RUNS)}
        pairs = [{**r, "refinement": r.get("refinement") or "refined", "cells": int(r["cells"]),
                  "fine_cells": int(r["fine_cells"]), "spacing_um": float(r["spacing_um"]),
                  "fine_spacing_um": float(r["fine_spacing_um"])}
                 for r in _read_csv(TRADE_TABLE.with_name("trade_finer_pairs.csv"))]
        return cls(rows, convergence, auto, pairs)

    def kept_rows(self, path: Path) -> list[dict] | None:
        """The table's rows of ``path`` when they cover its every scene with the reference, else None."""
        from wavebrdf.solver.auto import REFERENCE

        mine = self.rows.get(config_digest(path), [])
        covered = {r["scene"] for r in mine if r["model"] == REFERENCE}
        if not mine or any(label not in covered for label, _ in _scenes(path)):
            return None
        return [{**r, "suite": path.parent.name, "config": str(path.relative_to(ROOT))} for r in mine]


def compare_suite(configs: list[Path], force: bool, log, record: Record | None = None,
                  rerun: tuple[str, ...] = ()) -> None:
    """Run ``wavebrdf compare`` on each config whose comparison is neither stored in ``out/trade``
    nor kept in ``record`` (or, ``force``, on every one), its BEM reference taken from a kept solve
    of the same scene and options where there is one (:func:`stored_solve`; not with ``force``).
    ``rerun``: rungs to run again on every config (after a rung changed): on a stored comparison
    of the config's current scenes whose reference did not fail alone, the other rungs' BRDFs and
    BEM's taken as stored; otherwise (a config kept only in ``record``, scenes that changed, a
    failed reference) the config is compared whole."""
    from wavebrdf.jobs.compare import compare_config
    from wavebrdf.jobs.config import load_config

    from wavebrdf.solver.auto import REFERENCE

    WORK.mkdir(parents=True, exist_ok=True)
    for path in configs:
        stored = not force and _stored(path).is_file()
        if stored and rerun:
            if _rerun_on_stored(path, rerun, log):
                continue
        elif stored:
            failed = [label for (label, model), m in stored_measurements(_stored(path)).items()
                      if model == REFERENCE and m.failure]
            if not failed:
                continue
            log(f"{path.relative_to(ROOT)}: the stored reference failed on {', '.join(failed)}; comparing it again")
        elif not force and not rerun and record is not None and record.kept_rows(path) is not None:
            continue
        t0 = time.perf_counter()
        measured = {} if force else _stored_references(path, log)
        comparison = compare_config(load_config(path), progress=lambda what: log(f"  {what}"), measured=measured)
        comparison.write(_stem(path))
        log(f"{path.relative_to(ROOT)}: {time.perf_counter() - t0:.0f} s")


def _rerun_on_stored(path: Path, rerun: tuple[str, ...], log) -> bool:
    """Run the ``rerun`` rungs again on ``path``'s stored comparison, every other measurement taken
    as stored; False (nothing run) where the stored comparison is not of the config's current
    scenes or its reference failed on one: the config is then to be compared whole."""
    from wavebrdf.jobs.compare import compare_config
    from wavebrdf.jobs.config import load_config

    from wavebrdf.solver.auto import REFERENCE

    stored = stored_measurements(_stored(path))
    labels = {label for label, _ in _scenes(path)}
    if {label for label, _ in stored} != labels:
        log(f"{path.relative_to(ROOT)}: its stored comparison is of other scenes; comparing it whole")
        return False
    if any(m.failure for (_, model), m in stored.items() if model == REFERENCE):
        log(f"{path.relative_to(ROOT)}: its stored reference failed; comparing it whole")
        return False
    absent = sorted(set(rerun) - {model for _, model in stored})
    if absent:
        log(f"{path.relative_to(ROOT)}: {', '.join(absent)} not among its compared rungs")
    t0 = time.perf_counter()
    kept = {key: m for key, m in stored.items() if key[1] not in rerun}
    comparison = compare_config(load_config(path), progress=lambda what: log(f"  {what}"), measured=kept)
    comparison.write(_stem(path))
    log(f"{path.relative_to(ROOT)}: {', '.join(sorted(set(rerun) - set(absent))) or 'nothing'} again, the others as "
        f"stored: {time.perf_counter() - t0:.0f} s")
    return True


def _stored_references(path: Path, log) -> dict:
    """(scene, "bem") → the stored solve (:func:`stored_solve`) of each scene of ``path`` that BEM was
    solved on with the options its comparison runs BEM with (the study's ``[model]``; none where a
    ``[compare.bem]`` table sets others)."""
    from wavebrdf.jobs.config import load_config
    from wavebrdf.solver.auto import REFERENCE

    case = load_config(path).cases[0]
    if case.model.name != REFERENCE or REFERENCE in _rungs_with_compare_options(path):
        return {}
    return {(label, REFERENCE): m for label, scene in _scenes(path)
            if (m := stored_solve(case.name, label, scene, case.model.options, log)) is not None}


def reference_measurement(path: Path, label: str, log):
    """The stored full-wave Measurement of scene ``label`` of ``path`` (BRDF included); a config kept
    only in the committed table is compared again first (its BRDFs are not in the table)."""
    from wavebrdf.solver.auto import REFERENCE

    if not _stored(path).is_file():
        log(f"{path.relative_to(ROOT)}: its BRDFs are not in out/trade; comparing it again")
        compare_suite([path], False, log)
    return stored_measurements(_stored(path))[label, REFERENCE]


@functools.cache
def _scenes(path: Path) -> list[tuple[str, object]]:
    """The config's (label, scene) pairs, planned once per run."""
    from wavebrdf.jobs.compare import plan_scenes
    from wavebrdf.jobs.config import load_config
    from wavebrdf.jobs.plan import plan_study

    return plan_scenes(plan_study(load_config(path)))


def stored_measurements(h5_path: Path) -> dict[tuple[str, str], object]:
    """(scene, model) → the Measurement a comparison's .h5 holds (its BRDF, times, failure and the
    warnings its row carried, where the file has them)."""
    from wavebrdf.jobs.compare import Measurement
    from wavebrdf.jobs.store import read_comparison

    out = {}
    table, brdfs = read_comparison(h5_path)
    warned = table.get("warnings") or [""] * len(table["scene"])  # files written before the column: none
    for i, (scene, model) in enumerate(zip(table["scene"], table["model"])):
        failure = table["failure"][i] or None
        out[scene, model] = Measurement(model, scene, float(table["wall_s"][i]), float(table["cpu_s"][i]),
                                        float(table["peak_mb"][i]), brdfs.get((scene, model)),
                                        {"warnings": warned[i]} if warned[i] else {}, failure)
    return out


def _speckle_sigma(scene) -> float:
    from wavebrdf.jobs.compare import speckle_sigma_u

    return speckle_sigma_u(scene.wavelength_um, scene.waist_um, scene.grid, scene.exterior_index)


def table_rows(path: Path, record: Record | None = None) -> list[dict]:
    """The rows of one config: every (scene, model) with its errors against BEM recomputed from the
    stored BRDFs, or, where they are not stored, the rows ``record`` keeps for it."""
    from wavebrdf.jobs.compare import comparison_metrics
    from wavebrdf.solver.auto import REFERENCE

    if not _stored(path).is_file() and record is not None and (kept := record.kept_rows(path)) is not None:
        return kept
    stored = stored_measurements(_stored(path))
    rows = []
    for label, scene in _scenes(path):
        ref = stored[label, REFERENCE]
        for (where, model), m in stored.items():
            if where != label:
                continue
            row = {"suite": path.parent.name, "config": str(path.resolve().relative_to(ROOT)),
                   "config_digest": config_digest(path), "scene": label, "model": model, "wall_s": m.wall_s,
                   "cpu_s": m.cpu_s, "peak_mb": m.peak_mb, "failure": m.failure or ""}
            if m.failure is None and ref.failure is None:
                row.update(comparison_metrics(m, ref, scene.grid, _speckle_sigma(scene), scene.theta_i, scene.phi_i))
            rows.append(row)
    return rows


def hardest_scene(path: Path) -> tuple[str, object]:
    """The config's scene the mesh resolves worst: the shortest λ, then the most oblique θ_i."""
    return min(_scenes(path), key=lambda ls: (ls[1].wavelength_um, -ls[1].theta_i))


def convergence(path: Path, force: bool, log, run: bool = True, record: Record | None = None) -> dict:
    """The config's reference against BEM on the same surface at ``REFINEMENT`` times the cells
    (:func:`wavebrdf.solver.surface.refined`), on its hardest scene: the relative L2 of the coarse
    reference with the fine one as truth (both stored in ``out/trade/<study>_converged.h5``; the
    coarse one from the comparison, or solved alone where the comparison is not stored; the fine
    one from a stored :func:`finer_pair` at the same cells where there is one, else solved; a coarse
    one solved here is kept, :func:`keep_solve`, and taken again unless ``force``). Not
    stored: the row ``record`` keeps for the config; none, and ``run`` false: "not measured"."""
    import h5py

    from wavebrdf.jobs.compare import MeasuringProcess
    from wavebrdf.jobs.config import load_config
    from wavebrdf.solver.auto import REFERENCE

    label, scene = hardest_scene(path)
    cells = scene.surface.cells
    fine_cells = int(round(REFINEMENT * cells))
    case = load_config(path).cases[0]
    store = WORK / f"{case.name}_converged.h5"
    cells_row = {"suite": path.parent.name, "config": str(path.resolve().relative_to(ROOT)),
                 "config_digest": config_digest(path), "scene": label, "spacing_um": scene.surface.spacing_um,
                 "fine_spacing_um": scene.surface.size_um / fine_cells, "cells": cells, "fine_cells": fine_cells}
    kept = None if record is None else record.convergence.get(config_digest(path))
    fine = dataclasses.replace(scene, surface=surface_at(scene.surface, fine_cells))
    if store.is_file():
        with h5py.File(store) as h5:
            stored_cells = int(h5.attrs.get("cells", -1))
            stored_surface = str(h5.attrs.get("fine_surface_digest", ""))
        if stored_cells != fine_cells:  # solved for another version of the config: not this one's
            stale = store.with_name(f"{store.stem}_{stored_cells}cells.h5")
            log(f"{label}: {store.name} holds a {stored_cells}² solve, not {fine_cells}²: moved to {stale.name}")
            store.rename(stale)
        elif stored_surface and stored_surface != surface_digest(fine.surface):  # stores before the digest: kept
            stale = store.with_name(f"{store.stem}_surface_{stored_surface}.h5")
            log(f"{label}: {store.name} holds a solve of another surface: moved to {stale.name}")
            store.rename(stale)
    pair = None if force else _stored_pair(case.name, label, scene.surface, fine_cells, log)
    if not force and not store.is_file() and kept is not None:
        return {**kept, **cells_row}
    if not run and not store.is_file() and pair is None:
        return {**cells_row, "cpu_s": np.nan, "fine_cpu_s": np.nan, "failure": "not measured"}
    if force or not store.is_file():
        WORK.mkdir(parents=True, exist_ok=True)
        options = case.model.options
        with MeasuringProcess() as process:
            if _stored(path).is_file():
                coarse = stored_measurements(_stored(path))[label, REFERENCE]
            elif pair is not None:
                coarse = pair[1]
            elif force or (coarse := stored_solve(case.name, label, scene, options, log)) is None:
                log(f"{label}: BEM at {cells}² cells (the comparison is not stored)")
                coarse = process.measure(REFERENCE, options, scene, label)
                keep_solve(case.name, label, scene, options, coarse)
            if pair is not None:
                m, _, settings = pair
                log(f"{label}: BEM at {fine_cells}² cells from {pair_path(case.name, cells, fine_cells).name}")
            else:
                fine_options, settings = fine_solve_options(options, coarse.peak_mb, (fine_cells / cells) ** 2)
                log(f"{label}: BEM at {fine_cells}² cells (d = {fine.surface.spacing_um:.4g} µm), {settings}")
                m = process.measure(REFERENCE, fine_options, fine, label)
        _write_refinement(store, label, fine_cells, m, coarse, settings,
                          fine_surface_digest=surface_digest(fine.surface))
        log(f"{label}: converged reference {m.cpu_s:.0f} s CPU{' — ' + m.failure if m.failure else ''}")
    return {**cells_row, **_refinement_row(*_read_refinement(store, label), scene)}


def finer_pair(path: Path, cells: int, log, preconditioner: str | None = None, subdivide: int | None = None,
               restart: int = 30) -> Path:
    """One refinement beside the table's: the config's hardest scene at ``cells`` per side (below the
    config's own cells only where its surface can be rebuilt there, :func:`surface_at`) against
    BEM on a finer mesh, by default the scene rebuilt at ``REFINEMENT`` × ``cells`` (stored in ``out/trade/<study>_pair_<cells>_<fine>.h5`` and listed
    under the convergence table). The solve at ``cells`` is taken from the config's converged store
    where that holds it of the same surface (the table's own fine solve; the store records its fine
    surface as ``fine_surface_digest``, a pair file its coarse one as ``surface_digest``), else from a solve kept before with the same
    options (:func:`stored_solve`), else run; so is the fine one; each solve run here is kept as it
    finishes (delete its file to solve it again). ``preconditioner`` ("local" | "flat-patch"):
    the solves run here with the local inverses and GMRES(``restart``), or the flat patch's inner
    solve and FGMRES(``restart``), even where the near LU would fit (it factors slowly there); they
    converge to the same discrete solution as the LU's, to the solver's tolerance.
    ``subdivide``: the fine mesh is the surface at ``cells`` with every cell split into
    ``subdivide``² (:func:`wavebrdf.solver.surface.subdivided`: the same bilinear geometry), so the
    pair measures the solver's discretization alone, not the scene's sampling
    (``<study>_pair_<cells>_<fine>_subdivided.h5``)."""
    from wavebrdf.jobs.compare import MeasuringProcess
    from wavebrdf.jobs.config import load_config
    from wavebrdf.solver.auto import REFERENCE
    from wavebrdf.solver.surface import subdivided

    if subdivide is not None and (int(subdivide) != subdivide or subdivide < 2):
        raise ValueError(f"--subdivide must be an integer >= 2, got {subdivide!r}")
    label, scene = hardest_scene(path)
    case = load_config(path).cases[0]
    fine_cells = cells * subdivide if subdivide else int(round(REFINEMENT * cells))
    kind = "subdivided" if subdivide else "refined"
    out = pair_path(case.name, cells, fine_cells, bool(subdivide))
    store = WORK / f"{case.name}_converged.h5"
    options = case.model.options
    coarse_surface = surface_at(scene.surface, cells)  # refused here, before any solve, where it cannot be built
    fine_surface = subdivided(coarse_surface, subdivide) if subdivide else surface_at(scene.surface, fine_cells)
    WORK.mkdir(parents=True, exist_ok=True)
    progress = out.with_suffix(".progress")
    log(f"{label}: the solves' progress is appended to {progress.relative_to(ROOT)}")
    with MeasuringProcess(progress_path=progress) as process:
        coarse = None
        if store.is_file():
            stored, _, attrs = _read_refinement(store, label)
            if int(attrs["cells"]) == cells and stored.brdf is not None:
                if str(attrs.get("fine_surface_digest", "")) == surface_digest(coarse_surface):
                    coarse = stored
                    # a peak without the LU says nothing of what the LU needs: stay without it
                    if preconditioner is None and str(attrs.get("settings", "")).startswith("local"):
                        preconditioner = "local"
                else:
                    log(f"{label}: {store.name}'s {cells}² solve is not known to be of this surface (another "
                        "surface, or stored before surfaces were recorded): not taken")
        fine_options, settings = fine_solve_options(options, np.nan, 1.0, f"{cells}²", preconditioner, restart)
        at_cells = dataclasses.replace(scene, surface=coarse_surface)
        if coarse is None:
            coarse = stored_solve(case.name, label, at_cells, fine_options, log)
        if coarse is None:
            log(f"{label}: BEM at {cells}² cells, {settings}")
            coarse = process.measure(REFERENCE, fine_options, at_cells, label)
            keep_solve(case.name, label, at_cells, fine_options, coarse, settings)
        fine_options, settings = fine_solve_options(options, coarse.peak_mb, (fine_cells / cells) ** 2, f"{cells}²",
                                                    preconditioner, restart)
        at_fine = dataclasses.replace(scene, surface=fine_surface)
        if (m := stored_solve(case.name, label, at_fine, fine_options, log)) is None:
            log(f"{label}: BEM at {fine_cells}² cells ({kind}), {settings}")
            m = process.measure(REFERENCE, fine_options, at_fine, label)
            keep_solve(case.name, label, at_fine, fine_options, m, settings)
    WORK.mkdir(parents=True, exist_ok=True)
    _write_refinement(out, label, fine_cells, m, coarse, settings, suite=path.parent.name, coarse_cells=cells,
                      size_um=scene.surface.size_um, surface_digest=surface_digest(coarse_surface), refinement=kind)
    return out


def pair_path(study: str, cells: int, fine_cells: int, subdivided: bool = False) -> Path:
    """Where :func:`finer_pair` keeps the pair of ``study`` at ``cells`` against ``fine_cells``."""
    return WORK / f"{study}_pair_{cells}_{fine_cells}{'_subdivided' if subdivided else ''}.h5"


def surface_at(surface, cells: int):
    """The config's ``surface`` at ``cells`` cells a side: refined (:func:`~wavebrdf.solver.surface.refined`)
    to at least its own cells, rebuilt (:func:`~wavebrdf.solver.surface.rebuilt`) below them, which
    only a generator independent of the grid allows (SurfaceError otherwise)."""
    from wavebrdf.solver.surface import rebuilt, refined

    if cells == surface.cells:
        return surface  # refined would interpolate a random realization anew: same heights to rounding only
    return refined(surface, cells) if cells > surface.cells else rebuilt(surface, cells)


def surface_digest(surface) -> str:
    """A short hash of a height field's nodes and size: which surface a stored solve was of."""
    import hashlib

    z = np.ascontiguousarray(surface.z, dtype=np.float64)
    return hashlib.sha256(z.tobytes() + repr(float(surface.size_um)).encode()).hexdigest()[:16]


def solve_digest(scene, options) -> str | None:
    """What a full-wave solve computes, as 16 hex digits: the scene's physics and output grid (its
    surface's nodes included, the memory budget left out) and the solver's options; None where the
    options let the solver fit its settings to the memory at hand (``[model.aim] fit_memory``), so
    that the options do not say what ran."""
    aim = getattr(options, "aim", None)
    if aim is not None and getattr(options, "method", "aim") == "aim" and aim.fit_memory:
        return None
    fields = {f.name: getattr(scene, f.name) for f in dataclasses.fields(scene)
              if f.name not in ("surface", "memory_budget_bytes", "index", "grid")}
    fields.update(surface=surface_digest(scene.surface), index=[scene.index.real, scene.index.imag],
                  grid=scene.grid.resolution, options=dataclasses.asdict(options))
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:16]


def keep_solve(study: str, label: str, scene, options, m, settings: str = "") -> Path | None:
    """Store BEM Measurement ``m`` of ``scene`` (labelled ``label``) with ``options`` as soon as it
    is made (``out/trade/<study>_bem_<solve digest>.h5``, :func:`solve_digest`; written whole or
    not at all), so a later solve that dies does not take it along and a comparison of the same
    scene with the same options takes it instead of solving again (:func:`stored_solve`). Not kept:
    a failed solve, and one whose options fit to the memory at hand."""
    from wavebrdf.jobs.store import atomic_h5

    digest = solve_digest(scene, options)
    if digest is None or m.failure is not None or m.brdf is None:
        return None
    path = WORK / f"{study}_bem_{digest}.h5"
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_h5(path) as h5:
        h5.attrs.update(scene=label, cells=scene.surface.cells, wall_s=m.wall_s, cpu_s=m.cpu_s, peak_mb=m.peak_mb,
                        settings=settings, diagnostics=json.dumps(m.diagnostics, sort_keys=True, default=str))
        h5["brdf"] = m.brdf
    return path


def stored_solve(study: str, label: str, scene, options, log=None):
    """The BEM Measurement :func:`keep_solve` stored of ``scene`` with these ``options`` (its
    diagnostics name the file: ``measured_before``), else None."""
    import h5py

    from wavebrdf.jobs.compare import Measurement
    from wavebrdf.solver.auto import REFERENCE

    digest = solve_digest(scene, options)
    path = WORK / f"{study}_bem_{digest}.h5"
    if digest is None or not path.is_file():
        return None
    with h5py.File(path) as h5:
        a = dict(h5.attrs)
        brdf = h5["brdf"][()]
    if log is not None:
        log(f"{label}: BEM at {scene.surface.cells}² cells from {path.name} ({float(a['cpu_s']):.0f} CPU-s, "
            f"{a['settings'] or 'the options given'})")
    diagnostics = {**json.loads(a["diagnostics"]), "measured_before": path.name}
    return Measurement(REFERENCE, str(a["scene"]), float(a["wall_s"]), float(a["cpu_s"]), float(a["peak_mb"]), brdf,
                       diagnostics)


def _stored_pair(study: str, label: str, surface, fine_cells: int, log=None):
    """(the fine Measurement, the coarse one, the fine solve's settings) of a stored
    :func:`finer_pair` of ``study`` whose coarse solve was of this ``surface`` (its cells) in the
    scene ``label``, refined to ``fine_cells``, and did not fail; else None (a pair of another
    surface — a random realization drawn anew at other cells — is not used, and ``log`` says so)."""
    path = pair_path(study, surface.cells, fine_cells)
    if not path.is_file():
        return None
    fine, coarse, a = _read_refinement(path, label)
    if fine.failure or fine.brdf is None or coarse.brdf is None:
        return None
    if str(a["scene"]) != label or str(a.get("surface_digest", "")) != surface_digest(surface):
        if log is not None:
            log(f"{label}: {path.name} is of another scene or surface: not used")
        return None
    return fine, coarse, str(a["settings"])


def _write_refinement(store: Path, label: str, fine_cells: int, fine, coarse, settings: str, **extra) -> None:
    """A refinement's .h5: the fine and coarse BEM Measurements' BRDFs and figures (and ``extra`` attrs)."""
    import h5py

    with h5py.File(store, "w") as h5:
        h5.attrs.update(scene=label, cells=fine_cells, cpu_s=fine.cpu_s, wall_s=fine.wall_s, peak_mb=fine.peak_mb,
                        failure=fine.failure or coarse.failure or "", coarse_cpu_s=coarse.cpu_s, settings=settings,
                        **extra)
        for name, run_ in (("brdf", fine), ("coarse_brdf", coarse)):
            if run_.brdf is not None:
                h5[name] = run_.brdf


def _read_refinement(store: Path, label: str):
    """(the fine Measurement, the coarse one, the attrs) of a :func:`_write_refinement` .h5."""
    import h5py

    from wavebrdf.jobs.compare import Measurement
    from wavebrdf.solver.auto import REFERENCE

    with h5py.File(store) as h5:
        a = dict(h5.attrs)
        fine = Measurement(REFERENCE, label, float(a["wall_s"]), float(a["cpu_s"]), float(a["peak_mb"]),
                           h5["brdf"][()] if "brdf" in h5 else None, {}, a["failure"] or None)
        coarse = Measurement(REFERENCE, label, cpu_s=float(a["coarse_cpu_s"]),
                             brdf=h5["coarse_brdf"][()] if "coarse_brdf" in h5 else None)
    return fine, coarse, a


def _refinement_row(fine, coarse, attrs: dict, scene) -> dict:
    """The convergence tables' figures of one refinement: times, settings and, unless it failed,
    the coarse BRDF's errors with the fine one as truth."""
    from wavebrdf.jobs.compare import comparison_metrics

    row = {"cpu_s": coarse.cpu_s, "fine_cpu_s": fine.cpu_s, "fine_peak_mb": fine.peak_mb,
           "fine_settings": attrs.get("settings", ""), "failure": fine.failure or ""}
    if fine.failure is None:
        row.update(comparison_metrics(coarse, fine, scene.grid, _speckle_sigma(scene), scene.theta_i, scene.phi_i))
    return row


def _pair_key(row: dict) -> tuple:
    """Which refinement a finer-pair row is: its config, scene, kind and both meshes' cells."""
    return (row["config_digest"], row["scene"], row.get("refinement") or "refined", int(row["cells"]),
            int(row["fine_cells"]))


def finer_pairs(configs: list[Path], record: Record | None = None) -> list[dict]:
    """The rows of every stored :func:`finer_pair` of ``configs`` beside the table's own check, finer
    or coarser (the convergence table's columns), and those ``record`` keeps of a config whose pair
    is no longer in ``out/trade`` (while the config is unchanged); sorted by suite, scene, kind and
    cells."""
    from wavebrdf.jobs.config import load_config
    from wavebrdf.solver.surface import SurfaceError

    rows = []
    for path in configs:
        label, scene = hardest_scene(path)
        for stored in sorted(WORK.glob(f"{load_config(path).cases[0].name}_pair_*.h5")):
            fine, coarse, a = _read_refinement(stored, label)
            refinement = str(a.get("refinement", "refined"))
            coarse_cells = int(a["coarse_cells"])
            try:
                coarse_surface = surface_at(scene.surface, coarse_cells)
            except SurfaceError as e:
                logging.getLogger("trade").info(f"{stored.name}: not listed ({e})")
                continue
            if str(a["scene"]) != label or str(a.get("surface_digest", "")) != surface_digest(coarse_surface):
                logging.getLogger("trade").info(f"{stored.name} is of another scene or surface than {path.name}'s: "
                                                "not listed")
                continue
            if refinement == "refined" and coarse_cells == scene.surface.cells:
                continue  # the table's own check: convergence() reads it, its table lists it
            rows.append({"suite": path.parent.name, "config_digest": config_digest(path), "scene": label,
                         "refinement": refinement, "cells": coarse_cells, "fine_cells": int(a["cells"]),
                         "spacing_um": a["size_um"] / coarse_cells, "fine_spacing_um": a["size_um"] / a["cells"],
                         **_refinement_row(fine, coarse, a, scene)})
    measured = {_pair_key(r) for r in rows}
    digests = {config_digest(path) for path in configs}
    rows += [r for r in (record.pairs if record else []) if r["config_digest"] in digests and _pair_key(r) not in measured]
    return sorted(rows, key=lambda r: (r["suite"], r["scene"], _pair_key(r)[2:]))


FINE_PRECONDITIONERS = {  # the finer solve's preconditioner where the near LU is not used → what the table says
    "local": "local inverses for the near LU, GMRES",
    "flat-patch": "the flat patch's inner solve for the near LU, FGMRES",
}


def fine_solve_options(options, coarse_peak_mb: float, unknowns_ratio: float,
                       measured_at: str = "the table's spacing", preconditioner: str | None = None,
                       restart: int = 30):
    """(options, what they are) of the finer convergence solve: the table's own where the coarse
    solve's measured peak, scaled by the unknowns and the LU fill's growth, fits
    :data:`FINE_MEMORY_SHARE` of this machine's RAM; else the same operator and tolerance with
    ``preconditioner`` for the near LU (default "local": the local inverses, GMRES(``restart``),
    ~1.1 KB per unknown; "flat-patch": the flat patch's inner solve, FGMRES(``restart``), ~120 B per
    unknown): no factor — the solution it converges to is the same to the solver's tolerance, only
    the path there differs. ``preconditioner`` given: that one whether or not the LU would fit."""
    from wavebrdf.solver.resources import meminfo_bytes

    need = coarse_peak_mb * 2**20 * unknowns_ratio * LU_FILL_GROWTH
    fits = not np.isfinite(need) or need <= FINE_MEMORY_SHARE * meminfo_bytes("MemTotal")
    if fits and preconditioner is None:
        return options, "the table's settings"  # the near LU: a restart other than the table's is not used
    preconditioner = preconditioner or "local"
    if preconditioner not in FINE_PRECONDITIONERS:
        raise ValueError(f"the finer solve's preconditioner must be one of {tuple(FINE_PRECONDITIONERS)}, "
                         f"got {preconditioner!r}")
    deflate = 0 if preconditioner == "flat-patch" else min(options.aim.deflate, restart - 1)
    aim = dataclasses.replace(options.aim, preconditioner=preconditioner, solver="gmres", restart=restart,
                              deflate=deflate, fit_memory=False)
    why = "asked for" if fits else f"the LU would need ≈ {need / 2**30:.0f} GiB"
    if np.isfinite(coarse_peak_mb):
        why += f"; the solve at {measured_at} peaked at {coarse_peak_mb / 1024:.1f} GiB"
    return dataclasses.replace(options, aim=aim), f"{FINE_PRECONDITIONERS[preconditioner]}({restart}) ({why})"


def scene_features(configs: list[Path], log) -> dict[str, dict]:
    """label → the features ``auto`` measures (and the pilot's wall time ``pilot_s``)."""
    from wavebrdf.solver.auto import measure_scene

    features = {}
    for path in configs:
        for label, scene in _scenes(path):
            t0 = time.perf_counter()
            measured = measure_scene(scene)
            features[label] = {**dataclasses.asdict(measured), "pilot_s": time.perf_counter() - t0}
    log(f"measured the features of {len(features)} scenes")
    return features


def _cheapest_within(rows: dict[str, dict], tolerance: float) -> str | None:
    """The rung of ``rows`` (model → table row of one scene) with the least measured CPU time
    whose measured error meets ``tolerance`` (None: none does)."""
    from wavebrdf.solver.auto import table_error

    within = sorted((_num(r["cpu_s"]), m) for m, r in rows.items() if table_error(r) <= tolerance)
    return within[0][1] if within else None


def evaluate_auto(configs: list[Path], table: list[dict], tolerance: float, leave_out: bool = False) -> list[dict]:
    """Per scene: auto's choice (the rule fitted to ``table``; with ``leave_out``, to the table
    without the scene's own config: a scene the rule has not seen), its measured error (the worst
    of s, p and unpolarized, each beside) and CPU time, the cheapest rung whose measured error meets ``tolerance`` (by measured CPU time), and
    BEM's."""
    from wavebrdf.solver.auto import FEATURES, REFERENCE, Rule, SceneFeatures, choose, next_rung_up, table_error

    fitted = Rule.fit(table)
    rows = []
    for path in configs:
        config = str(path.relative_to(ROOT))
        rule = Rule.fit([r for r in table if r["config"] != config]) if leave_out else fitted
        for label, scene in _scenes(path):
            mine = {r["model"]: r for r in table if r["scene"] == label}
            first = next(iter(mine.values()))
            features = SceneFeatures(**{k: float(first[k]) for k in FEATURES})
            choice = choose(scene, tolerance, rule, features)
            error = {m: table_error(r) for m, r in mine.items()}
            cpu = {m: _num(r["cpu_s"]) for m, r in mine.items()}
            check = next_rung_up(choice, choice.model) if choice.model != REFERENCE else None
            cost = float(first["pilot_s"]) + cpu[choice.model] + (cpu[check] if check else 0.0)
            rows.append({"suite": path.parent.name, "scene": label, "auto": choice.model,
                         "predicted": choice.predicted_error, "measured": error[choice.model],
                         "measured_unpolarized": _num(mine[choice.model].get("rel_l2_smooth")),
                         "measured_s": _num(mine[choice.model].get("rel_l2_smooth_s")),
                         "measured_p": _num(mine[choice.model].get("rel_l2_smooth_p")),
                         "cheapest_within": _cheapest_within(mine, tolerance) or "", "auto_cpu_s": cost,
                         "check": check or "",
                         "bem_cpu_s": cpu[REFERENCE], "reason": choice.reason})
    return rows


def measured_auto(configs: list[Path], table: list[dict], tolerance: float, log, record: Record | None = None,
                  force: bool = False, rerun: tuple[str, ...] = ()) -> list[dict]:
    """``model = "auto"`` run on every scene (one task: the rule's path and its escalation check)
    in the measuring process, its rung's error against the stored BEM and its CPU time measured;
    where it picks BEM, that is the table's own full-wave run (its CPU plus the pilot's). A run
    ``record`` keeps for the same scene, config, tolerance and pick is reused (not with ``force``,
    nor with ``rerun``: a changed rung may be the pick, the rung run or the one its check measures)."""
    from wavebrdf.jobs.compare import MeasuringProcess, comparison_metrics
    from wavebrdf.solver.auto import REFERENCE, AutoModel, default_rule

    default_rule.cache_clear()  # the table just written
    rows = []
    with MeasuringProcess() as process:
        for path in configs:
            for label, scene in _scenes(path):
                mine = {r["model"]: r for r in table if r["scene"] == label}
                t0 = time.process_time()
                picked = AutoModel({"tolerance": tolerance}).choice(scene).model
                pilot = time.process_time() - t0
                bem_cpu = _num(mine[REFERENCE]["cpu_s"])
                reuse = record is not None and not force and not rerun  # a re-run rung may be auto's check
                kept = record.auto.get((label, tolerance, picked)) if reuse else None
                if kept is not None and kept["config_digest"] == config_digest(path):
                    run = {k: (kept[k] if k in ("picked", "ran") else _num(kept[k]))
                           for k in ("picked", "ran", "error", "error_s", "error_p", "cpu_s")}
                elif picked == REFERENCE:
                    run = {"picked": picked, "ran": REFERENCE, "error": 0.0, "error_s": 0.0, "error_p": 0.0,
                           "cpu_s": bem_cpu + pilot}
                else:
                    measured = process.measure("auto", {"tolerance": tolerance}, scene, label)
                    if measured.failure is not None:
                        raise RuntimeError(f"{label}: auto failed: {measured.failure}")
                    ran = measured.diagnostics.get("model", picked)
                    if _stored(path).is_file() or ran in _rungs_with_compare_options(path):
                        ref = reference_measurement(path, label, log)
                        metrics = comparison_metrics(measured, ref, scene.grid, _speckle_sigma(scene), scene.theta_i,
                                                     scene.phi_i)
                    else:  # the same rung with the same options on the same scene: the table's measured row
                        metrics = {k: _num(mine[ran][k]) for k in ("rel_l2_smooth", "rel_l2_smooth_s", "rel_l2_smooth_p")}
                    run = {"picked": picked, "ran": ran, "error": metrics["rel_l2_smooth"],
                           "error_s": metrics["rel_l2_smooth_s"], "error_p": metrics["rel_l2_smooth_p"],
                           "cpu_s": measured.cpu_s}
                rows.append({"suite": path.parent.name, "scene": label, "config_digest": config_digest(path),
                             "tolerance": tolerance, **run, "bem_cpu_s": bem_cpu,
                             "cheapest_within": _cheapest_within(mine, tolerance) or REFERENCE})
                log(f"auto on {label}: {run['ran']} error {_worst(run):.3g} (the worst of unpolarized, s and p), "
                    f"{run['cpu_s']:.3g} CPU-s")
    return rows


def _rungs_with_compare_options(path: Path) -> set[str]:
    """Rungs the config's ``[compare.<rung>]`` tables run with other options than ``auto`` runs them
    (the table's error of such a rung is not the error of auto's run)."""
    section = tomllib.loads(Path(path).read_text()).get("compare", {})
    return {name for name, table in section.items() if isinstance(table, dict)}


def measured_summary(rows: list[dict], tolerance: float) -> str:
    """One line per suite (and all): within, cheapest, worst error, measured CPU of BEM / auto."""
    lines = ["| suite | within | cheapest | worst error | BEM CPU / auto CPU (measured) | rungs run |",
             "|---|---|---|---|---|---|"]
    for suite in list(dict.fromkeys(r["suite"] for r in rows)) + ["all"]:
        mine = [r for r in rows if suite in ("all", r["suite"])]
        within = sum(_worst(r) <= tolerance for r in mine)
        cheapest = sum(r["ran"] == r["cheapest_within"] for r in mine)
        ratio = sum(r["bem_cpu_s"] for r in mine) / sum(r["cpu_s"] for r in mine)
        ran = {}
        for r in mine:
            ran[r["ran"]] = ran.get(r["ran"], 0) + 1
        runs = ", ".join(f"{k} ×{v}" for k, v in sorted(ran.items(), key=lambda kv: -kv[1]))
        lines.append(f"| {suite} | {within}/{len(mine)} | {cheapest}/{len(mine)} | "
                     f"{max(_worst(r) for r in mine):.3g} | {ratio:.3g}× | {runs} |")
    return "\n".join(lines)


def _worst(run: dict) -> float:
    """An auto run's error as its tolerance reads it: the worst of unpolarized, s and p (NaN where
    one is)."""
    from wavebrdf.solver.metrics import worst_speckle_error

    return worst_speckle_error({"unpolarized": run["error"], "s": run["error_s"], "p": run["error_p"]})


def _write_csv(path: Path, columns, rows: list[dict]) -> None:
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--force", action="store_true", help="recompute scenes already compared")
    parser.add_argument("--configs", nargs="*", type=Path,
                        help="scene configs (default: configs/compare/trade/<suite>/*.toml of every suite)")
    parser.add_argument("--tolerance", type=float, default=0.05, help="auto's tolerance in the summary (0.05)")
    parser.add_argument("--convergence", choices=("all", "cached", "none"), default="all",
                        help="finer-mesh reference solves: run the missing ones (all), use only those stored in "
                             "out/trade (cached; the others are listed as not measured), or none")
    parser.add_argument("--measured-tolerances", nargs="*", type=float, default=[0.05, 0.01],
                        help="tolerances at which auto is run on every scene, end to end (0.05 0.01)")
    parser.add_argument("--rerun", nargs="+", default=(), metavar="RUNG",
                        help="run these rungs again everywhere (after they changed): on a comparison stored in "
                             "out/trade alone, the other rungs and BEM as stored; a config kept only in the "
                             "committed table is compared whole")
    parser.add_argument("--finer-pair", nargs=2, metavar=("CONFIG", "CELLS"),
                        help="only solve one refinement beside the table's: CONFIG's hardest scene at CELLS per side "
                             f"and at {REFINEMENT:g}× CELLS (listed under the convergence table at the next run); "
                             "CELLS below the config's only for a surface its generator can rebuild there")
    parser.add_argument("--subdivide", type=int, metavar="FACTOR",
                        help="with --finer-pair: the fine mesh is the surface at CELLS with every cell split into "
                             "FACTOR² (the same bilinear geometry: the solver's convergence alone), not the scene "
                             f"refined to {REFINEMENT:g}× CELLS")
    preconditioners = parser.add_mutually_exclusive_group()
    preconditioners.add_argument("--local-inverses", dest="preconditioner", action="store_const", const="local",
                        help="with --finer-pair: both solves with local inverses and GMRES(--restart) even where "
                             "the near LU fits (the LU factors slowly at ≳ 150,000 unknowns)")
    preconditioners.add_argument("--flat-patch", dest="preconditioner", action="store_const", const="flat-patch",
                        help="with --finer-pair: both solves with the flat patch's inner solve and FGMRES(--restart) "
                             "even where the near LU fits")
    parser.add_argument("--restart", type=int, default=None, metavar="M",
                        help="with --finer-pair: (F)GMRES's restart length where the LU is not used "
                             "(default 30; Krylov vectors take 32 n M bytes for n unknowns, FGMRES's 64 n M)")
    args = parser.parse_args(argv)
    if args.subdivide is not None and not args.finer_pair:
        parser.error("--subdivide goes with --finer-pair CONFIG CELLS")
    if args.preconditioner is not None and not args.finer_pair:
        parser.error(f"--{'local-inverses' if args.preconditioner == 'local' else 'flat-patch'} goes with --finer-pair "
                     "CONFIG CELLS")
    if args.restart is not None and (args.restart < 1 or not args.finer_pair):
        parser.error(f"--restart must be a positive integer and goes with --finer-pair; got {args.restart}")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", stream=sys.stderr)
    log = logging.getLogger("trade").info
    if args.finer_pair:
        log(f"wrote {finer_pair(Path(args.finer_pair[0]).resolve(), int(args.finer_pair[1]), log, args.preconditioner, args.subdivide, args.restart or 30)}")
        return 0
    configs = sorted(p.resolve() for p in args.configs) if args.configs else suite_configs()
    record = Record.read()
    from wavebrdf.solver.models import model_names

    rerun = tuple(args.rerun)
    unknown = sorted(set(rerun) - set(model_names()))
    if unknown:
        parser.error(f"--rerun {' '.join(unknown)}: not a model (the models: {', '.join(model_names())})")
    compare_suite(configs, args.force, log, record, rerun)
    converged = [] if args.convergence == "none" else \
        [convergence(p, args.force, log, args.convergence == "all", record) for p in configs]
    features = scene_features(configs, log)
    table = [{**row, **features[row["scene"]]} for path in configs for row in table_rows(path, record)]
    from wavebrdf.solver.auto import FEATURES, TRADE_TABLE

    _write_csv(TRADE_TABLE, COLUMNS + FEATURES + ("pilot_s",), table)
    _write_csv(TRADE_TABLE.with_name("trade_convergence.csv"), CONVERGENCE_COLUMNS, converged)
    log(f"wrote {TRADE_TABLE} and its convergence table")
    auto_rows = evaluate_auto(configs, table, args.tolerance)
    sweep = {tol: evaluate_auto(configs, table, tol) for tol in SWEEP}
    unseen = {tol: evaluate_auto(configs, table, tol, leave_out=True) for tol in SWEEP}
    ran = {tol: measured_auto(configs, table, tol, log, record, args.force, rerun)
           for tol in args.measured_tolerances}
    AUTO_RUNS.parent.mkdir(parents=True, exist_ok=True)
    _write_csv(AUTO_RUNS, AUTO_COLUMNS, [r for rows in ran.values() for r in rows])
    for suite in dict.fromkeys(r["suite"] for r in table):
        plot([r for r in table if r["suite"] == suite], args.tolerance, ROOT / "docs" / "images" / f"trade_{suite}.png",
             SUITES.get(suite, suite))
    pairs = finer_pairs(configs, record)
    _write_csv(TRADE_TABLE.with_name("trade_finer_pairs.csv"), PAIR_COLUMNS, pairs)
    (ROOT / "docs" / "trade.md").write_text(markdown(table, converged, auto_rows, args.tolerance, sweep, ran, unseen,
                                                     pairs))
    log("wrote docs/trade.md and docs/images/trade_*.png")
    return 0


def _num(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def plot(table: list[dict], tolerance: float, path: Path, regime: str) -> None:
    """Error (the worst of s, p and unpolarized, speckle-averaged) vs CPU time (log-log), one marker
    per model, one colour per scene config."""
    from wavebrdf.jobs.compare import plot_trade
    from wavebrdf.solver.auto import table_error

    rows = [{**r, "scene_config": Path(r["config"]).stem.replace("_", " "), "reference": "bem",
             "worst": table_error(r), "cpu_s": _num(r["cpu_s"])} for r in table]
    plot_trade(rows, path, group="scene_config", tolerance=tolerance, title=f"every rung vs AIM BEM\n{regime}",
               error="worst", error_label="speckle-averaged, worst of s, p and unpolarized")


def _cell(value) -> str:
    v = _num(value)
    if isinstance(value, str) and not np.isfinite(v):
        return value
    return "" if not np.isfinite(v) else f"{v:.3g}"


def summary(auto_rows: list[dict], tolerance: float) -> tuple[int, int, float, float]:
    """(scenes within tolerance, scenes where auto is the cheapest such rung, worst measured error,
    CPU time of BEM everywhere / auto's)."""
    within = sum(r["measured"] <= tolerance for r in auto_rows)
    cheapest = sum(r["auto"] == (r["cheapest_within"] or "bem") for r in auto_rows)
    worst = max(r["measured"] for r in auto_rows)
    saved = sum(r["bem_cpu_s"] for r in auto_rows) / sum(r["auto_cpu_s"] for r in auto_rows)
    return within, cheapest, worst, saved


def _picks(rows: list[dict]) -> str:
    chosen = {}
    for row in rows:
        chosen[row["auto"]] = chosen.get(row["auto"], 0) + 1
    return ", ".join(f"{k} ×{v}" for k, v in sorted(chosen.items(), key=lambda kv: -kv[1]))


def _convergence_line(r: dict) -> str:
    """One row of the convergence tables."""
    from wavebrdf.solver.auto import table_error

    serves = table_error(r) / CONVERGENCE_SHARE  # as the tolerance reads it: the worst of unpolarized, s and p
    return (f"| {r['suite']} | {r['scene']} | {r['spacing_um']:.4g} | {r['fine_spacing_um']:.4g} | "
            f"{_cell(r.get('rel_l2_smooth'))} | {_cell(r.get('rel_l2_smooth_s'))} | "
            f"{_cell(r.get('rel_l2_smooth_p'))} | {_cell(r.get('rel_l2'))} | {_cell(serves)} | "
            f"{_cell(r['cpu_s'])} | {_cell(r['fine_cpu_s'])} | "
            f"{'; '.join(x for x in (r.get('fine_settings'), r['failure']) if x)} |")


def markdown(table: list[dict], converged: list[dict], auto_rows: list[dict], tolerance: float, sweep: dict,
             ran: dict, unseen: dict, pairs: list[dict] = ()) -> str:
    from wavebrdf.solver.auto import (ERROR_CEILING, MIN_ROWS_PER_REGRESSOR, OPTIONAL_REGRESSORS, Rule, SceneFeatures,
                                      table_error)

    suites = list(dict.fromkeys(r["suite"] for r in table))
    lines = [HEADER.format(refinement=REFINEMENT, share=round(1 / CONVERGENCE_SHARE)), ""]
    lines += [f"- `{s}`: {SUITES.get(s, s)} — ![{s}](images/trade_{s}.png)" for s in suites]
    lines += ["", "## The references, converged", "",
              f"Each config's BEM on its hardest scene (shortest λ, most oblique θ_i) against BEM on the same surface "
              f"at {REFINEMENT:g}× the cells per side (solver/surface.py `refined`: deterministic generators rebuilt, "
              "random realizations trigonometrically interpolated): the relative L2 over the lobe of the coarse one "
              f"with the fine one as truth. A reference serves tolerances ≥ {round(1 / CONVERGENCE_SHARE)}× its "
              "figure (speckle-averaged, the worst of unpolarized, s and p: as `auto`'s tolerance reads it).", "",
              "| suite | scene | d (µm) | fine d (µm) | unpolarized (speckle-avg) | s | p | raw | serves tolerance ≥ | "
              "CPU (s) | fine CPU (s) | fine solve |", "|" + "---|" * 12]
    lines += [_convergence_line(r) for r in converged]
    measured = [r for r in converged if not r["failure"]]
    if measured:
        worst = max(table_error(r) for r in measured)
        lines += ["", f"Worst convergence figure {worst:.3g} over the {len(measured)} configs measured "
                  f"({len(converged) - len(measured)} not measured): those serve tolerances ≥ "
                  f"{worst / CONVERGENCE_SHARE:.3g} (each row: its own)."]
    head = ["| suite | scene | d (µm) | fine d (µm) | unpolarized (speckle-avg) | s | p | raw | serves tolerance ≥ | "
            "CPU (s) | fine CPU (s) | fine solve |", "|" + "---|" * 12]
    further = [r for r in pairs if (r.get("refinement") or "refined") == "refined"]
    if further:
        lines += ["", "Beside the table's spacing (`benchmarks/trade.py --finer-pair CONFIG CELLS`): the same scene at "
                  f"CELLS against it refined to {REFINEMENT:g}× CELLS (as in the table above) — finer than the table's where its reference "
                  "misses ⅓ of 0.05 (how fast it converges, what a finer table would serve), coarser where the "
                  "table's own check is out of reach (how the references converge toward the table's spacing).",
                  ""] + head
        lines += [_convergence_line(r) for r in further]
    fixed = [r for r in pairs if r.get("refinement") == "subdivided"]
    if fixed:
        lines += ["", "The solver alone, on a fixed surface (`benchmarks/trade.py --finer-pair CONFIG CELLS --subdivide "
                  "FACTOR`): the scene's surface at CELLS with every bilinear cell split into FACTOR² (solver/surface.py "
                  "`subdivided`: the same geometry), so the difference is the BEM's discretization of that surface "
                  "and not the scene's sampling, which the tables above include (there the scene is rebuilt on the "
                  "finer grid: its edges and walls move). The table compares every rung with BEM on one and the "
                  "same sampled surface, the one at the table's spacing. Each pair's fine-solve column gives the "
                  "settings it ran with (`--restart M`: GMRES(M) with the local inverses; the subdivided steep "
                  "hemispheres' 360² solve stalled with them at GMRES(30) and GMRES(200): docs/aim.md).", ""] + head
        lines += [_convergence_line(r) for r in fixed]
    for tol, rows in ran.items():
        lines += ["", f"## auto run on every scene, tolerance {tol:g} (measured)", "",
                  "`model = \"auto\"` run as a one-task study on each scene (the rule fitted to this table, its "
                  "escalation check), in the measuring process: the error of what it ran against BEM and its CPU "
                  "(pilot and check included; where it picks BEM, the table's own BEM run plus the pilot).", "",
                  measured_summary(rows, tol), "",
                  "| scene | ran | unpolarized | s | p | cheapest within | CPU (s) | bem CPU (s) |", "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {r['scene']} | {r['ran']} | {r['error']:.3g} | {r['error_s']:.3g} | {r['error_p']:.3g} | "
                  f"{r['cheapest_within']} | {r['cpu_s']:.3g} | {r['bem_cpu_s']:.3g} |" for r in rows]
    lines += ["", "## auto on the suites (from the table)", "",
              f"Tolerance {tolerance:g} (speckle-averaged, the worst of unpolarized, s and p; each beside). `auto` = the rule's choice "
              "(a single-task study: no spot checks); `cheapest within` = the cheapest rung whose measured error "
              "meets the tolerance (by measured CPU time); `auto CPU` ≈ pilot + chosen rung + the escalation check's "
              "rung (their full-resolution times from the table: an estimate, not a run — the measured end-to-end "
              "figures are in docs/auto.md).", "",
              "| scene | auto | predicted | measured (worst) | unpolarized | s | p | cheapest within | auto CPU (s) | "
              "bem CPU (s) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in auto_rows:
        lines.append(f"| {r['scene']} | {r['auto']} | {_cell(r['predicted'])} | {_cell(r['measured'])} | "
                     f"{_cell(r['measured_unpolarized'])} | {_cell(r['measured_s'])} | {_cell(r['measured_p'])} | {r['cheapest_within']} | "
                     f"{_cell(r['auto_cpu_s'])} | {_cell(r['bem_cpu_s'])} |")
    lines += ["", "| suite | within | cheapest | worst error | BEM CPU / auto CPU (estimate) | rungs chosen |",
              "|---|---|---|---|---|---|"]
    for suite in suites + ["all"]:
        rows = [r for r in auto_rows if suite in ("all", r["suite"])]
        w, c, e, ratio = summary(rows, tolerance)
        lines.append(f"| {suite} | {w}/{len(rows)} | {c}/{len(rows)} | {e:.3g} | {ratio:.3g}× | {_picks(rows)} |")
    lines += ["", "Other tolerances (the same rule, the same table):", "",
              "| tolerance | suite | within | cheapest | worst error | BEM CPU / auto CPU (estimate) | rungs chosen |",
              "|---|---|---|---|---|---|---|"]
    for tol, all_rows in sweep.items():
        for suite in suites:
            rows = [r for r in all_rows if r["suite"] == suite]
            w, c, e, ratio = summary(rows, tol)
            lines.append(f"| {tol:g} | {suite} | {w}/{len(rows)} | {c}/{len(rows)} | {e:.3g} | {ratio:.3g}× | "
                         f"{_picks(rows)} |")
    lines += ["", "Scenes the rule has not seen: each config's scenes chosen by the rule fitted to the table "
              "without that config (the check of tests/test_auto.py):", "",
              "| tolerance | suite | within | cheapest | worst error | BEM CPU / auto CPU (estimate) | rungs chosen | "
              "beyond the tolerance |", "|---|---|---|---|---|---|---|---|"]
    for tol, all_rows in unseen.items():
        for suite in suites + ["all"]:
            rows = [r for r in all_rows if suite in ("all", r["suite"])]
            w, c, e, ratio = summary(rows, tol)
            beyond = "; ".join(f"{r['scene']} {r['auto']} {r['measured']:.3g}" for r in rows if r["measured"] > tol)
            lines.append(f"| {tol:g} | {suite} | {w}/{len(rows)} | {c}/{len(rows)} | {e:.3g} | {ratio:.3g}× | "
                         f"{_picks(rows)} | {beyond or '—'} |")
    lines.append("")
    exceptions = [r for r in auto_rows if r["auto"] != (r["cheapest_within"] or "bem")]
    if exceptions:
        lines += [f"Exceptions at {tolerance:g} (auto is not the cheapest rung within tolerance):", ""]
        lines += [f"- {r['scene']}: auto {r['auto']}, cheapest {r['cheapest_within'] or 'none (bem)'} — "
                  f"{r['reason']}" for r in exceptions]
        lines.append("")
    rule = Rule.fit(table)
    names = SceneFeatures.REGRESSORS
    lines += ["## The rule", "",
              "log₁₀(error) = Σ cₖ xₖ + margin per rung, xₖ = " + ", ".join(names) + f" (c₀ … c{str(len(names) - 1).translate(str.maketrans('0123456789', '₀₁₂₃₄₅₆₇₈₉'))}; "
              + ", ".join(OPTIONAL_REGRESSORS) + " only in the rungs whose largest residual on scene configs left "
              "out of the fit it lowers, else its c is 0); errors measured at or beyond "
              f"{ERROR_CEILING:g} are censored there (such a row costs the fit only where predicted below it); "
              "margin = the "
              "smallest that puts every row's prediction at or above its measured error, or above "
              f"{ERROR_CEILING:g} where the error measured more (auto's tolerances are below {ERROR_CEILING:g}), "
              "also with the row's scene config left out of the fit (the largest left-out residual); rows "
              "a single-scattering rung's multi-bounce floor covers impose nothing; outside the fitted range of the "
              "regressors a prediction is the larger of the extrapolated one and the one at the nearest fitted point; "
              "single-scattering rungs are never predicted below the multi-bounce share; a rung with fewer than "
              f"{MIN_ROWS_PER_REGRESSOR} rows per regressor is not fitted (solver/auto.py). Rungs not listed: not "
              "chosen.", "",
              "| rung | rows | " + " | ".join(f"c{k}" for k in range(len(names))) + " | margin |",
              "|" + "---|" * (len(names) + 3)]
    for name, c in rule.coefficients.items():
        lines.append(f"| {name} | {rule.rows[name]} | " + " | ".join(f"{x:.3g}" for x in c) +
                     f" | {rule.margin[name]:.3g} |")
    keys = ("scene", "model", "cpu_s", "peak_mb", "albedo_diff", "rel_l2", "rel_l2_smooth", "rel_l2_smooth_s",
            "rel_l2_smooth_p", "peak_offset_deg", "height_over_wavelength", "rms_slope", "shadowed", "multi_bounce",
            "waist_over_wavelength", "index_contrast", "grazing_share", "failure")
    lines += ["", "## Every scene × rung", "",
              "| scene | model | CPU (s) | peak MB | Δalbedo | rel L2 (raw) | rel L2 (speckle-avg) | s | p | "
              "peak offset (°) | σ/λ | rms slope | shadowed | multi-bounce | w/λ | abs(n₂)/n₁ | grazing share | failure |", "|" + "---|" * len(keys)]
    for r in table:
        lines.append("| " + " | ".join(_cell(r.get(k)) if k not in ("scene", "model", "failure") else (r[k] or "")
                                        for k in keys) + " |")
    return "\n".join(lines) + "\n"


HEADER = """# The speed/accuracy trade table of record

Every rung on seven scene kinds (smooth random, rough random, brushed, shallow grating, steep
hemispheres, corner cubes, spherical pits; at the reference simulator's waist also a bumpy random
surface of its steering surfaces' roughness) in the regimes listed below (one suite each:
configs/compare/trade/<suite>/*.toml), with the same footprint, output grid and normalization,
against the full-wave reference (AIM BEM) at d = 0.05 µm (where that did not converge to ⅓ of 0.05: 0.0333 or 0.025 µm, listed
below); each reference checked against BEM at
{refinement:g}× the cells where that solve was run (below). Errors are the relative L2 over the lobe of the BRDF against BEM: raw, and
speckle-averaged (both blurred by the footprint's own angular spread λ/(πw)), unpolarized and per
incident polarization (s, p); `auto`'s tolerance applies to the worst of the three speckle-averaged
ones. Times are CPU seconds
of each model run alone in `compare`'s measuring process on the 2-core development VM, shared
with other work while measured: compare ratios, not absolute times (where a config's BEM solve
is a `--finer-pair`'s at the same spacing and settings, its time is that run's: the steep
hemispheres and the corner cubes' θ_i 30° at waist 2.5 µm). The ray rungs ran with 2²⁰ rays. Regenerate (resumes where it stopped):

    .venv/bin/python benchmarks/trade.py            # --force to recompute every scene

It writes this page, docs/images/trade_<suite>.png, solver/data/trade.csv (the table
`model = "auto"` fits its rule to; docs/auto.md), solver/data/trade_convergence.csv and
benchmarks/results/trade_auto.csv (auto run end to end). Those CSVs are the record: a config whose
comparison is not in out/trade keeps its rows while its content is unchanged, so a new scene
config is measured alone.
"""


if __name__ == "__main__":
    sys.exit(main())
