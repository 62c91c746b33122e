"""The planner fits the AIM settings to the memory a task may use (solver/bem3d/aim/budget.py).

What is checked here is the choice, against the estimates it is made from; the estimates
themselves are compared with measured runs in docs/aim.md ("Memory and time at scale",
``benchmarks/bench_aim.py subarea``).
"""

from __future__ import annotations

from dataclasses import replace

import pytest

from wavebrdf.jobs.config import load_config
from wavebrdf.jobs.plan import PlanError, check_memory, plan_study
from wavebrdf.solver.bem3d.aim.budget import (FITTED_KEYS, SPEED_MARGIN, candidate_options, fit_to_budget,
                                              given_options)
from wavebrdf.solver.bem3d.aim.estimate import estimate_aim, memory_breakdown
from wavebrdf.solver.bem3d.aim.options import AIMOptions
from wavebrdf.solver.bem3d.media import Media
from wavebrdf.solver.surface import generate

AL = 0.46582 - 4.7119j
GIB = 2**30


@pytest.fixture(scope="module")
def surface():
    return generate("gaussian", cells=200, size_um=5.0, seed=1, rms_height_um=0.05, correlation_um=0.5)


def _estimates(surface, options):
    media = Media(0.4, AL)
    return [(o, estimate_aim(surface, 0.4, AL, aim=o))
            for o in candidate_options(options, surface.cells, media, surface.spacing_um)]


def _fastest_within(table, budget, precision):
    """The least predicted seconds of the candidates within ``budget`` at ``precision``."""
    return min(e["seconds"] for o, e in table if e["bytes"] <= budget and o.precision == precision)


def test_settings_that_fit_give_way_only_to_much_faster_ones_at_their_precision(surface):
    """With memory to spare the fit still takes the fastest settings, but only at the precision
    given (single precision is taken for memory only) and only when they are predicted
    SPEED_MARGIN faster than those given, which it keeps otherwise."""
    given = AIMOptions()
    table = _estimates(surface, given)
    need = table[0][1]["bytes"]
    for budget in (2 * need, float("inf")):
        fit = fit_to_budget(surface, 0.4, AL, given, budget)
        assert fit.fits and fit.options.precision == given.precision
        fastest = _fastest_within(table, budget, given.precision)
        assert fastest < (1 - SPEED_MARGIN) * table[0][1]["seconds"]  # this surface: much faster settings exist
        assert fit.estimate["seconds"] == pytest.approx(fastest) and fit.changed
        assert "faster than given" in fit.summary() and all(k in fit.summary() for k in fit.changed)
    assert "with no memory limit" in fit.summary()
    # fit_speed = false: settings that fit are kept
    pinned = replace(given, fit_speed=False)
    kept = fit_to_budget(surface, 0.4, AL, pinned, float("inf"))
    assert kept.options == pinned and not kept.changed and "as given" in kept.summary()


def test_settings_within_the_margin_of_the_fastest_are_kept(surface, monkeypatch):
    """Given settings that fit and another predicted faster by less than SPEED_MARGIN (here the
    flat patch at the near radius 6 against 7): kept, or where they fit only without their kept
    tables, kept without them; with no margin, the faster one."""
    import wavebrdf.solver.bem3d.aim.budget as budget

    given = AIMOptions(preconditioner="flat-patch", solver="gmres", restart=30, deflate=0)
    table = _estimates(surface, given)
    fastest = _fastest_within(table, float("inf"), given.precision)
    assert (1 - SPEED_MARGIN) * table[0][1]["seconds"] < fastest < table[0][1]["seconds"]
    kept = fit_to_budget(surface, 0.4, AL, given, float("inf"))
    assert kept.options == given and not kept.changed
    # a budget the given settings fit only without their kept tables: those, not the faster others
    with_tables, without = (estimate_aim(surface, 0.4, AL, aim=replace(given, reuse_setup=r))["bytes"]
                            for r in (True, False))
    lean = fit_to_budget(surface, 0.4, AL, given, 0.5 * (with_tables + without))
    assert lean.fits and lean.options == replace(given, reuse_setup=False)
    monkeypatch.setattr(budget, "SPEED_MARGIN", 0.0)
    changed = fit_to_budget(surface, 0.4, AL, given, float("inf"))
    assert changed.changed and changed.estimate["seconds"] == pytest.approx(fastest)


def test_a_tight_budget_gets_the_fastest_settings_that_fit(surface):
    given = AIMOptions()
    table = _estimates(surface, given)
    need = table[0][1]["bytes"]
    smallest = min(e["bytes"] for _, e in table)
    assert smallest < 0.8 * need  # the candidates do trade memory
    budget = 0.5 * (need + smallest)
    fit = fit_to_budget(surface, 0.4, AL, given, budget)
    assert fit.fits and fit.estimate["bytes"] <= budget
    assert fit.changed and set(fit.changed) <= set(FITTED_KEYS)
    assert fit.estimate["seconds"] == pytest.approx(_fastest_within(table, budget, given.precision))
    assert all(k in fit.summary() for k in fit.changed) and "fitted to the memory" in fit.summary()
    pinned = fit_to_budget(surface, 0.4, AL, replace(given, fit_speed=False), budget)  # changed for memory all the same
    assert pinned.fits and pinned.changed and pinned.estimate["bytes"] <= budget
    # a budget only single precision fits: the fastest of those
    double_need = min(e["bytes"] for o, e in table if o.precision == given.precision)
    single = [e for o, e in table if o.precision != given.precision and e["bytes"] < double_need]
    assert single
    budget = 0.5 * (double_need + min(e["bytes"] for e in single))
    fit = fit_to_budget(surface, 0.4, AL, given, budget)
    assert fit.fits and fit.options.precision != given.precision
    assert fit.estimate["seconds"] == pytest.approx(min(e["seconds"] for e in single if e["bytes"] <= budget))


def test_nothing_fits_gives_the_smallest_need_and_fit_memory_false_keeps_the_settings(surface):
    given = AIMOptions()
    table = _estimates(surface, given)
    smallest = min(e["bytes"] for _, e in table)
    fit = fit_to_budget(surface, 0.4, AL, given, 0.5 * smallest)
    assert not fit.fits and fit.estimate["bytes"] == smallest
    strict = fit_to_budget(surface, 0.4, AL, AIMOptions(fit_memory=False), 0.9 * table[0][1]["bytes"])
    assert not strict.fits and strict.options == AIMOptions(fit_memory=False)


def test_the_breakdown_adds_up(surface):
    e = estimate_aim(surface, 0.4, AL, aim=AIMOptions(), resolution=256)
    held, transient = e["held"], e["transient"]
    late = sum(held.values()) + max(v for k, v in transient.items() if k != "set-up")
    early = sum(held.values()) - held["preconditioner"] + transient["set-up"]
    assert e["bytes"] == pytest.approx(max(early, late), abs=8)
    assert "near field" in memory_breakdown(e) and "preconditioner" in memory_breakdown(e)


CONFIG = {
    "study": {"name": "budget", "output": "out/budget.h5"},
    "surface": {"generator": "gaussian", "size_um": 5.0, "cells": 200, "rms_height_um": 0.05, "correlation_um": 0.5,
                "seed": 1},
    "material": {"n": 0.46582, "kappa": 4.7119},
    "illumination": {"wavelengths_um": [0.4], "directions_deg": [[0, 0]], "waist_um": 1.0},
    "model": {"name": "bem", "method": "aim"},
    "output": {"resolution": 64},
}


def test_plan_and_run_use_the_settings_fitted_to_run_memory_gb(surface):
    given = estimate_aim(surface, 0.4, AL, aim=AIMOptions(), resolution=64, waist_um=1.0)["bytes"]
    table = [e["bytes"] for _, e in _estimates(surface, AIMOptions())]
    memory_gb = 0.5 * (given + min(table)) / GIB
    plan = plan_study(load_config({**CONFIG, "run": {"memory_gb": memory_gb}}))
    task = plan.tasks[0]
    estimate = plan.estimate(task)
    assert estimate.memory_bytes <= memory_gb * GIB
    check_memory(plan, 1, memory_gb)  # fits: no PlanError
    model = plan.model_spec(task).build()
    chosen = model.aim_options(plan.scene(task))  # what the run builds its operator with
    assert chosen != AIMOptions() and any(f"{k} = " in estimate.detail for k in FITTED_KEYS)
    tiny = plan_study(load_config({**CONFIG, "run": {"memory_gb": 0.5 * min(table) / GIB}}))
    with pytest.raises(PlanError, match="GiB"):
        check_memory(tiny, 1, 0.5 * min(table) / GIB)


def test_the_local_inverses_are_a_candidate_between_the_lu_and_none(surface):
    """The local inverses (GMRES(30)) need less than any near LU and more than no preconditioner,
    and are predicted to need fewer products than MINRES without one; a budget between their need
    and the LU's gets them when they are the fastest that fit."""
    table = _estimates(surface, AIMOptions())
    for o, e in table:
        if o.preconditioner != "local":
            continue
        assert o.solver == "gmres" and o.restart == 30
        same = {p: e2 for p2, e2 in table if p2.precision == o.precision and p2.near_cells == o.near_cells
                for p in [p2.preconditioner] if p2.preconditioner_tile_cells == 0}
        held = {p: e2["held"]["preconditioner"] for p, e2 in same.items()}
        assert 0 == held["none"] < e["held"]["preconditioner"] < held["near"] / 5
        assert same["none"]["bytes"] <= e["bytes"] <= same["near"]["bytes"]
        assert e["iterations_guess"] < same["none"]["iterations_guess"] / 3
    local = min((e["bytes"], e["seconds"]) for o, e in table if o.preconditioner == "local")
    lu = min(e["bytes"] for o, e in table if o.preconditioner == "near")
    fit = fit_to_budget(surface, 0.4, AL, AIMOptions(), 0.5 * (local[0] + lu))
    fastest = _fastest_within(table, 0.5 * (local[0] + lu), AIMOptions().precision)
    assert fit.fits and fit.estimate["seconds"] == pytest.approx(fastest)
    if fastest == local[1]:
        assert fit.options.preconditioner == "local" and "restart" in fit.summary()


def test_the_flat_patch_inner_solve_is_a_candidate_under_fgmres(surface):
    """The flat patch's inner solve runs under FGMRES(30) without deflation, at the inner steps its
    count was fitted at; it holds a fraction of the local inverses' memory and its estimate counts
    FGMRES's preconditioned vectors (30 more per right-hand side than the local inverses' GMRES(30))."""
    table = _estimates(surface, AIMOptions())
    flat = [(o, e) for o, e in table if o.preconditioner == "flat-patch"]
    assert flat
    n = surface.cells * (surface.cells - 1) * 4
    for o, e in flat:
        assert o.solver == "gmres" and o.restart == 30 and o.deflate == 0 and o.flat_inner_steps == 16
        local = next(e2 for o2, e2 in table if o2 == replace(o, preconditioner="local"))
        assert e["held"]["preconditioner"] < local["held"]["preconditioner"] / 4
        extra_krylov = e["transient"]["products"] - local["transient"]["products"]
        assert extra_krylov >= 16 * n * 2 * 30


def test_the_static_tables_kept_between_wavelengths_are_counted_and_dropped_when_they_do_not_fit(surface):
    """With ``reuse_setup`` the estimate holds the static tables (9 touching pairs × 33 float64 per
    element) through the solve; every candidate comes with and without them (the same predicted
    time), and a budget between the given settings' needs with and without them gets the fastest
    that fits, with the tables kept unless they are what does not fit."""
    kept = estimate_aim(surface, 0.4, AL, aim=AIMOptions())
    dropped = estimate_aim(surface, 0.4, AL, aim=AIMOptions(reuse_setup=False))
    assert kept["held"]["static tables"] == 9 * 33 * 8 * surface.cells**2 and dropped["held"]["static tables"] == 0
    assert kept["bytes"] - dropped["bytes"] == pytest.approx(kept["held"]["static tables"], abs=8)
    assert dropped["seconds"] == pytest.approx(kept["seconds"])
    table = _estimates(surface, AIMOptions())
    assert all(replace(o, reuse_setup=False) in [p for p, _ in table] for o, _ in table)
    budget = 0.5 * (kept["bytes"] + dropped["bytes"])
    fit = fit_to_budget(surface, 0.4, AL, AIMOptions(), budget)
    assert fit.fits and fit.estimate["seconds"] == pytest.approx(_fastest_within(table, budget, AIMOptions().precision))
    assert fit.estimate["seconds"] <= kept["seconds"] * (1 + 1e-12)
    # from the fastest settings, a budget they fit only without the tables: the same, without them
    fastest = replace(fit.options, reuse_setup=True)
    need = estimate_aim(surface, 0.4, AL, aim=fastest)["bytes"]
    tight = need - 0.5 * kept["held"]["static tables"]
    refit = fit_to_budget(surface, 0.4, AL, fastest, tight)
    assert refit.fits and refit.options == replace(fastest, reuse_setup=False)
    assert "reuse_setup True -> False" in refit.summary()
    given_without = fit_to_budget(surface, 0.4, AL, AIMOptions(fit_memory=False), budget)
    assert not given_without.fits  # fit_memory = false: not even the tables are dropped


def test_a_sub_area_after_its_first_wavelength_is_planned_as_a_following_solve():
    """A steered study's patch tasks: the first wavelength of a sub-area is planned as a whole solve,
    the next ones (same worker, just after it) without the kept static tables (COST
    ``static_table_s`` per element) and with warm-started products; with both off they cost the same."""
    from wavebrdf.solver.bem3d.aim.estimate import COST

    config = {**CONFIG, "surface": {**CONFIG["surface"], "size_um": 6.0, "cells": 240},
              "illumination": {"wavelengths_um": [0.4, 0.412], "directions_deg": [[0, 0]], "waist_um": 1.0},
              "material": {"table": [[0.4, 0.46582, 4.7119], [0.412, 0.4998, 4.8561]]},
              "steering": {"patches": [2, 1], "patch_size_um": 4.0, "shift_um": 2.0}}
    for aim, kept in (({}, True), ({"reuse_setup": False, "warm_start": False}, False)):
        plan = plan_study(load_config({**config, "model": {"name": "bem", "method": "aim", "aim": aim}}))
        patches = [t for t in plan.tasks if t.kind == "patch"]
        assert {t.wavelength for t in patches} == {0, 1} and len(patches) == 4
        for task in patches:
            whole = plan.model_spec(task).build().estimate(plan.model_scene(task))
            planned = plan.estimate(task).seconds
            if task.wavelength == 0 or not kept:
                assert planned == whole.seconds
                continue
            assert planned == whole.following_seconds
            cells = plan.model_scene(task).surface.cells
            assert whole.seconds - planned >= COST["static_table_s"] * cells**2 * (1 - 1e-9)


def test_the_budget_fit_keeps_deflation_within_each_candidates_solver():
    """Deflated restarts survive the planner's candidates: none with MINRES, below the local
    inverses' shorter restart."""
    from wavebrdf.solver.bem3d.aim import AIMOptions
    from wavebrdf.solver.bem3d.aim.budget import candidate_options

    for deflate in (10, 45):
        for o in candidate_options(AIMOptions(deflate=deflate, restart=60), 64):
            assert o.deflate == 0 if o.solver == "csym" else o.deflate < o.restart
            if o.preconditioner == "local":
                assert o.deflate == min(deflate, o.restart - 1)


def test_a_surface_steeper_than_the_product_counts_fit_is_named_in_the_estimate_and_the_plan(surface):
    """Corner cubes (faces at slope √2) lie beyond the fitted rms slope finer than λ: the estimate
    says so (its count held at the fitted edge) for the preconditioners whose count follows the
    slope, not for the near LU's, and the budget fit does not act on it for speed alone; the
    gentle fixture lies within."""
    from wavebrdf.solver.bem3d.aim.estimate import COST

    cubes = generate("corner-cubes", cells=40, size_um=2.0, period_um=1.0, shape="full")
    assert cubes.rms_slope_below(0.5) > COST["products_fine_slope_max"]
    flat_patch = AIMOptions(preconditioner="flat-patch", solver="gmres", restart=30, deflate=0)
    steep = estimate_aim(cubes, 0.5, AL, aim=flat_patch)
    assert "beyond the product count's fitted" in steep["outside_fit"]
    assert estimate_aim(cubes, 0.5, AL, aim=AIMOptions())["outside_fit"] == ""  # the near LU's count
    assert estimate_aim(surface, 0.4, AL, aim=flat_patch)["outside_fit"] == ""
    config = {**CONFIG, "surface": {"generator": "corner-cubes", "size_um": 2.0, "cells": 40, "period_um": 1.0,
                                    "shape": "full"},
              "model": {"name": "bem", "method": "aim", "aim": {"preconditioner": "flat-patch", "solver": "gmres",
                                                                "restart": 30, "deflate": 0}}}
    plan = plan_study(load_config(config))
    assert "beyond the product count's fitted" in plan.estimate(plan.tasks[0]).detail
    # such an estimate does not swap settings that fit for speed: the LU given stays, though the
    # flat patch's held count predicts it more than the margin faster
    larger = generate("corner-cubes", cells=80, size_um=4.0, period_um=1.0, shape="full")
    lu = estimate_aim(larger, 0.5, AL, aim=AIMOptions())
    patch = estimate_aim(larger, 0.5, AL, aim=flat_patch)
    assert patch["outside_fit"] and patch["seconds"] < (1 - SPEED_MARGIN) * lu["seconds"]
    kept = fit_to_budget(larger, 0.5, AL, AIMOptions(), float("inf"))
    assert kept.options == AIMOptions() and not kept.changed


def test_settings_a_user_gives_are_fitted_to_the_memory_only():
    """A benchmark's --aim: nothing given keeps the fit's choice for speed; anything given turns it
    off (fit_speed false) and keeps what was given, fit_speed itself included when given."""
    assert given_options({}) == AIMOptions()
    assert given_options({"precision": "single"}) == AIMOptions(precision="single", fit_speed=False)
    assert given_options({"near_cells": 5.0, "fit_speed": True}).fit_speed is True
