"""The speed/accuracy trade table of record: every scene of ``configs/compare/trade/<suite>/*.toml``
through every rung that fits it, against the full-wave reference (AIM BEM), each reference shown
converged in the mesh, aggregated into ``docs/trade.md``, ``docs/images/trade_<suite>.png``,
``solver/data/trade.csv`` (the data ``model = "auto"`` fits its rule to) and
``solver/data/trade_convergence.csv``.

    .venv/bin/python benchmarks/trade.py              # resumes: scenes already compared are reused
    .venv/bin/python benchmarks/trade.py --force      # recompute every scene

Suites (one folder each; the regime in every config's second line): aluminium at waist 0.6 µm
(≈ λ) on 4 µm patches, aluminium at waist 2.5 µm (5 λ, the reference simulator's) on 9 µm
patches, both at d = 0.05 µm (λ/10 at 0.5 µm; |k₂|d ≤ 4 on aluminium).

Each scene's comparison is written to ``out/trade/<study>_compare.*`` (``wavebrdf compare``'s
files) as soon as it finishes, and each convergence solve to ``out/trade/<study>_converged.h5``,
so an interrupted regeneration loses at most the solve it was on. The errors of the table are
recomputed from the stored BRDFs (unpolarized and per incident polarization, raw and
speckle-averaged), so every column comes from one definition (``jobs.compare.comparison_metrics``).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import functools
import logging
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SUITE = ROOT / "configs" / "compare" / "trade"
WORK = ROOT / "out" / "trade"
REFINEMENT = 1.5  # the convergence solve's cells per side / the table's (d → d/1.5: λ/10 → λ/15)
CONVERGENCE_SHARE = 1 / 3  # a reference serves tolerances at least this many times its convergence figure
SWEEP = (0.01, 0.02, 0.05, 0.1, 0.2)  # tolerances of the summary table
SUITES = {  # folder → the regime, as the tables print it
    "al_waist0.6": "aluminium, waist 0.6 µm (≈ λ), 4 µm patch, 80² cells, λ 0.5 & 0.7 µm, θ_i 0° & 60°",
    "al_waist2.5": "aluminium, waist 2.5 µm (5 λ), 9 µm patch, 180² cells, λ 0.5 µm, θ_i 0° & 30° (the configs in "
                   "its folder; corner cubes, spherical pits and steep hemispheres not measured yet)",
}
COLUMNS = ("suite", "config", "scene", "model", "wall_s", "cpu_s", "peak_mb", "albedo", "albedo_diff", "rel_l2",
           "rel_l2_smooth", "rel_l2_s", "rel_l2_smooth_s", "rel_l2_p", "rel_l2_smooth_p", "misplaced",
           "peak_offset_deg", "retro", "failure")
CONVERGENCE_COLUMNS = ("suite", "config", "scene", "spacing_um", "fine_spacing_um", "cells", "fine_cells", "cpu_s",
                       "fine_cpu_s", "rel_l2", "rel_l2_smooth", "rel_l2_smooth_s", "rel_l2_smooth_p", "failure")


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


def compare_suite(configs: list[Path], force: bool, log) -> None:
    """Run ``wavebrdf compare`` on each config whose comparison is not stored yet (or every one)."""
    from wavebrdf.jobs.compare import compare_config
    from wavebrdf.jobs.config import load_config

    WORK.mkdir(parents=True, exist_ok=True)
    for path in configs:
        stem = _stem(path)
        if force or not _stored(path).is_file():
            t0 = time.perf_counter()
            comparison = compare_config(load_config(path), progress=lambda what: log(f"  {what}"))
            comparison.write(stem)
            log(f"{path.relative_to(ROOT)}: {time.perf_counter() - t0:.0f} s")


@functools.cache
def _scenes(path: Path) -> list[tuple[str, object]]:
    """The config's (label, scene) pairs, planned once per run."""
    from wavebrdf.jobs.compare import plan_scenes
    from wavebrdf.jobs.config import load_config
    from wavebrdf.jobs.plan import plan_study

    return plan_scenes(plan_study(load_config(path)))


def stored_measurements(h5_path: Path) -> dict[tuple[str, str], object]:
    """(scene, model) → the Measurement a comparison's .h5 holds (its BRDF, times, failure)."""
    from wavebrdf.jobs.compare import Measurement
    from wavebrdf.jobs.store import read_comparison

    out = {}
    table, brdfs = read_comparison(h5_path)
    for i, (scene, model) in enumerate(zip(table["scene"], table["model"])):
        failure = table["failure"][i] or None
        out[scene, model] = Measurement(model, scene, float(table["wall_s"][i]), float(table["cpu_s"][i]),
                                        float(table["peak_mb"][i]), brdfs.get((scene, model)), {}, failure)
    return out


def _speckle_sigma(scene) -> float:
    from wavebrdf.jobs.compare import speckle_sigma_u

    return speckle_sigma_u(scene.wavelength_um, scene.waist_um, scene.grid, scene.exterior_index)


def table_rows(path: Path) -> list[dict]:
    """The rows of one config: every (scene, model) with its errors against BEM recomputed from the
    stored BRDFs."""
    from wavebrdf.jobs.compare import comparison_metrics
    from wavebrdf.solver.auto import REFERENCE

    stored = stored_measurements(_stored(path))
    rows = []
    for label, scene in _scenes(path):
        ref = stored[label, REFERENCE]
        for (where, model), m in stored.items():
            if where != label:
                continue
            row = {"suite": path.parent.name, "config": str(path.resolve().relative_to(ROOT)), "scene": label,
                   "model": model, "wall_s": m.wall_s, "cpu_s": m.cpu_s, "peak_mb": m.peak_mb, "failure": m.failure or ""}
            if m.failure is None and ref.failure is None:
                row.update(comparison_metrics(m, ref, scene.grid, _speckle_sigma(scene), scene.theta_i, scene.phi_i))
            rows.append(row)
    return rows


def hardest_scene(path: Path) -> tuple[str, object]:
    """The config's scene the mesh resolves worst: the shortest λ, then the most oblique θ_i."""
    return min(_scenes(path), key=lambda ls: (ls[1].wavelength_um, -ls[1].theta_i))


def convergence(path: Path, force: bool, log, run: bool = True) -> dict:
    """The config's reference against BEM on the same surface at ``REFINEMENT`` times the cells
    (:func:`wavebrdf.solver.surface.refined`), on its hardest scene: the relative L2 of the coarse
    reference with the fine one as truth (stored in ``out/trade/<study>_converged.h5``). With
    ``run`` false a solve not stored yet is not run: the row says "not measured"."""
    import h5py

    from wavebrdf.jobs.compare import MeasuringProcess, Measurement, comparison_metrics
    from wavebrdf.jobs.config import load_config
    from wavebrdf.solver.auto import REFERENCE
    from wavebrdf.solver.surface import refined

    label, scene = hardest_scene(path)
    cells = scene.surface.cells
    fine_cells = int(round(REFINEMENT * cells))
    case = load_config(path).cases[0]
    store = WORK / f"{case.name}_converged.h5"
    cells_row = {"suite": path.parent.name, "config": str(path.resolve().relative_to(ROOT)), "scene": label,
                 "spacing_um": scene.surface.spacing_um, "fine_spacing_um": scene.surface.size_um / fine_cells,
                 "cells": cells, "fine_cells": fine_cells}
    if not run and not store.is_file():
        return {**cells_row, "cpu_s": np.nan, "fine_cpu_s": np.nan, "failure": "not measured"}
    if force or not store.is_file():
        fine = dataclasses.replace(scene, surface=refined(scene.surface, fine_cells))
        options = case.model.options
        log(f"{label}: BEM at {fine_cells}² cells (d = {fine.surface.spacing_um:.4g} µm)")
        with MeasuringProcess() as process:
            m = process.measure(REFERENCE, options, fine, label)
        with h5py.File(store, "w") as h5:
            h5.attrs.update(scene=label, cells=fine_cells, cpu_s=m.cpu_s, wall_s=m.wall_s, peak_mb=m.peak_mb,
                            failure=m.failure or "")
            if m.brdf is not None:
                h5["brdf"] = m.brdf
        log(f"{label}: converged reference {m.cpu_s:.0f} s CPU{' — ' + m.failure if m.failure else ''}")
    with h5py.File(store) as h5:
        fine_run = Measurement(REFERENCE, label, float(h5.attrs["wall_s"]), float(h5.attrs["cpu_s"]),
                               float(h5.attrs["peak_mb"]), h5["brdf"][()] if "brdf" in h5 else None, {},
                               h5.attrs["failure"] or None)
    coarse = stored_measurements(_stored(path))[label, REFERENCE]
    row = {**cells_row, "cpu_s": coarse.cpu_s, "fine_cpu_s": fine_run.cpu_s, "failure": fine_run.failure or ""}
    if fine_run.failure is None:
        row.update(comparison_metrics(coarse, fine_run, scene.grid, _speckle_sigma(scene), scene.theta_i, scene.phi_i))
    return row


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
    from wavebrdf.solver.auto import ERROR_COLUMN

    within = sorted((_num(r["cpu_s"]), m) for m, r in rows.items() if _num(r.get(ERROR_COLUMN)) <= tolerance)
    return within[0][1] if within else None


def evaluate_auto(configs: list[Path], table: list[dict], tolerance: float) -> list[dict]:
    """Per scene: auto's choice (the rule fitted to ``table``), its measured error and CPU time,
    the cheapest rung whose measured error meets ``tolerance`` (by measured CPU time), and BEM's."""
    from wavebrdf.solver.auto import ERROR_COLUMN, FEATURES, REFERENCE, Rule, SceneFeatures, choose, next_rung_up

    rule = Rule.fit(table)
    rows = []
    for path in configs:
        for label, scene in _scenes(path):
            mine = {r["model"]: r for r in table if r["scene"] == label}
            first = next(iter(mine.values()))
            features = SceneFeatures(**{k: float(first[k]) for k in FEATURES})
            choice = choose(scene, tolerance, rule, features)
            error = {m: _num(r.get(ERROR_COLUMN)) for m, r in mine.items()}
            cpu = {m: _num(r["cpu_s"]) for m, r in mine.items()}
            check = next_rung_up(choice, choice.model) if choice.model != REFERENCE else None
            cost = float(first["pilot_s"]) + cpu[choice.model] + (cpu[check] if check else 0.0)
            rows.append({"suite": path.parent.name, "scene": label, "auto": choice.model,
                         "predicted": choice.predicted_error, "measured": error[choice.model],
                         "measured_s": _num(mine[choice.model].get("rel_l2_smooth_s")),
                         "measured_p": _num(mine[choice.model].get("rel_l2_smooth_p")),
                         "cheapest_within": _cheapest_within(mine, tolerance) or "", "auto_cpu_s": cost,
                         "check": check or "",
                         "bem_cpu_s": cpu[REFERENCE], "reason": choice.reason})
    return rows


def measured_auto(configs: list[Path], table: list[dict], tolerance: float, log) -> list[dict]:
    """``model = "auto"`` run on every scene (one task: the rule's path and its escalation check)
    in the measuring process, its rung's error against the stored BEM and its CPU time measured;
    where it picks BEM, that is the table's own full-wave run (its CPU plus the pilot's)."""
    from wavebrdf.jobs.compare import MeasuringProcess, comparison_metrics
    from wavebrdf.solver.auto import REFERENCE, AutoModel, default_rule

    default_rule.cache_clear()  # the table just written
    rows = []
    with MeasuringProcess() as process:
        for path in configs:
            stored = stored_measurements(_stored(path))
            for label, scene in _scenes(path):
                t0 = time.process_time()
                picked = AutoModel({"tolerance": tolerance}).choice(scene).model
                pilot = time.process_time() - t0
                ref = stored[label, REFERENCE]
                if picked == REFERENCE:
                    metrics, cpu, ran = {"rel_l2_smooth": 0.0, "rel_l2_smooth_s": 0.0, "rel_l2_smooth_p": 0.0}, \
                        ref.cpu_s + pilot, REFERENCE
                else:
                    run = process.measure("auto", {"tolerance": tolerance}, scene, label)
                    if run.failure is not None:
                        raise RuntimeError(f"{label}: auto failed: {run.failure}")
                    metrics = comparison_metrics(run, ref, scene.grid, _speckle_sigma(scene), scene.theta_i, scene.phi_i)
                    cpu, ran = run.cpu_s, run.diagnostics.get("model", picked)
                rows.append({"suite": path.parent.name, "scene": label, "picked": picked, "ran": ran,
                             "error": metrics["rel_l2_smooth"], "error_s": metrics["rel_l2_smooth_s"],
                             "error_p": metrics["rel_l2_smooth_p"], "cpu_s": cpu, "bem_cpu_s": ref.cpu_s,
                             "cheapest_within": _cheapest_within({r["model"]: r for r in table if r["scene"] == label},
                                                                  tolerance) or REFERENCE})
                log(f"auto on {label}: {ran} error {metrics['rel_l2_smooth']:.3g}, {cpu:.3g} CPU-s")
    return rows


def measured_summary(rows: list[dict], tolerance: float) -> str:
    """One line per suite (and all): within, cheapest, worst error, measured CPU of BEM / auto."""
    lines = ["| suite | within | cheapest | worst error | BEM CPU / auto CPU (measured) | rungs run |",
             "|---|---|---|---|---|---|"]
    for suite in list(dict.fromkeys(r["suite"] for r in rows)) + ["all"]:
        mine = [r for r in rows if suite in ("all", r["suite"])]
        within = sum(r["error"] <= tolerance for r in mine)
        cheapest = sum(r["ran"] == r["cheapest_within"] for r in mine)
        ratio = sum(r["bem_cpu_s"] for r in mine) / sum(r["cpu_s"] for r in mine)
        ran = {}
        for r in mine:
            ran[r["ran"]] = ran.get(r["ran"], 0) + 1
        runs = ", ".join(f"{k} ×{v}" for k, v in sorted(ran.items(), key=lambda kv: -kv[1]))
        lines.append(f"| {suite} | {within}/{len(mine)} | {cheapest}/{len(mine)} | "
                     f"{max(r['error'] for r in mine):.3g} | {ratio:.3g}× | {runs} |")
    return "\n".join(lines)


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
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", stream=sys.stderr)
    log = logging.getLogger("trade").info
    configs = sorted(p.resolve() for p in args.configs) if args.configs else suite_configs()
    compare_suite(configs, args.force, log)
    converged = [] if args.convergence == "none" else \
        [convergence(p, args.force, log, run=args.convergence == "all") for p in configs]
    features = scene_features(configs, log)
    table = [{**row, **features[row["scene"]]} for path in configs for row in table_rows(path)]
    from wavebrdf.solver.auto import FEATURES, TRADE_TABLE

    _write_csv(TRADE_TABLE, COLUMNS + FEATURES + ("pilot_s",), table)
    _write_csv(TRADE_TABLE.with_name("trade_convergence.csv"), CONVERGENCE_COLUMNS, converged)
    log(f"wrote {TRADE_TABLE} and its convergence table")
    auto_rows = evaluate_auto(configs, table, args.tolerance)
    sweep = {tol: evaluate_auto(configs, table, tol) for tol in SWEEP}
    ran = {tol: measured_auto(configs, table, tol, log) for tol in args.measured_tolerances}
    for suite in dict.fromkeys(r["suite"] for r in table):
        plot([r for r in table if r["suite"] == suite], args.tolerance, ROOT / "docs" / "images" / f"trade_{suite}.png",
             SUITES.get(suite, suite))
    (ROOT / "docs" / "trade.md").write_text(markdown(table, converged, auto_rows, args.tolerance, sweep, ran))
    log("wrote docs/trade.md and docs/images/trade_*.png")
    return 0


def _num(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def plot(table: list[dict], tolerance: float, path: Path, regime: str) -> None:
    """Error vs CPU time (log-log), one marker per model, one colour per scene config."""
    from wavebrdf.jobs.compare import plot_trade

    rows = [{**r, "scene_config": Path(r["config"]).stem.replace("_", " "), "reference": "bem",
             "rel_l2_smooth": _num(r.get("rel_l2_smooth")), "cpu_s": _num(r["cpu_s"])} for r in table]
    plot_trade(rows, path, group="scene_config", tolerance=tolerance, title=f"every rung vs AIM BEM\n{regime}")


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


def markdown(table: list[dict], converged: list[dict], auto_rows: list[dict], tolerance: float, sweep: dict,
             ran: dict) -> str:
    from wavebrdf.solver.auto import Rule, SceneFeatures

    suites = list(dict.fromkeys(r["suite"] for r in table))
    lines = [HEADER.format(refinement=REFINEMENT, share=round(1 / CONVERGENCE_SHARE)), ""]
    lines += [f"- `{s}`: {SUITES.get(s, s)} — ![{s}](images/trade_{s}.png)" for s in suites]
    lines += ["", "## The references, converged", "",
              f"Each config's BEM on its hardest scene (shortest λ, most oblique θ_i) against BEM on the same surface "
              f"at {REFINEMENT:g}× the cells per side (solver/surface.py `refined`: deterministic generators rebuilt, "
              "random realizations trigonometrically interpolated): the relative L2 over the lobe of the coarse one "
              f"with the fine one as truth. A reference serves tolerances ≥ {round(1 / CONVERGENCE_SHARE)}× its "
              "figure (speckle-averaged; both polarizations shown).", "",
              "| suite | scene | d (µm) | fine d (µm) | rel L2 (speckle-avg) | s | p | raw | serves tolerance ≥ | "
              "CPU (s) | fine CPU (s) |", "|" + "---|" * 11]
    for r in converged:
        serves = _num(r.get("rel_l2_smooth")) / CONVERGENCE_SHARE
        lines.append(f"| {r['suite']} | {r['scene']} | {r['spacing_um']:.4g} | {r['fine_spacing_um']:.4g} | "
                     f"{_cell(r.get('rel_l2_smooth'))} | {_cell(r.get('rel_l2_smooth_s'))} | "
                     f"{_cell(r.get('rel_l2_smooth_p'))} | {_cell(r.get('rel_l2'))} | {_cell(serves)} | "
                     f"{_cell(r['cpu_s'])} | {_cell(r['fine_cpu_s'])} |" + (f" {r['failure']}" if r["failure"] else ""))
    measured = [r for r in converged if not r["failure"]]
    if measured:
        worst = max(_num(r.get("rel_l2_smooth")) for r in measured)
        lines += ["", f"Worst convergence figure {worst:.3g} over the {len(measured)} configs measured "
                  f"({len(converged) - len(measured)} not measured): those serve tolerances ≥ "
                  f"{worst / CONVERGENCE_SHARE:.3g} (each row: its own)."]
    for tol, rows in ran.items():
        lines += ["", f"## auto run on every scene, tolerance {tol:g} (measured)", "",
                  "`model = \"auto\"` run as a one-task study on each scene (the rule fitted to this table, its "
                  "escalation check), in the measuring process: the error of what it ran against BEM and its CPU "
                  "(pilot and check included; where it picks BEM, the table's own BEM run plus the pilot).", "",
                  measured_summary(rows, tol), "",
                  "| scene | ran | error | s | p | cheapest within | CPU (s) | bem CPU (s) |", "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {r['scene']} | {r['ran']} | {r['error']:.3g} | {r['error_s']:.3g} | {r['error_p']:.3g} | "
                  f"{r['cheapest_within']} | {r['cpu_s']:.3g} | {r['bem_cpu_s']:.3g} |" for r in rows]
    lines += ["", "## auto on the suites (from the table)", "",
              f"Tolerance {tolerance:g} (rel_l2_smooth, unpolarized; s and p beside). `auto` = the rule's choice "
              "(a single-task study: no spot checks); `cheapest within` = the cheapest rung whose measured error "
              "meets the tolerance (by measured CPU time); `auto CPU` ≈ pilot + chosen rung + the escalation check's "
              "rung (their full-resolution times from the table: an estimate, not a run — the measured end-to-end "
              "figures are in docs/auto.md).", "",
              "| scene | auto | predicted | measured | s | p | cheapest within | auto CPU (s) | bem CPU (s) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for r in auto_rows:
        lines.append(f"| {r['scene']} | {r['auto']} | {_cell(r['predicted'])} | {_cell(r['measured'])} | "
                     f"{_cell(r['measured_s'])} | {_cell(r['measured_p'])} | {r['cheapest_within']} | "
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
              "log₁₀(error) = Σ cₖ xₖ + margin per rung, xₖ = " + ", ".join(names) + " (c₀ … c₇); margin = the fit's "
              "largest residual; outside the fitted range of the regressors a prediction is the larger of the "
              "extrapolated one and the one at the nearest fitted point; single-scattering rungs are never predicted "
              "below the multi-bounce share (solver/auto.py).", "",
              "| rung | rows | " + " | ".join(f"c{k}" for k in range(len(names))) + " | margin |",
              "|" + "---|" * (len(names) + 3)]
    for name, c in rule.coefficients.items():
        lines.append(f"| {name} | {rule.rows[name]} | " + " | ".join(f"{x:.3g}" for x in c) +
                     f" | {rule.margin[name]:.3g} |")
    keys = ("scene", "model", "cpu_s", "peak_mb", "albedo_diff", "rel_l2", "rel_l2_smooth", "rel_l2_smooth_s",
            "rel_l2_smooth_p", "peak_offset_deg", "height_over_wavelength", "rms_slope", "shadowed", "multi_bounce",
            "waist_over_wavelength", "index_contrast", "failure")
    lines += ["", "## Every scene × rung", "",
              "| scene | model | CPU (s) | peak MB | Δalbedo | rel L2 (raw) | rel L2 (speckle-avg) | s | p | "
              "peak offset (°) | σ/λ | rms slope | shadowed | multi-bounce | w/λ | abs(n₂)/n₁ | failure |", "|" + "---|" * len(keys)]
    for r in table:
        lines.append("| " + " | ".join(_cell(r.get(k)) if k not in ("scene", "model", "failure") else (r[k] or "")
                                        for k in keys) + " |")
    return "\n".join(lines) + "\n"


HEADER = """# The speed/accuracy trade table of record

Every rung on seven scene kinds (smooth random, rough random, brushed, shallow grating, steep
hemispheres, corner cubes, spherical pits) in the regimes listed below (one suite each:
configs/compare/trade/<suite>/*.toml), with the same footprint, output grid and normalization,
against the full-wave reference (AIM BEM) at d = 0.05 µm; each reference checked against BEM at
{refinement:g}× the cells where that solve was run (below). Errors are the relative L2 over the lobe of the BRDF against BEM: raw, and
speckle-averaged (both blurred by the footprint's own angular spread λ/(πw): the figure `auto`'s
tolerance applies to), unpolarized and per incident polarization (s, p). Times are CPU seconds
of each model run alone in `compare`'s measuring process on the 2-core development VM, shared
with other work while measured: compare ratios, not absolute times. The ray rungs ran with 2²⁰
rays. Regenerate (resumes where it stopped):

    .venv/bin/python benchmarks/trade.py            # --force to recompute every scene

It writes this page, docs/images/trade_<suite>.png, solver/data/trade.csv (the table
`model = "auto"` fits its rule to; docs/auto.md) and solver/data/trade_convergence.csv.
"""


if __name__ == "__main__":
    sys.exit(main())
