"""Fitted cost constants are data with provenance (solver/data/aim_cost.csv, solver/fitted.py):
every row names the run it came from, the AIM estimate reads them, and tools/refit_aim_cost.py
refits the set-up and product rows from measured stage clocks."""

from __future__ import annotations

import importlib.util
import math
import re
from pathlib import Path

import pytest

from wavebrdf.solver.bem3d.aim import estimate
from wavebrdf.solver.fitted import COLUMNS, fitted, fitted_rows, write_fitted
from wavebrdf.solver.surface import generate

ROOT = Path(__file__).resolve().parents[1]


def _refit_tool():
    spec = importlib.util.spec_from_file_location("refit_aim_cost", ROOT / "tools" / "refit_aim_cost.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_constant_names_its_run():
    rows = fitted_rows("aim_cost")
    names = [r["name"] for r in rows]
    assert len(names) == len(set(names))
    for row in rows:
        assert math.isfinite(float(row["value"])), row["name"]
        assert all(row[c].strip() for c in COLUMNS), f"{row['name']}: empty {[c for c in COLUMNS if not row[c]]}"
        assert re.fullmatch(r"[0-9a-f]{7,40}( \+ uncommitted changes)?", row["commit"]), row
    assert set(fitted("aim_cost")) == set(names)
    source = (ROOT / "solver" / "bem3d" / "aim" / "estimate.py").read_text()
    source += (ROOT / "solver" / "bem3d" / "aim" / "preconditioner.py").read_text()
    assert [n for n in names if f'"{n}"' not in source] == [], "rows the estimate does not read"


def test_the_estimate_reads_the_file(monkeypatch):
    surface = generate("gaussian", cells=16, size_um=0.4, seed=1, rms_height_um=0.02, correlation_um=0.2)
    options = {"precision": "single", "preconditioner": "none", "solver": "csym"}
    before = estimate.estimate_aim(surface, 0.4, 1.5, aim=options)
    monkeypatch.setitem(estimate.COST, "product_scale", 2 * estimate.COST["product_scale"])
    monkeypatch.setitem(estimate.COST, "runtime_bytes", estimate.COST["runtime_bytes"] + 2**30)
    monkeypatch.setattr(estimate, "RUNTIME_BYTES", estimate.COST["runtime_bytes"])
    after = estimate.estimate_aim(surface, 0.4, 1.5, aim=options)
    assert after["product_s"] == pytest.approx(2 * before["product_s"], rel=1e-12)
    assert after["bytes"] - before["bytes"] == 2**30


def test_refit_from_stage_clocks_and_rewrite_only_those_rows(tmp_path):
    tool = _refit_tool()
    cost = fitted("aim_cost")
    stage = lambda s: {"wall_s": s}  # noqa: E731
    rough = {"stages": {"near field": stage(100.0), "projection": stage(10.0), "grid spectra": stage(5.0),
                        "excitation": stage(5.0), "Krylov solve": stage(2.2 * 50)},
             "estimate": {"near_nnz": 1e7, "unknowns": 2e5, "product_s": 4.0}, "calls": 50}
    flat = {"stages": {"near field": stage(1.0), "projection": stage(1.0), "grid spectra": stage(0.5),
                       "excitation": stage(0.5)},
            "estimate": {"near_nnz": 1e6, "unknowns": 1e5, "product_s": 1.0}, "calls": 30}
    values = tool.fits(rough, flat, cost)
    assert values["near_pair_s_rough"] == pytest.approx(1e-5) and values["near_pair_s_flat"] == pytest.approx(1e-6)
    assert values["grid_setup_s_rough"] == pytest.approx(1e-4) and values["grid_setup_s_flat"] == pytest.approx(2e-5)
    assert values["product_scale"] == pytest.approx(cost["product_scale"] * 2.2 / cost["product_overhead"] / 4.0)
    assert set(values) == set(tool.REFIT)
    rows = fitted_rows("aim_cost")
    write_fitted(rows, tmp_path / "copy.csv")
    assert fitted_rows("aim_cost", tmp_path / "copy.csv") == rows


@pytest.mark.slow
def test_refit_tool_runs_on_a_small_case(tmp_path):
    """The documented command on a small case (~30 s): the five rows rewritten with this run's
    command, commit and machine, the others as they were."""
    out = tmp_path / "aim_cost.csv"
    assert _refit_tool().main(["--cells", "24", "--flat-size", "0.6", "--resolution", "64", "--out", str(out)]) == 0
    old, new = ({r["name"]: r for r in fitted_rows("aim_cost", p)} for p in (None, out))
    changed = {n for n in old if old[n] != new[n]}
    assert changed == {"near_pair_s_rough", "near_pair_s_flat", "grid_setup_s_rough", "grid_setup_s_flat",
                       "product_scale"}
    assert all(new[n]["command"].startswith("tools/refit_aim_cost.py --cells 24") for n in changed)
    assert all(float(new[n]["value"]) > 0 for n in changed)
