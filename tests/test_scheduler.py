"""Execution: resume after SIGKILL, MPI = serial, processes = serial, failures and retries,
`wavebrdf plan` and `wavebrdf submit` (VALIDATION.md item 11)."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from wavebrdf.jobs.cli import main
from wavebrdf.solver import models
from wavebrdf.solver.approx.kirchhoff import KirchhoffModel

BIN = Path(sys.executable).parent
STUDY = """
[study]
name = "batch"
output = "{out}"

[surface]
generator = "gaussian"
size_um = 6.0
cells = 96
rms_height_um = 0.06
correlation_um = 0.8

[material]
name = "gold"

[illumination]
wavelengths_um = [0.45, 0.55, 0.65]
directions_deg = [[0, 0], [20, 10], [40, 90], [60, 200]]
waist_um = 1.1

[model]
name = "{model}"

[output]
resolution = 96

[sweep]
"surface.seed" = [1, 2]
{extra}
"""


def write_study(folder: Path, name: str, model: str = "kirchhoff", extra: str = "") -> Path:
    path = folder / f"{name}.toml"
    path.write_text(textwrap.dedent(STUDY.format(out=folder / f"{name}.h5", model=model, extra=extra)))
    return path


def read(path: Path) -> dict:
    with h5py.File(path, "r") as h5:
        tasks = h5["tasks"]
        return {
            "brdf": h5["brdf"][()], "albedo": h5["albedo"][()],
            "ids": tasks["id"][()], "status": tasks["status"][()].astype(str),
        }


@pytest.fixture(scope="module")
def serial_reference(tmp_path_factory):
    folder = tmp_path_factory.mktemp("serial")
    cfg = write_study(folder, "batch")
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    return read(folder / "batch.h5")


def assert_same(a: dict, b: dict):
    assert sorted(a["ids"]) == sorted(b["ids"]) and len(set(a["ids"])) == len(a["ids"])
    assert set(a["status"]) == set(b["status"]) == {"done"}
    scale = np.nanmax(np.abs(b["brdf"]))
    assert np.allclose(a["brdf"], b["brdf"], rtol=1e-12, atol=1e-12 * scale, equal_nan=True)
    assert np.allclose(a["albedo"], b["albedo"], rtol=1e-12)


def test_resume_after_sigkill(tmp_path, serial_reference):
    """Kill a run at a random task, re-run the same command: nothing missing, nothing twice."""
    cfg = write_study(tmp_path, "batch")
    parts = tmp_path / "batch.h5.parts"
    stop_after = random.Random().randint(2, 18)  # 24 tasks in all
    cmd = [str(BIN / "wavebrdf"), "run", str(cfg), "-q", "--no-render"]
    proc = subprocess.Popen(cmd, start_new_session=True)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if parts.is_dir() and len(list(parts.glob("task-*.npz"))) >= stop_after:
            break
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (tmp_path / "batch.h5").exists() or proc.returncode == 0
    finished_before = len(list(parts.glob("task-*.npz"))) if parts.is_dir() else 0
    assert 0 < finished_before < 24, finished_before
    rerun = subprocess.run(cmd, capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr
    assert not parts.exists()
    assert_same(read(tmp_path / "batch.h5"), serial_reference)


def stop_with_sigterm(tmp_path, cmd: list[str], env=None) -> subprocess.CompletedProcess:
    """Start ``cmd`` on the 48-task po study, SIGTERM its process group (every rank, as a batch
    system's clean stop does) once 4 tasks are done; its outcome."""
    parts = tmp_path / "batch.h5.parts"
    proc = subprocess.Popen(cmd, start_new_session=True, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if parts.is_dir() and len(list(parts.glob("task-*.npz"))) >= 4:
            break
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(cmd, proc.returncode, "", err)


def po_study(tmp_path) -> Path:
    cfg = write_study(tmp_path, "batch", model="po")
    cfg.write_text(cfg.read_text().replace('"surface.seed" = [1, 2]', '"surface.seed" = [1, 2, 3, 4]'))
    return cfg


def test_sigterm_stops_with_status_143_and_the_same_command_resumes(tmp_path):
    cfg = po_study(tmp_path)
    cmd = [str(BIN / "wavebrdf"), "run", str(cfg), "-q", "--no-render"]
    stopped = stop_with_sigterm(tmp_path, cmd)
    assert stopped.returncode == 143, stopped.stderr
    assert "wavebrdf: stopped by SIGTERM; finished tasks are kept" in stopped.stderr
    done = len(list((tmp_path / "batch.h5.parts").glob("task-*.npz")))
    assert 4 <= done < 48 and not (tmp_path / "batch.h5").exists()
    assert subprocess.run(cmd, capture_output=True).returncode == 0
    assert not (tmp_path / "batch.h5.parts").exists()


@pytest.mark.mpi
def test_sigterm_to_every_rank_stops_each_cleanly_without_an_abort(tmp_path):
    cfg = po_study(tmp_path)
    env = {**os.environ, "PATH": f"{BIN}:{os.environ['PATH']}"}
    cmd = [str(BIN / "mpiexec"), "-n", "2", str(BIN / "wavebrdf"), "run", str(cfg), "-q", "--no-render"]
    stopped = stop_with_sigterm(tmp_path, cmd, env)
    for rank in (0, 1):
        assert f"wavebrdf: stopped by SIGTERM (rank {rank})" in stopped.stderr, stopped.stderr
    assert "error on rank" not in stopped.stderr and "MPI_Abort" not in stopped.stderr, stopped.stderr
    assert subprocess.run(cmd, capture_output=True, env=env, timeout=600).returncode == 0
    assert (tmp_path / "batch.h5").is_file() and not (tmp_path / "batch.h5.parts").exists()


def test_a_finished_study_without_its_pictures_gets_them_on_the_next_run(tmp_path, capsys):
    """A stop while the pictures were drawn leaves the dataset and no picture folder (it is moved
    into place whole): the next run says "up to date" and draws them; one more run draws nothing."""
    cfg = write_study(tmp_path, "batch")
    assert main(["run", str(cfg), "-q", "--no-render"]) == 0
    assert not (tmp_path / "batch_png").exists()
    capsys.readouterr()
    assert main(["run", str(cfg), "-q"]) == 0
    out, err = capsys.readouterr()
    assert "is up to date" in err and "wrote" in out and list((tmp_path / "batch_png").glob("*.png"))
    assert main(["run", str(cfg), "-q"]) == 0
    assert "wrote" not in capsys.readouterr().out


def test_changed_config_is_refused_on_resume(tmp_path):
    cfg = write_study(tmp_path, "batch")
    parts = tmp_path / "batch.h5.parts"
    parts.mkdir()
    (parts / "manifest.json").write_text('{"fingerprint": "0123456789abcdef0123", "tasks": 24}')
    code = main(["run", str(cfg), "-q", "--no-render"])
    assert code == 2 and not (tmp_path / "batch.h5").exists()


@pytest.mark.mpi
def test_mpiexec_three_ranks_equals_serial(tmp_path, serial_reference):
    cfg = write_study(tmp_path, "batch")
    env = {**os.environ, "PATH": f"{BIN}:{os.environ['PATH']}"}
    result = subprocess.run([str(BIN / "mpiexec"), "-n", "3", str(BIN / "wavebrdf"), "run", str(cfg), "-q",
                             "--no-render"], capture_output=True, text=True, env=env, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "3 MPI ranks" in result.stderr
    assert_same(read(tmp_path / "batch.h5"), serial_reference)


def test_local_processes_equal_serial(tmp_path, serial_reference):
    cfg = write_study(tmp_path, "batch")
    assert main(["run", str(cfg), "-q", "--no-render", "--executor", "processes", "--workers", "2"]) == 0
    assert_same(read(tmp_path / "batch.h5"), serial_reference)


class FlakyModel(KirchhoffModel):
    """Fails the first attempt at θ_i = 20° (retried), always fails at θ_i = 40° on case 1."""

    name = "flaky-test"
    seen: set = set()

    def run(self, ctx, scene):
        theta = round(float(np.rad2deg(scene.theta_i)))
        key = (theta, round(scene.wavelength_um, 3), float(scene.surface.z[3, 3]))
        if theta == 20 and key not in FlakyModel.seen:
            FlakyModel.seen.add(key)
            raise RuntimeError("transient failure (first attempt)")
        if theta == 40 and scene.wavelength_um == 0.55 and scene.surface.z[0, 0] == self.case1_z00:
            error = RuntimeError("solver did not converge")
            error.diagnostics = {"iterations": 500, "residual": 3e-2}
            raise error
        return super().run(ctx, scene)


def test_failed_tasks_are_retried_recorded_and_rerun(tmp_path, monkeypatch):
    monkeypatch.setitem(models._REGISTRY, "flaky-test", f"{__name__}:FlakyModel")  # gone after the test
    cfg = write_study(tmp_path, "flaky", model="flaky-test")
    from wavebrdf.jobs.config import load_config

    config = load_config(cfg)
    FlakyModel.case1_z00 = float(config.cases[1].surface.build().z[0, 0])
    FlakyModel.seen = set()
    code = main(["run", str(cfg), "-q", "--no-render"])
    assert code == 1
    out = tmp_path / "flaky.h5"
    with h5py.File(out, "r") as h5:
        status = h5["tasks/status"][()].astype(str)
        assert list(status).count("failed") == 1
        failed = int(np.flatnonzero(status == "failed")[0])
        assert "did not converge" in h5["tasks/error"][failed].decode()
        assert h5["tasks/iterations"][failed] == 500 and h5["tasks/attempts"][failed] == 2
        assert np.all(np.isnan(h5["brdf"][1, 1, 2]))  # case 1, λ 0.55, incidence 2: never written
        assert np.isfinite(h5["albedo"][()]).sum() == 23
    assert (tmp_path / "flaky.h5.parts").is_dir()
    FlakyModel.case1_z00 = None  # the "solver" converges now: the re-run retries only that task
    assert main(["-v", "run", str(cfg), "-q", "--no-render"]) == 0
    with h5py.File(out, "r") as h5:
        assert set(h5["tasks/status"][()].astype(str)) == {"done"} and np.all(np.isfinite(h5["albedo"][()]))


def test_plan_prints_estimates_fast(tmp_path):
    cfg = Path(__file__).resolve().parent.parent / "configs" / "default.toml"
    t0 = time.perf_counter()
    result = subprocess.run([str(BIN / "wavebrdf"), "plan", str(cfg)], capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    assert result.returncode == 0, result.stderr
    assert "total: 9 tasks" in result.stdout and "memory (GiB)" in result.stdout
    print(f"wavebrdf plan took {elapsed:.2f} s")


def test_plan_refuses_what_does_not_fit(tmp_path, capsys):
    cfg = write_study(tmp_path, "batch", extra="\n[run]\nmemory_gb = 0.01\n")
    assert main(["plan", str(cfg)]) == 2
    assert "more than the node's" in capsys.readouterr().err


def test_submit_writes_valid_bash(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = write_study(tmp_path, "batch")
    assert main(["submit", str(cfg), "--nodes", "2", "--time", "01:30", "--ntasks-per-node", "4"]) == 0
    script = tmp_path / "batch.slurm.sh"
    text = script.read_text()
    assert "#SBATCH --nodes=2" in text and "srun --mpi=list" in text and f"run {cfg}" in text
    assert subprocess.run(["bash", "-n", str(script)]).returncode == 0
    assert main(["submit", str(cfg), "--nodes", "1", "--time", "90 minutes"]) == 2


def test_a_worker_caps_the_blas_threads_already_loaded():
    """numpy and scipy start their OpenBLAS thread pools at import, before a worker's environment
    is applied: apply_worker_environment must cap them too (an uncapped pool spins on the other
    workers' cores: measured 5-6x slower near-field LU under --executor processes)."""
    probe = ("import numpy, scipy.linalg, scipy.sparse.linalg\n"
             "from threadpoolctl import threadpool_info\n"
             "from wavebrdf.jobs.node import apply_worker_environment, worker_environment\n"
             "apply_worker_environment(worker_environment(2, 0, cores=2))\n"
             "print(sorted({p['num_threads'] for p in threadpool_info()}), len(threadpool_info()))\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    threads, pools = out.stdout.split("]")
    assert threads + "]" == "[1]" and int(pools) >= 2, out.stdout
