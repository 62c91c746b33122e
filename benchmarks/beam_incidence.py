"""The wave rungs lit by the footprint plane wave against the same rungs lit by the exact beam's
plane waves (``[model.<rung>] incidence``: po, ws-v, wm), each against AIM BEM on the same scenes.

    .venv/bin/python benchmarks/beam_incidence.py                 # po on the trade scenes whose BEM BRDFs are in out/trade
    .venv/bin/python benchmarks/beam_incidence.py --second-suite  # also tests/test_auto.py's second suite (25 BEM solves)
    .venv/bin/python benchmarks/beam_incidence.py --second-suite --rungs ws-v wm

The trade scenes are those of ``configs/compare/trade`` whose comparison ``benchmarks/trade.py``
left in ``out/trade`` (the others are listed as skipped: their BRDFs are only in the committed
table's aggregates). The second suite's BEM solves (16 min on 2 cores) are kept in
``out/beam_incidence/second_suite.*`` and reused (by scene label, which does not name every
parameter: delete that folder when the suite changes). Each rung runs with each incidence in this process
on the default OpenCL device (wm's path tracer with ``--rays``); errors are the trade table's (``jobs.compare.comparison_metrics``: speckle-averaged
relative L2 over the lobe, unpolarized and per incident polarization) and the time is the rung's
wall time. Per rung a line per scene, then the median and worst of each column.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))
WORK = ROOT / "out" / "beam_incidence"
COLUMNS = ("rel_l2_smooth", "rel_l2_smooth_s", "rel_l2_smooth_p")


def trade_scenes(log) -> list[tuple[str, object, object]]:
    """(label, scene, BEM Measurement) of every trade scene whose comparison is in out/trade."""
    import trade

    out = []
    for path in sorted(trade.SUITE.glob("*/*.toml")):
        if not trade._stored(path).is_file():
            log(f"skipped {path.relative_to(ROOT)}: its BRDFs are not in out/trade")
            continue
        stored = trade.stored_measurements(trade._stored(path))
        out += [(label, scene, stored[label, "bem"]) for label, scene in trade._scenes(path)
                if (label, "bem") in stored and stored[label, "bem"].failure is None]
    return out


def second_suite_scenes(log) -> list[tuple[str, object, object]]:
    """(label, scene, BEM Measurement) of the second suite of tests/test_auto.py (solved once, kept)."""
    import trade
    from test_auto import second_suite_scenes as scenes

    from wavebrdf.jobs.compare import compare_scenes

    stem = WORK / "second_suite"
    pairs = scenes()
    if not stem.with_suffix(".h5").is_file():
        WORK.mkdir(parents=True, exist_ok=True)
        log("solving the second suite's 25 BEM references (≈ 16 min on 2 cores)")
        compare_scenes(pairs, ["bem"], {"bem": {"method": "aim"}}, reference="bem",
                       progress=lambda what: log(f"  {what}")).write(stem)
    stored = trade.stored_measurements(stem.with_suffix(".h5"))
    return [(label, scene, stored[label, "bem"]) for label, scene in pairs]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--second-suite", action="store_true", help="also the second suite of tests/test_auto.py")
    parser.add_argument("--rungs", nargs="+", default=["po"], choices=("po", "ws-v", "wm"), help="the rungs (po)")
    parser.add_argument("--rays", type=int, default=1 << 20, help="wm's path-traced rays (2^20, as the trade table)")
    args = parser.parse_args(argv)

    from wavebrdf.solver.opencl import create_context

    def log(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    scenes = trade_scenes(log) + (second_suite_scenes(log) if args.second_suite else [])
    ctx = create_context()
    print(f"device: {ctx.describe()}")
    for rung in args.rungs:
        compare_rung(ctx, rung, {"rays": args.rays} if rung == "wm" else {}, scenes)


def compare_rung(ctx, rung: str, options: dict, scenes) -> None:
    """The table of one rung, footprint against beam, on every (label, scene, BEM Measurement)."""
    from wavebrdf.jobs.compare import Measurement, comparison_metrics, speckle_sigma_u
    from wavebrdf.solver.models import get_model

    print(f"\n## {rung}\n")
    print("| scene | footprint: unpolarized / s / p | beam: unpolarized / s / p | plane waves "
          "| wall footprint / beam (s) |")
    print("|---|---|---|---|---|")
    table = []
    for label, scene, ref in scenes:
        sigma = speckle_sigma_u(scene.wavelength_um, scene.waist_um, scene.grid)
        errors, walls, waves = {}, {}, None
        for incidence in ("footprint", "beam"):
            model = get_model(rung, {**options, "incidence": incidence})
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                t0 = time.perf_counter()
                result = model.run(ctx, scene)
                walls[incidence] = time.perf_counter() - t0
            waves = result.diagnostics.get("plane_waves", waves)
            metrics = comparison_metrics(Measurement(rung, label, brdf=result.brdf()), ref, scene.grid, sigma,
                                         scene.theta_i, scene.phi_i)
            errors[incidence] = [metrics[c] for c in COLUMNS]
        table.append(errors["footprint"] + errors["beam"])
        print(f"| {label} | {' / '.join(f'{e:.3g}' for e in errors['footprint'])} | "
              f"{' / '.join(f'{e:.3g}' for e in errors['beam'])} | {waves} | "
              f"{walls['footprint']:.2f} / {walls['beam']:.2f} |", flush=True)
    table = np.array(table)
    for name, value in (("median", np.median(table, axis=0)), ("worst", np.max(table, axis=0))):
        print(f"| {name} of {len(table)} | {' / '.join(f'{e:.3g}' for e in value[:3])} | "
              f"{' / '.join(f'{e:.3g}' for e in value[3:])} | | |")
    worst_footprint, worst_beam = np.max(table[:, :3], axis=1), np.max(table[:, 3:], axis=1)
    print(f"\n{rung}: the beam's worst of unpolarized, s and p below the footprint's in "
          f"{int(np.sum(worst_beam < worst_footprint))} of {len(table)} scenes; median of that worst "
          f"{np.median(worst_footprint):.3g} (footprint), {np.median(worst_beam):.3g} (beam)")


if __name__ == "__main__":
    main()
