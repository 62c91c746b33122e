"""The extremes suite (VALIDATION.md "Numerical stability at the extremes", issue 17 item 3):
every case of tests/extremes.py on every registered model it applies to must end ``ok`` (within
the tolerance of an independent reference), ``warned`` (loudly, in what the dataset keeps),
``refused`` (a clear ValueError) or ``skipped`` (beyond the machine by the model's own
estimate) — never ``FAIL``, a silent wrong number. CI runs :data:`CI_PAIRS`; the whole grid is
``-m slow`` (and docs/extremes.md, ``python -m benchmarks.extremes``)."""

from __future__ import annotations

import logging

import pytest

from extremes import CASE_BY_ID, CASES, models_for, run_case

logger = logging.getLogger(__name__)

# CI: each (case, model) below runs in a few seconds here; together they cover every registered
# model at an extreme and every fix the suite brought (PO/WS-V near index matching, OHS's
# dropped spectrum, the dataset's EnergyWarning at grazing incidence, fiber Rayleigh limit)
CI_PAIRS = {
    ("patch-5lambda", "kirchhoff"), ("patch-5lambda", "ohs"),
    ("grazing-89", "kirchhoff"), ("grazing-89", "ohs"), ("grazing-89", "ghs"), ("grazing-89", "gs"),
    ("grazing-89", "stam"), ("grazing-89", "ws-v"), ("grazing-89", "bem"), ("grazing-89", "po"),
    ("pec-rough-0", "ohs"), ("pec-rough-0", "gm"), ("pec-rough-0", "wm"),
    ("n-1.0001", "po"), ("n-1.0001", "kirchhoff"), ("n-1.0001", "stam"),
    ("kappa-1000", "ghs"), ("kappa-1e-08", "gs"),
    ("fiber-x-0.01", "mie"), ("fiber-x-0.01", "fiber-bem"), ("fiber-theta-89.9", "mie"), ("fiber-theta-89.9", "fiber-bem"),
    ("fiber-cusp", "fiber-bem"), ("fiber-cusp", "mie"),
}

# a model registered later and not named above gets the first of these cases that applies to it
DEFAULT_CI_CASES = ("grazing-89", "fiber-x-0.01")


def _ci_pairs() -> set:
    named = {n for _, n in CI_PAIRS}
    pairs = set(CI_PAIRS)
    for case_id in DEFAULT_CI_CASES:
        for name in models_for(CASE_BY_ID[case_id]):
            if name not in named:
                pairs.add((case_id, name))
                named.add(name)
    return pairs


CI = _ci_pairs()
PAIRS = [pytest.param(case.id, name, id=f"{case.id}-{name}", marks=() if (case.id, name) in CI else pytest.mark.slow)
         for case in CASES for name in models_for(case)]


@pytest.fixture(scope="module")
def kept():
    """One model instance at a time, reused by the next case of the same model and options."""
    return {}


@pytest.mark.parametrize("case_id,name", PAIRS)
def test_extreme_is_right_or_loud(cl_ctx, kept, case_id, name):
    out = run_case(cl_ctx, CASE_BY_ID[case_id], name, models=kept)
    logger.info("%s %s: %s value %.6g vs %s (error %.3g, tol %.3g) in %.1f s; %s %s", case_id, name, out.verdict,
                out.value, out.reference, out.error, out.tolerance, out.seconds, out.refused, out.warnings)
    assert not out.refused.startswith("crash"), f"{case_id} on {name}: {out.refused} ({out.note})"
    assert out.verdict != "FAIL", (f"{case_id} on {name}: a silent wrong number: {out.value} vs {out.reference} "
                                   f"(error {out.error:.3g} > {out.tolerance:.3g}), no warning {out.refused}")
    if out.verdict == "refused":
        assert "\n" not in out.refused.strip(), out.refused


def test_ci_pairs_are_cases():
    """The CI subset names existing (case, model) pairs and covers every registered model."""
    from wavebrdf.solver.models import model_names

    pairs = {(c.id, n) for c in CASES for n in models_for(c)}
    assert CI_PAIRS <= pairs, CI_PAIRS - pairs
    assert {n for _, n in CI} == set(model_names())


def test_rayleigh_reference_agrees_with_treams():
    """The thin-cylinder closed form (tests/references.py) against treams' T-matrix at x = 0.01,
    so that neither reference of the fiber cases is taken on trust."""
    import numpy as np

    from references import cylinder_rayleigh_widths, cylinder_widths_treams

    # the first corrections are O(x²|ε| ln x): 0.5% for the metal ε = −8.75 − 3j, 1e-4 for glass
    for m, rtol in ((1.55 - 0.01j, 1e-3), (1.55 - 1e-8j, 1e-3), (0.5 - 3.0j, 1e-2)):
        radius = 0.01 * 0.5 / (2 * np.pi)
        closed = cylinder_rayleigh_widths(0.5, radius, m)
        series = cylinder_widths_treams(0.5, radius, m, 0.0, orders=6)
        np.testing.assert_allclose(closed, series, rtol=rtol)


def test_update_replaces_the_rerun_cases_rows_once(tmp_path):
    """``python -m benchmarks.extremes --update --cases …`` keeps the other cases' rows and puts
    each rerun row in once (a rerun row identical to the old one was kept twice)."""
    from benchmarks.extremes import _merged

    first, second = CASES[0].id, CASES[1].id
    page = tmp_path / "extremes.md"
    page.write_text("| case | model | verdict |\n|---|---|---|\n"
                    f"| {first} | po | **ok** |\n| {first} | ohs | **warned** |\n| {second} | po | **ok** |\n")
    rows, counts, _ = _merged(page, [f"| {first} | po | **ok** |", f"| {first} | ohs | **ok** |"], {first})
    assert rows == [f"| {first} | po | **ok** |", f"| {first} | ohs | **ok** |", f"| {second} | po | **ok** |"]
    assert counts == {"ok": 3}
