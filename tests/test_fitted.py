"""Fitted cost constants are data with provenance (solver/data/aim_cost.csv, solver/fitted.py):
every row names the run it came from, the AIM estimate reads them, and tools/refit_aim_cost.py
refits the set-up and product rows from measured stage clocks."""

from __future__ import annotations

import importlib.util
import math
import re
from pathlib import Path

import numpy as np
import pytest

from wavebrdf.solver.bem3d.aim import estimate
from wavebrdf.solver.fitted import COLUMNS, fitted, fitted_rows, write_fitted
from wavebrdf.solver.surface import HeightField, generate

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


def _product_tool():
    spec = importlib.util.spec_from_file_location("refit_product_counts", ROOT / "tools" / "refit_product_counts.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


PRODUCT_ROWS = ("products_minres", "products_minres_size_exp", "products_minres_slope_exp", "products_metal_slope_exp",
                "products_plasmon_exp", "products_dielectric_ratio", "products_local_ratio", "products_local_size_exp")
RANGE_ROWS = ("products_slope_offset", "products_fine_slope_max", "products_plasmon_binding_min",
              "products_plasmon_binding_max")


@pytest.mark.parametrize("scale_um", [0.1, 0.2])
def test_slope_below_a_scale_of_a_sinusoid(scale_um):
    """The product count's roughness feature against the closed form: a Gaussian of σ keeps
    e^{-(kσ)²/2} of a sinusoid's amplitude, so the relief finer than σ has the rms slope
    a k (1 − e^{-(kσ)²/2}) / √2 (k = 2π/P)."""
    a, period = 0.05, 0.8
    surface = generate("sinusoid", cells=160, size_um=4.0, amplitude_um=a, period_um=period)
    k = 2 * math.pi / period
    assert surface.rms_slope() == pytest.approx(a * k / math.sqrt(2), rel=5e-3)
    expected = a * k * (1 - math.exp(-((k * scale_um) ** 2) / 2)) / math.sqrt(2)
    assert surface.rms_slope_below(scale_um) == pytest.approx(expected, rel=1e-2)
    assert generate("flat", cells=16, size_um=1.0).rms_slope_below(0.4) == 0.0
    with pytest.raises(ValueError, match="scale_um must be a finite number > 0"):
        surface.rms_slope_below(0.0)
    tilted = HeightField(0.1 * np.add.outer(np.linspace(0, 1, 33), np.zeros(33)), 1.0)  # not periodic
    assert tilted.rms_slope() == pytest.approx(0.1, rel=1e-9)
    assert tilted.rms_slope_below(0.2) < 1e-12


@pytest.mark.parametrize("angle_deg", [0.0, 30.0])
def test_slope_along_an_azimuth_of_a_sinusoid(angle_deg):
    """The spot checks' in-plane slope against the closed form: z = a sin(k·x) with k at angle α
    from x has the slope a|k| cos(kx)(cos α cos φ + sin α sin φ) along φ, rms a|k||cos(φ − α)|/√2
    (the grid's central difference keeps sinc(|k|d/2) of it: 0.2–0.4 % off at d = Λ/32)."""
    a, period = 0.05, 0.8
    surface = generate("sinusoid", cells=160, size_um=4.0, amplitude_um=a, period_um=period, angle_deg=angle_deg)
    k = 2 * math.pi / period
    for phi_deg in (0.0, 30.0, 60.0, 90.0, 135.0):
        expected = a * k * abs(math.cos(math.radians(phi_deg - angle_deg))) / math.sqrt(2)
        assert surface.rms_slope_along(math.radians(phi_deg)) == pytest.approx(expected, rel=5e-3, abs=1e-6)
    tilted = HeightField(0.1 * np.add.outer(np.zeros(33), np.linspace(0, 1, 33)), 1.0)  # z rises along y
    assert tilted.rms_slope_along(math.pi / 2) == pytest.approx(0.1, rel=1e-9)
    assert tilted.rms_slope_along(0.0) < 1e-12


def test_product_rows_are_the_fit_of_the_measured_counts():
    """aim_cost.csv's product-count constants are tools/refit_product_counts.py's least-squares fit
    of solver/data/aim_products.csv (to the three digits the file keeps), and the estimate reads
    them through the same feature (the relief's rms slope finer than λ)."""
    tool = _product_tool()
    counts = tool.measured_counts()
    values = {**tool.fit(counts), **tool.fitted_ranges(counts)}
    assert set(values) == set(PRODUCT_ROWS + RANGE_ROWS)
    for name in values:
        assert fitted("aim_cost")[name] == pytest.approx(values[name], rel=5e-3, abs=1e-3), name
    row = next(r for r in counts if r["local"] and r["case"] == "glass, the sub-area family scaled to λ = 0.5 µm, 5 µm")
    surface = generate("gaussian", cells=160, size_um=5.0, seed=1, rms_height_um=0.125, correlation_um=1.25)
    aim = {"precision": "single", "near_cells": 7, "preconditioner": "local", "restart": 30}
    planned = estimate.estimate_aim(surface, 0.5, 1.5, waist_um=5.0 / 4.8, aim=aim)["iterations_guess"]
    options = estimate.AIMOptions.from_mapping(aim)
    assert planned == int(estimate._products(options, row["size_waves"], 1.5 + 0j, row["fine_slope"]))
    assert planned == pytest.approx(row["products"], rel=0.2)


def test_product_fit_recovers_known_constants():
    """Counts made from chosen constants by the estimate's own formula (``_products``) over the
    data file's surfaces and indices: the fit returns those constants."""
    tool = _product_tool()
    rows = [r for r in tool.measured_counts() if r["role"] == "fit"]
    truth = {"products_minres": 900.0, "products_minres_size_exp": 0.3, "products_minres_slope_exp": 0.5,
             "products_metal_slope_exp": 0.1, "products_plasmon_exp": 0.25, "products_dielectric_ratio": 0.1,
             "products_local_ratio": 0.3, "products_local_size_exp": 0.2}
    cost = {**fitted("aim_cost"), **truth, "products_fine_slope_max": 10.0, "products_plasmon_binding_min": -100.0,
            "products_plasmon_binding_max": 100.0}
    for r in rows:
        options = estimate.AIMOptions(preconditioner="local" if r["local"] else "none",
                                      solver="gmres" if r["local"] else "csym")
        r["products"] = estimate._products(options, r["size_waves"], r["index_complex"], r["fine_slope"], cost)
    values = tool.fit(rows, cost["products_slope_offset"])
    assert values == pytest.approx(truth, rel=1e-9)


def test_plasmon_binding_against_the_closed_form():
    """b = ln(Re n_spp − 1) of the flat interface's surface plasmon, n_spp² = ε/(1+ε) (Raether,
    *Surface Plasmons*, eq. 2.2, written out here for a lossless Drude-like ε = −9: n_spp = √(9/8)),
    and none for a dielectric or for −1 ≤ Re ε < 0."""
    assert estimate.plasmon_binding(3j) == pytest.approx(math.log(math.sqrt(9 / 8) - 1), rel=1e-12)
    # a lossy metal, in real arithmetic: ε = (n² − κ²) − 2nκ j; w = ε/(1+ε) = a + b j;
    # Re √w = √((|w| + a)/2) (the half-angle formula, branch-free)
    n, kappa = 0.46582, 4.7119  # aluminium at 0.4 µm: ε = −22.0 − 4.39j, weakly bound
    er, ei = n * n - kappa * kappa, -2 * n * kappa
    den = (1 + er) ** 2 + ei**2
    a, b = (er * (1 + er) + ei * ei) / den, (ei * (1 + er) - er * ei) / den
    expected = math.log(math.sqrt((math.hypot(a, b) + a) / 2) - 1)
    al = complex(n, -kappa)
    assert estimate.plasmon_binding(al) == pytest.approx(expected, rel=1e-12)
    assert estimate.plasmon_binding(al.conjugate()) == pytest.approx(expected, rel=1e-12)  # Re n_spp: either sign of κ
    assert -5 < estimate.plasmon_binding(al) < estimate.plasmon_binding(3j) < -2
    assert estimate.plasmon_binding(1.5) is None and estimate.plasmon_binding(0.5j) is None
    assert estimate.plasmon_binding(1j) is None and estimate.plasmon_binding(1.001j) > 0  # ε = −1: unbound; just below: tight


def test_the_count_of_a_metal_in_water_uses_the_relative_index_and_holds_the_binding():
    """estimate_aim counts a metal's products at its index relative to the exterior, L/λ and the
    fine slope in the exterior wavelength; an unbound plasmon (−1 ≤ Re ε < 0) gets the most
    tightly bound fitted count, not a dielectric's."""
    surface = generate("gaussian", cells=40, size_um=1.0, seed=2, rms_height_um=0.02, correlation_um=0.2)
    aim = {"precision": "single", "preconditioner": "local", "restart": 30}
    options = estimate.AIMOptions.from_mapping(aim)
    al, water, lam = 0.46582 - 4.7119j, 1.33, 0.4
    planned = estimate.estimate_aim(surface, lam, al, exterior_index=water, aim=aim, waist_um=0.3)["iterations_guess"]
    inside = lam / water
    assert planned == int(estimate._products(options, surface.size_um / inside, al / water,
                                             surface.rms_slope_below(inside)))
    assert planned != int(estimate._products(options, surface.size_um / inside, al, surface.rms_slope_below(inside)))
    unbound = estimate._products(options, 10.0, 0.3 - 1.0j, 0.2)  # ε = −0.91 − 0.6j
    assert unbound > 2 * estimate._products(options, 10.0, 1.5, 0.2)  # not glass's count
    assert unbound == pytest.approx(estimate._products(options, 10.0, 1.0001j, 0.2), rel=1e-9)  # the tightest


def test_product_fit_refuses_data_that_cannot_determine_it():
    tool = _product_tool()
    counts = [r for r in tool.measured_counts() if not r["local"]]
    with pytest.raises(ValueError, match="do not determine the model"):
        tool.fit(counts)
