"""``auto``'s spot checks in a study of several tasks (solver/auto.py, docs/auto.md).

A model whose capabilities say ``spot_checks`` measures its own choice: :func:`add_spot_checks`
describes every task it decides — direct tasks, or the patch tasks of a steered case — to the
model (``check_unit``), which picks a few to check (``plan_spot_checks``: extremes of λ and θ_i,
the steepest sub-areas, within its share of the all-full-wave estimate, but at both ends of the
spectrum checks as oblique and as steep as every task there whose full wave fits, whatever the
share). Each pick becomes a
"check" task with the indices of the task it copies (same scene); every decided task depends on
the checks that represent it and reads their measurements when it runs (jobs/tasks.py).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

__all__ = ["add_spot_checks", "expectation_scene", "spot_check_summary", "twin_of"]


def _series(task) -> tuple:
    """The tasks that share one rung across wavelengths: a case's direction or sub-area."""
    return (task.case, task.basic, task.patch) if task.on_patch else (task.case, task.incidence)


def add_spot_checks(plan) -> None:
    """Append the spot-check tasks of every case whose model measures its choice, and point the
    tasks it decides at the checks that represent them (``Task.checks``, also in ``depends``)."""
    tasks = list(plan.tasks)
    for case, study in enumerate(plan.config.cases):
        if not study.model.capabilities.spot_checks:
            continue
        decided = [t for t in tasks if t.case == case and t.kind in ("direct", "patch")]
        if len(decided) < 2:
            continue
        model = study.model.build()
        # chosen from the config alone (the same on every machine, so run, shards and merge agree):
        # [run] memory_gb for the whole node, else no memory limit (the budget fit's choice there)
        budget = study.run.memory_gb * 2**30 if study.run.memory_gb else float("inf")
        units = [model.check_unit(t.id, _series(t), replace(plan.scene(t), memory_budget_bytes=budget))
                 for t in decided]
        picked, represented = model.plan_spot_checks(units)
        plan.spot_check_units[case] = (units, picked)
        ids = []
        for unit in picked:
            ids.append(len(tasks))
            tasks.append(replace(tasks[unit.task], id=len(tasks), kind="check", depends=(), checks=()))
        heads = {}
        for task in decided:
            checks = tuple(ids[i] for i in represented.get(task.id, ()))
            if checks:
                tasks[task.id] = replace(task, checks=checks, depends=task.depends + checks)
                plan.series_heads[task.id] = heads.setdefault(_series(task), task.id)
    plan.tasks = tasks


def expectation_scene(plan, task):
    """The scene whose rule choice stands for ``task``'s expected rung in ``plan``: the first task
    of its series for a task with spot checks (its series takes one rung), else its own."""
    head = plan.series_heads.get(task.id)
    return plan.model_scene(task if head is None else plan.tasks[head])


def twin_of(plan, task):
    """The spot check among ``task.checks`` that simulates ``task``'s very scene (None: none)."""
    for i in task.checks:
        check = plan.tasks[i]
        if (check.case, check.wavelength, check.incidence, check.basic, check.patch) == (
                task.case, task.wavelength, task.incidence, task.basic, task.patch):
            return check
    return None


def _full_wave_seconds(units) -> float:
    """The full-wave estimates of the units where the full wave fits (their all-full-wave cost)."""
    return sum(u.full_wave_seconds for u in units if u.full_wave_fits and np.isfinite(u.full_wave_seconds))


def _shares_exceeded(plan) -> list[float]:
    """The ``spot_check_share`` of every case whose checks cost more than it of that case's
    all-full-wave estimate (the hardest tasks at both ends of the spectrum are checked whatever the share)."""
    out = set()
    for case, (units, picked) in plan.spot_check_units.items():
        share = plan.config.cases[case].model.options.spot_check_share
        if sum(u.full_wave_seconds for u in picked) > share * _full_wave_seconds(units) * (1 + 1e-9):
            out.add(share)
    return sorted(out)


def spot_check_summary(plan, estimates) -> str | None:
    """``plan``'s lines on the spot checks: which tasks, their share of the all-full-wave estimate
    (an estimate, from the models' own cost models, at the selection's budget), and how many tasks
    they represent."""
    checks = [(t, e) for t, e in zip(plan.tasks, estimates) if t.kind == "check"]
    if not checks:
        return None
    decided = [t for t in plan.tasks if t.checks]
    all_full = sum(_full_wave_seconds(units) for units, _ in plan.spot_check_units.values())
    checked = sum(u.full_wave_seconds for _, picked in plan.spot_check_units.values() for u in picked)
    spent = sum(e.seconds for _, e in checks)
    where = ", ".join(f"#{t.id} ({t.label})" for t, _ in checks[:8]) + (" ..." if len(checks) > 8 else "")
    exceeded = _shares_exceeded(plan)
    above = (f" (above [model] spot_check_share = {' / '.join(f'{a:g}' for a in exceeded)}: the hardest task at "
             "each end of the spectrum, and any less oblique but steeper one, is checked whatever the share)"
             if exceeded else "")
    return (f"auto spot checks: {len(checks)} task(s) [{where}] run the full wave and the cheaper rungs (≈ {spent:.3g} s "
            f"as planned here); their full wave is {checked / max(all_full, 1e-9):.1%} of the all-full-wave estimate "
            f"{all_full:.3g} s ({all_full / 3600:.3g} CPU-h at the full wave's settings fitted to [run] memory_gb, or "
            "without it as the budget fit chooses with no memory limit: the same on every machine, and "
            f"not the plan of the study all-full-wave, whose tasks plan fits to the worker's memory){above}; {len(decided)} "
            "task(s) take the cheapest rung measured within tolerance there (the rung per task above is what the "
            "checks are expected to measure: the rule's fit without its margin; where they measure no rung within "
            "the tolerance the tasks run the full wave, up to the all-full-wave figure)")

