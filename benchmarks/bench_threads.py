"""Threads of a run's worker processes: how many exist and how many run at once.

    python benchmarks/bench_threads.py wavebrdf run configs/bem_aim_aluminium.toml \\
        --executor processes --workers 2 --no-render -q -o /tmp/threads.h5

Runs the command and samples every 5 ms the threads of its child processes from /proc (state R =
running). Prints the wall time and, per worker, the most threads it had, the most running at one
sample and the share of samples with more than one running: a worker capped to one thread
(``worker_environment``) shows at most 2 briefly (its main thread handing a kernel to PoCL's).
Linux only.
"""

from __future__ import annotations

import collections
import os
import subprocess
import sys
import time


def _state_and_parent(path: str) -> tuple[str, int]:
    with open(path) as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return fields[0], int(fields[1])


def main(command: list[str]) -> None:
    t0 = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    stats = collections.defaultdict(lambda: {"samples": 0, "max_running": 0, "multi": 0, "max_threads": 0})
    while proc.poll() is None:
        for pid in (p for p in os.listdir("/proc") if p.isdigit()):
            try:
                if _state_and_parent(f"/proc/{pid}/stat")[1] != proc.pid:
                    continue
                tasks = os.listdir(f"/proc/{pid}/task")
                running = sum(_state_and_parent(f"/proc/{pid}/task/{t}/stat")[0] == "R" for t in tasks)
            except OSError:  # the thread or process ended meanwhile
                continue
            s = stats[pid]
            s["samples"] += 1
            s["max_running"] = max(s["max_running"], running)
            s["multi"] += running > 1
            s["max_threads"] = max(s["max_threads"], len(tasks))
        time.sleep(0.005)
    print(f"exit {proc.returncode}, wall {time.perf_counter() - t0:.1f} s")
    for pid, s in stats.items():
        if s["samples"] > 20:
            print(f"worker {pid}: {s['max_threads']} threads at most, {s['max_running']} running at once at most, "
                  f"more than one running in {s['multi'] / s['samples']:.1%} of {s['samples']} samples")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    main(sys.argv[1:])
