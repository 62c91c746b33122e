"""The lit-facet check against the trade table (solver/validity.py check_lit_facets): each
tangent-plane rung (kirchhoff, po, ws-v, wm) run on each of the trade table's scenes
(configs/compare/trade/*/*.toml), its recorded ``lit_facet_deficit`` beside the error the table
measured for it against the full wave (solver/data/trade.csv, as ``auto`` reads it). Prints, per
rung, the largest deficit where the error is ≤ 0.05, the runs the check warns of and the least
error among them, and where the deficit exceeded the error; writes every run to ``--csv``.

    nice .venv/bin/python benchmarks/lit_facets.py [--csv out/lit_facets.csv]    # ~10 min on 2 cores
"""

from __future__ import annotations

import argparse
import csv
import glob
import warnings
from pathlib import Path

import numpy as np

from wavebrdf.jobs.config import load_config
from wavebrdf.jobs.plan import plan_study
from wavebrdf.solver.auto import read_table, table_error
from wavebrdf.solver.models import get_model
from wavebrdf.solver.opencl import create_context
from wavebrdf.solver.validity import LIT_FACET_DEFICIT, horizon_loss

ROOT = Path(__file__).resolve().parent.parent
RUNGS = ("kirchhoff", "po", "ws-v", "wm")
WITHIN = 0.05


def measure(ctx) -> list[dict]:
    """One row per (scene, rung) of the trade table: deficit, lit facets' albedo, table error."""
    measured = {(r["scene"], r["model"]): table_error(r) for r in read_table()}
    rows = []
    for path in sorted(glob.glob(str(ROOT / "configs" / "compare" / "trade" / "*" / "*.toml"))):
        config = load_config(path)
        plan = plan_study(config)
        for task in plan.tasks:
            if task.kind not in ("direct", "patch"):
                continue
            scene = plan.model_scene(task)
            label = f"{config.name} λ={scene.wavelength_um:g} µm θi={np.degrees(scene.theta_i):.0f}°"
            for name in RUNGS:
                if (label, name) not in measured:
                    continue
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    figures = get_model(name).run(ctx, scene).diagnostics
                if "lit_facet_deficit" not in figures:  # a BRDF with NaN: the run's own failure, not measured
                    continue
                loss = horizon_loss(figures)
                rows.append({"scene": label, "model": name, "deficit": figures["lit_facet_deficit"],
                             "warned": loss is not None and loss > LIT_FACET_DEFICIT,
                             "lit_albedo": figures["lit_facet_albedo"], "error": measured[(label, name)]})
                print(f"{label:52s} {name:9s} deficit {rows[-1]['deficit']:+.3f} error {rows[-1]['error']:.3f}",
                      flush=True)
    return rows


def summary(rows: list[dict]) -> str:
    lines = [f"| rung | largest deficit where the error ≤ {WITHIN:g} | runs warned (deficit > {LIT_FACET_DEFICIT:g}, "
             "not the pixels') | least error among them | deficit above the error |", "|---|---|---|---|---|"]
    for name in RUNGS:
        mine = [r for r in rows if r["model"] == name]
        within = [r["deficit"] for r in mine if r["error"] <= WITHIN]
        warned = [r["error"] for r in mine if r["warned"]]
        above = [r["deficit"] - r["error"] for r in mine if r["deficit"] > r["error"]]
        lines.append(f"| {name} | {max(within, default=float('nan')):.3f} | {len(warned)} of {len(mine)} | "
                     f"{min(warned, default=float('nan')):.3f} | "
                     f"{f'{len(above)} run(s), by ≤ {max(above):.3f}' if above else 'never'} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--csv", type=Path, help="write every run's figures here")
    args = parser.parse_args()
    rows = measure(create_context())
    if args.csv:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        with open(args.csv, "w", newline="") as fh:
            writer = csv.DictWriter(fh, list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    print(summary(rows))


if __name__ == "__main__":
    main()
