"""Command line: ``wavebrdf run | inspect | render | devices | bench``.

Errors in user input (config, surface files, output paths, datasets) are printed as one line
``wavebrdf: error: ...`` with exit status 2; nothing is written in that case.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

__all__ = ["main"]

logger = logging.getLogger("wavebrdf")


def _user_errors():
    from wavebrdf.jobs.config import ConfigError
    from wavebrdf.jobs.scheduler import ResumeError
    from wavebrdf.jobs.store import StoreError
    from wavebrdf.solver.materials import MaterialError
    from wavebrdf.solver.opencl import OpenCLUnavailable
    from wavebrdf.solver.surface import SurfaceError

    return (ConfigError, ResumeError, StoreError, MaterialError, OpenCLUnavailable, SurfaceError, OSError)


def cmd_run(args) -> int:
    from wavebrdf.jobs.config import load_config
    from wavebrdf.jobs.plan import plan_study
    from wavebrdf.jobs.render import render_dataset
    from wavebrdf.jobs.scheduler import run_plan
    from wavebrdf.solver.opencl import create_context

    config = load_config(args.config, output=args.output)
    plan = plan_study(config)
    ctx = create_context(args.device)
    print(f"study {config.name!r}: {len(plan.tasks)} task(s) on {ctx.describe()}", file=sys.stderr)
    path = run_plan(plan, ctx, progress=not args.quiet)
    print(f"wrote {path}")
    if not args.no_render:
        for png in render_dataset(path):
            print(f"wrote {png}")
    return 0


def cmd_inspect(args) -> int:
    from wavebrdf.jobs.store import Dataset

    with Dataset(args.file) as ds:
        attrs = ds.attrs
        print(f"{ds.path}: study {attrs.get('study')!r}, wavebrdf {attrs.get('software_version')}, "
              f"format v{attrs.get('format_version')}, created {attrs.get('created')}")
        print(f"device: {attrs.get('device')}")
        for name in ("brdf", "albedo", "albedo_sp", "brdf_sp"):
            if name in ds.h5:
                dims = [d.label or (d[0].name.lstrip('/') if len(d) else '?') for d in ds.h5[name].dims]
                print(f"  {name:10s} {dict(zip(dims, ds.h5[name].shape))}")
        coords = ds.coords
        for key in ds.sweep_keys:
            print(f"  sweep {key}: {list(coords[key])}")
        print(f"  wavelengths (µm): {np.round(coords['wavelength_um'], 6).tolist()}")
        albedo = ds.albedo
        lead = albedo.shape[: len(ds.sweep_keys)]
        print("albedo (rows: incidence θi/φi in degrees; columns: wavelengths):")
        for case_index in np.ndindex(*lead) if lead else [()]:
            if case_index:
                print("  case " + ", ".join(f"{k}={coords[k][i]}" for k, i in zip(ds.sweep_keys, case_index)))
            for inc in range(albedo.shape[-1]):
                values = " ".join(f"{a:9.5f}" for a in albedo[case_index + (slice(None), inc)])
                print(f"  {coords['theta_i'][inc]:6.2f} {coords['phi_i'][inc]:7.2f} | {values}")
        tasks = ds.tasks
        if tasks:
            wall = np.asarray(tasks.get("wall_time_s", []), dtype=float)
            print(f"tasks: {len(wall)} done, wall time total {wall.sum():.2f} s, max {wall.max():.2f} s")
            warns = [w.decode() if isinstance(w, bytes) else w for w in tasks.get("warnings", [])]
            for w in sorted({w for w in warns if w}):
                print(f"  warning: {w}")
        if args.config:
            print("config:\n" + ds.config)
    return 0


def cmd_render(args) -> int:
    from wavebrdf.jobs.render import render_dataset

    for png in render_dataset(args.file, args.out):
        print(f"wrote {png}")
    return 0


def cmd_devices(args) -> int:
    from wavebrdf.solver.opencl import choose_device, list_devices

    infos = list_devices()
    import os

    chosen = choose_device(os.environ.get("WAVEBRDF_DEVICE", "auto"), infos)
    for info in infos:
        mark = "*" if info == chosen else " "
        print(f"{mark} {info.spec}  {info.platform} / {info.name}  [{info.kind}]  fp64={'yes' if info.fp64 else 'no'}"
              f"  CUs={info.compute_units}  mem={info.global_mem_gib:.1f} GiB (max alloc {info.max_alloc_gib:.1f})")
    print("* = device used (WAVEBRDF_DEVICE=auto|gpu|cpu|pocl|P:D|name)")
    return 0


def cmd_bench(args) -> int:
    import runpy

    script = Path(__file__).resolve().parent.parent / "benchmarks" / f"bench_{args.name}.py"
    if not script.is_file():
        available = sorted(p.stem[6:] for p in script.parent.glob("bench_*.py"))
        raise SystemExit(f"wavebrdf: error: no benchmark {args.name!r}; available: {', '.join(available)}")
    sys.argv = [str(script)] + list(args.rest)
    runpy.run_path(str(script), run_name="__main__")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from wavebrdf import __version__

    parser = argparse.ArgumentParser(prog="wavebrdf", description="Wave-optics BRDFs of microgeometry.")
    parser.add_argument("--version", action="version", version=f"wavebrdf {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log every task")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("run", help="run a study from a TOML config into an HDF5 dataset (+ PNGs)")
    p.add_argument("config", type=Path)
    p.add_argument("--output", "-o", type=Path, help="override [study] output")
    p.add_argument("--device", help="OpenCL device (overrides WAVEBRDF_DEVICE)")
    p.add_argument("--no-render", action="store_true", help="do not write PNGs")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("inspect", help="summarise a dataset")
    p.add_argument("file", type=Path)
    p.add_argument("--config", action="store_true", help="also print the stored config")
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("render", help="write PNGs of a dataset's BRDF slices")
    p.add_argument("file", type=Path)
    p.add_argument("--out", type=Path, help="output folder (default: <file stem>_png)")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("devices", help="list OpenCL platforms/devices and their fp64 support")
    p.set_defaults(func=cmd_devices)

    p = sub.add_parser("bench", help="run a benchmark from benchmarks/ (source checkouts)")
    p.add_argument("name", help="e.g. kirchhoff")
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except _user_errors() as exc:
        print(f"wavebrdf: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("wavebrdf: interrupted; finished tasks are kept, re-run the same command to resume", file=sys.stderr)
        return 130
