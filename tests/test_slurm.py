"""`wavebrdf submit` scripts under a real SLURM (VALIDATION.md item 11; docs/batch.md): the scripts
are submitted with `sbatch` unmodified, on the single-node SLURM of tools/slurm-local.sh.

* 2 MPI ranks under `srun` and a 2-job array with its merge give the serial run's dataset bit for
  bit, pictures included;
* USR1 (what `--signal=B:USR1@lead` sends before the time limit) stops every rank cleanly (each
  says so and exits 143, nothing aborts), requeues the job, and the second attempt resumes: the
  dataset equals the serial one and the first attempt's log lines are still at the top of the log;
* a real time limit does the same on its own;
* with `--no-requeue` the stopped job ends FAILED with the ranks' status 143 (the study is
  unfinished), and submitting the script again finishes it.

    sudo bash tools/slurm-local.sh && .venv/bin/python -m pytest -m slurm tests/test_slurm.py

Slow (a requeued job waits SLURM's two minutes before it starts again): deselected with `slow`.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from test_scheduler import write_study
from wavebrdf.jobs.cli import main

pytestmark = [pytest.mark.slurm, pytest.mark.slow]
BIN = Path(sys.executable).parent
TASK_LINE = re.compile(r"\[\d+/\d+\] task (\d+) ")


@pytest.fixture(scope="module", autouse=True)
def slurm():
    """A SLURM that takes jobs: a missing one fails (these tests are what it is for)."""
    if shutil.which("sbatch") is None:
        pytest.fail("sbatch is not installed: sudo bash tools/slurm-local.sh")
    state = subprocess.run(["sinfo", "-h", "-N", "-o", "%t"], capture_output=True, text=True)
    if state.returncode != 0 or not state.stdout.split() or state.stdout.split()[0] not in ("idle", "mix", "alloc"):
        pytest.fail(f"no SLURM node takes jobs (sinfo: {state.stdout.strip() or state.stderr.strip()}): "
                    "sudo bash tools/slurm-local.sh")


def study(folder: Path, model: str = "kirchhoff", seeds: int = 2) -> Path:
    """tests/test_scheduler.py's study (3 λ × 4 directions × ``seeds`` surfaces)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = write_study(folder, "batch", model=model)
    path.write_text(path.read_text().replace('"surface.seed" = [1, 2]', f'"surface.seed" = {list(range(1, seeds + 1))}'))
    return path


def small_bem_study(folder: Path, seeds: int) -> Path:
    """The full wave on 2 µm patches (40² cells, waist 0.5 µm, λ 0.55 µm, 4 directions per
    surface): about 40 s for a surface's first direction (its factorization), 5 s for each other."""
    path = study(folder, model="bem", seeds=seeds)
    text = path.read_text()
    for old, new in (("size_um = 6.0", "size_um = 2.0"), ("cells = 96", "cells = 40"), ("waist_um = 1.1", "waist_um = 0.5"),
                     ("wavelengths_um = [0.45, 0.55, 0.65]", "wavelengths_um = [0.55]"),
                     ("resolution = 96", "resolution = 48")):
        assert old in text
        text = text.replace(old, new)
    path.write_text(text)
    return path


def serial(folder: Path, make=None, **kwargs) -> dict:
    path = (make or study)(folder, **kwargs)
    assert main(["run", str(path), "-q", "--no-render"]) == 0
    return read(folder / "batch.h5")


def read(path: Path) -> dict:
    with h5py.File(path) as h5:
        return {"brdf": h5["brdf"][()], "albedo": h5["albedo"][()]}


def assert_bit_identical(a: dict, b: dict) -> None:
    for key in ("brdf", "albedo"):
        assert a[key].shape == b[key].shape and np.array_equal(a[key], b[key], equal_nan=True), key


def submit(path: Path, *argv: str) -> tuple[str, Path]:
    """Write the script with `wavebrdf submit` and `sbatch` it from its folder: (job id, script)."""
    script = path.parent / "job.sh"
    assert main(["submit", str(path), "--script", str(script), *argv]) == 0
    out = subprocess.run(["sbatch", "--parsable", script.name], cwd=path.parent, capture_output=True, text=True,
                         check=True)
    return out.stdout.strip().split(";")[0], script


def job(job_id: str) -> list[dict[str, str]]:
    """`scontrol show job`: one record per job (an array's: one per array task)."""
    text = subprocess.run(["scontrol", "show", "job", job_id], capture_output=True, text=True).stdout
    return [dict(re.findall(r"(\w+)=(\S*)", record)) for record in text.split("\n\n") if "JobState=" in record]


def wait_for(job_id: str, states=("COMPLETED", "FAILED", "CANCELLED", "TIMEOUT"), timeout: float = 900) -> dict:
    """The job's record once it (every task of an array) is in one of ``states``; for an array,
    the last task's record with the worst state and exit code of all."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        records = job(job_id)
        if records and all(r.get("JobState") in states for r in records):
            worst = max(records, key=lambda r: (r["JobState"] != "COMPLETED", r.get("ExitCode") != "0:0"))
            return worst
        time.sleep(2)
    subprocess.run(["scancel", job_id])
    pytest.fail(f"job {job_id} still {[r.get('JobState') for r in job(job_id)]} after {timeout:.0f} s")


def wait_for_parts(folder: Path, count: int, timeout: float = 300) -> int:
    deadline = time.time() + timeout
    while time.time() < deadline:
        done = len(list((folder / "batch.h5.parts").glob("task-*.npz")))
        if done >= count:
            return done
        time.sleep(0.5)
    pytest.fail(f"fewer than {count} tasks finished in {timeout:.0f} s")


def logs(folder: Path) -> str:
    return "".join(p.read_text() for p in sorted(folder.glob("batch-*.log")))


def test_two_ranks_and_an_array_with_its_merge_equal_the_serial_run(tmp_path):
    reference = serial(tmp_path / "serial")
    ranks, _ = submit(study(tmp_path / "ranks"), "--time", "10:00", "--ntasks-per-node", "2", "--cpus-per-task", "1")
    array, _ = submit(study(tmp_path / "array"), "--time", "10:00", "--array", "2", "--ntasks-per-node", "1")
    for job_id, folder in ((ranks, tmp_path / "ranks"), (array, tmp_path / "array")):
        info = wait_for(job_id)
        assert (info["JobState"], info["ExitCode"]) == ("COMPLETED", "0:0"), logs(folder)
    assert "2 MPI ranks" in logs(tmp_path / "ranks")
    for folder in (tmp_path / "ranks", tmp_path / "array"):
        assert_bit_identical(read(folder / "batch.h5"), reference)
        assert list((folder / "batch_png").glob("*.png")), logs(folder)


def test_usr1_stops_every_rank_cleanly_and_the_requeued_job_resumes_with_the_whole_log(tmp_path):
    reference = serial(tmp_path / "serial", model="po", seeds=4)
    folder = tmp_path / "run"
    job_id, _ = submit(study(folder, model="po", seeds=4), "--time", "30:00", "--ntasks-per-node", "2",
                       "--cpus-per-task", "1")
    wait_for_parts(folder, 4)
    t0 = time.time()
    subprocess.run(["scancel", "--signal=USR1", "--batch", job_id], check=True)
    info = wait_for(job_id, states=("PENDING",), timeout=120)
    stopped_in = time.time() - t0
    first = logs(folder)
    assert info["Restarts"] == "1" and "wavebrdf: requeueing job" in first, first
    for rank in (0, 1):
        assert f"wavebrdf: stopped by SIGTERM (rank {rank})" in first, first
    assert "Exited with exit code 143" in first and "the ranks stopped (exit status 143)" in first, first
    assert "MPI_Abort" not in first and "error on rank" not in first and "Killed" not in first, first
    first_tasks = set(TASK_LINE.findall(first))
    info = wait_for(job_id, timeout=600)
    final = logs(folder)
    assert (info["JobState"], info["ExitCode"]) == ("COMPLETED", "0:0"), final
    assert final.startswith(first)  # --open-mode=append: the first attempt's lines kept
    second_tasks = set(TASK_LINE.findall(final[len(first):]))
    assert first_tasks and second_tasks and not first_tasks & second_tasks  # resumed, nothing run twice
    assert len(first_tasks | second_tasks) == 48
    assert_bit_identical(read(folder / "batch.h5"), reference)
    assert list((folder / "batch_png").glob("*.png"))
    print(f"USR1: ranks stopped and job requeued {stopped_in:.1f} s after the signal; log lines "
          f"{first.count(chr(10))} before the requeue, {final.count(chr(10))} after; tasks {len(first_tasks)} + "
          f"{len(second_tasks)}")


def test_a_real_time_limit_requeues_until_the_study_is_done(tmp_path):
    """--time 3 (min) and a few minutes of full-wave solves on 2 ranks: SLURM's own USR1
    (36 s before the limit, or up to 60 s earlier) stops and requeues the job until it is done."""
    reference = serial(tmp_path / "serial", make=small_bem_study, seeds=4)
    folder = tmp_path / "run"
    job_id, _ = submit(small_bem_study(folder, seeds=4), "--time", "3", "--ntasks-per-node", "2", "--cpus-per-task", "1")
    t0 = time.time()
    info = wait_for(job_id, timeout=2400)
    text = logs(folder)
    assert (info["JobState"], info["ExitCode"]) == ("COMPLETED", "0:0"), text
    assert int(info["Restarts"]) >= 1 and text.count("wavebrdf: requeueing job") == int(info["Restarts"]), text
    assert text.count("wavebrdf: time limit near") == int(info["Restarts"]), text
    assert "MPI_Abort" not in text and "error on rank" not in text and "TIME LIMIT" not in text, text
    assert_bit_identical(read(folder / "batch.h5"), reference)
    assert list((folder / "batch_png").glob("*.png"))
    print(f"time limit: {info['Restarts']} requeue(s), {time.time() - t0:.0f} s from submission to completion")


def test_no_requeue_ends_failed_with_status_143_and_a_second_submission_finishes(tmp_path):
    reference = serial(tmp_path / "serial", model="po", seeds=4)
    folder = tmp_path / "run"
    job_id, script = submit(study(folder, model="po", seeds=4), "--time", "30:00", "--ntasks-per-node", "2",
                            "--cpus-per-task", "1", "--no-requeue")
    wait_for_parts(folder, 4)
    subprocess.run(["scancel", "--signal=USR1", "--batch", job_id], check=True)
    info = wait_for(job_id)
    text = logs(folder)
    assert (info["JobState"], info["ExitCode"]) == ("FAILED", "143:0"), text
    assert "is not requeued (--no-requeue): the study is unfinished" in text and "requeueing" not in text, text
    again = subprocess.run(["sbatch", "--parsable", script.name], cwd=folder, capture_output=True, text=True,
                           check=True).stdout.strip()
    info = wait_for(again)
    assert (info["JobState"], info["ExitCode"]) == ("COMPLETED", "0:0"), logs(folder)
    assert_bit_identical(read(folder / "batch.h5"), reference)


def test_submit_reads_the_partitions_from_the_clusters_sinfo(tmp_path, capsys):
    """tools/slurm-local.sh's one partition, debug, has no time limit: any --time is taken without
    a word; a partition it does not list is warned of (the script may be for another cluster)."""
    path = study(tmp_path)
    assert main(["submit", str(path), "--time", "30-00:00:00", "--script", str(tmp_path / "a.sh")]) == 0
    assert "warning" not in capsys.readouterr().err
    assert main(["submit", str(path), "--time", "10", "--partition", "nope", "--script", str(tmp_path / "b.sh")]) == 0
    assert "nope is not a partition of this machine's SLURM (sinfo: debug)" in capsys.readouterr().err
