"""The speed/accuracy trade table of record: every scene of ``configs/compare/trade/*.toml``
through every rung that fits it, against the full-wave reference (AIM BEM), aggregated into
``docs/trade.md``, ``docs/images/trade.png`` and ``solver/data/trade.csv`` (the data
``model = "auto"`` fits its rule to).

    .venv/bin/python benchmarks/trade.py              # resumes: scenes already compared are reused
    .venv/bin/python benchmarks/trade.py --force      # recompute every scene

Each scene's comparison is written to ``out/trade/<study>_compare.*`` (``wavebrdf compare``'s
files) as soon as it finishes, so an interrupted regeneration loses at most the scene it was on.
The CSV also carries the scene features that ``model = "auto"`` measures
(:mod:`wavebrdf.solver.auto`), so its rule can be refitted from the table alone.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import logging
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SUITE = ROOT / "configs" / "compare" / "trade"
WORK = ROOT / "out" / "trade"


def compare_suite(configs: list[Path], force: bool, log) -> list[dict]:
    """Run (or reuse) ``wavebrdf compare`` on each config; the rows of every scene."""
    from wavebrdf.jobs.compare import compare_config
    from wavebrdf.jobs.config import load_config

    rows = []
    WORK.mkdir(parents=True, exist_ok=True)
    for path in configs:
        config = load_config(path)
        stem = WORK / f"{config.cases[0].name}_compare"
        if force or not stem.with_suffix(".csv").is_file():
            t0 = time.perf_counter()
            comparison = compare_config(config, progress=lambda what: log(f"  {what}"))
            comparison.write(stem)
            log(f"{path.name}: {time.perf_counter() - t0:.0f} s")
        with open(stem.with_suffix(".csv"), newline="") as fh:
            for row in csv.DictReader(fh):
                row["config"] = str(path.resolve().relative_to(ROOT))
                rows.append(row)
    return rows


COLUMNS = ("config", "scene", "model", "wall_s", "cpu_s", "peak_mb", "albedo", "albedo_diff", "rel_l2",
           "rel_l2_smooth", "misplaced", "peak_offset_deg", "retro", "failure")


def scene_features(configs: list[Path], log) -> dict[str, dict]:
    """label → the features ``auto`` measures (and the pilot's wall time ``pilot_s``)."""
    from wavebrdf.jobs.compare import plan_scenes
    from wavebrdf.jobs.config import load_config
    from wavebrdf.jobs.plan import plan_study
    from wavebrdf.solver.auto import measure_scene

    features = {}
    for path in configs:
        for label, scene in plan_scenes(plan_study(load_config(path))):
            t0 = time.perf_counter()
            measured = measure_scene(scene)
            features[label] = {**dataclasses.asdict(measured), "pilot_s": time.perf_counter() - t0}
    log(f"measured the features of {len(features)} scenes")
    return features


def evaluate_auto(configs: list[Path], table: list[dict], tolerance: float) -> list[dict]:
    """Per scene: auto's choice (the rule fitted to ``table``), its measured error and CPU time,
    the cheapest rung whose measured error meets ``tolerance`` (by measured CPU time), and BEM's."""
    from wavebrdf.jobs.compare import plan_scenes
    from wavebrdf.jobs.config import load_config
    from wavebrdf.jobs.plan import plan_study
    from wavebrdf.solver.auto import ERROR_COLUMN, FEATURES, REFERENCE, Rule, SceneFeatures, choose, next_rung_up

    rule = Rule.fit(table)
    rows = []
    for path in configs:
        for label, scene in plan_scenes(plan_study(load_config(path))):
            mine = {r["model"]: r for r in table if r["scene"] == label}
            first = next(iter(mine.values()))
            features = SceneFeatures(**{k: float(first[k]) for k in FEATURES})
            choice = choose(scene, tolerance, rule, features)
            error = {m: float(r[ERROR_COLUMN]) if r[ERROR_COLUMN] not in ("", None) else np.nan for m, r in mine.items()}
            cpu = {m: float(r["cpu_s"]) if r["cpu_s"] not in ("", None) else np.nan for m, r in mine.items()}
            within = sorted((cpu[m], m) for m in mine if error[m] <= tolerance)
            check = next_rung_up(choice, choice.model) if choice.model != REFERENCE else None
            cost = float(first["pilot_s"]) + cpu[choice.model] + (cpu[check] if check else 0.0)
            rows.append({"scene": label, "auto": choice.model, "predicted": choice.predicted_error,
                         "measured": error[choice.model], "cheapest_within": within[0][1] if within else "",
                         "auto_cpu_s": cost, "check": check or "", "bem_cpu_s": cpu[REFERENCE],
                         "reason": choice.reason})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--force", action="store_true", help="recompute scenes already compared")
    parser.add_argument("--configs", nargs="*", type=Path, help="scene configs (default: configs/compare/trade/*.toml)")
    parser.add_argument("--tolerance", type=float, default=0.05, help="auto's tolerance in the summary (0.05)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", stream=sys.stderr)
    log = logging.getLogger("trade").info
    configs = sorted(args.configs or SUITE.glob("*.toml"))
    rows = compare_suite(configs, args.force, log)
    features = scene_features(configs, log)
    table = [{**{k: row.get(k, "") for k in COLUMNS}, **features[row["scene"]]} for row in rows]
    from wavebrdf.solver.auto import FEATURES, TRADE_TABLE

    with open(TRADE_TABLE, "w", newline="") as fh:
        writer = csv.DictWriter(fh, COLUMNS + FEATURES + ("pilot_s",))
        writer.writeheader()
        writer.writerows(table)
    log(f"wrote {TRADE_TABLE}")
    auto_rows = evaluate_auto(configs, table, args.tolerance)
    sweep = {tol: evaluate_auto(configs, table, tol) for tol in SWEEP}
    plot(table, args.tolerance, ROOT / "docs" / "images" / "trade.png")
    (ROOT / "docs" / "trade.md").write_text(markdown(table, auto_rows, args.tolerance, sweep))
    log("wrote docs/trade.md and docs/images/trade.png")
    return 0


def _num(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def plot(table: list[dict], tolerance: float, path: Path) -> None:
    """Error vs CPU time (log-log), one marker per model, one colour per scene config."""
    from wavebrdf.jobs.compare import plot_trade

    rows = [{**r, "scene_config": Path(r["config"]).stem.replace("_", " "), "reference": "bem",
             "rel_l2_smooth": _num(r["rel_l2_smooth"]), "cpu_s": _num(r["cpu_s"])} for r in table]
    plot_trade(rows, path, group="scene_config", tolerance=tolerance,
               title="the speed/accuracy trade: 7 scenes × 2 λ × 2 θ_i, every rung vs AIM BEM")


def _cell(value) -> str:
    v = _num(value)
    if isinstance(value, str) and not np.isfinite(v):
        return value
    return "" if not np.isfinite(v) else f"{v:.3g}"


SWEEP = (0.02, 0.05, 0.1, 0.2)  # tolerances of the summary table


def summary(auto_rows: list[dict], tolerance: float) -> tuple[int, int, float, float]:
    """(scenes within tolerance, scenes where auto is the cheapest such rung, worst measured error,
    CPU time of BEM everywhere / auto's)."""
    within = sum(r["measured"] <= tolerance for r in auto_rows)
    cheapest = sum(r["auto"] == (r["cheapest_within"] or "bem") for r in auto_rows)
    worst = max(r["measured"] for r in auto_rows)
    saved = sum(r["bem_cpu_s"] for r in auto_rows) / sum(r["auto_cpu_s"] for r in auto_rows)
    return within, cheapest, worst, saved


def markdown(table: list[dict], auto_rows: list[dict], tolerance: float, sweep: dict) -> str:
    from wavebrdf.solver.auto import Rule

    lines = [HEADER.format(tolerance=tolerance), "",
             "## auto on the suite", "",
             f"Tolerance {tolerance:g} (rel_l2_smooth). `auto` = its choice; `cheapest within` = the cheapest rung "
             "whose measured error meets the tolerance (by measured CPU time); `auto CPU` ≈ pilot + chosen rung + "
             "the escalation check's rung (their full-resolution times from the table; the check runs both at 32² "
             "directions; escalation is not simulated here — on the second suite, where auto ran with its check, it "
             "never escalated).", "",
             "| scene | auto | predicted | measured | cheapest within | check | auto CPU (s) | bem CPU (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in auto_rows:
        lines.append(f"| {r['scene']} | {r['auto']} | {_cell(r['predicted'])} | {_cell(r['measured'])} | "
                     f"{r['cheapest_within']} | {r['check']} | {_cell(r['auto_cpu_s'])} | {_cell(r['bem_cpu_s'])} |")
    within, cheapest, worst, saved = summary(auto_rows, tolerance)
    lines += ["", f"Within tolerance: {within}/{len(auto_rows)} scenes; the cheapest such rung: {cheapest}/"
              f"{len(auto_rows)}; worst measured error {worst:.3g}; CPU time of BEM everywhere / auto: "
              f"**{saved:.3g}×**.", "",
              "Other tolerances (the same rule, the same table):", "",
              "| tolerance | within | cheapest | worst error | BEM CPU / auto CPU | rungs chosen |", "|---|---|---|---|---|---|"]
    for tol, rows in sweep.items():
        w, c, e, r = summary(rows, tol)
        chosen = {}
        for row in rows:
            chosen[row["auto"]] = chosen.get(row["auto"], 0) + 1
        picks = ", ".join(f"{k} ×{v}" for k, v in sorted(chosen.items(), key=lambda kv: -kv[1]))
        lines.append(f"| {tol:g} | {w}/{len(rows)} | {c}/{len(rows)} | {e:.3g} | {r:.3g}× | {picks} |")
    lines.append("")
    exceptions = [r for r in auto_rows if r["auto"] != (r["cheapest_within"] or "bem")]
    if exceptions:
        lines += ["Exceptions (auto is not the cheapest rung within tolerance):", ""]
        lines += [f"- {r['scene']}: auto {r['auto']}, cheapest {r['cheapest_within'] or 'none (bem)'} — "
                  f"{r['reason']}" for r in exceptions]
        lines.append("")
    rule = Rule.fit(table)
    lines += ["## The rule", "",
              "log₁₀(error) = c₀ + c₁ log₁₀(σ/λ) + c₂ rms slope + c₃ sin²θ_i + c₄ multi-bounce + c₅ shadowed + "
              "margin (the fit's largest residual), per rung; single-scattering rungs are never predicted "
              "below the multi-bounce share (solver/auto.py).", "",
              "| rung | rows | c₀ | c₁ | c₂ | c₃ | c₄ | c₅ | margin |", "|---|---|---|---|---|---|---|---|---|"]
    for name, c in rule.coefficients.items():
        lines.append(f"| {name} | {rule.rows[name]} | " + " | ".join(f"{x:.3g}" for x in c) +
                     f" | {rule.margin[name]:.3g} |")
    lines += ["", "## Every scene × rung", "",
              "| scene | model | CPU (s) | wall (s) | peak MB | albedo | Δalbedo | rel L2 | rel L2 (speckle-avg) | "
              "peak offset (°) | retro | σ/λ | rms slope | shadowed | multi-bounce | failure |",
              "|" + "---|" * 16]
    for r in table:
        lines.append("| " + " | ".join(_cell(r[k]) if k not in ("scene", "model", "failure") else (r[k] or "")
                                        for k in ("scene", "model", "cpu_s", "wall_s", "peak_mb", "albedo",
                                                  "albedo_diff", "rel_l2", "rel_l2_smooth", "peak_offset_deg",
                                                  "retro", "height_over_wavelength", "rms_slope", "shadowed",
                                                  "multi_bounce", "failure")) + " |")
    return "\n".join(lines) + "\n"


HEADER = """# The speed/accuracy trade table of record

Every rung on the same 7 scenes (configs/compare/trade/*.toml: smooth random, rough random,
brushed, shallow grating, steep hemispheres, corner cubes, spherical pits; aluminium, 4 µm patches
of 64² cells, waist 0.6 µm, λ = 0.5 and 0.7 µm, θ_i = 0° and 60°), with the same footprint, output
grid and normalization, against the full-wave reference (AIM BEM, 16 128 unknowns). Errors are
the relative L2 over the lobe of the unpolarized BRDF (`rel L2`) and of the speckle-averaged one
(blurred by the footprint's own angular spread λ/(πw); `rel L2 (speckle-avg)`, the figure `auto`'s
tolerance applies to); times are CPU seconds of each model run alone in `compare`'s measuring
process (one per scene config) on the 2-core development VM, shared with other work while measured:
compare ratios, not absolute times. The ray rungs ran with 2²⁰ rays.
Regenerate (≈ 1–2 h here; resumes where it stopped):

    .venv/bin/python benchmarks/trade.py            # --force to recompute every scene

It writes this page, docs/images/trade.png and solver/data/trade.csv (the table `model = "auto"`
fits its rule to; docs/auto.md).

![error vs CPU time](images/trade.png)
"""


if __name__ == "__main__":
    sys.exit(main())
