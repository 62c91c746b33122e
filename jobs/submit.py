"""``wavebrdf submit``: a SLURM (or PBS) batch script for a study, sized from its plan.

The script is ``jobs/templates/<scheduler>.sh`` (with ``prelude.sh`` at ``@PRELUDE@``) with its
``@NAME@`` fields filled in:

- **time**: ``--time`` read as SLURM reads it (:func:`parse_duration`), written as
  ``D-HH:MM:SS``, with a warning when it is shorter than the plan's estimate, and one where the
  ``sinfo`` of this machine's SLURM says it exceeds the partition's limit (:func:`check_partition_time`);
- **layout**: ranks per node and threads per rank from the plan's largest task, the node's
  cores and memory (``--cores-per-node``, ``--memory-gb``), or as given; one rank per GPU with
  ``--gpus-per-node`` (each rank takes the GPU of its local rank); ``--mem`` from the plan;
- **clean stop**: ``--signal=B:USR1@<lead>`` and ``--requeue``: the script passes SIGTERM to
  every rank through the launcher, the ranks stop (exit status 143, finished tasks kept) and the
  job is requeued, appending to its log (``--open-mode=append``), and resumes from the parts
  folder; with ``--no-requeue`` the job ends with the ranks' status (not 0: unfinished);
- **launcher**: ``srun`` with the MPI plugin the cluster offers (pmi2, else pmix; detected
  when the job starts), or ``mpiexec``; a prologue (module loads, venv activation) from
  ``[run] prologue`` or ``--prologue``;
- **array sharding** (``--array K``): K independent jobs, each ``run --shard i/K``; the last
  to finish merges the shards into the dataset (``wavebrdf merge``, jobs/shards.py).

Every string option that reaches the script is checked first (:func:`check_script_options`), and
ranks without mpi4py are refused here, not by the queued job.
"""

from __future__ import annotations

import math
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from wavebrdf.jobs.config import ConfigError, load_config
from wavebrdf.jobs.plan import estimate_tasks, node_memory_bytes, plan_study

__all__ = ["Layout", "add_submit_parser", "check_script_options", "choose_layout", "cmd_submit", "parse_duration",
           "render_script", "slurm_duration"]

RANK_BASE_BYTES = 0.5 * 2**30  # a rank's memory besides its task: Python, NumPy, OpenCL runtime (measured ~0.4 GiB)
MEMORY_SLACK = 1.15  # --mem = ranks x (largest task + base) x this
START_S = 60.0  # start-up of a job (ranks, imports, kernels from the cache) in the wall-time check
SIGNAL_LEAD_S = 300  # USR1 this long before the time limit
SLURM_SIGNAL_EARLY_S = 60  # sbatch(1) --signal: "may be sent up to 60 seconds earlier than specified"

_DURATION = [  # SLURM's --time formats
    (re.compile(r"(\d+)"), ("m",)),
    (re.compile(r"(\d+):(\d+)"), ("m", "s")),
    (re.compile(r"(\d+):(\d+):(\d+)"), ("h", "m", "s")),
    (re.compile(r"(\d+)-(\d+)"), ("d", "h")),
    (re.compile(r"(\d+)-(\d+):(\d+)"), ("d", "h", "m")),
    (re.compile(r"(\d+)-(\d+):(\d+):(\d+)"), ("d", "h", "m", "s")),
]
_UNIT_S = {"d": 86400, "h": 3600, "m": 60, "s": 1}


def parse_duration(text: str) -> int:
    """Seconds of a SLURM time limit: "minutes", "minutes:seconds", "hours:minutes:seconds",
    "days-hours", "days-hours:minutes" or "days-hours:minutes:seconds" (so "01:00" is one
    minute). ConfigError naming ``--time`` otherwise."""
    value = str(text).strip()
    for pattern, units in _DURATION:
        match = pattern.fullmatch(value)
        if match:
            seconds = sum(int(g) * _UNIT_S[u] for g, u in zip(match.groups(), units))
            if seconds <= 0:
                break
            return seconds
    raise ConfigError(f"--time {text!r}: use minutes, minutes:seconds, hours:minutes:seconds, days-hours, "
                      "days-hours:minutes or days-hours:minutes:seconds (SLURM's formats), longer than 0")


def partition_time_limits(sinfo_text: str) -> tuple[dict[str, int | None], str | None]:
    """The partitions' time limits (seconds; None: infinite or unset) and the default partition,
    from the lines of ``sinfo --noheader --format "%P %l"`` ("debug* 1:00:00", "long infinite")."""
    limits, default = {}, None
    for line in sinfo_text.splitlines():
        fields = line.split()
        if len(fields) != 2:
            continue
        name, limit = fields
        if name.endswith("*"):
            name = default = name[:-1]
        try:
            limits[name] = parse_duration(limit)
        except ConfigError:  # "infinite", "n/a"
            limits[name] = None
    return limits, default


def cluster_time_limits() -> str | None:
    """``sinfo``'s partitions and time limits on this machine (None: no SLURM here, or it did not answer)."""
    sinfo = shutil.which("sinfo")
    if sinfo is None:
        return None
    try:
        done = subprocess.run([sinfo, "--all", "--noheader", "--format", "%P %l"], capture_output=True, text=True,
                              timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


def check_partition_time(seconds: int, time_text: str, partition: str | None, sinfo_text: str | None,
                         requeue: bool = True) -> list[str]:
    """Warnings where this machine's SLURM (``sinfo_text``, :func:`cluster_time_limits`; None: none
    here, nothing checked) would leave the job pending for ever: a ``--time`` longer than the limit
    of every partition the job may run in (``--partition``, a comma list, else the default one), or a
    partition it does not list. Warnings, not refusals: the script may be meant for another cluster."""
    if not sinfo_text:
        return []
    limits, default = partition_time_limits(sinfo_text)
    names = [name for name in partition.split(",") if name] if partition else [default] if default else []
    unknown = [name for name in names if name not in limits]
    if unknown:
        return [f"--partition {partition}: {', '.join(unknown)} is not a partition of this machine's SLURM (sinfo: "
                f"{', '.join(sorted(limits))}); if the script is for this cluster, SLURM will refuse it"]
    finite = [limits[name] for name in names]
    if not names or not all(limit is not None and seconds > limit for limit in finite):
        return []
    longest = max(finite)
    which = f"partition {names[0]}" if len(names) == 1 else f"partitions {partition}"
    which += "" if partition else " (the default)"
    offered = ", ".join(f"{name} {spoken(limit) if limit else 'infinite'}" for name, limit in sorted(limits.items()))
    then = "is requeued and resumes" if requeue else "resumes when submitted again"
    return [f"--time {time_text}: {spoken(seconds)} is longer than the time limit of {which}, {spoken(longest)} "
            f"(sinfo): SLURM would leave the job pending or refuse it; give --time {slurm_duration(longest)} or less "
            f"(a job stopped at its limit {then}) or a partition with a longer limit ({offered})"]


def slurm_duration(seconds: int) -> str:
    """``D-HH:MM:SS`` (unambiguous for SLURM)."""
    days, rest = divmod(int(seconds), 86400)
    return f"{days}-{rest // 3600:02d}:{rest % 3600 // 60:02d}:{rest % 60:02d}"


def pbs_duration(seconds: int) -> str:
    """``HH:MM:SS`` (hours may exceed 24)."""
    s = int(seconds)
    return f"{s // 3600:02d}:{s % 3600 // 60:02d}:{s % 60:02d}"


def spoken(seconds: float) -> str:
    s = int(round(seconds))
    d, s = divmod(s, 86400)
    h, s = divmod(s, 3600)
    m, s = divmod(s, 60)
    parts = [f"{v} {u}" for v, u in ((d, "d"), (h, "h"), (m, "min"), (s, "s")) if v]
    return " ".join(parts) or "0 s"


@dataclass(frozen=True)
class Layout:
    """How a job runs a plan: nodes, ranks per node, threads per rank, GPUs, memory, wall time."""

    nodes: int
    ranks_per_node: int
    threads_per_rank: int
    gpus_per_node: int
    memory_bytes_per_node: float
    estimate_s: float  # the plan's wall-time estimate on this layout (start-up included)
    shards: int = 1


def choose_layout(estimates, *, nodes: int, cores_per_node: int, memory_bytes: float, ranks: int | None = None,
                  threads: int | None = None, gpus: int = 0, shards: int = 1) -> Layout:
    """Ranks per node: as given, else one per GPU, else as many as the node's cores and memory
    hold for the largest task (and no more than there are tasks per node); threads per rank:
    as given, else the node's cores shared by its ranks. ConfigError when what is given does not
    fit the node."""
    n_tasks = max(1, math.ceil(len(estimates) / max(1, shards)))
    peak = max((e.memory_bytes for e in estimates), default=0.0) + RANK_BASE_BYTES
    if ranks is None:
        if gpus:
            ranks = gpus
        else:
            fit = max(1, int(memory_bytes // (peak * MEMORY_SLACK)))
            ranks = max(1, min(cores_per_node if threads is None else max(1, cores_per_node // threads), fit,
                               math.ceil(n_tasks / nodes)))
    if threads is None:
        threads = max(1, cores_per_node // ranks)
    if ranks * threads > cores_per_node:
        raise ConfigError(f"--ntasks-per-node {ranks} x --cpus-per-task {threads} = {ranks * threads} CPUs, more "
                          f"than --cores-per-node {cores_per_node}")
    need = ranks * peak * MEMORY_SLACK
    if need > memory_bytes:
        raise ConfigError(f"{ranks} rank(s) per node need about {need / 2**30:.1f} GiB (largest task "
                          f"{(peak - RANK_BASE_BYTES) / 2**30:.2f} GiB + {RANK_BASE_BYTES / 2**30:.1f} GiB per rank), "
                          f"more than the node's {memory_bytes / 2**30:.1f} GiB (--memory-gb); use fewer ranks")
    seconds = [e.seconds for e in estimates]
    per_shard = sum(seconds) / max(1, shards)
    wall = max(per_shard / (nodes * ranks), max(seconds, default=0.0)) + START_S
    return Layout(nodes, ranks, threads, gpus, need, wall, shards)


def _template(name: str) -> str:
    return resources.files("wavebrdf.jobs").joinpath("templates", name).read_text()


def render_script(scheduler: str, fields: dict[str, str]) -> str:
    """``templates/<scheduler>.sh``, ``templates/prelude.sh`` at ``@PRELUDE@``, every other
    ``@NAME@`` replaced by ``fields[NAME]``."""
    prelude = _template("prelude.sh").split("\n", 1)[1].rstrip("\n")  # without its own comment line
    text = _template(f"{scheduler}.sh").replace("@PRELUDE@", prelude)
    return re.sub(r"@([A-Z_]+)@", lambda m: str(fields[m.group(1)]), text)


def _directives(scheduler: str, layout: Layout, args, job: str, seconds: int) -> list[str]:
    mem_mib = math.ceil(layout.memory_bytes_per_node / 2**20)
    if scheduler == "pbs":
        select = (f"select={layout.nodes}:ncpus={layout.ranks_per_node * layout.threads_per_rank}"
                  f":mpiprocs={layout.ranks_per_node}:ompthreads={layout.threads_per_rank}:mem={mem_mib}mb")
        if layout.gpus_per_node:
            select += f":ngpus={layout.gpus_per_node}"
        lines = [f"#PBS -N {job}", f"#PBS -l {select}", f"#PBS -l walltime={pbs_duration(seconds)}",
                 "#PBS -r y", "#PBS -j oe"]
        if layout.shards > 1:
            lines.append(f"#PBS -J 0-{layout.shards - 1}")
        lines += [f"#PBS -q {args.partition}"] * bool(args.partition) + [f"#PBS -A {args.account}"] * bool(args.account)
        return lines
    lines = [f"--job-name={job}", f"--nodes={layout.nodes}", f"--ntasks-per-node={layout.ranks_per_node}",
             f"--cpus-per-task={layout.threads_per_rank}", f"--mem={mem_mib}M", f"--time={slurm_duration(seconds)}",
             f"--signal=B:USR1@{args.signal_lead}", "--open-mode=append"]  # a requeued job appends to its log
    if not args.no_requeue:
        lines.append("--requeue")
    if layout.gpus_per_node:
        lines.append(f"--gpus-per-node={layout.gpus_per_node}")
    if layout.shards > 1:
        lines += [f"--array=0-{layout.shards - 1}", f"--output={job}-%A_%a.log"]
    else:
        lines.append(f"--output={job}-%j.log")
    lines += [f"--partition={args.partition}"] * bool(args.partition) + [f"--account={args.account}"] * bool(args.account)
    return [f"#SBATCH {line}" for line in lines]


_SCHEDULER_NAME = re.compile(r"[A-Za-z0-9_.+-]+(,[A-Za-z0-9_.+-]+)*")  # partitions, queues, accounts (comma lists)
_MPI_PLUGIN = re.compile(r"[A-Za-z0-9_]+")
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def check_script_options(args) -> None:
    """Every string option that reaches the batch script, checked before it is written: names
    (--partition, --account, --mpi) in the characters schedulers allow; each --prologue one line
    of shell (it is the user's shell code, written as given); --script a path without control
    characters in an existing folder. ConfigError naming the option and the value."""
    names = "letters, digits and _ . + - (comma-separated)"
    for option, value, pattern, what in (
            ("--partition", args.partition, _SCHEDULER_NAME, f"partition/queue names: {names}"),
            ("--account", args.account, _SCHEDULER_NAME, f"account names: {names}"),
            ("--mpi", args.mpi, _MPI_PLUGIN, "an srun --mpi plugin name: letters, digits and _")):
        if value is not None and not pattern.fullmatch(value):
            raise ConfigError(f"{option} {value!r}: must be {what}")
    for line in args.prologue or ():
        if _CONTROL.search(line):
            raise ConfigError(f"--prologue {line!r}: one line of shell each (no newlines or control characters); "
                              "repeat --prologue for several lines")
    if args.script is not None:
        if _CONTROL.search(str(args.script)):
            raise ConfigError(f"--script {str(args.script)!r}: a path without newlines or control characters")
        folder = Path(args.script).parent
        if not folder.is_dir():
            raise ConfigError(f"--script {str(args.script)!r}: the folder {str(folder)!r} does not exist; create it "
                              "or choose another path")


def check_mpi_available(layout: Layout, launcher: str) -> None:
    """Ranks need mpi4py in the Python the script runs (this one): refused before the script is
    written, not found by the ranks of a queued job."""
    import importlib.util

    ranks = layout.nodes * layout.ranks_per_node
    if (ranks > 1 or launcher == "mpiexec") and importlib.util.find_spec("mpi4py") is None:
        raise ConfigError(f"--nodes {layout.nodes} x --ntasks-per-node {layout.ranks_per_node} = {ranks} MPI rank(s)"
                          f"{' under mpiexec' if launcher == 'mpiexec' else ''} need mpi4py, which {sys.executable} "
                          "lacks: pip install 'wavebrdf[mpi]', or one rank (--nodes 1 --ntasks-per-node 1, "
                          "--launcher srun)")


def _one_line(text) -> str:
    """``text`` for a comment line of the script: control characters escaped."""
    return _CONTROL.sub(lambda m: repr(m.group())[1:-1], str(text))


def cmd_submit(args) -> int:
    """Write the batch script of ``args.config`` (see the module docstring)."""
    scheduler = args.scheduler
    seconds = parse_duration(args.time)
    if args.gpus_per_node < 0:
        raise ConfigError(f"--gpus-per-node {args.gpus_per_node}: must be an integer >= 0")
    check_script_options(args)
    if scheduler == "slurm":
        for warning in check_partition_time(seconds, args.time, args.partition, cluster_time_limits(),
                                            requeue=not args.no_requeue):
            print(f"wavebrdf: warning: {warning}", file=sys.stderr)
    config = load_config(args.config)
    study = config.cases[0]
    plan = plan_study(config)
    estimates = estimate_tasks(plan)
    memory = (args.memory_gb or study.run.memory_gb or node_memory_bytes() / 2**30) * 2**30
    cores = args.cores_per_node or max(os.cpu_count() or 1, (args.ntasks_per_node or 1) * (args.cpus_per_task or 1))
    layout = choose_layout(estimates, nodes=args.nodes, cores_per_node=cores, memory_bytes=memory,
                           ranks=args.ntasks_per_node, threads=args.cpus_per_task, gpus=args.gpus_per_node,
                           shards=args.array)
    if seconds < layout.estimate_s:
        read_as = " (minutes:seconds)" if re.fullmatch(r"\d+:\d+", args.time.strip()) else ""
        then = "resumes when submitted again" if args.no_requeue else "is requeued (it resumes)"
        print(f"wavebrdf: warning: --time {args.time} is {spoken(seconds)} to {scheduler.upper()}{read_as}, shorter than the "
              f"plan's estimate of {spoken(layout.estimate_s)} on {layout.nodes} node(s) x {layout.ranks_per_node} "
              f"rank(s); the job will be stopped at its limit and {then}, but a longer --time wastes less",
              file=sys.stderr)
    check_mpi_available(layout, args.launcher if scheduler == "slurm" else "mpiexec")
    args.signal_lead = min(args.signal_lead, max(1, seconds // 5))  # the stop must come well inside the limit
    if scheduler == "slurm" and seconds < args.signal_lead + SLURM_SIGNAL_EARLY_S + START_S:
        print(f"wavebrdf: warning: --time {args.time} is {spoken(seconds)}: SLURM signals a clean stop "
              f"{args.signal_lead} s before the limit and up to {SLURM_SIGNAL_EARLY_S} s earlier still, so the run "
              f"may be stopped before it gets going; it resumes when requeued, but give at least "
              f"{spoken(args.signal_lead + SLURM_SIGNAL_EARLY_S + START_S)}", file=sys.stderr)
    job = re.sub(r"\W", "_", config.name)
    script = Path(args.script or f"{config.name}.{scheduler}.sh")
    prologue = [p for p in (study.sections.get("run", {}).get("prologue"), *(args.prologue or [])) if p]
    wavebrdf = shlex.quote(str(Path(sys.executable).parent / "wavebrdf"))
    config_path = shlex.quote(str(Path(args.config).resolve()))
    run_args, after = "", ""
    if layout.shards > 1:
        index = "${SLURM_ARRAY_TASK_ID}" if scheduler == "slurm" else "${PBS_ARRAY_INDEX:-${PBS_ARRAYID:-0}}"
        run_args = f"--shard {index}/{layout.shards}"
        after = (f'if [ "$status" -eq 0 ]; then  # the last shard to finish writes the dataset\n'
                 f"  {wavebrdf} merge {config_path} --shards {layout.shards} --if-complete --wait || status=$?\nfi")
    exports = "WAVEBRDF_DEVICE=gpu" if layout.gpus_per_node else ""
    if args.no_requeue:
        stopped = ('  echo "wavebrdf: job ${SLURM_JOB_ID} stopped before its time limit and is not requeued '
                   '(--no-requeue): the study is unfinished; submit this script again to resume" >&2\n'
                   '  exit "$status"')
        stop_word = "the job ends with the ranks' status (--no-requeue: not requeued)"
    else:
        stopped = ('  echo "wavebrdf: requeueing job ${SLURM_JOB_ID}: it resumes from the finished tasks" >&2\n'
                   '  scontrol requeue "${SLURM_JOB_ID}"\n  exit 0')
        stop_word = "the job is requeued (--requeue) and resumes"
    fields = {
        "STUDY": repr(config.name), "SCRIPT": _one_line(script),
        "DIRECTIVES": "\n".join(_directives(scheduler, layout, args, job, seconds)),
        "PLAN": (f"{len(plan.tasks)} task(s), largest {max(e.memory_bytes for e in estimates) / 2**30:.2f} GiB, "
                 f"about {spoken(layout.estimate_s)} on {layout.nodes} node(s) x {layout.ranks_per_node} rank(s) "
                 f"x {layout.threads_per_rank} thread(s)" + (f", {layout.shards} shards" if layout.shards > 1 else "")),
        "PARTS": _one_line(f"{config.output}.parts" if layout.shards == 1
                           else f"{Path(config.output).with_suffix('')}.shard-*"),
        "CWD": shlex.quote(str(Path.cwd())), "PROLOGUE": "\n".join(prologue) or ":",
        "BINDIR": shlex.quote(str(Path(sys.executable).parent)), "THREADS": layout.threads_per_rank,
        "RANKS": layout.ranks_per_node, "TOTAL_RANKS": layout.ranks_per_node * layout.nodes, "EXPORTS": exports,
        "MPI": shlex.quote(args.mpi), "LAUNCHER": args.launcher, "LEAD": args.signal_lead,
        "STOPPED": stopped, "STOP_WORD": stop_word,
        "WAVEBRDF": wavebrdf, "CONFIG": config_path, "RUN_ARGS": run_args, "AFTER": after or ":",
    }
    script.write_text(render_script(scheduler, fields))
    script.chmod(0o755)
    print(f"wrote {script}: {len(plan.tasks)} tasks on {layout.nodes} node(s) x {layout.ranks_per_node} rank(s) x "
          f"{layout.threads_per_rank} thread(s), {layout.memory_bytes_per_node / 2**30:.1f} GiB per node, "
          f"time limit {slurm_duration(seconds)} (estimate {spoken(layout.estimate_s)})")
    print(f"submit with: {'sbatch' if scheduler == 'slurm' else 'qsub'} {script}")
    return 0


def add_submit_parser(sub, count, gib) -> None:
    """The ``submit`` subcommand (``count``/``gib``: the CLI's checked number types)."""
    p = sub.add_parser("submit", help="write a SLURM (or PBS) batch script sized from the plan")
    p.add_argument("config", type=Path)
    p.add_argument("--time", required=True,
                   help="wall-clock limit as SLURM reads it: minutes, minutes:seconds, hours:minutes:seconds, "
                        "days-hours, days-hours:minutes, days-hours:minutes:seconds (01:00 is ONE MINUTE)")
    p.add_argument("--nodes", type=count("--nodes"), default=1)
    p.add_argument("--scheduler", choices=["slurm", "pbs"], default="slurm")
    p.add_argument("--cores-per-node", type=count("--cores-per-node"),
                   help="CPU cores of a compute node (default: this machine's, or the ranks x threads given)")
    p.add_argument("--memory-gb", type=gib("--memory-gb"),
                   help="memory of a compute node (default: [run] memory_gb, else this machine's)")
    p.add_argument("--ntasks-per-node", type=count("--ntasks-per-node"),
                   help="MPI ranks per node (default: from the plan, the cores and the memory)")
    p.add_argument("--cpus-per-task", type=count("--cpus-per-task"),
                   help="threads per rank (default: the node's cores / ranks)")
    p.add_argument("--gpus-per-node", type=int, default=0, help="GPUs per node: one rank per GPU")
    p.add_argument("--partition", help="SLURM partition / PBS queue")
    p.add_argument("--account")
    p.add_argument("--prologue", action="append",
                   help="shell line run before wavebrdf (module loads, venv activation); repeatable; "
                        "added after [run] prologue")
    p.add_argument("--launcher", choices=["srun", "mpiexec"], default="srun", help="SLURM: how ranks start")
    p.add_argument("--mpi", default="auto", help="srun --mpi plugin (default: detected when the job starts: pmi2, "
                                                 "else pmix, else none)")
    p.add_argument("--signal-lead", type=count("--signal-lead"), default=SIGNAL_LEAD_S,
                   help="seconds before the time limit at which the run is stopped and the job requeued")
    p.add_argument("--no-requeue", action="store_true", help="do not requeue a job stopped at its time limit")
    p.add_argument("--array", type=count("--array"), default=1,
                   help="split the study over this many independent array jobs, merged by the last one")
    p.add_argument("--script", help="output path (default <study>.<scheduler>.sh)")
    p.set_defaults(func=cmd_submit)
