"""Per-stage time and memory (solver/stages.py) against what the stages really did, and the BLAS
thread limit (solver/resources.py)."""

from __future__ import annotations

import mmap
import os

import numpy as np
import pytest

from wavebrdf.solver.resources import peak_memory_mb, peak_resident_bytes, reset_peak_memory
from wavebrdf.solver.stages import StageClock, format_stages

MB = 2**20


def _touch(megabytes: int) -> np.ndarray:
    """``megabytes`` of fresh anonymous memory, every page resident (an mmap of its own: malloc
    could serve the request from free heap memory that is resident already)."""
    a = np.frombuffer(mmap.mmap(-1, megabytes * MB), dtype=np.uint8)
    a[::4096] = 1
    return a


def test_a_stage_sees_its_own_peak_and_growth():
    clock = StageClock()
    with clock("temporary"):
        del_me = _touch(300)
        del del_me
    with clock("kept"):
        kept = _touch(200)
    t, k = clock.stages["temporary"], clock.stages["kept"]
    if np.isnan(t["peak_mb"]) or t["peak_mb"] == 0:
        pytest.fail("this kernel does not let a process reset its peak RSS (/proc/self/clear_refs)")
    assert t["peak_mb"] - (t["rss_mb"] - t["grew_mb"]) >= 290  # the 300 MB were resident inside the stage
    assert t["grew_mb"] < 50  # and given back (large arrays are mmapped)
    assert k["grew_mb"] >= 190 and k["peak_mb"] >= k["rss_mb"] - 1
    assert kept.sum() > 0
    assert "temporary" in format_stages(clock.as_dict())


def test_nested_stages_and_the_process_peak_survive_the_resets():
    reset_peak_memory()
    outer_clock, inner_clock = StageClock(), StageClock()
    with outer_clock("outer"):
        a = _touch(250)
        del a
        with inner_clock("inner"):  # its reset must not hide the outer stage's earlier peak
            b = _touch(50)
            del b
    base = outer_clock.stages["outer"]["rss_mb"]
    assert outer_clock.stages["outer"]["peak_mb"] >= base + 240
    assert inner_clock.stages["inner"]["peak_mb"] < base + 150
    assert peak_resident_bytes() / MB >= base + 240  # a measurement's peak (compare's MeasuringProcess)
    assert peak_memory_mb() >= base + 240  # the task's peak (jobs/tasks.py)


def test_repeated_stages_accumulate_time_and_keep_the_largest_memory():
    clock = StageClock()
    for size in (100, 20):
        with clock("direction"):
            a = _touch(size)
            del a
    d = clock.stages["direction"]
    assert d["calls"] == 2 and d["wall_s"] > 0
    assert d["peak_mb"] - (d["rss_mb"] - d["grew_mb"]) >= 90


def test_one_blas_thread_limits_every_loaded_blas_and_lifts_the_limit():
    """SuperLU's factorization runs under one_blas_thread (solver/bem3d/aim/preconditioner.py):
    inside, numpy's and scipy's BLAS libraries report one thread; after, the two set before."""
    import scipy.sparse.linalg  # noqa: F401  (loads scipy's own OpenBLAS where it has one)
    from threadpoolctl import threadpool_info, threadpool_limits

    from wavebrdf.solver.resources import one_blas_thread

    def counts():
        return {lib["filepath"]: lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}

    with threadpool_limits(2, user_api="blas"):
        before = counts()
        assert before and set(before.values()) == {2}
        with one_blas_thread():
            assert set(counts().values()) == {1}
        assert counts() == before


def test_huge_page_advice_follows_the_measurement_unless_the_user_asks(monkeypatch):
    """Without NUMPY_MADVISE_HUGEPAGE the advice is what huge_pages_pay measures; the variable wins."""
    from numpy._core.multiarray import _set_madvise_hugepage  # numpy >= 2, as locked

    from wavebrdf.solver import resources
    from wavebrdf.solver.resources import huge_page_advice

    previous = _set_madvise_hugepage(False)
    try:
        monkeypatch.delenv("NUMPY_MADVISE_HUGEPAGE", raising=False)
        for measured in (True, False):
            monkeypatch.setattr(resources, "huge_pages_pay", lambda measured=measured: measured)
            _set_madvise_hugepage(not measured)
            huge_page_advice()
            assert _set_madvise_hugepage(False) is measured
        monkeypatch.setattr(resources, "huge_pages_pay", lambda: pytest.fail("the user's choice is not measured"))
        for value, expected in (("1", True), ("0", False)):
            monkeypatch.setenv("NUMPY_MADVISE_HUGEPAGE", value)
            _set_madvise_hugepage(not expected)
            huge_page_advice()
            assert _set_madvise_hugepage(False) is expected
        assert huge_page_advice(False) is False and huge_page_advice(True) is False
    finally:
        _set_madvise_hugepage(previous)


def test_huge_pages_do_not_pay_where_the_kernel_has_them_off(monkeypatch, tmp_path):
    """THP "never" (or no THP settings at all): no advice, and nothing is probed."""
    from wavebrdf.solver import resources

    monkeypatch.setattr(resources, "_first_touch_seconds", lambda *a: pytest.fail("probed"))
    (tmp_path / "enabled").write_text("always madvise [never]\n")
    monkeypatch.setattr(resources, "THP_SETTINGS", str(tmp_path))
    assert resources.huge_pages_pay() is False
    monkeypatch.setattr(resources, "THP_SETTINGS", str(tmp_path / "missing"))
    assert resources.huge_pages_pay() is False


def test_the_probe_touches_a_fresh_mapping_and_records_its_answer(monkeypatch, tmp_path):
    """The real first-touch measurement on this machine, both ways, and its record."""
    from wavebrdf.solver import resources

    assert resources._first_touch_seconds(2**21, False) > 0 and resources._first_touch_seconds(2**21, True) > 0
    (tmp_path / "enabled").write_text("always [madvise] never\n")
    monkeypatch.setattr(resources, "THP_SETTINGS", str(tmp_path))
    monkeypatch.setattr(resources, "HUGE_PAGE_PROBE", {})
    answer = resources.huge_pages_pay()
    assert resources.HUGE_PAGE_PROBE["pays"] is answer and resources.HUGE_PAGE_PROBE["plain_s"] > 0


def test_huge_pages_pay_where_advised_pages_fill_no_slower(monkeypatch, tmp_path):
    from wavebrdf.solver import resources

    (tmp_path / "enabled").write_text("always [madvise] never\n")
    monkeypatch.setattr(resources, "THP_SETTINGS", str(tmp_path))
    for advised, plain, expected in ((0.001, 0.007, True), (0.2, 0.007, False)):
        monkeypatch.setattr(resources, "_first_touch_seconds",
                            lambda n, advise, a=advised, p=plain: a if advise else p)
        assert resources.huge_pages_pay() is expected
