"""Batch-layer benchmark (issue 5): parallel efficiency of 1 vs 2 MPI ranks on a many-task study,
and the coordinator's overhead per task.

    python benchmarks/bench_batch.py [--tasks 16] [--cells 400] [--resolution 1024]
    wavebrdf bench batch

Runs the same Kirchhoff study (tasks of about a second each) three ways in one go:
  serial, 1 thread      (POCL_MAX_PTHREAD_COUNT = FFT workers = 1)
  serial, all threads   (one process using both cores through PoCL/FFT threads)
  mpiexec -n 2          (task parallelism: each rank 1 thread; rank 0 also coordinates)
Parallel efficiency = T(serial, 1 thread) / (2 · T(2 ranks)). Overhead per task = the workers'
mean wait between asking for a task and receiving it (``dispatch_wait_s`` in the task table),
relative to the mean task time.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np

BIN = Path(sys.executable).parent
STUDY = """
[study]
name = "bench-batch"
output = "{out}"
[surface]
generator = "gaussian"
size_um = 12.5
cells = {cells}
rms_height_um = 0.09
correlation_um = 1.8
[material]
name = "aluminium"
[illumination]
wavelengths_um = {wavelengths}
directions_deg = [[0, 0], [30, 0], [45, 90], [60, 180]]
waist_um = 2.3
[model]
name = "kirchhoff"
[output]
resolution = {resolution}
"""


def run(cmd, env):
    t0 = time.perf_counter()
    result = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(result.stderr[-2000:])
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", type=int, default=16, help="multiple of 4 (4 directions per wavelength)")
    parser.add_argument("--cells", type=int, default=400)
    parser.add_argument("--resolution", type=int, default=1024)
    args = parser.parse_args()
    n_wl = max(1, args.tasks // 4)
    wavelengths = [round(float(x), 4) for x in np.linspace(0.42, 0.68, n_wl)]
    folder = Path(tempfile.mkdtemp(prefix="bench-batch-"))
    base_env = {**os.environ, "PATH": f"{BIN}:{os.environ['PATH']}"}
    one_thread = {**base_env, "POCL_MAX_PTHREAD_COUNT": "1", "WAVEBRDF_FFT_WORKERS": "1", "OMP_NUM_THREADS": "1"}
    wavebrdf = str(BIN / "wavebrdf")
    times = {}
    for label, env, prefix in (
        ("serial, 1 thread", one_thread, []),
        ("serial, all threads", base_env, []),
        ("mpiexec -n 2", base_env, [str(BIN / "mpiexec"), "-n", "2"]),
    ):
        cfg = folder / f"{label.replace(' ', '_').replace(',', '')}.toml"
        out = cfg.with_suffix(".h5")
        cfg.write_text(textwrap.dedent(STUDY.format(out=out, cells=args.cells, wavelengths=wavelengths,
                                                    resolution=args.resolution)))
        times[label] = run(prefix + [wavebrdf, "run", str(cfg), "-q", "--no-render"], env)
        with h5py.File(out, "r") as h5:
            task_time = h5["tasks/wall_time_s"][()]
            wait = h5["tasks/dispatch_wait_s"][()] if "dispatch_wait_s" in h5["tasks"] else None
        print(f"{label:22s} wall {times[label]:7.2f} s   {len(task_time)} tasks, mean task {task_time.mean():.2f} s")
        if wait is not None:
            steady = np.sort(wait)[:-2]  # the first request of each rank also waits for start-up
            print(f"{'':22s} coordinator round trip per task: mean {steady.mean() * 1e3:.2f} ms "
                  f"({100 * steady.mean() / task_time.mean():.3f} % of the mean task time)")
    t1, t2 = times["serial, 1 thread"], times["mpiexec -n 2"]
    print(f"parallel efficiency 1 -> 2 ranks: {t1 / (2 * t2):.2f} (speed-up {t1 / t2:.2f}x); "
          f"2 ranks vs one 2-thread process: {times['serial, all threads'] / t2:.2f}x")


if __name__ == "__main__":
    main()
