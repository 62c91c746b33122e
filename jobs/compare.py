"""The speed/accuracy trade, measured (``wavebrdf compare``; approx.md §4–§6).

Every listed surface model runs on the same scenes — the (case, wavelength, incident direction)
slices of a study config, so one footprint, one output grid and one BRDF normalization — each run
alone in a measuring process (:class:`MeasuringProcess`, one per comparison: the interpreter and
OpenCL start once), which gives its wall time, CPU time (all threads, OpenCL's included) and peak
memory over the process's resident memory when it started (the peak RSS is reset before each
model; NaN where the kernel refuses the reset). A model's first use in the process includes
loading its kernels from the PoCL cache. Each BRDF is then
compared with the reference model's on the same scene (solver/metrics.py):

* ``rel_l2``: relative L2 over the reference's lobe of the unpolarized BRDF (the raw slices);
* ``rel_l2_smooth``: the same after a Gaussian blur of the speckle width on both (the
  speckle-averaged variant; statistical models such as ``stam`` are meant to be read here);
* ``misplaced``: E₁ = ½∫|f − f_ref| d²u (fraction of the incident power);
* ``albedo_diff``: albedo − the reference's albedo (unpolarized);
* ``peak_offset_deg``: angle between the blurred lobes' peak centroids;
* ``retro``: share of the reflected power within :data:`RETRO_CONE_DEG` of ω_i;
* ``warnings``: what the model said of its own figure while it ran (validity, sampling, the
  full wave's checks) and an albedo above 1 (the line a run's task table carries): the Markdown
  table gives their kinds and lists a warned reference's in full, since every error measured
  against it carries them.

The reference is ``--reference`` or the most accurate rung (the models' ``Capabilities.rung``) whose
estimate fits the memory budget; a lower rung as reference is said so in the table. Results: a
CSV and a Markdown table, a log-log plot of error vs time (one marker per model, one colour per
scene) and an HDF5 file with the same numbers and every BRDF.
"""

from __future__ import annotations

import csv
import dataclasses
import logging
import re
import time
import traceback
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wavebrdf.jobs.progress import degrees_text
from wavebrdf.jobs.store import StoreError, is_comparison, write_comparison
from wavebrdf.solver.farfield import HemisphereGrid, albedo
from wavebrdf.solver.metrics import (
    angular_distance_deg,
    blur,
    cone_fraction,
    misplaced_energy,
    peak_direction,
    relative_l2,
    speckle_sigma_u,
)
from wavebrdf.solver.models import get_model, model_class, model_names, rung_order, rungs
from wavebrdf.solver.validity import energy_excess_warning, recorded_warnings

logger = logging.getLogger(__name__)

__all__ = ["COMPARISON_ENDINGS", "Comparison", "Measurement", "check_comparison_outputs", "choose_reference",
           "comparison_paths", "compare_options", "compare_scenes", "comparison_markdown",
           "comparison_metrics", "measure", "speckle_sigma_u", "warning_kinds"]

RETRO_CONE_DEG = 5.0
COLUMNS = ("scene", "model", "reference", "wall_s", "cpu_s", "peak_mb", "albedo", "albedo_diff", "rel_l2",
           "rel_l2_smooth", "rel_l2_s", "rel_l2_smooth_s", "rel_l2_p", "rel_l2_smooth_p", "misplaced",
           "peak_offset_deg", "retro", "failure", "warnings")
TEXT_COLUMNS = ("scene", "model", "reference", "failure", "warnings")  # the others are numbers (NaN where missing)


@dataclass
class Measurement:
    """One model on one scene: cost, unpolarized and per-polarization BRDF, diagnostics."""

    model: str
    scene: str
    wall_s: float = float("nan")
    cpu_s: float = float("nan")
    peak_mb: float = float("nan")
    brdf: np.ndarray | None = None  # (2, res, res), NaN outside the disk
    diagnostics: dict = field(default_factory=dict)
    failure: str | None = None


def _run_one(ctx, name: str, options, scene) -> dict:
    """Run model ``name`` once on ``scene``: wall/CPU time, peak memory over the baseline, BRDF,
    diagnostics (warnings included), or the failure."""
    import warnings

    from wavebrdf.jobs.tasks import plain
    from wavebrdf.solver.resources import peak_resident_bytes, reset_peak_memory

    caught: list = []
    try:
        model = get_model(name, options)
        baseline = reset_peak_memory()  # NaN where the peak cannot be reset: the peak is then not this model's
        t0, c0 = time.perf_counter(), time.process_time()  # ns resolution (os.times ticks at 10 ms)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = model.run(ctx, scene)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        diagnostics, brdf = plain(result.diagnostics), result.brdf()
        diagnostics["warnings"] = recorded_warnings(caught)
        return dict(wall_s=wall, cpu_s=cpu,
                    peak_mb=max(peak_resident_bytes() - baseline, 0.0) / 2**20, brdf=brdf, diagnostics=diagnostics)
    except Exception as exc:  # noqa: BLE001 - reported in the table, the comparison goes on
        return dict(failure=f"{type(exc).__name__}: {exc}", trace=traceback.format_exc(),
                    diagnostics={"warnings": recorded_warnings(caught)})  # what it said before it failed


PROGRESS_FILE_VARIABLE = "WAVEBRDF_MEASURE_PROGRESS"


class _ProgressFile:
    """The measuring process's progress reporter: one timestamped line per report (stage, fraction,
    figures such as Krylov products and residual), at most one per ``seconds`` and at every new
    stage, appended to a file that can be watched while a long solve runs. A file that cannot be
    written ends the reports, not the solve."""

    def __init__(self, path: str, seconds: float = 30.0):
        self.path, self.seconds = path, seconds
        self._stage, self._last = None, -float("inf")

    def __call__(self, stage: str, fraction: float | None = None, **figures) -> None:
        now = time.monotonic()
        if self.path is None or (stage == self._stage and now - self._last < self.seconds):
            return
        self._stage, self._last = stage, now
        done = "" if fraction is None else f" {100 * fraction:.0f} %"
        shown = " ".join(f"{k}={v:.3g}" if isinstance(v, (float, np.floating)) else f"{k}={v}"
                         for k, v in figures.items())
        if not write_progress_line(self.path, f"{stage}{done} {shown}".rstrip()):
            self.path = None


def write_progress_line(path, text: str) -> bool:
    """Append ``text`` to ``path`` with a timestamp; False (and a warning) where it cannot be written."""
    try:
        with open(path, "a") as fh:
            fh.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {text}\n")
        return True
    except OSError as exc:
        logger.warning("progress file %s: %s; no more progress lines", path, exc)
        return False


def _worker_main() -> None:
    """Entry of the measuring process: (name, options, scene) requests, length-prefixed pickles on
    stdin, each answered on the original stdout (model output is sent to stderr)."""
    import os
    import pickle
    import sys

    from wavebrdf.jobs.scheduler import die_with_parent
    from wavebrdf.solver.opencl import create_context

    die_with_parent(os.getppid())
    answers = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    requests = sys.stdin.buffer
    ctx = create_context()
    if path := os.environ.get(PROGRESS_FILE_VARIABLE):
        ctx.progress = _ProgressFile(path)
    while header := requests.read(8):
        name, options, scene = pickle.loads(requests.read(int.from_bytes(header, "little")))
        data = pickle.dumps(_run_one(ctx, name, options, scene))
        answers.write(len(data).to_bytes(8, "little") + data)
        answers.flush()


class MeasuringProcess:
    """One process that runs the models of a comparison one at a time, so that the interpreter
    and OpenCL start once, not per model; each model's peak memory is measured from a reset of the
    process's peak RSS (``clear_refs``). A model that kills the process is reported as a failure
    and the next one gets a fresh process. ``progress_path``: the models' progress reports
    (solver/progress.py) are appended there, one line at most every 30 s per stage, to watch a
    long solve. Use as a context manager."""

    def __init__(self, progress_path: Path | None = None):
        self._proc = None
        self._stderr = None
        self.progress_path = progress_path

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        self.close(kill=exc_type is not None)

    def close(self, kill: bool = False) -> None:
        """End the process: after its current model (``kill``: at once)."""
        if self._proc is not None:
            if kill:
                self._proc.kill()
            try:
                self._proc.stdin.close()
            except OSError:
                pass
            self._proc.wait()
            self._proc = None
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None

    def _start(self) -> None:
        import os
        import subprocess
        import sys
        import tempfile

        self._stderr = tempfile.TemporaryFile()
        # a fixed mmap threshold: large arrays are mapped and unmapped, never kept in the heap for the
        # next model (glibc's dynamic threshold would hide that model's peak)
        env = {**os.environ, "MALLOC_MMAP_THRESHOLD_": str(1 << 17)}
        if self.progress_path is not None:
            env[PROGRESS_FILE_VARIABLE] = str(self.progress_path)
        self._proc = subprocess.Popen([sys.executable, "-c", "from wavebrdf.jobs.compare import _worker_main; "
                                       "_worker_main()"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      stderr=self._stderr, env=env)

    def measure(self, name: str, options, scene, label: str) -> Measurement:
        """Run model ``name`` (Options or mapping) on ``scene`` in the measuring process."""
        import pickle

        if self._proc is None or self._proc.poll() is not None:
            self.close()
            self._start()
        request = pickle.dumps((name, options, scene))
        if self.progress_path is not None:
            write_progress_line(self.progress_path, f"{name} on {label} ({scene.surface.cells}² cells)"
                                if hasattr(scene, "surface") else f"{name} on {label}")
        try:
            self._proc.stdin.write(len(request).to_bytes(8, "little") + request)
            self._proc.stdin.flush()
            header = self._proc.stdout.read(8)
            out = pickle.loads(self._proc.stdout.read(int.from_bytes(header, "little"))) if len(header) == 8 else None
        except Exception:  # noqa: BLE001 - a broken pipe, a truncated or garbled answer: the process is done for
            out = None
        if out is None:
            self._proc.kill()
            rc = self._proc.wait()
            self._stderr.seek(0)
            tail = self._stderr.read().decode(errors="replace").strip().splitlines()[-1:] or ["no output"]
            out = {"failure": f"the measuring process exited with {rc}: {tail[0]}"}
            self.close()
        if "trace" in out:
            logger.debug("%s on %s failed:\n%s", name, label, out.pop("trace"))
        return Measurement(model=name, scene=label, **out)


def measure(name: str, options, scene, label: str) -> Measurement:
    """Run model ``name`` (Options or mapping) on ``scene`` in a fresh measuring process."""
    with MeasuringProcess() as process:
        return process.measure(name, options, scene, label)


def choose_reference(models: list[str], scene, memory_budget_bytes: float) -> tuple[str, str]:
    """(reference model, why): the highest rung (:func:`~wavebrdf.solver.models.rung_order`) among
    ``models`` whose estimate fits ``memory_budget_bytes``."""
    ranked = sorted(models, key=rung_order, reverse=True)
    needs = {name: get_model(name).estimate(scene).memory_bytes for name in ranked}
    for name in ranked:
        if needs[name] <= memory_budget_bytes:
            top = ranked[0]
            why = "the most accurate rung" if name == top else (
                f"{top} needs {needs[top] / 2**30:.2f} GiB > budget {memory_budget_bytes / 2**30:.2f} GiB")
            return name, why
    raise ValueError(f"no model fits the memory budget of {memory_budget_bytes / 2**30:.2f} GiB")


@dataclass
class Comparison:
    """The rows of one comparison (one per scene × model) and the BRDFs they came from."""

    rows: list[dict]
    measurements: list[Measurement]
    grid: HemisphereGrid

    def write(self, stem: Path) -> list[Path]:
        """``stem``.csv, .md, .png (error vs time), _gallery.png (every model's BRDF side by side)
        and .h5 (returns the paths written); the stem's name is kept whole (``a0.6_compare`` →
        ``a0.6_compare.csv``)."""
        paths = comparison_paths(stem)
        with open(paths[0], "w", newline="") as fh:
            writer = csv.DictWriter(fh, COLUMNS)
            writer.writeheader()
            for row in self.rows:
                writer.writerow({k: row.get(k, "") for k in COLUMNS})
        paths[1].write_text(self.markdown())
        self.plot(paths[2])
        self._write_h5(paths[3])
        self.gallery(paths[4])
        return paths

    def markdown(self) -> str:
        return comparison_markdown(self.rows)

    def plot(self, path: Path) -> None:
        plot_trade(self.rows, path)

    def gallery(self, path: Path, decades: float = 5.0) -> None:
        """One row per scene (a single scene: rows of five), one hemisphere per model: log₁₀ of the unpolarized BRDF over
        ``decades`` below the scene's highest value (shared colour scale within a row)."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        scenes = list(dict.fromkeys(m.scene for m in self.measurements))
        models = list(dict.fromkeys(m.model for m in self.measurements))
        rows = {(r["scene"], r["model"]): r for r in self.rows}
        columns = len(models) if len(scenes) > 1 else min(5, len(models))  # one scene: rows of 5
        per_scene = -(-len(models) // columns)
        fig, axes = plt.subplots(len(scenes) * per_scene, columns, figsize=(2.3 * columns, 2.5 * len(scenes) * per_scene),
                                 dpi=110, squeeze=False)
        for ax in axes.ravel():
            ax.set_axis_off()
        t = np.linspace(0, 2 * np.pi, 361)
        for i, scene in enumerate(scenes):
            runs = {m.model: m for m in self.measurements if m.scene == scene}
            logs = {}
            for name, m in runs.items():
                if m.brdf is not None:
                    with np.errstate(divide="ignore", invalid="ignore"):
                        logs[name] = np.log10(0.5 * (m.brdf[0] + m.brdf[1]))
            finite = [v[np.isfinite(v)] for v in logs.values() if np.any(np.isfinite(v))]
            top = max(v.max() for v in finite) if finite else 0.0
            for j, name in enumerate(models):
                ax = axes[i * per_scene + j // columns, j % columns]
                ax.set_axis_on()
                ax.set_facecolor("black")
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_aspect("equal")
                row = rows.get((scene, name), {})
                if name in logs:
                    ax.imshow(logs[name], origin="lower", extent=(-1, 1, -1, 1), cmap="magma", vmin=top - decades,
                              vmax=top, interpolation="nearest")
                    err = row.get("rel_l2_smooth", np.nan)
                    label = f"{name}\n{row.get('wall_s', np.nan):.3g} s" + (
                        "" if row.get("model") == row.get("reference", "").split(" ")[0] else f", L2 {err:.2g}")
                else:
                    label = f"{name}\nfailed"
                ax.plot(np.cos(t), np.sin(t), color="white", lw=0.5)
                ax.set_title(label, fontsize=7)
                if j % columns == 0:
                    ax.set_ylabel(scene, fontsize=6)
        fig.suptitle(f"unpolarized BRDF, log₁₀ over {decades:g} decades (axes: v horizontal, u vertical)", fontsize=8)
        fig.tight_layout()
        fig.savefig(path)
        plt.close(fig)

    def _write_h5(self, path: Path) -> None:
        write_comparison(path, COLUMNS, self.rows, [(m.scene, m.model, m.brdf, m.diagnostics)
                                                    for m in self.measurements if m.brdf is not None],
                         self.grid.resolution, TEXT_COLUMNS)


COMPARISON_ENDINGS = (".csv", ".md", ".png", ".h5", "_gallery.png")  # Comparison.write's files, in its order


def comparison_paths(stem: Path) -> list[Path]:
    """The files :meth:`Comparison.write` writes at ``stem`` (its name kept whole)."""
    stem = Path(stem)
    return [stem.with_name(stem.name + ending) for ending in COMPARISON_ENDINGS]


def check_comparison_outputs(stem: Path, force: bool = False) -> None:
    """StoreError (unless ``force``) where writing a comparison at ``stem`` would replace a file it
    does not own: ``stem``.h5 that is not a file of ``wavebrdf compare`` (a study's dataset, any other
    HDF5 or file), or, with no comparison's .h5 there, any of its other files (nothing tells a
    previous comparison's CSV, Markdown or PNG from a user's own). Checked before anything runs."""
    paths = comparison_paths(stem)
    h5 = paths[COMPARISON_ENDINGS.index(".h5")]
    if force or (h5.exists() and is_comparison(h5)):
        return
    present = [p for p in paths if p.exists()]
    if present:
        named, what = ((h5, "is not a file of `wavebrdf compare`") if h5 in present
                       else (present[0], "has no comparison's .h5 beside it"))
        raise StoreError(f"{named} {what}, so a comparison does not replace it; choose another --out, move it "
                         "away, or add --force to overwrite it")


def plot_trade(rows: list[dict], path: Path, group: str = "scene", title: str | None = None,
               tolerance: float | None = None, error: str = "rel_l2_smooth",
               error_label: str = "speckle-averaged, unpolarized") -> None:
    """Error (the rows' ``error`` key, described on the axis by ``error_label``) vs CPU time,
    log-log: one marker per model, one colour per ``group`` value; the reference's own rows become
    a grey band of its CPU times; ``tolerance`` a dashed line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def reference_of(r):
        return str(r.get("reference", "")).split(" ")[0]

    groups = list(dict.fromkeys(r[group] for r in rows))
    models = list(dict.fromkeys(r["model"] for r in rows if r["model"] != reference_of(r)))
    markers = "os^vD<>pX*hP"
    colours = plt.get_cmap("tab10")
    fig, ax = plt.subplots(figsize=(8.5, 5.5), dpi=120)
    for r in rows:
        err, t = r.get(error, np.nan), r.get("cpu_s", np.nan)
        if r["model"] == reference_of(r) or not (np.isfinite(err) and np.isfinite(t)) or err <= 0:
            continue
        ax.loglog(max(t, 1e-3), err, linestyle="none", marker=markers[models.index(r["model"]) % len(markers)],
                  color=colours(groups.index(r[group]) % 10), markersize=6, alpha=0.8)
    ref_times = [r["cpu_s"] for r in rows if r["model"] == reference_of(r) and np.isfinite(r.get("cpu_s", np.nan))]
    if ref_times:
        ax.axvspan(min(ref_times), max(ref_times) * 1.05, color="0.85", zorder=0,
                   label=f"{reference_of(rows[0])} (the reference) CPU time")
    if tolerance is not None:
        ax.axhline(tolerance, color="k", linestyle="--", lw=1, label=f"tolerance {tolerance:g}")
    for i, m in enumerate(models):
        ax.plot([], [], linestyle="none", marker=markers[i % len(markers)], color="0.3", label=m)
    for j, g in enumerate(groups):
        ax.plot([], [], linestyle="-", color=colours(j % 10), label=str(g))
    ax.set_xlabel("CPU time per scene (s)")
    ax.set_ylabel(f"relative L2 over the lobe vs reference ({error_label})")
    if title:
        ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6, loc="best", ncol=3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def comparison_markdown(rows: list[dict]) -> str:
    """The Markdown table of a comparison's rows (:data:`COLUMNS`; a warning by its kind) and,
    under it, the full text of every warning the reference raised."""
    def cell(r, k):  # a warning's kind in the table; its text is in the CSV and the .h5
        v = r.get(k)
        if k == "warnings":
            return warning_kinds(v or "")
        if isinstance(v, float):
            return "" if not np.isfinite(v) else f"{v:.3g}"
        return "" if v is None else str(v)

    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(cell(r, k) for k in COLUMNS) + " |" for r in rows]
    warned = [r for r in rows if r.get("warnings") and r.get("model") == str(r.get("reference", "")).split(" (")[0]]
    if warned:
        lines += ["", f"The reference warned on {len(warned)} scene(s); every error measured against it there "
                  "carries that warning (full text in the CSV's `warnings` column):"]
        lines += [f"- {r['scene']}, {r['model']}: {r['warnings']}" for r in warned]
    return "\n".join(lines) + "\n"


def _finite_or_failed(m: Measurement, scene) -> Measurement:
    """``m`` (run here or stored before), or where its BRDF holds NaN/inf inside the disk a failure
    saying so, as a run's task fails."""
    if m.failure is not None or m.brdf is None:
        return m
    bad = int(np.count_nonzero(~np.isfinite(m.brdf[:, scene.grid.inside])))
    if not bad:
        return m
    return dataclasses.replace(m, brdf=None, failure=f"FloatingPointError: {bad} BRDF value(s) NaN/inf inside the "
                                                     "unit disk")


def _row_warnings(m: Measurement, scene) -> str:
    """The ``warnings`` cell of ``m``'s row: what it raised while it ran and, where its albedo
    exceeds 1, the EnergyWarning naming the rung that ran (:func:`~wavebrdf.solver.validity.
    energy_excess_warning`, the line a run's task table carries)."""
    recorded = m.diagnostics.get("warnings")
    text = "; ".join(map(str, recorded)) if isinstance(recorded, (list, tuple)) else str(recorded or "")
    if m.failure is None and m.brdf is not None:
        energy = energy_excess_warning(m.diagnostics.get("model", m.model), float(np.rad2deg(scene.theta_i)),
                                       albedo(m.brdf, scene.grid))
        if energy and energy not in text:
            text = "; ".join(w for w in (text, energy) if w)
    return text


def warning_kinds(text: str) -> str:
    """The kinds of the warnings in a ``warnings`` cell ("ValidityWarning ×2, EnergyWarning"); a
    text without a "Category:" prefix (a solve stored by an older version) reads "warned"."""
    counts = Counter(re.findall(r"(?:^|; )(\w+Warning):", text))
    if not counts:
        return "warned" if text.strip() else ""
    return ", ".join(kind + (f" ×{n}" if n > 1 else "") for kind, n in sorted(counts.items()))


def comparison_metrics(m: Measurement, ref: Measurement, grid: HemisphereGrid, sigma_u: float, theta: float, phi: float) -> dict:
    """The columns of one model against the reference: the unpolarized BRDF's albedo, relative L2
    over the lobe raw and speckle-averaged (``_smooth``), the same per incident polarization
    (``_s``, ``_p``), misplaced energy, peak offset and retro-reflected share."""
    f = 0.5 * (m.brdf[0] + m.brdf[1])
    f_ref = 0.5 * (ref.brdf[0] + ref.brdf[1])
    smooth, smooth_ref = blur(f, grid, sigma_u), blur(f_ref, grid, sigma_u)
    a, a_ref = albedo(f, grid), albedo(f_ref, grid)
    per_polarization = {}
    for k, pol in enumerate("sp"):
        per_polarization[f"rel_l2_{pol}"] = float(relative_l2(m.brdf[k], ref.brdf[k], grid))
        per_polarization[f"rel_l2_smooth_{pol}"] = float(relative_l2(blur(m.brdf[k], grid, sigma_u),
                                                                     blur(ref.brdf[k], grid, sigma_u), grid))
    return {
        **per_polarization,
        "albedo": float(a),
        "albedo_diff": float(a - a_ref),
        "rel_l2": float(relative_l2(f, f_ref, grid)),
        "rel_l2_smooth": float(relative_l2(smooth, smooth_ref, grid)),
        "misplaced": float(misplaced_energy(f, f_ref, grid)),
        "peak_offset_deg": angular_distance_deg(peak_direction(smooth, grid), peak_direction(smooth_ref, grid)),
        "retro": cone_fraction(f, grid, theta, phi, RETRO_CONE_DEG),
    }


def compare_scenes(scenes: list[tuple[str, object]], models: list[str], options: dict | None = None,
                   reference: str | None = None, memory_budget_bytes: float | None = None,
                   progress=None, measured: dict | None = None) -> Comparison:
    """Run ``models`` (and the reference) on every (label, SurfaceScene) of ``scenes``.

    ``options``: model name → Options mapping; ``reference``: a model name, or None to choose
    (:func:`choose_reference`) per scene within ``memory_budget_bytes`` (default: available RAM).
    ``measured``: (label, model name) → a :class:`Measurement` of that model with the same options
    on that scene, made before (a stored solve): taken as it is instead of running the model again.
    """
    from wavebrdf.solver.resources import meminfo_bytes

    options = options or {}
    budget = memory_budget_bytes if memory_budget_bytes is not None else 0.8 * meminfo_bytes("MemAvailable")
    rows: list[dict] = []
    kept: list[Measurement] = []
    grid = scenes[0][1].grid
    with MeasuringProcess() as process:
        for label, scene in scenes:
            rows += _compare_one(process, label, scene, models, options, reference, budget, kept, grid, progress,
                                 measured or {})
    return Comparison(rows, kept, grid)


def _compare_one(process, label, scene, models, options, reference, budget, kept, grid, progress,
                 measured) -> list[dict]:
    """The rows of one scene: the reference and every model measured (or taken from ``measured``),
    then the metrics."""
    rows = []
    if reference is None:
        ref_name, why = choose_reference(models, scene, budget)
    else:
        ref_name, why = reference, "given"
    logger.info("%s: reference %s (%s)", label, ref_name, why)
    runs = {}
    for name in [ref_name] + [n for n in models if n != ref_name]:
        before = (label, name) in measured
        if progress:
            progress(f"{label}: {name}{' (measured before)' if before else ''}")
        runs[name] = _finite_or_failed(measured[label, name] if before else
                                       process.measure(name, options.get(name), scene, label), scene)
        kept.append(runs[name])
        logger.info("%s: %s %.3g s wall, %.3g s CPU, %.0f MB%s", label, name, runs[name].wall_s,
                    runs[name].cpu_s, runs[name].peak_mb, f" — {runs[name].failure}" if runs[name].failure else "")
    ref = runs[ref_name]
    sigma_u = speckle_sigma_u(scene.wavelength_um, scene.waist_um, grid, scene.exterior_index)
    for name, m in runs.items():
        row = {"scene": label, "model": name, "reference": ref_name if reference else f"{ref_name} ({why})",
               "wall_s": m.wall_s, "cpu_s": m.cpu_s, "peak_mb": m.peak_mb, "failure": m.failure,
               "warnings": _row_warnings(m, scene)}
        if m.failure is None and ref.failure is None:
            row.update(comparison_metrics(m, ref, grid, sigma_u, scene.theta_i, scene.phi_i))
        rows.append(row)
    return rows


def surface_models(plan) -> list[str]:
    """Registered surface models that can run the plan's scenes: height-field models, and
    statistics models when every case's surface carries its ensemble."""
    names = list(rungs("height_field"))
    if all(plan.surface(case).ensemble is not None for case in range(len(plan.config.cases))):
        names += list(rungs("statistics"))
    return sorted(names, key=rung_order)


def compare_options(study) -> dict:
    """Model name → its options for a comparison of ``study`` (one case of a config): ``[model]``
    for the study's model, the ``[compare.<name>]`` tables for the others (ConfigError naming the
    table where one is not a registered model or does not parse)."""
    from wavebrdf.jobs.config import ConfigError
    from wavebrdf.solver.options import parse_options

    options = {study.model.name: study.model.options}
    for name, table in study.sections["compare"]["options"].items():
        if isinstance(table, dict):
            if name not in model_names():
                raise ConfigError(f"[compare.{name}]: not a registered model (available: {', '.join(model_names())})")
            try:
                options[name] = parse_options(model_class(name).Options, table, f"compare.{name}")
            except ValueError as exc:
                raise ConfigError(str(exc)) from None
    return options


def compare_config(config, models: list[str] | None = None, reference: str | None = None,
                   memory_gb: float | None = None, progress=None, before_run=None,
                   measured: dict | None = None) -> Comparison:
    """Every (case, wavelength, incident direction) of a surface study config through ``models``
    (default: ``[compare] models``, else :func:`surface_models`) against ``reference`` (default:
    ``[compare] reference``, else chosen per scene). Options: ``[model]`` for the study's model,
    ``[compare.<name>]`` tables for the others. Every model is checked against the study before
    anything runs (a ConfigError naming the flag); ``before_run()`` is called once they pass.
    ``measured``: as :func:`compare_scenes`'s."""
    from wavebrdf.jobs.config import ConfigError
    from wavebrdf.jobs.plan import plan_study

    study = config.cases[0]
    if not study.kind.comparable:
        raise ConfigError("wavebrdf compare: a surface study is needed (fiber models have no rungs to compare)")
    if study.steering is not None:
        raise ConfigError("[steering]: wavebrdf compare runs whole-surface scenes; remove [steering]")
    section = study.sections["compare"]  # validated (jobs/sections.py)
    options = compare_options(study)
    plan = plan_study(config)
    if models is not None and not models:
        raise ConfigError("--models: no model named (an empty list would run none); give comma-separated names, e.g. "
                          f"--models {','.join(surface_models(plan)[:2])}, or leave --models out to run every surface "
                          "model")
    given = "--models" if models is not None else "[compare] models"
    models = models if models is not None else section["models"] or surface_models(plan)
    models = [models] if isinstance(models, str) else list(models)
    for name in models:
        if name not in model_names():
            raise ConfigError(f"{given} {name}: not a registered model (available: {', '.join(model_names())})")
    _check_runnable(plan, models, given)
    given = "--reference" if reference is not None else "[compare] reference"
    if reference is not None and not reference.strip():
        raise ConfigError("--reference: no model named; give one (e.g. --reference po) or leave it out to choose "
                          "the most accurate rung that fits")
    reference = reference or section["reference"]
    if reference is not None:
        if reference not in model_names():
            raise ConfigError(f"{given} {reference}: not a registered model (available: {', '.join(model_names())})")
        _check_runnable(plan, [reference], given)
        if reference not in models:
            models = [reference] + models
    budget = None if memory_gb is None else memory_gb * 2**30
    scenes = plan_scenes(plan)
    if before_run is not None:
        before_run()
    return compare_scenes(scenes, models, options, reference, budget, progress, measured)


def _check_runnable(plan, names: list[str], given: str) -> None:
    """Refuse, before anything runs, a model that cannot take the plan's surface scenes: a fiber
    model, or a statistics model on a surface without a Gaussian ensemble (``given`` names the
    flag or key the names came from)."""
    from wavebrdf.jobs.config import ConfigError

    runnable = surface_models(plan)
    for name in names:
        if name in runnable or model_class(name).capabilities.picks_rung:
            continue
        takes = model_class(name).capabilities.takes
        why = ("takes a fiber cross section, not a surface" if takes == "cross_section" else
               "takes surface statistics (a Gaussian ensemble), and this study's surface has none (surface.generator "
               "= \"gaussian\" or \"brushed\" has)")
        raise ConfigError(f"{given} {name}: the {name} model {why}; models that can run this study: "
                          f"{', '.join(runnable)}")


def plan_scenes(plan) -> list[tuple[str, object]]:
    """(label, SurfaceScene) of every direct task of a surface plan; the label names the case (and
    its swept values), λ, θ_i and φ_i (where not 0), each with the digits that tell it apart — the
    ``scene`` column of the comparison table, one per scene."""
    scenes = []
    for task in plan.tasks:
        if task.kind != "direct":
            continue
        scene = plan.scene(task)
        case = plan.config.cases[task.case]
        where = ", ".join(f"{k}={v}" for k, v in case.sweep_values.items())
        phi = float(np.rad2deg(scene.phi_i)) % 360.0
        azimuth = f" φi={degrees_text(phi, 0)}°" if min(phi, 360.0 - phi) > 1e-6 else ""
        label = (f"{case.name}{' (' + where + ')' if where else ''} λ={scene.wavelength_um:g} µm "
                 f"θi={degrees_text(float(np.rad2deg(scene.theta_i)), 0)}°{azimuth}")
        scenes.append((label, scene))
    return scenes
