"""Batch behaviour: logs a person can read (no progress-bar frames in files, one timestamped line
per task), a finished study stays finished, shards merge into the unsharded dataset, threads and
GPU per rank, progress inside a task, `plan` agreeing with `run` (issue 19)."""

from __future__ import annotations

import hashlib
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from wavebrdf.jobs.cli import build_parser, main

BIN = Path(sys.executable).parent
STUDY = """
[study]
name = "logs"
output = "{out}"

[surface]
generator = "gaussian"
size_um = 6.0
cells = 64
rms_height_um = 0.06
correlation_um = 0.8
seed = {seed}

[material]
name = "gold"

[illumination]
wavelengths_um = [0.45, 0.65]
directions_deg = [[0, 0], [40, 90]]
waist_um = 1.1

[model]
name = "kirchhoff"

[output]
resolution = 48
"""
TASK_LINE = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d \[\d+/4\] task \d+ direct: λ [\d.]+ µm, θ_i [\d.]+°, "
                       r"φ_i [\d.]+°; kirchhoff, [\d.]+ s, peak \d+ MB")


def write_study(folder: Path, name: str = "logs", seed: int = 3) -> Path:
    path = folder / f"{name}.toml"
    path.write_text(textwrap.dedent(STUDY.format(out=folder / f"{name}.h5", seed=seed)))
    return path


def wavebrdf(*argv, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "wavebrdf"), *map(str, argv)], capture_output=True, text=True, **kwargs)


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """One finished study, run with stderr into a file (not a terminal) and -v after the subcommand."""
    folder = tmp_path_factory.mktemp("logs")
    cfg = write_study(folder)
    with open(folder / "log", "w") as log:
        result = subprocess.run([str(BIN / "wavebrdf"), "run", str(cfg), "--no-render", "-v"], stderr=log,
                                stdout=subprocess.PIPE, text=True)
    assert result.returncode == 0
    return cfg, folder / "logs.h5", (folder / "log").read_text()


def test_log_file_has_no_bar_frames_and_one_timestamped_line_per_task(finished):
    _, _, log = finished
    assert "\r" not in log
    lines = [line for line in log.splitlines() if TASK_LINE.match(line)]
    assert len(lines) == 4, log
    assert {re.search(r"task (\d+)", line).group(1) for line in lines} == {"0", "1", "2", "3"}
    assert any("θ_i 40.0°, φ_i 90.0°" in line for line in lines)


def test_quiet_keeps_task_lines_in_files(tmp_path):
    cfg = write_study(tmp_path)
    with open(tmp_path / "log", "w") as log:
        assert subprocess.run([str(BIN / "wavebrdf"), "-q", "run", str(cfg), "--no-render"], stderr=log,
                              stdout=subprocess.DEVNULL).returncode == 0
    text = (tmp_path / "log").read_text()
    assert "\r" not in text and sum(bool(TASK_LINE.match(line)) for line in text.splitlines()) == 4


def test_rerun_of_a_finished_study_is_a_noop(finished, tmp_path):
    cfg, output, _ = finished
    before = digest(output)
    result = wavebrdf("run", cfg, "--no-render")
    assert result.returncode == 0 and "up to date" in result.stderr
    assert digest(output) == before
    changed = tmp_path / "changed.toml"
    changed.write_text(cfg.read_text().replace("rms_height_um = 0.06", "rms_height_um = 0.07"))
    result = wavebrdf("run", changed, "--output", output, "--no-render")
    assert result.returncode == 2 and "surface.rms_height_um 0.06 -> 0.07" in result.stderr
    assert result.stderr.count("\n") == 1 and digest(output) == before


def test_force_recomputes(tmp_path):
    cfg = write_study(tmp_path, seed=5)
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    with h5py.File(tmp_path / "logs.h5") as h5:
        created = h5.attrs["created"]
    assert main(["run", str(cfg), "-q", "--no-render", "--force"]) == 0
    with h5py.File(tmp_path / "logs.h5") as h5:
        assert set(h5["tasks/status"][()].astype(str)) == {"done"} and "fingerprint" in h5.attrs
        assert h5.attrs["created"] >= created


def test_two_shards_merged_equal_the_unsharded_run(finished, tmp_path):
    _, unsharded, _ = finished
    cfg = tmp_path / "logs.toml"
    cfg.write_text(finished[0].read_text().replace(str(unsharded), str(tmp_path / "logs.h5")))
    for shard in ("0/2", "1/2"):
        assert main(["run", str(cfg), "-q", "--no-render", "--shard", shard]) == 0
    assert not (tmp_path / "logs.h5").exists()
    assert main(["merge", str(cfg), "--no-render"]) == 0
    assert not list(tmp_path.glob("*.parts"))
    with h5py.File(unsharded) as a, h5py.File(tmp_path / "logs.h5") as b:
        for name in ("brdf", "albedo", "albedo_sp", "ior_n", "ior_kappa"):
            x, y = a[name][()], b[name][()]
            assert np.array_equal(np.isnan(x), np.isnan(y))
            assert np.nanmax(np.abs(x - y)) == 0.0, name
        assert set(b["tasks/status"][()].astype(str)) == {"done"}


def test_a_plain_run_takes_the_finished_shards_tasks_and_computes_the_rest(finished, tmp_path, capsys):
    """Shard 1 of 2 ran; a plain ``run`` copies its 2 tasks, computes shard 0's 2 (their task lines
    only) and writes the unsharded run's dataset to the bit; the shard's folder is then removed."""
    _, unsharded, _ = finished
    cfg = tmp_path / "logs.toml"
    cfg.write_text(finished[0].read_text().replace(str(unsharded), str(tmp_path / "logs.h5")))
    assert main(["run", str(cfg), "-q", "--no-render", "--shard", "1/2"]) == 0
    capsys.readouterr()
    assert main(["run", str(cfg), "--no-render"]) == 0
    err = capsys.readouterr().err
    assert "took 2 finished task(s) of 4 from 1 shard folder(s) of 'run --shard i/2'" in err, err
    assert len([line for line in err.splitlines() if TASK_LINE.match(line)]) == 2, err
    assert not list(tmp_path.glob("*.parts"))
    with h5py.File(unsharded) as a, h5py.File(tmp_path / "logs.h5") as b:
        for name in ("brdf", "albedo"):
            assert np.array_equal(a[name][()], b[name][()], equal_nan=True), name
        # how each task ran, the shard's tasks too (kept beside their parts)
        assert np.all(b["tasks/threads"][()] >= 1) and np.all(np.isfinite(b["tasks/kernel_build_s"][()]))


def test_a_plain_run_leaves_another_configurations_shards_and_a_running_shards_folder(tmp_path, capsys):
    """Shard folders of another configuration beside the output are neither taken nor removed (the
    run computes all 4 tasks); a shard of this one whose lock is held (it runs) gives its finished
    tasks but keeps its folder, said so."""
    from wavebrdf.jobs.parts import OutputLock
    from wavebrdf.jobs.shards import shard_output

    cfg = write_study(tmp_path, seed=11)
    assert main(["run", str(cfg), "-q", "--no-render", "--shard", "1/2"]) == 0
    folder = tmp_path / "logs.shard-1-of-2.h5.parts"
    before = sorted(p.name for p in folder.iterdir())
    other = write_study(tmp_path, seed=12)  # the same output, another surface
    capsys.readouterr()
    assert main(["run", str(other), "--no-render"]) == 0
    err = capsys.readouterr().err
    assert "took" not in err and len([line for line in err.splitlines() if TASK_LINE.match(line)]) == 4, err
    assert sorted(p.name for p in folder.iterdir()) == before
    cfg = write_study(tmp_path, seed=11)
    (tmp_path / "logs.h5").unlink()
    with OutputLock(shard_output(tmp_path / "logs.h5", 1, 2)).acquire():
        assert main(["run", str(cfg), "--no-render"]) == 0
    err = capsys.readouterr().err
    assert "took 2 finished task(s) of 4" in err and f"{folder} is left: its shard is running" in err, err
    assert sorted(p.name for p in folder.iterdir()) == before and not list(tmp_path.glob("*.lock"))


def test_merge_waits_for_unfinished_shards(tmp_path, capsys):
    cfg = write_study(tmp_path, seed=9)
    assert main(["run", str(cfg), "-q", "--no-render", "--shard", "1/2"]) == 0
    assert main(["merge", str(cfg), "--if-complete"]) == 0 and not (tmp_path / "logs.h5").exists()
    assert main(["merge", str(cfg)]) == 2
    assert "shard 0: 2 of 2 task(s)" in capsys.readouterr().err


@pytest.mark.mpi
def test_threads_per_rank_under_mpiexec_follow_slurm_cpus_per_task(tmp_path):
    cfg = write_study(tmp_path, seed=4)
    env = {**os.environ, "SLURM_CPUS_PER_TASK": "1"}
    result = subprocess.run([str(BIN / "mpiexec"), "-n", "2", str(BIN / "wavebrdf"), "run", str(cfg), "-q",
                             "--no-render"], env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    with h5py.File(tmp_path / "logs.h5") as h5:
        assert set(h5["tasks/threads"][()]) == {1} and set(h5["tasks/rank"][()]) <= {0, 1}


def test_threads_per_rank_rules():
    from wavebrdf.jobs.node import threads_per_rank

    assert threads_per_rank(4, environ={}, cpus=16) == 4  # the affinity mask shared by the ranks
    assert threads_per_rank(4, environ={"SLURM_CPUS_PER_TASK": "1"}, cpus=16) == 1
    assert threads_per_rank(1, environ={"SLURM_CPUS_PER_TASK": "32"}, cpus=8) == 8  # never more than allowed
    assert threads_per_rank(2, environ={"OMP_NUM_THREADS": "3"}, cpus=16) == 3  # the user's setting
    assert threads_per_rank(2, environ={"OMP_NUM_THREADS": "30"}, cpus=16) == 8
    assert threads_per_rank(64, environ={}, cpus=16) == 1


def test_local_rank_picks_one_gpu_per_rank():
    from wavebrdf.jobs.node import local_rank
    from wavebrdf.solver.opencl import DeviceInfo, choose_device

    assert local_rank({"SLURM_LOCALID": "3"}) == 3 and local_rank({"OMPI_COMM_WORLD_LOCAL_RANK": "1"}) == 1
    assert local_rank({"MPI_LOCALRANKID": "0", "PMI_LOCAL_RANK": "5"}) == 0 and local_rank({}) == 0
    gpus = [DeviceInfo(0, d, "CUDA", "OpenCL 3.0", f"GPU {d}", "GPU", True, 100, 80.0, 20.0) for d in range(4)]
    cpu = DeviceInfo(1, 0, "Portable Computing Language", "OpenCL 3.0 PoCL", "cpu", "CPU", True, 64, 500.0, 100.0)
    assert [choose_device("auto", gpus + [cpu], r).device_index for r in range(6)] == [0, 1, 2, 3, 0, 1]
    assert choose_device("gpu", gpus, 2).device_index == 2
    assert choose_device("cpu", gpus + [cpu], 3) == cpu


@pytest.mark.parametrize("argv", [["-v", "plan", "x"], ["plan", "x", "-v"], ["-q", "run", "x"], ["run", "x", "-q"],
                                  ["run", "-v", "-q", "x"]])
def test_verbosity_flags_before_or_after_the_subcommand(argv):
    args = build_parser().parse_args(argv)
    assert args.verbose == ("-v" in argv) and args.quiet == ("-q" in argv)


def test_krylov_reports_products_and_residual():
    from wavebrdf.solver.krylov import solve

    rng = np.random.default_rng(2)
    n = 60
    A = np.eye(n) * 4 + rng.standard_normal((n, n)) / np.sqrt(n) + 0j
    b = rng.standard_normal((1, n)) + 0j
    seen = []
    result = solve(lambda X: X @ A.T, b, tol=1e-8, progress=lambda stage, fraction, **f: seen.append((stage, f)))
    assert np.linalg.norm(A @ result.x[0] - b[0]) / np.linalg.norm(b) < 1e-7
    assert seen and seen[0][0] == "krylov"
    assert 1 <= seen[0][1]["products"] <= result.iterations[0] and 0 < seen[0][1]["residual"] < 1


def test_stage_lines_are_timestamped_and_bounded(monkeypatch, capsys):
    from wavebrdf.jobs import progress
    from wavebrdf.jobs.config import parse_config
    from wavebrdf.jobs.plan import plan_study

    monkeypatch.setattr(progress, "STAGE_QUIET_S", 0.0)
    plan = plan_study(parse_config(textwrap.dedent(STUDY.format(out="/tmp/x.h5", seed=1)), Path("x.toml")))
    reporter = progress.StageReporter(plan, plan.tasks[1], lines=True)
    reporter("near field", 0.5)
    for products in range(1, 50):
        reporter("krylov", None, products=products, residual=1.0 / products)
    reporter("far field", None)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 3  # one per stage change; the same stage again waits STAGE_INTERVAL_S
    assert all(re.match(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d task 1 running: ", line) for line in lines)
    assert "krylov, 1 products, residual 1.00e+00" in lines[1] and "plan ~" in lines[1] and "GiB" in lines[1]


FIBER = """
[study]
name = "fib"
output = "{out}"
[fiber]
shape = "ellipse"
semi_axes_um = [0.4, 0.25]
segments = 32
[material]
n = 1.55
[illumination]
wavelengths_um = [0.5]
theta_i_deg = [0, 30]
[model]
name = "fiber-bem"
[output]
phi_i_bins = 12
phi_r_bins = 36
[run]
executor = "processes"
"""


def test_plan_phi_column_for_fibers_and_workers_as_run(tmp_path, capsys):
    cfg = tmp_path / "fib.toml"
    cfg.write_text(textwrap.dedent(FIBER.format(out=tmp_path / "fib.h5")))
    assert main(["plan", str(cfg)]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if re.match(r"\s+\d+ fiber", line)]
    assert len(rows) == 2 and all(line.split()[5:7] == ["all", "12"] for line in rows), out
    cpus = len(os.sched_getaffinity(0))  # what `run --executor processes` uses without --workers
    assert f"on {cpus} worker(s)" in out


def test_angles_are_printed_with_the_digits_that_tell_them_apart():
    """89.9999° (a near-grazing study) must not read as 90.00° in ``plan`` or 90.0° in progress
    lines; rounding noise of a degree-radian round trip must not add digits."""
    from wavebrdf.jobs.progress import degrees_text

    assert degrees_text(89.9999, 2) == "89.9999" and degrees_text(89.9999, 1) == "89.9999"
    assert degrees_text(89.999998, 2) == "89.999998" and degrees_text(1.23e-5, 2) == "0.000012"
    assert degrees_text(float(np.rad2deg(np.deg2rad(30.0))), 2) == "30.00"
    assert degrees_text(12.25, 1) == "12.25" and degrees_text(40.0, 1) == "40.0"
