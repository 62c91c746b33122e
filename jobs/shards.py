"""Array sharding: one study split over K independent jobs, merged into one dataset.

``run --shard i/K`` runs shard i's tasks with its own output ``<stem>.shard-<i>-of-<K><suffix>``
(own lock and parts folder, so K jobs never contend) and keeps its parts; it writes no dataset.
Shards are contiguous groups of tasks (a steered basic direction's patch and synthesis tasks stay
together; consecutive tasks share a model's operator). ``wavebrdf merge CONFIG`` verifies every
shard's parts, adopts them into the output's parts folder and writes the dataset with the same
writer as an unsharded run, so the two are equal; the shards' folders are then removed. A plain
``run`` of the study takes the shards' finished tasks the same way (:func:`adopt_finished_shards`)
and computes only the rest.
"""

from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path

from wavebrdf.jobs.config import ConfigError, load_config
from wavebrdf.jobs.finished import up_to_date
from wavebrdf.jobs.overrides import assignment_text
from wavebrdf.jobs.parts import OutputBusy, OutputLock, PartsFolder, ResumeError, StorageError
from wavebrdf.jobs.plan import Plan, plan_study
from wavebrdf.jobs.render import render_dataset
from wavebrdf.jobs.scheduler import prepare_output
from wavebrdf.jobs.store import write_dataset

__all__ = ["add_merge_parser", "adopt_finished_shards", "cmd_merge", "parse_shard", "remove_adopted_shards",
           "same_flags", "shard_output", "shard_tasks", "with_output"]


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/K"`` → (i, K) with 0 <= i < K."""
    match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", str(text))
    if not match or not 0 <= int(match.group(1)) < int(match.group(2)):
        raise ConfigError(f"--shard {text!r}: use i/K with 0 <= i < K, e.g. 0/4")
    return int(match.group(1)), int(match.group(2))


def shard_output(output: Path, index: int, shards: int) -> Path:
    output = Path(output)
    return output.with_name(f"{output.stem}.shard-{index}-of-{shards}{output.suffix}")


def _group(task) -> tuple:
    """Tasks of one group go to one shard: a basic direction's patches and syntheses."""
    if task.kind in ("patch", "synth"):
        return ("steered", task.case, task.wavelength, task.basic)
    return ("task", task.id)


def shard_tasks(plan, index: int, shards: int) -> set[int]:
    """Ids of the tasks of shard ``index`` of ``shards`` (contiguous groups, balanced by count),
    with the spot checks its tasks read (``Task.checks``: a check a task of two shards reads runs
    in both; the same part either way)."""
    groups: dict[tuple, list[int]] = {}
    for task in plan.tasks:
        groups.setdefault(_group(task), []).append(task.id)
    ordered = list(groups.values())
    lo, hi = len(ordered) * index // shards, len(ordered) * (index + 1) // shards
    ids = {i for ids in ordered[lo:hi] for i in ids}
    return ids | {c for i in ids for c in plan.tasks[i].checks}


def with_output(config, output: Path):
    """``config`` writing to ``output`` (every case)."""
    from dataclasses import replace

    return replace(config, cases=tuple(replace(case, output=Path(output)) for case in config.cases))


def _shard_plan(plan, index: int, shards: int):
    """The plan with the shard's output (same tasks, same fingerprint)."""
    config = with_output(plan.config, shard_output(plan.config.output, index, shards))
    return Plan(config, plan.tasks, plan.steering, plan._geometry)


def found_shards(output: Path) -> int | None:
    """K of the shard folders beside ``output`` (None: none there)."""
    output = Path(output)
    pattern = re.compile(re.escape(output.stem) + r"\.shard-\d+-of-(\d+)" + re.escape(output.suffix) + r"\.parts")
    counts = {int(m.group(1)) for p in output.parent.glob(f"{output.stem}.shard-*")
              if (m := pattern.fullmatch(p.name))}
    if len(counts) > 1:
        raise ResumeError(f"shard folders of different shard counts {sorted(counts)} beside {output}; "
                          "remove the stale ones")
    return counts.pop() if counts else None


def _shard_state(plan, index: int, shards: int) -> tuple[PartsFolder, str | None]:
    """Shard ``index``'s parts folder and what it lacks ("3 of 3 task(s) missing (not started)";
    None: every task done or failed for good). Refuses (ResumeError) a folder of another
    configuration. Reads only: a damaged part stays where it is, for the shard's run to redo."""
    folder = PartsFolder(_shard_plan(plan, index, shards))
    wanted = shard_tasks(plan, index, shards)
    if not folder.path.exists():
        return folder, f"{len(wanted)} of {len(wanted)} task(s) missing (not started)"
    folder.check()
    done, bad = folder.inspect()
    failed = {t for t in wanted if folder.failure(plan.tasks[t]) is not None}
    lacking = wanted - done - failed
    if not lacking:
        return folder, None
    damaged = len(lacking & set(bad))
    why = f" ({damaged} damaged part(s), recomputed by the shard's run)" if damaged else ""
    return folder, f"{len(lacking)} of {len(wanted)} task(s) missing{why}"


def _own_shard_folders(plan) -> tuple[int | None, list[tuple[int, PartsFolder]]]:
    """K and the (index, folder) of each shard folder beside the output that holds this plan's
    parts (another configuration's, or of mixed shard counts, are not this run's to take)."""
    try:
        shards = found_shards(plan.config.output)
    except ResumeError:
        return None, []
    folders = []
    for index in range(shards or 0):
        folder = PartsFolder(_shard_plan(plan, index, shards))
        try:
            if folder.path.exists() and folder.check() is not None:
                folders.append((index, folder))
        except ResumeError:
            continue
    return shards, folders


def adopt_finished_shards(plan, parts: PartsFolder) -> str | None:
    """An unsharded run of a study whose shards ran (``run --shard i/K``) takes their finished
    tasks instead of computing them again: each verified part in a shard folder of this plan is
    copied into ``parts`` (the run's own folder; the caller holds the output's lock). The shards'
    folders are read, not changed. Returns what was taken, or None."""
    shards, folders = _own_shard_folders(plan)
    taken, sources = 0, 0
    for _, folder in folders:
        took = sum(1 for task in plan.tasks if not parts.done(task) and folder.done(task) and parts.adopt(task, folder))
        taken, sources = taken + took, sources + bool(took)
    if not taken:
        return None
    return (f"took {taken} finished task(s) of {len(plan.tasks)} from {sources} shard folder(s) of "
            f"'run --shard i/{shards}' beside {plan.config.output}; computing the rest")


def remove_adopted_shards(plan) -> list[Path]:
    """Once the study's dataset holds every task, its shards' folders hold nothing it lacks:
    remove each one whose shard is not running (its lock is free). Returns the folders kept."""
    shards, folders = _own_shard_folders(plan)
    kept = []
    for index, folder in folders:
        try:
            with OutputLock(shard_output(plan.config.output, index, shards)).acquire(False):
                folder.remove()
        except (OutputBusy, StorageError):
            kept.append(folder.path)
    return kept


def same_flags(args) -> str:
    """`` -o OUTPUT --set KEY=VALUE …`` of ``args`` (run's or merge's), shell-quoted: what the other
    command needs to name the same study."""
    flags = [] if getattr(args, "output", None) is None else ["-o", str(args.output)]
    for key, value in getattr(args, "set", None) or []:
        flags += ["--set", assignment_text(key, value)]
    return "".join(" " + shlex.quote(flag) for flag in flags)


def cmd_merge(args) -> int:
    """``wavebrdf merge CONFIG``: the shards' parts into the study's dataset. Everything is checked
    before anything is written or moved: a refusal leaves the shards' folders as they were."""
    plan = plan_study(load_config(args.config, output=args.output, overrides=args.set))
    output = Path(plan.config.output)
    with OutputLock(output).acquire(args.wait):
        if up_to_date(plan, args.force):
            print(f"{output} is up to date")
            return 0
        shards = args.shards or found_shards(output)
        if shards is None:
            raise ResumeError(f"no shard folders beside {output} (run 'wavebrdf run CONFIG --shard i/K' first)")
        states = [_shard_state(plan, index, shards) for index in range(shards)]
        own = PartsFolder(plan)
        if own.path.exists():
            own.check()  # a parts folder of another configuration beside the output
        missing = {index: lack for index, (_, lack) in enumerate(states) if lack is not None}
        if missing:
            lacking = "; ".join(f"shard {index}: {lack}" for index, lack in missing.items())
            if args.if_complete:
                print(f"merge of {output} waits for: {lacking}", file=sys.stderr)
                return 0
            raise ResumeError(f"cannot merge {output}: not finished: {lacking}; finish them with 'wavebrdf run "
                              f"{args.config}{same_flags(args)} --shard I/{shards}' for I in "
                              f"{', '.join(map(str, missing))}")
        folders = [folder for folder, _ in states]
        parts = prepare_output(plan)
        device = ""
        for folder in folders:
            for task in plan.tasks:
                if folder.done(task) and parts.adopt(task, folder):
                    device = device or parts.load_diagnostics(task).get("device", "")
                elif folder.failure(task) is not None:
                    parts.save_failure(task, folder.failure(task))
        path = write_dataset(plan, parts, device=device)
        failed = [t for t in plan.tasks if not parts.done(t)]
        if not failed:
            parts.remove()
            for folder in folders:
                folder.remove()
        print(f"wrote {path} ({shards} shards)")
        if failed:
            print(f"wavebrdf: {len(failed)} task(s) failed; their results are NaN", file=sys.stderr)
            return 1
        if not args.no_render:
            for png in render_dataset(path):
                print(f"wrote {png}")
    return 0


def add_merge_parser(sub, count, add_set_flag) -> None:
    """The ``merge`` subcommand; ``count(flag)`` the CLI's argparse type of a positive integer flag,
    ``add_set_flag(parser)`` its ``--set`` (the shards' run took the same ``--set`` and ``-o``)."""
    p = sub.add_parser("merge", help="merge the shards of 'run --shard i/K' into the study's dataset")
    p.add_argument("config", type=Path)
    add_set_flag(p)
    p.add_argument("--output", "-o", type=Path, help="override [study] output, as the shards' run did")
    p.add_argument("--shards", type=count("--shards"), help="K (default: found beside the output)")
    p.add_argument("--if-complete", action="store_true",
                   help="exit 0 without merging while a shard is unfinished (the array jobs' last step)")
    p.add_argument("--wait", action="store_true", help="wait for another run or merge holding the output")
    p.add_argument("--force", action="store_true", help="overwrite an output that holds another configuration's "
                                                       "results or is not a wavebrdf dataset")
    p.add_argument("--no-render", action="store_true", help="do not write PNGs")
    p.set_defaults(func=cmd_merge)
