"""Command line: ``wavebrdf run | plan | submit | inspect | render | export | example | devices | bench``.

Errors in user input (config, surface files, output paths, datasets, command-line flags), an
output held by another run (``run`` without ``--wait``) and a failed write (disk full: the previous
state is kept) are printed as one line ``wavebrdf: error: ...`` with exit status 2; nothing is
written in that case. Exit status 1: a run finished with failed tasks; 130: interrupted.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wavebrdf._version import __version__
from wavebrdf.jobs.batch import STOPPED_STATUS, Stopped, run_scope, stop_on_sigterm
from wavebrdf.jobs.config import ConfigError, load_config
from wavebrdf.jobs.executors import Executor, executor_names, resolve_executor, share_from_root
from wavebrdf.jobs.export import ExportError, add_case_flags, add_export_parser, select_case
from wavebrdf.jobs.node import local_rank
from wavebrdf.jobs.output_path import make_output_folder
from wavebrdf.jobs.overrides import parse_assignment
from wavebrdf.jobs.parts import OutputBusy, OutputLock, ResumeError, StorageError
from wavebrdf.jobs.pictures.common import check_decades
from wavebrdf.jobs.plan import (PlanError, check_memory, device_info, estimate_tasks, format_bytes, format_number,
                                plan_study)
from wavebrdf.jobs.progress import add_verbosity_flags, configure_logging, degrees_text, phi_text
from wavebrdf.jobs.render import add_render_flags, pictures_folder, render_dataset, render_options
from wavebrdf.jobs.scheduler import prepare_output, run_plan
from wavebrdf.jobs.shards import add_merge_parser, adopt_finished_shards, remove_adopted_shards, same_flags
from wavebrdf.jobs.spot_checks import expectation_scene, spot_check_summary
from wavebrdf.jobs.store import Dataset, StoreError, is_comparison, read_comparison
from wavebrdf.jobs.study_kinds import study_kind
from wavebrdf.jobs.submit import add_submit_parser
from wavebrdf.solver.auto import plan_summary
from wavebrdf.solver.materials import MaterialError
from wavebrdf.solver.models import model_class, model_names
from wavebrdf.solver.opencl import OpenCLUnavailable, choose_device, create_context, list_devices
from wavebrdf.solver.options import describe_options
from wavebrdf.solver.surface import SurfaceError

__all__ = ["main"]

logger = logging.getLogger("wavebrdf")


USER_ERRORS = (ConfigError, PlanError, ResumeError, OutputBusy, StoreError, MaterialError, OpenCLUnavailable,
               SurfaceError, ExportError, OSError)  # printed as one line, exit status 2


@dataclass(frozen=True)
class MpiLaunch:
    """What the launcher (mpiexec/srun) tells this process, read before MPI is initialised."""

    size: int
    rank: int
    local_size: int


def detect_mpi_launch() -> MpiLaunch | None:
    """Size/rank/ranks-on-this-node from MPICH (hydra), Open MPI or Slurm variables."""
    env = os.environ

    def first(*names, default=None):
        for name in names:
            if env.get(name, "").strip():
                return env[name]
        return default

    size = first("PMI_SIZE", "OMPI_COMM_WORLD_SIZE", "PMIX_SIZE")
    if size is None and "SLURM_PROCID" in env and "SLURM_STEP_ID" in env:
        size = env.get("SLURM_NTASKS")
    if size is None or int(size) <= 1:
        return None
    rank = int(first("PMI_RANK", "OMPI_COMM_WORLD_RANK", "PMIX_RANK", "SLURM_PROCID", default="0"))
    local = first("MPI_LOCALNRANKS", "OMPI_COMM_WORLD_LOCAL_SIZE", "SLURM_NTASKS_PER_NODE")
    local = int(str(local).split("(")[0]) if local else int(size)
    return MpiLaunch(int(size), rank, local)


def cmd_run(args) -> int:
    loaded = load_config(args.config, output=args.output, overrides=args.set)
    scope = run_scope(args, loaded)  # None: up to date
    if scope is None:
        return _missing_pictures(args, loaded)
    stop_on_sigterm()
    args.scope, config = scope, scope.config
    study = config.cases[0]
    launch = detect_mpi_launch()
    executor = resolve_executor(args.executor or study.run.executor, launch)
    executor.check(launch)
    workers = executor.tasks_per_node(study, args.workers, launch)
    comm = executor.start(launch)
    plan = plan_study(config)
    plan.tasks_per_node = workers  # the AIM settings are fitted to the memory each of them may use
    check_memory(plan, workers, study.run.memory_gb, device=device_info(args.device))
    make_output_folder(config.output)
    lock = OutputLock(config.output)

    def still_to_run() -> bool:
        """The output checked again under its lock, as a run this one waited for may have written it
        since: False when up to date (said), ResumeError when it is not this study's to replace.
        A shard writes no dataset (its parts folder is checked under its own lock)."""
        return scope.shard is not None or run_scope(args, loaded) is not None

    if comm is None:
        with lock.acquire(args.wait):  # held until the dataset and its PNGs are written
            if not still_to_run():
                return 0
            return _run_and_report(args, plan, executor, workers, None)
    try:
        code = _mpi_lock(comm, lock, args.wait, still_to_run)
        if code is not None:
            return code
        return _run_and_report(args, plan, executor, workers, comm)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM reaches every rank of a launch: each stops, none aborts
        raise
    except BaseException as exc:  # one failing rank must not leave the others waiting forever
        print(f"wavebrdf: error on rank {comm.Get_rank()}: {type(exc).__name__}: {exc}", file=sys.stderr)
        comm.Abort(2)
        raise
    finally:
        lock.release()


def _missing_pictures(args, config) -> int:
    """An up-to-date study whose pictures a stop left unmade (they are moved into place whole, so
    the folder is missing) gets them now: on rank 0, not for a shard, not with ``--no-render``."""
    launch = detect_mpi_launch()
    if (args.no_render or getattr(args, "shard", None) or (launch is not None and launch.rank != 0)
            or pictures_folder(config.output).exists()):
        return 0
    for png in render_dataset(config.output):
        print(f"wrote {png}")
    return 0


def _mpi_lock(comm, lock, wait: bool, still_to_run) -> int | None:
    """Rank 0 takes the output's lock before any rank works, checks under it that there is work
    (``still_to_run()``), and tells every rank the outcome: None to run, else the exit status (0 up
    to date, 2 refused: said once by rank 0)."""
    code = None
    if comm.Get_rank() == 0:
        try:
            lock.acquire(wait)
            code = None if still_to_run() else 0
        except (OutputBusy, StorageError, ResumeError) as exc:
            print(f"wavebrdf: error: {one_line(str(exc))}", file=sys.stderr)
            code = 2
    return share_from_root(comm, code)


def _run_and_report(args, plan, executor: Executor, workers: int, comm) -> int:
    rank = comm.Get_rank() if comm is not None else 0
    if rank == 0:
        parts = prepare_output(plan)  # a parts folder that cannot be used is refused before anything starts
        taken = adopt_finished_shards(plan, parts) if args.scope.shard is None else None
        if taken:
            print(taken, file=sys.stderr)
    ctx = create_context(args.device, require_fp64=plan.needs_fp64,
                         local_rank=local_rank())  # one GPU per local rank
    if rank == 0:
        print(f"study {plan.config.name!r}: {len(plan.tasks)} task(s) on {ctx.describe()}, "
              f"{executor.describe(workers, comm)}", file=sys.stderr)
    summary = run_plan(plan, ctx, executor=executor, workers=workers, comm=comm, progress=rank == 0,
                       quiet=args.quiet, only=args.scope.only)
    if summary is None:
        return 0
    if args.scope.shard is not None and not summary.failed:
        print(f"shard {args.scope.shard[0]}/{args.scope.shard[1]}: {summary.done} task(s) done in {summary.path}; "
              f"when every shard is done: wavebrdf merge {args.config}{same_flags(args)}")
        return 0
    print(f"wrote {summary.path}")
    if not summary.failed:
        for kept in remove_adopted_shards(plan):
            print(f"{kept} is left: its shard is running or its lock cannot be taken (the dataset holds its "
                  "tasks already; delete the folder once that shard has stopped)", file=sys.stderr)
    if summary.failed:
        print(f"wavebrdf: {summary.failed} of {summary.tasks} task(s) failed (see 'wavebrdf inspect "
              f"{summary.path}'); their results are NaN. Re-run the same command to retry them.", file=sys.stderr)
        return 1
    if not args.no_render:
        for png in render_dataset(summary.path):
            print(f"wrote {png}")
    return 0


def cmd_plan(args) -> int:
    overrides = list(args.set or [])
    if args.memory_gb:  # the tasks' budget too: the AIM solver fits its settings to it
        overrides.append(("run.memory_gb", args.memory_gb))
    config = load_config(args.config, overrides=overrides)
    study = config.cases[0]
    plan = plan_study(config)
    workers = args.workers or resolve_executor(study.run.executor).tasks_per_node(study)  # as `run` counts
    plan.tasks_per_node = workers  # the AIM settings are fitted to the memory each task may use
    estimates = estimate_tasks(plan)
    budget = check_memory(plan, workers, args.memory_gb or study.run.memory_gb, device=device_info(),
                          estimates=estimates)
    print(f"study {config.name!r} -> {config.output}")
    for case, st in plan.steering.items():
        layout = st.layout
        print(f"  steering (case {case}): {layout.counts[0]}x{layout.counts[1]} patches of {layout.patch_size_um:g} µm "
              f"shifted by {layout.shift_um:g} µm; hexagon radius {st.tiling.radius:.4f}; "
              f"{len(st.basics_rad)} basic direction(s) for {len(st.basic_of)} requested")
    print(f"{'id':>6} {'kind':6} {'case':>4} {'λ (µm)':>7} {'θ (°)':>7} {'φ (°)':>7} {'patch':>6} "
          f"{'memory (GiB)':>12} {'time (s)':>9}  model")
    rows = list(zip(plan.tasks, estimates))
    tail = min(5, args.rows // 2)
    shown = rows if len(rows) <= args.rows else rows[: args.rows - tail] + [None] + rows[len(rows) - tail:]
    for row in shown:
        if row is None:
            print(f"{'...':>6} ({len(rows) - args.rows} more)")
            continue
        task, est = row
        theta, phi = np.rad2deg(plan.direction_rad(task))
        lam = plan.wavelengths_um[task.wavelength]
        patch = "x".join(map(str, task.patch)) or "-"
        model = "steering synthesis" if task.kind == "synth" else plan.model_name(task)
        if est.detail:
            model += f" ({est.detail})"
        phi = phi_text(plan, task).rstrip("°")
        print(f"{task.id:6d} {task.kind:6} {task.case:4d} {lam:7.3f} {degrees_text(theta, 2):>7} {phi:>7} {patch:>6} "
              f"{format_number(est.memory_bytes / 2**30, 12)} {format_number(est.seconds, 9)}  {model}")
    total = sum(e.seconds for e in estimates)
    peak = max(e.memory_bytes for e in estimates)
    print(f"total: {len(plan.tasks)} tasks, {format_number(total, decimals=1)} s of compute "
          f"({format_number(total / 3600)} h); about {format_number(total / workers, decimals=1)} s wall on {workers} "
          f"worker(s); peak {format_bytes(peak)} per worker (node budget {format_bytes(budget)})")
    _print_validity(plan)
    auto = [(t, e) for t, e in zip(plan.tasks, estimates)
            if t.kind in ("direct", "patch") and plan.model_spec(t).capabilities.spot_checks]
    if auto:  # what auto expects per scene, the full-wave cost it avoids, and its spot checks

        choices = [plan.model_spec(t).build().choice(expectation_scene(plan, t), checked=bool(t.checks))
                   for t, _ in auto]
        print(plan_summary(choices, [e.seconds for _, e in auto]))
        checks = spot_check_summary(plan, estimates)
        if checks:
            print(checks)
    return 0


def cmd_compare(args) -> int:
    # imported here: its scipy.ndimage (solver/metrics.py) would cost every command 0.3 s
    from wavebrdf.jobs.compare import check_comparison_outputs, compare_config

    config = load_config(args.config)
    models = None if args.models is None else [m.strip() for m in args.models.split(",") if m.strip()]
    stem = args.out or Path(config.output).with_suffix("").with_name(Path(config.output).stem + "_compare")
    check_comparison_outputs(stem, args.force)

    def progress(what: str) -> None:
        if not args.quiet:
            print(f"  running {what}", file=sys.stderr, flush=True)

    # one missing folder level is created once the models pass their checks, as `run` does; deeper: an error
    comparison = compare_config(config, models, args.reference, args.memory_gb, progress,
                                before_run=lambda: make_output_folder(stem))
    print(comparison.markdown(), end="")
    for path in comparison.write(stem):
        print(f"wrote {path}")
    return 0


def cmd_models(args) -> int:
    """Every registered model: what it takes and returns, its flags and its options."""
    for name in model_names():
        cls = model_class(name)
        caps = cls.capabilities
        flags = [f for f in ("polarized", "steerable", "reciprocal", "conserves_energy") if getattr(caps, f)]
        print(f"{name}: {cls.summary}" if cls.summary else f"{name}:")
        print(f"    takes {caps.takes}, returns {caps.returns}; {', '.join(flags) or 'no flags'}")
        for key, kind, default, doc in describe_options(cls.Options):
            print(f"    {key} = {default!r} ({kind}): {doc}")
    return 0


def cmd_inspect(args) -> int:
    if is_comparison(args.file):
        return _inspect_comparison(args.file, args.config)
    with Dataset(args.file) as ds, ds.reading():
        attrs = ds.attrs
        print(f"{ds.path}: {ds.kind} study {attrs.get('study')!r}, wavebrdf {attrs.get('software_version')}, "
              f"format v{attrs.get('format_version')}, created {attrs.get('created')}")
        print(f"device: {attrs.get('device')}")
        for name in ("brdf", "albedo", "albedo_sp", "brdf_sp", "jones", "mueller", "bcsdf", "dCs_dphi", "C_ext"):
            if name in ds.h5:
                dims = [d.label or (d[0].name.lstrip('/') if len(d) else '?') for d in ds.h5[name].dims]
                print(f"  {name:10s} {dict(zip(dims, ds.h5[name].shape))}")
        coords = ds.coords
        for key in ds.sweep_keys:
            print(f"  sweep {key}: {np.asarray(coords[key]).tolist()}")
        print(f"  wavelengths (µm): {np.round(coords['wavelength_um'], 6).tolist()}")
        _print_summary_table(ds, coords)
        tasks = ds.tasks
        if tasks:
            wall = np.asarray(tasks.get("wall_time_s", []), dtype=float)
            status = [x.decode() if isinstance(x, bytes) else str(x) for x in tasks.get("status", [])]
            longest = np.nanmax(wall) if np.any(np.isfinite(wall)) else float("nan")
            print(f"tasks: {status.count('done')} done, {status.count('failed')} failed, wall time total "
                  f"{np.nansum(wall):.2f} s, max {longest:.2f} s")
            errors = [x.decode() if isinstance(x, bytes) else str(x) for x in tasks.get("error", [])]
            for i, (st, err) in enumerate(zip(status, errors)):
                if st == "failed":
                    print(f"  failed task {tasks['id'][i]}: {err}")
            warns = [w.decode() if isinstance(w, bytes) else w for w in tasks.get("warnings", [])]
            for w in sorted({w for w in warns if w}):
                print(f"  warning: {w}")
            _print_spot_checks(tasks)
            _print_spectral_seams(ds, tasks)
        if args.config:
            print("config:\n" + ds.config)
    return 0


def _print_validity(plan) -> None:
    """The warnings (and refusals) each task's model would carry that need no run (sampling, the
    footprint's spread: Model.foreseen_warnings), once per message with the tasks that carry it."""
    models, notes = {}, {}
    for task in plan.tasks:
        if task.kind not in ("direct", "patch", "fiber"):
            continue
        spec = plan.model_spec(task)
        if id(spec) not in models:
            models[id(spec)] = spec.build()
        model = models[id(spec)]
        try:  # a task with spot checks: the rung expected for its series (jobs/spot_checks.py)
            found = model.foreseen_warnings(plan.model_scene(task),
                                            *([expectation_scene(plan, task)] if task.checks else []))
        except ValueError as exc:
            found = [f"refused: {exc}"]
        for message in found:
            notes.setdefault(message, []).append(task.id)
    for message, ids in notes.items():
        more = f", ... ({len(ids)} tasks)" if len(ids) > 3 else ""
        print(f"WARNING (task {', '.join(f'#{i}' for i in ids[:3])}{more}): {message}")


def _inspect_comparison(path, config: bool = False) -> int:
    """A file of ``wavebrdf compare``: its scenes, models and table, as ``compare`` printed it."""
    from wavebrdf.jobs.compare import comparison_markdown

    table, brdfs = read_comparison(path)
    rows = [dict(zip(table, values)) for values in zip(*table.values())]
    print(f"{path}: wavebrdf compare of {len(set(table['model']))} model(s) on {len(set(table['scene']))} scene(s), "
          f"{len(brdfs)} BRDF(s) stored")
    print(comparison_markdown(rows), end="")
    if config:
        print("config: a comparison file keeps no config (the study's config wrote it)")
    return 0


def _texts(tasks: dict, column: str) -> list[str]:
    """A task-table column as strings."""
    return [x.decode() if isinstance(x, bytes) else str(x) for x in tasks.get(column, [])]


def _print_spot_checks(tasks: dict) -> None:
    """``auto``'s measured figures: each spot check's errors per rung, and the rungs the tasks ran."""
    kinds, models, checks, where = (_texts(tasks, c) for c in ("kind", "model", "spot_check", "spot_check_where"))
    if "check" not in kinds:
        return
    print("auto spot checks (speckle-averaged relative L2 over the lobe vs the full wave, worst of s, p, unpolarized "
          "[raw unpolarized]):")
    for i, kind in enumerate(kinds):
        if kind != "check" or not checks[i] or checks[i] == "nan":
            continue
        measured = json.loads(checks[i])
        figures = ", ".join(f"{name} {m['error']:.3g} [{m['raw']:.3g}]" if m.get("error") is not None
                            else f"{name} failed" for name, m in measured.items())
        print(f"  task {tasks['id'][i]} ({where[i]}): {figures or 'no rung measured'}")
    ran = {}
    for kind, model in zip(kinds, models):
        if kind in ("direct", "patch"):
            ran[model] = ran.get(model, 0) + 1
    measured_errors = np.asarray(tasks.get("model_measured_error", []), dtype=float)
    worst = f"; worst measured error of the rung taken {np.nanmax(measured_errors):.3g}" if np.any(
        np.isfinite(measured_errors)) else ""
    print("  rungs run: " + ", ".join(f"{m} ×{k}" for m, k in sorted(ran.items(), key=lambda kv: -kv[1])) + worst)


def _print_spectral_seams(ds, tasks: dict) -> None:
    """Where the rung a direction's result came from changes between neighbouring wavelengths
    (``auto`` with ``mix_wavelengths``): the albedo step there beside the median step between
    neighbours of one rung (the spectrum's own smoothness)."""
    kinds, models = _texts(tasks, "kind"), _texts(tasks, "model")
    if "check" not in kinds:  # spot checks: auto's, of surface studies
        return
    number = lambda column: np.asarray(tasks.get(column, []), dtype=int)  # noqa: E731
    case, wl, inc, basic = number("case"), number("wavelength_index"), number("incidence_index"), number("basic_index")
    rungs = {}  # (case, λ index, incidence) → the rung(s) its result came from
    for i, kind in enumerate(kinds):
        if kind == "direct":
            rungs[(case[i], wl[i], inc[i])] = models[i]
    patches = {}
    for i, kind in enumerate(kinds):
        if kind == "patch":
            patches.setdefault((case[i], wl[i], basic[i]), []).append(models[i])
    for i, kind in enumerate(kinds):
        if kind == "synth":
            rungs[(case[i], wl[i], inc[i])] = "+".join(sorted(set(patches.get((case[i], wl[i], basic[i]), []))))
    albedo = np.asarray(ds.albedo)
    lead = albedo.shape[:-2]
    lams = ds.coords["wavelength_um"]
    seams, smooth = [], []
    for c, d in sorted({(c, d) for c, _, d in rungs}):
        series = albedo[np.unravel_index(c, lead) if lead else ()][:, d]
        for k in range(len(lams) - 1):
            a, b = rungs.get((c, k, d)), rungs.get((c, k + 1, d))
            step = abs(float(series[k + 1] - series[k]))
            (smooth if a == b else seams).append((step, c, d, k, a, b))
    if not seams:
        return
    baseline = float(np.median([x[0] for x in smooth])) if smooth else float("nan")
    print(f"spectral seams (the rung changes between neighbouring wavelengths; median albedo step elsewhere "
          f"{baseline:.3g}):")
    for step, c, d, k, a, b in seams[:20]:
        print(f"  case {c}, incidence #{d}: {a} → {b} between λ {lams[k]:g} and {lams[k + 1]:g} µm: albedo step {step:.3g}")


def _print_summary_table(ds, coords) -> None:
    """The table of the dataset's kind per case (jobs/study_kinds.py ``summary_table``): the albedo
    (surfaces), or unpolarized C_ext and the albedo C_sca/C_ext (fibers)."""
    keys = ds.sweep_keys
    heading, rows, values, albedo = study_kind(ds.kind).summary_table(ds, coords)
    print(heading)
    for case_index in np.ndindex(*ds.sweep_shape):
        if case_index:
            print("  case " + ", ".join(f"{k}={coords[k][i]}" for k, i in zip(keys, case_index)))
        for r, row in enumerate(rows):
            text = " ".join(f"{x:9.5f}" for x in values(case_index, r)[:12])
            if albedo is not None:
                text += "  [" + " ".join(f"{x:.3f}" for x in albedo(case_index, r)[:12]) + "]"
            more = " ..." if len(coords["wavelength_um"]) > 12 else ""
            print(f"  {row if isinstance(row, str) else f'{row:8.2f}'} | {text}{more}")


def cmd_render(args) -> int:
    if getattr(args, "scene", None):
        with Dataset(args.file) as ds:
            case = select_case(ds, args.case, args.sweep)  # a swept dataset: the case named, else refused listing them
            swept = bool(ds.sweep_keys)
        try:
            from wavebrdf.mitsuba import render_scene

            stem = Path(args.file).stem + (f"_case{case}" if swept else "")  # a swept dataset's cases side by side
            out = (Path(args.out) if args.out else Path(args.file).parent) / f"{stem}_{args.scene}.png"
            result = render_scene(args.file, args.scene, out, spp=args.spp, resolution=args.resolution,
                                  variant=args.variant, case=case)
        except (ImportError, ValueError) as exc:
            print(f"wavebrdf: error: {one_line(str(exc))}", file=sys.stderr)
            return 2
        print(f"wrote {result['path']} (Mitsuba {result['variant']}: load {result['load_s']:.1f} s, "
              f"render {result['render_s']:.1f} s)")
        return 0

    mitsuba_only = [f"{flag} {value}" for flag, value in (("--spp", args.spp), ("--resolution", args.resolution),
                                                          ("--variant", args.variant), ("--case", args.case),
                                                          ("--sweep", " ".join(f"{k}={v}" for k, v in args.sweep or [])
                                                           or None)) if value is not None]
    if mitsuba_only:
        raise ConfigError(f"{', '.join(mitsuba_only)}: only with --scene (a Mitsuba render)")
    check_decades(args.decades)  # before the dataset is opened
    for png in render_dataset(args.file, args.out, **render_options(args)):
        print(f"wrote {png}")
    return 0


def cmd_example(args) -> int:
    from wavebrdf.jobs.examples import list_examples, write_example

    if args.name is None:
        examples = list_examples()
        width = max(map(len, examples), default=0)
        for name, summary in examples.items():
            print(f"{name:{width}}  {summary}")
        print("write one: wavebrdf example NAME [--out DIR]; then: wavebrdf run DIR/NAME.toml")
        return 0
    written = write_example(args.name, args.out, force=args.force)
    for path in written:
        print(f"wrote {path}")
    print(f"run it: wavebrdf run {written[0]}")
    return 0


def cmd_devices(args) -> int:
    infos = list_devices()
    import os

    chosen = choose_device(os.environ.get("WAVEBRDF_DEVICE", "auto"), infos)
    for info in infos:
        mark = "*" if info == chosen else " "
        print(f"{mark} {info.spec}  {info.platform} / {info.name}  [{info.kind}]  fp64={'yes' if info.fp64 else 'no'}"
              f"  CUs={info.compute_units}  mem={info.global_mem_gib:.1f} GiB (max alloc {info.max_alloc_gib:.1f})")
    print("* = device used (WAVEBRDF_DEVICE=auto|gpu|cpu|pocl|P:D|name)")
    return 0


def benchmarks_folder(package_root: Path, cwd: Path) -> Path | None:
    """The ``benchmarks/`` folder of a source checkout: the one the package runs from
    (``package_root``: an editable install), else one in the working directory ``cwd`` (a checkout
    beside an installed copy); None when neither holds ``bench_*.py`` (the wheel ships none)."""
    for root in (package_root, cwd):
        folder = root / "benchmarks"
        if any(folder.glob("bench_*.py")):
            return folder
    return None


def cmd_bench(args) -> int:
    import runpy

    folder = benchmarks_folder(Path(__file__).resolve().parent.parent, Path.cwd())
    if folder is None:
        raise ConfigError("wavebrdf bench runs the scripts in a source checkout's benchmarks/ folder, which an "
                          "installed wavebrdf does not include: clone the repository and run 'wavebrdf bench "
                          f"{args.name}' (or 'python benchmarks/bench_{args.name}.py') in it")
    script = folder / f"bench_{args.name}.py"
    if not script.is_file():
        available = sorted(p.stem[6:] for p in folder.glob("bench_*.py"))
        raise ConfigError(f"bench {args.name}: no such benchmark in {folder}; available: {', '.join(available)}")
    sys.argv = [str(script)] + list(args.rest)
    sys.path.insert(0, str(script.parent))  # benchmarks import their sibling helpers
    runpy.run_path(str(script), run_name="__main__")
    return 0


def one_line(text: str) -> str:
    """``text`` on one line: line breaks become spaces, other unprintable characters escapes."""
    text = " ".join(text.splitlines())
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)


class _Parser(argparse.ArgumentParser):
    """argparse with the CLI's one-line errors (``wavebrdf: error: ...``, exit 2)."""

    def error(self, message: str):
        message = re.sub(r"^argument (\S+): (?=\1 )", "", message)  # the type check names the flag itself
        print(f"wavebrdf: error: {one_line(message)}; see '{self.prog} --help'", file=sys.stderr)
        sys.exit(2)


def _number_flag(flag: str, *, integer: bool, low: float, low_open: bool = False):
    """argparse type: a finite number (integer) >= low (> low when ``low_open``), refused with one
    line naming the flag and the value."""
    what = "an integer" if integer else "a number"
    bound = f"{'>' if low_open else '>='} {low:g}"

    def parse(text: str):
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            value = None
        if value is None or not math.isfinite(value) or value < low or (low_open and value == low):
            raise argparse.ArgumentTypeError(f"{flag} {text}: must be {what} {bound}")
        return value

    return parse


def _count(flag: str):
    return _number_flag(flag, integer=True, low=1)


def _gib(flag: str):
    return _number_flag(flag, integer=False, low=0, low_open=True)


def _assignment(text: str):
    """argparse type of ``--set key=value`` (jobs/overrides.py)."""
    try:
        return parse_assignment(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _add_set_flag(p) -> None:
    p.add_argument("--set", action="append", type=_assignment, metavar="KEY=VALUE",
                   help="override a config key (dotted, e.g. surface.rms_height_um=0.1; the value is TOML: "
                        "[0.45, 0.55], {start = 0.4, stop = 0.7, count = 4}, a bare word is a string); repeatable")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="wavebrdf", description="Wave-optics BRDFs of microgeometry.")
    parser.add_argument("--version", action="version", version=f"wavebrdf {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log every task")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("run", help="run a study from a TOML config into an HDF5 dataset (+ PNGs)")
    p.add_argument("config", type=Path)
    _add_set_flag(p)
    p.add_argument("--output", "-o", type=Path, help="override [study] output")
    p.add_argument("--device", help="OpenCL device (overrides WAVEBRDF_DEVICE)")
    p.add_argument("--executor", choices=executor_names(),
                   help="override [run] executor (auto: MPI under mpiexec/srun, else serial)")
    p.add_argument("--workers", type=_count("--workers"), help="worker processes for --executor processes")
    p.add_argument("--wait", action="store_true",
                   help="if another run holds the output, wait for it to end (default: exit with status 2)")
    p.add_argument("--no-render", action="store_true", help="do not write PNGs")
    p.add_argument("--quiet", "-q", action="store_true",
                   help="no progress bar (a log file keeps one line per task)")
    p.add_argument("--force", action="store_true", help="recompute a study whose output is up to date, or overwrite "
                                                       "another configuration's results")
    p.add_argument("--shard", metavar="I/K", help="run shard I of K (array jobs; see 'wavebrdf merge')")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("plan", help="list a study's tasks with memory/time estimates (runs nothing)")
    p.add_argument("config", type=Path)
    _add_set_flag(p)
    p.add_argument("--workers", type=_count("--workers"), help="concurrent tasks per node (default [run] workers or 1)")
    p.add_argument("--memory-gb", type=_gib("--memory-gb"),
                   help="node memory (default: [run] memory_gb or this machine)")
    p.add_argument("--rows", type=_count("--rows"), default=40, help="maximum task rows to print")
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("compare", help="run several models on a study's scenes: time, memory and error vs a "
                                       "reference (CSV, Markdown, plots, HDF5)")
    p.add_argument("config", type=Path)
    p.add_argument("--models", help="comma-separated model names (default: [compare] models, else every "
                                    "surface model that fits the scenes)")
    p.add_argument("--reference", help="the reference model (default: [compare] reference, else the most "
                                       "accurate rung that fits the memory budget, per scene)")
    p.add_argument("--memory-gb", type=_gib("--memory-gb"), help="memory budget for the reference (default: 80%% "
                                                                  "of the available memory)")
    p.add_argument("--out", type=Path, help="output stem (default: <output stem>_compare)")
    p.add_argument("--force", action="store_true", help="overwrite files at the output stem that are not a "
                                                        "previous comparison's")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("models", help="list the registered models, their capabilities and options")
    p.set_defaults(func=cmd_models)


    add_submit_parser(sub, _count, _gib)
    add_merge_parser(sub, _count, _add_set_flag)

    p = sub.add_parser("inspect", help="summarise a dataset")
    p.add_argument("file", type=Path)
    p.add_argument("--config", action="store_true", help="also print the stored config")
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("render", help="write PNGs of a dataset: hemisphere maps, polar slices, spectra, albedo, "
                                      "height maps, fiber cross sections (docs/pictures.md)")
    p.add_argument("file", type=Path)
    p.add_argument("--out", type=Path, help="output folder (default: <file stem>_png)")

    add_render_flags(p)
    p.add_argument("--scene", choices=["sphere", "plate", "fibers"],
                   help="render the material with Mitsuba 3 (extra 'render') under a sky instead: "
                        "<file stem>_<scene>.png (sphere/plate: surface datasets; fibers: fiber datasets)")
    p.add_argument("--spp", type=_count("--spp"), help="with --scene: samples per pixel (default 64, 16 in scalar "
                                                        "variants)")
    p.add_argument("--resolution", type=_count("--resolution"), help="with --scene: image side in pixels (default "
                                                                      "256, 128 in scalar variants)")
    p.add_argument("--variant", help="with --scene: the Mitsuba variant, e.g. scalar_rgb, llvm_ad_rgb, "
                                     "llvm_ad_spectral (default llvm_ad_rgb where a libLLVM >= 17 is found, else "
                                     "scalar_rgb)")
    add_case_flags(p, "with --scene: ")
    p.set_defaults(func=cmd_render)

    add_export_parser(sub)

    p = sub.add_parser("example", help="list the example studies, or write one (a config and the files it reads) "
                                       "to start from")
    p.add_argument("name", nargs="?", help="the example, e.g. default (the quick start); none: list them")
    p.add_argument("--out", type=Path, default=Path("."), help="folder to write into (default: here)")
    p.add_argument("--force", action="store_true", help="overwrite files of the same names")
    p.set_defaults(func=cmd_example)

    p = sub.add_parser("devices", help="list OpenCL platforms/devices and their fp64 support")
    p.set_defaults(func=cmd_devices)

    p = sub.add_parser("bench", help="run a benchmark from benchmarks/ (source checkouts)")
    p.add_argument("name", help="e.g. kirchhoff")
    p.add_argument("rest", nargs=argparse.REMAINDER)
    p.set_defaults(func=cmd_bench)

    add_verbosity_flags(parser, sub)  # -v/-q before or after the subcommand
    return parser


PIPE_CLOSED_STATUS = 141  # 128 + SIGPIPE: what a shell reports for a writer whose reader left


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a flag refused in one line
        return exc.code if isinstance(exc.code, int) else 0

    configure_logging(args.verbose)  # timestamped, printed above the progress bar
    try:
        return args.func(args)
    except BrokenPipeError:  # output piped into a reader that closed it (`wavebrdf inspect x.h5 | head`)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return PIPE_CLOSED_STATUS
    except USER_ERRORS as exc:
        print(f"wavebrdf: error: {one_line(str(exc))}", file=sys.stderr)
        return 2
    except Stopped:
        launch = detect_mpi_launch()
        who = f" (rank {launch.rank})" if launch is not None else ""
        print(f"wavebrdf: stopped by SIGTERM{who}; finished tasks are kept, re-run the same command to resume",
              file=sys.stderr)
        return STOPPED_STATUS
    except KeyboardInterrupt:
        print("wavebrdf: interrupted; finished tasks are kept, re-run the same command to resume", file=sys.stderr)
        return 130
