"""MPI start overhead and kernel builds: ``wavebrdf run CONFIG`` serial vs ``mpiexec -n N``, each
from a cold kernel cache, with the node-shared cache (now) and with one cache per rank (before
issue 19, emulated by giving each rank its own ``POCL_CACHE_DIR``).

    python benchmarks/bench_mpi_start.py [CONFIG] [--ranks 2 8] [--repeat 1]

Prints per run: wall time, and the kernel build time per rank (program builds plus kernels'
first launches, summed over the rank's tasks: the dataset's ``tasks/kernel_build_s``), its mean
over ranks, and the ratio per-rank caches / shared cache. Run under ``nice``, nothing else busy.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

BIN = Path(sys.executable).parent


def run(config: str, ranks: int, per_rank_cache: bool, scratch: Path) -> tuple[float, float]:
    """(wall s, mean kernel build s per rank) of one cold run."""
    cache = scratch / "cache"
    shutil.rmtree(cache, ignore_errors=True)
    output = scratch / "bench.h5"
    for p in scratch.glob("bench.h5*"):
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    env = {**os.environ, "POCL_CACHE_DIR": str(cache)}
    command = [str(BIN / "wavebrdf"), "run", config, "-o", str(output), "-q", "--no-render"]
    if ranks > 1:
        if per_rank_cache:  # the old layout: $POCL_CACHE_DIR/rank-<r>
            command = ["bash", "-c", f'POCL_CACHE_DIR="{cache}/rank-$PMI_RANK" exec "$@"', "rank"] + command
        command = [str(BIN / "mpiexec"), "-n", str(ranks)] + command
    t0 = time.perf_counter()
    subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    with h5py.File(output, "r") as h5:
        build = h5["tasks/kernel_build_s"][()]
        rank = h5["tasks/rank"][()] if "rank" in h5["tasks"] else np.zeros(len(build), dtype=int)
    per_rank = [build[rank == r].sum() for r in np.unique(rank)]
    return wall, float(np.mean(per_rank))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("config", nargs="?", default="configs/default.toml")
    parser.add_argument("--ranks", type=int, nargs="+", default=[2, 8])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        wall, build = run(args.config, 1, False, scratch)
        print(f"serial            : wall {wall:6.2f} s, kernel build {build:5.2f} s")
        for n in args.ranks:
            old = run(args.config, n, True, scratch)
            new = run(args.config, n, False, scratch)
            print(f"mpiexec -n {n}, per-rank caches (before): wall {old[0]:6.2f} s, kernel build per rank "
                  f"{old[1]:5.2f} s")
            print(f"mpiexec -n {n}, shared cache   (now)   : wall {new[0]:6.2f} s, kernel build per rank "
                  f"{new[1]:5.2f} s; ratio before/now {old[1] / max(new[1], 1e-9):.2f}, wall {old[0] / new[0]:.2f}")


if __name__ == "__main__":
    main()
