"""`wavebrdf submit`: the generated #SBATCH header read as SLURM reads it, for four representative
plans; every template (SLURM and PBS) is valid bash; durations in SLURM's formats."""

from __future__ import annotations

import shlex
import subprocess
from pathlib import Path

import pytest

from wavebrdf.jobs.cli import main
from wavebrdf.jobs.config import load_config
from wavebrdf.jobs.plan import plan_study
from test_scheduler import write_study

GIB = 2**30
def slurm_seconds(text: str) -> int:
    """SLURM's reading of a --time value (sbatch(1)): minutes, minutes:seconds,
    hours:minutes:seconds, days-hours, days-hours:minutes, days-hours:minutes:seconds."""
    days, rest = (text.split("-", 1) + [None])[:2] if "-" in text else (None, text)
    fields = [int(x) for x in rest.split(":")]
    if days is None:
        if len(fields) == 1:
            return 60 * fields[0]
        if len(fields) == 2:
            return 60 * fields[0] + fields[1]
        return 3600 * fields[0] + 60 * fields[1] + fields[2]
    fields += [0] * (3 - len(fields))
    return 86400 * int(days) + 3600 * fields[0] + 60 * fields[1] + fields[2]


def sbatch_options(script: str) -> dict[str, str]:
    """The #SBATCH options SLURM takes from a script: only the lines before the first command
    (blank and comment lines do not end the header)."""
    options = {}
    for line in script.splitlines()[1:]:
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            break
        if stripped.startswith("#SBATCH"):
            for word in shlex.split(stripped[len("#SBATCH"):]):
                key, _, value = word.lstrip("-").partition("=")
                options[key] = value
    return options


def mem_bytes(value: str) -> float:
    units = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    return float(value[:-1]) * units[value[-1]] if value[-1] in units else float(value) * 2**20


@pytest.fixture(autouse=True)
def no_cluster(monkeypatch):
    """The scripts these tests write are for no particular cluster: this machine's SLURM (if any)
    is not asked for its partitions (test_slurm.py does that)."""
    import wavebrdf.jobs.submit as submit

    monkeypatch.setattr(submit, "cluster_time_limits", lambda: None)


@pytest.fixture
def study(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return write_study(tmp_path, "sub")


def largest_task_bytes(path: Path) -> float:
    plan = plan_study(load_config(path))
    return max(plan.estimate(t).memory_bytes for t in plan.tasks)


@pytest.mark.parametrize("time", ["90", "01:00", "1:30:00", "2-12", "0-4:30", "1-00:00:05"])
def test_time_limits_are_read_as_slurm_reads_them(study, time):
    assert main(["submit", str(study), "--time", time, "--script", "t.sh"]) == 0
    options = sbatch_options(Path("t.sh").read_text())
    assert slurm_seconds(options["time"]) == slurm_seconds(time)


REPRESENTATIVE = {  # argv, what the header must say
    "cpu nodes": (["--nodes", "2", "--cores-per-node", "16", "--memory-gb", "64", "--time", "01:00"],
                  {"nodes": "2", "cores": 16, "node_gib": 64, "time_s": 60, "gpus": None}),
    "gpu nodes": (["--nodes", "1", "--cores-per-node", "32", "--memory-gb", "256", "--gpus-per-node", "4",
                   "--time", "12:00:00"], {"nodes": "1", "cores": 32, "node_gib": 256, "time_s": 43200, "gpus": "4"}),
    "memory-bound": (["--nodes", "3", "--cores-per-node", "64", "--memory-gb", "2", "--time", "2-0"],
                     {"nodes": "3", "cores": 64, "node_gib": 2, "time_s": 172800, "gpus": None}),
    "explicit array": (["--nodes", "1", "--cores-per-node", "8", "--memory-gb", "32", "--ntasks-per-node", "2",
                        "--cpus-per-task", "3", "--array", "4", "--time", "0-6:30"],
                       {"nodes": "1", "cores": 8, "node_gib": 32, "time_s": 23400, "gpus": None, "ranks": 2,
                        "threads": 3}),
}


@pytest.mark.parametrize("name", list(REPRESENTATIVE))
def test_sbatch_header_of_representative_plans(study, name):
    argv, want = REPRESENTATIVE[name]
    assert main(["submit", str(study), *argv, "--script", "job.sh"]) == 0
    text = Path("job.sh").read_text()
    options = sbatch_options(text)
    ranks, threads = int(options["ntasks-per-node"]), int(options["cpus-per-task"])
    assert options["nodes"] == want["nodes"]
    assert slurm_seconds(options["time"]) == want["time_s"]
    assert ranks * threads <= want["cores"]  # never more CPUs than the node has
    assert ranks >= 1 and threads >= 1
    if "ranks" in want:
        assert (ranks, threads) == (want["ranks"], want["threads"])
    if want["gpus"]:
        assert options["gpus-per-node"] == want["gpus"] and ranks == int(want["gpus"])  # one rank per GPU
        assert threads == want["cores"] // ranks
    else:
        assert "gpus-per-node" not in options
    peak = largest_task_bytes(study)
    assert ranks * peak <= mem_bytes(options["mem"]) <= want["node_gib"] * GIB  # the plan's tasks fit in --mem
    assert "requeue" in options and options["signal"].startswith("B:USR1@")
    if name == "explicit array":
        assert options["array"] == "0-3" and "--shard ${SLURM_ARRAY_TASK_ID}/4" in text and "merge" in text
    if name == "memory-bound":
        assert ranks < want["cores"]
    assert f"OMP_NUM_THREADS={threads}" in text
    assert subprocess.run(["bash", "-n", "job.sh"]).returncode == 0


def test_pbs_script_and_every_template_are_valid_bash(study):
    assert main(["submit", str(study), "--scheduler", "pbs", "--nodes", "2", "--cores-per-node", "8",
                 "--memory-gb", "16", "--time", "1:00:00", "--array", "2", "--prologue", "module load gcc",
                 "--script", "job.pbs.sh"]) == 0
    text = Path("job.pbs.sh").read_text()
    assert "#PBS -l walltime=01:00:00" in text and "#PBS -J 0-1" in text and "module load gcc" in text
    header = text.split("\nset ")[0]
    assert "select=2:" in header and "mpiprocs=" in header
    assert subprocess.run(["bash", "-n", "job.pbs.sh"]).returncode == 0
    templates = Path(__file__).resolve().parent.parent / "jobs" / "templates"
    names = sorted(p.name for p in templates.glob("*.sh"))
    assert names == ["pbs.sh", "prelude.sh", "slurm.sh"]
    for name in names:
        assert subprocess.run(["bash", "-n", str(templates / name)]).returncode == 0, name


def test_prologue_from_the_config_and_short_time_warning(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    path = write_study(tmp_path, "p", extra='[run]\nprologue = "source /opt/venv/bin/activate"\n')
    assert main(["submit", str(path), "--time", "0:01", "--script", "p.sh"]) == 0
    assert "source /opt/venv/bin/activate" in Path("p.sh").read_text()
    err = capsys.readouterr().err
    assert "shorter than the plan's estimate" in err and "minutes:seconds" in err


@pytest.mark.parametrize("bad", ["1 hour", "1:2:3:4", "0", "-5", "1-", ""])
def test_bad_time_is_one_line_exit_2(study, bad, capsys):
    assert main(["submit", str(study), "--time", bad]) == 2
    err = capsys.readouterr().err
    assert err.startswith("wavebrdf: error: --time") and err.count("\n") == 1


@pytest.mark.parametrize("bad", ["-3", "0", "two"])
def test_a_shard_count_below_one_is_refused_by_merge_before_it_writes(study, bad, capsys):
    """`merge --shards K` takes a positive count: 0 or -3 once wrote an all-NaN dataset."""
    assert main(["merge", str(study), "--shards", bad]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"wavebrdf: error: --shards {bad}") and err.count("\n") == 1
    assert not Path(load_config(study).output).exists()


INJECTIONS = ["x\nrm -rf ~", "a'b", 'a"b', "$(touch pwned)", "a;b", "`id`", "a b"]


@pytest.mark.parametrize("option", ["--partition", "--account", "--mpi"])
@pytest.mark.parametrize("value", INJECTIONS)
def test_names_that_reach_the_script_are_refused_with_shell_syntax(study, option, value, capsys):
    assert main(["submit", str(study), "--time", "1:00:00", option, value, "--script", "x.sh"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"wavebrdf: error: {option} ") and err.count("\n") == 1
    assert not Path("x.sh").exists() and not Path("pwned").exists()


def test_each_option_is_one_directive_and_a_prologue_one_line(study):
    """Good values are written as given, one #SBATCH line each; a --prologue is the user's shell
    (quotes, $(...) and ; kept), one line each; a newline in one is refused."""
    assert main(["submit", str(study), "--time", "1:00:00", "--partition", "gpu,debug", "--account", "proj-1.a",
                 "--mpi", "pmix", "--prologue", "module load x; echo \"$(hostname)\"", "--prologue", "true",
                 "--script", "ok.sh"]) == 0
    text = Path("ok.sh").read_text()
    header = [line for line in text.splitlines() if line.startswith("#SBATCH")]
    for key in ("partition", "account", "time", "requeue", "open-mode", "signal", "output", "mem"):
        assert sum(line.split()[1].lstrip("-").split("=")[0] == key for line in header) == 1, key
    options = sbatch_options(text)
    assert (options["partition"], options["account"], options["open-mode"]) == ("gpu,debug", "proj-1.a", "append")
    assert "\nmodule load x; echo \"$(hostname)\"\ntrue\n" in text and "mpi_plugin=pmix" in text
    assert subprocess.run(["bash", "-n", "ok.sh"]).returncode == 0
    assert main(["submit", str(study), "--time", "1:00:00", "--prologue", "a\nb", "--script", "bad.sh"]) == 2
    assert not Path("bad.sh").exists()


def test_script_into_a_missing_folder_and_ranks_without_mpi4py_are_refused_by_submit(study, monkeypatch, capsys):
    assert main(["submit", str(study), "--time", "1:00:00", "--script", "nowhere/job.sh"]) == 2
    assert "--script 'nowhere/job.sh': the folder 'nowhere' does not exist" in capsys.readouterr().err
    import importlib.util
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "mpi4py" else real(name, *a))
    assert main(["submit", str(study), "--time", "1:00:00", "--cores-per-node", "4", "--ntasks-per-node", "2",
                 "--script", "mpi.sh"]) == 2
    err = capsys.readouterr().err
    assert "2 MPI rank(s) need mpi4py" in err and "pip install 'wavebrdf[mpi]'" in err and not Path("mpi.sh").exists()
    assert main(["submit", str(study), "--time", "1:00:00", "--ntasks-per-node", "1", "--script", "one.sh"]) == 0


def test_no_requeue_ends_the_job_with_the_ranks_status_and_a_short_limit_is_warned(study, capsys):
    assert main(["submit", str(study), "--time", "1", "--no-requeue", "--script", "nr.sh"]) == 0
    text = Path("nr.sh").read_text()
    assert "requeue" not in sbatch_options(text) and "scontrol requeue" not in text
    assert 'exit "$status"' in text.rsplit("is not requeued", 1)[1].split("\nfi\n")[0]
    assert "up to 60 s earlier still" in capsys.readouterr().err


# `sinfo --noheader --format "%P %l"` as SLURM prints it: "*" marks the default partition, limits
# in SLURM's duration formats (sinfo(1) %l), "infinite" where there is none; one line per node state
SINFO = "debug* 1:00:00\nlong infinite\nshort 30:00\nweek 7-00:00:00\ndebug* 1:00:00\n"


def test_partition_limits_are_read_from_sinfo():
    from wavebrdf.jobs.submit import partition_time_limits

    limits, default = partition_time_limits(SINFO)
    assert default == "debug"
    assert limits == {"debug": 3600, "long": None, "short": 1800, "week": 7 * 86400}


@pytest.mark.parametrize("time, partition, warned", [
    ("2:00:00", None, "longer than the time limit of partition debug (the default), 1 h"),
    ("50", None, None),
    ("8-00:00:00", "long", None),
    ("8-00:00:00", "week", "give --time 7-00:00:00 or less"),
    ("2:00:00", "short,debug", "partitions short,debug, 1 h"),
    ("20", "short,debug,", None),
    ("20", "gpu", "--partition gpu: gpu is not a partition of this machine's SLURM (sinfo: debug, long, short, week)"),
])
def test_a_time_beyond_the_partitions_limit_is_warned_naming_it(time, partition, warned):
    from wavebrdf.jobs.submit import check_partition_time, parse_duration

    said = check_partition_time(parse_duration(time), time, partition, SINFO)
    assert (said == []) if warned is None else (len(said) == 1 and warned in said[0]), said


def test_submit_says_a_time_beyond_the_partitions_limit_in_its_warnings(study, monkeypatch, capsys):
    import wavebrdf.jobs.submit as submit

    monkeypatch.setattr(submit, "cluster_time_limits", lambda: SINFO)
    assert main(["submit", str(study), "--time", "2:00:00", "--no-requeue"]) == 0
    err = capsys.readouterr().err
    assert "wavebrdf: warning: --time 2:00:00: 2 h is longer than the time limit of partition debug" in err
    assert "resumes when submitted again" in err
