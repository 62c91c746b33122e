"""A steered study's task order: each sub-area's wavelengths consecutive in the plan, and the
scheduler keeping a sub-area on one worker (so its solves share an operator across basic
directions and warm-start from the previous wavelength, solver/bem3d/warm_start.py)."""

from __future__ import annotations

import textwrap

from wavebrdf.jobs.config import load_config
from wavebrdf.jobs.plan import plan_study
from wavebrdf.jobs.scheduler import TaskBoard, prepare_output, sub_area
from wavebrdf.jobs.shards import shard_tasks

STUDY = """
[study]
name = "order"
output = "{out}"

[surface]
generator = "gaussian"
size_um = 6.0
cells = 60
rms_height_um = 0.02
correlation_um = 0.5
seed = 1

[material]
name = "silver"

[illumination]
wavelengths_um = [0.5, 0.55, 0.6]
directions_deg = [[0, 0], [30, 0]]
waist_um = 0.8

[model]
name = "kirchhoff"

[output]
resolution = 32

[steering]
patches = [2, 2]
patch_size_um = 4.0
"""


def steered_plan(tmp_path):
    path = tmp_path / "order.toml"
    path.write_text(textwrap.dedent(STUDY.format(out=tmp_path / "order.h5")))
    return plan_study(load_config(path))


def test_a_sub_areas_wavelengths_are_consecutive_in_the_plan(tmp_path):
    plan = steered_plan(tmp_path)
    patches = [t for t in plan.tasks if t.kind == "patch"]
    basics = len(plan.steering[0].basics_rad)
    assert basics >= 2 and len(patches) == 4 * 3 * basics
    for start in range(0, len(patches), 3 * basics):  # sub-area → wavelength → basic direction
        block = patches[start: start + 3 * basics]
        assert len({t.patch for t in block}) == 1
        assert [(t.wavelength, t.basic) for t in block] == [(w, b) for w in range(3) for b in range(basics)]
    for synth in (t for t in plan.tasks if t.kind == "synth"):  # every sub-area of its (λ, basic)
        depends = [plan.tasks[i] for i in synth.depends]
        assert {(t.wavelength, t.basic) for t in depends} == {(synth.wavelength, synth.basic)} and len(depends) == 4
    # shards still take whole (wavelength, basic direction) groups with their syntheses
    for index in range(3):
        ids = shard_tasks(plan, index, 3)
        for t in (plan.tasks[i] for i in ids if plan.tasks[i].kind == "synth"):
            assert set(t.depends) <= ids


def test_the_scheduler_keeps_a_sub_area_on_one_worker(tmp_path):
    """Two workers asking in turn: each gets whole sub-areas, in wavelength order, and no
    sub-area is shared while another is free."""
    plan = steered_plan(tmp_path)
    board = TaskBoard(plan, prepare_output(plan), retries=0, progress=False, quiet=True)
    given: dict[int, list] = {0: [], 1: []}
    worker = 0
    while not board.finished:
        task = board.next_task(worker)
        if task is None:  # the other worker's task must finish first (never here: all finish at once)
            raise AssertionError("nothing ready although no task runs")
        given[worker].append(task)
        board.finish(task, {})
        worker = 1 - worker
    areas = {w: [sub_area(t) for t in tasks if t.kind == "patch"] for w, tasks in given.items()}
    assert set(areas[0]).isdisjoint(areas[1]) and len(set(areas[0])) == len(set(areas[1])) == 2
    for w, tasks in given.items():
        patches = [t for t in tasks if t.kind == "patch"]
        for area in set(areas[w]):
            mine = [t for t in patches if sub_area(t) == area]
            assert len(mine) == 3 * len(plan.steering[0].basics_rad)
            assert [t.wavelength for t in mine] == sorted(t.wavelength for t in mine)
    # without a worker name the board hands out plan order (the serial executor)
    board = TaskBoard(plan, prepare_output(plan), retries=0, progress=False, quiet=True)
    order = []
    while not board.finished:
        task = board.next_task()
        order.append(task.id)
        board.finish(task, {})
    assert order == sorted(order)
