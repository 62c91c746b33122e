"""Inputs at their extremes, inputs that would be ignored, and tracebacks turned into messages
(issue 35, items 8–10).

The property test is generated from the schemas: every numeric key of the config's sections
(``jobs/sections.py`` SCHEMA: numbers, pairs, lists and rows, with their
:class:`~wavebrdf.solver.options.Limits`; [surface] with every generator's keys) and every
numeric field of every registered model's Options dataclass gets each of :data:`EXTREMES`. Such a
case either loads and ``wavebrdf plan`` works (exit 0), or it is refused at load with a
ConfigError that names the key and the value — no other exception, nothing written. The ends of
each key's accepted range are tried too: they load, and ``plan`` then works or refuses in one
line (a 1 m patch of 12 cells is refused by the sampling check, in the words of cells). Every
CI run checks all cases (their count is printed and recorded as the test's ``cases`` property).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import typing
from pathlib import Path

import numpy as np
import pytest

from wavebrdf.jobs.cli import main
from wavebrdf.jobs.config import SCHEMA, ConfigError, load_config
from wavebrdf.jobs.overrides import dump_toml
from wavebrdf.jobs.sections import check_key
from wavebrdf.solver.options import Limits, OptionField

EXTREMES = (0, -1, 1e-300, 1e300, math.nan, math.inf, True, "1.5", [])

SURFACE = {"generator": "gaussian", "size_um": 3.0, "cells": 12, "rms_height_um": 0.02, "correlation_um": [0.6, 0.4],
           "angle_deg": 20.0, "seed": 1}
ILLUMINATION = {"wavelengths_um": [0.5], "directions_deg": [[10, 0]], "waist_um": 0.6}
BASE = {
    "study": {"name": "x", "output": "x.h5"},
    "surface": SURFACE,
    "material": {"n": 1.5, "kappa": 0.01, "exterior_index": 1.0},
    "illumination": ILLUMINATION,
    "model": {"name": "kirchhoff"},
    "output": {"resolution": 16, "per_polarization": False},
    "run": {"workers": 1, "memory_gb": 4.0, "retries": 1},
}
FIBER = {
    "study": {"name": "x", "output": "x.h5"},
    "fiber": {"shape": "circle", "radius_um": 0.3, "segments": 32, "rotation_deg": 10.0,
              "longitudinal_variance": 0.02},
    "material": {"n": 1.55, "kappa": 0.01},
    "illumination": {"wavelengths_um": [0.5], "theta_i_deg": [0, 30], "phi_i_deg": [0, 90]},
    "model": {"name": "mie"},
    "output": {"phi_r_bins": 16},
}
# every numeric key must appear in one of these (asserted): the surface generators' parameters,
# the other material sources, the fiber shapes and binned φ_i, steering
BASES = [
    BASE,
    {**BASE, "material": {"table": [[0.4, 1.5, 0.0], [0.7, 1.6, 0.1]]}},
    {**BASE, "surface": {"generator": "sinusoid", "size_um": 3.0, "cells": 12, "amplitude_um": 0.05,
                         "period_um": 1.0}},
    {**BASE, "surface": {"generator": "spherical-pits", "size_um": 3.0, "cells": 12, "radius_um": 0.4,
                         "depth_um": 0.1, "period_um": 1.0}},
    {**BASE, "surface": {"generator": "hemispheres", "size_um": 3.0, "cells": 12, "radius_um": 0.3, "fill": 0.2,
                         "placement": "random"}},
    {**BASE, "surface": {"generator": "corner-cubes", "size_um": 3.0, "cells": 12, "period_um": 1.0, "shape": "full",
                         "cant_deg": 5.0, "cant_azimuth_deg": 30.0}},
    {**BASE, "surface": {**SURFACE, "size_um": 6.0, "cells": 24}, "output": {"resolution": 64},
     "steering": {"patches": [2, 2], "patch_size_um": 4.0, "shift_um": 2.0, "hexagon_fill": 0.97}},
    FIBER,
    {**FIBER, "fiber": {"shape": "ellipse", "semi_axes_um": [0.3, 0.2], "segments": 32}, "model": {"name": "fiber-bem"},
     "illumination": {"wavelengths_um": [0.5], "theta_i_deg": [0]}, "output": {"phi_r_bins": 16, "phi_i_bins": 4}},
]


def tree(folder: Path) -> set:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def _edges(check: Limits, integer: bool = False) -> list[float]:
    """The ends of ``check``'s accepted range (its closed domain bounds and its physical span)."""
    ends = [] if check.low is None or check.low_open else [check.low]
    ends += [] if check.high is None or check.high_open else [check.high]
    if check.span is not None:
        ends += [e for e in check.span if e > 0] + ([-e for e in check.span] if check.low is None else [])
    return sorted({int(e) if integer else float(e) for e in ends})


def _variants(check: OptionField, base_value) -> list[tuple[str, object]]:
    """(label, value) of every extreme value, and of the ends of the accepted range, in every place
    ``check`` takes a number: the value itself, one element of a pair or list, one column of a row."""
    out = []
    if check.form == "rows":
        for j, (name, column) in enumerate(check.columns):
            for x, strict in [(x, True) for x in EXTREMES] + [(x, False) for x in _edges(column)]:
                row = list(base_value[0])
                row[j] = x
                out.append((f"{name}={x!r}", [row] + list(base_value[1:]), strict))
        return out
    for x, strict in [(x, True) for x in EXTREMES] + [(x, False) for x in _edges(check.limits, check.integer)]:
        if check.form == "list":
            out.append((repr([x]), [x], strict))
        elif check.form == "fixed":
            out.append((f"[{x!r}, b]", [x, base_value[1]], strict))
        else:
            out.append((repr(x), x, strict))
            if check.form == "one_or_pair" and isinstance(x, (int, float)) and not isinstance(x, bool):
                out.append((f"[{x!r}, {x!r}]", [x, x], strict))
    return out


def _schema_cases() -> list[tuple[str, dict, str, object, bool]]:
    """(case id, config, key, value, strict) for every numeric key of SCHEMA (strict: an extreme
    value, not an end of the range)."""
    cases = []
    for section, keys in SCHEMA.items():
        for key, spec in keys.items():
            if not spec.numeric:
                continue
            base = next((b for b in BASES if key in b.get(section, {})), None)
            assert base is not None, f"[{section}] {key} is numeric but no base config of {__name__} sets it: add it"
            for label, value, strict in _variants(spec, base[section][key]):
                config = copy.deepcopy(base)
                config[section][key] = value
                cases.append((f"{section}.{key}={label}", config, key, value, strict))
    return cases


def _numeric_fields(cls, path=()) -> list[tuple[tuple[str, ...], object, object]]:
    """(path, type, default) of every int/float/tuple[int] field of an options dataclass, nested
    dataclasses (sub-tables) included."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        kind = hints[f.name]
        if dataclasses.is_dataclass(kind):
            out += _numeric_fields(kind, path + (f.name,))
        elif kind in (int, float) or typing.get_origin(kind) is tuple:
            out.append((path + (f.name,), kind, f.default))
    return out


def _options_cases() -> list[tuple[str, dict, str, object, bool]]:
    """(case id, config, key, value, strict) for every numeric field of every registered model's
    Options (extreme values only: their ranges are the models' own)."""
    from wavebrdf.solver.models import model_class, model_names

    cases = []
    for name in model_names():
        cls = model_class(name)
        base = FIBER if cls.capabilities.takes == "cross_section" else BASE
        for path, kind, default in _numeric_fields(cls.Options):
            for x in EXTREMES:
                value = [x] + list(default[1:]) if typing.get_origin(kind) is tuple else x
                config = copy.deepcopy(base)
                table = config["model"] = {"name": name}
                for part in (name,) + path[:-1]:
                    table = table.setdefault(part, {})
                table[path[-1]] = value
                cases.append((f"model.{name}.{'.'.join(path)}={x!r}", config, path[-1], value, True))
    return cases


ALL_CASES = _schema_cases() + _options_cases()


def _shown(value) -> list[str]:
    """Ways a message may show ``value`` (Python's repr or TOML's spelling)."""
    if isinstance(value, list):
        return [_shown(v)[0] for v in value if not isinstance(v, list)][:1] or ["["]
    if isinstance(value, bool):
        return ["True", "true"]
    if isinstance(value, str):
        return [value]
    return [repr(value), f"{value:g}", str(value)]


def _check_case(folder: Path, config: dict, key: str, value, strict: bool, capsys) -> str:
    """How the case ended ("loaded", "refused", and for range ends "plan refused"); fails on
    anything else (module docstring)."""
    folder.mkdir()
    path = folder / "x.toml"
    path.write_text(dump_toml(config))
    before = tree(folder)
    cwd = os.getcwd()
    os.chdir(folder)
    try:
        try:
            load_config(path)
        except ConfigError as exc:
            message = str(exc)
            assert "\n" not in message, message
            if strict:
                assert key in message and any(text in message for text in _shown(value)), message
            assert tree(folder) == before, tree(folder) - before
            return "refused"
        code = main(["plan", str(path), "--rows", "2"])
        err = capsys.readouterr().err
        assert "Traceback" not in err, err
        assert tree(folder) == before, tree(folder) - before
        if code == 2 and not strict:
            assert len(err.strip().splitlines()) == 1 and err.startswith("wavebrdf: error: "), err
            return "plan refused"
        assert code == 0, f"{key} = {value!r} loads but `wavebrdf plan` exits {code}: {err}"
        return "loaded"
    finally:
        os.chdir(cwd)


def test_extreme_values_of_every_numeric_key_load_and_plan_or_are_refused_at_load(tmp_path, capsys,
                                                                                  record_property):
    outcomes = {"loaded": 0, "refused": 0, "plan refused": 0}
    for i, (label, config, key, value, strict) in enumerate(ALL_CASES):
        try:
            outcomes[_check_case(tmp_path / f"case{i}", config, key, value, strict, capsys)] += 1
        except (AssertionError, Exception) as exc:
            raise AssertionError(f"{label}: {type(exc).__name__}: {exc}") from None
    record_property("cases", len(ALL_CASES))
    print(f"\nproperty test: {len(ALL_CASES)} cases ({sum(c[-1] for c in ALL_CASES)} extreme values, the rest "
          f"range ends): {outcomes}")
    assert sum(outcomes.values()) == len(ALL_CASES) > 700


@pytest.mark.parametrize("key, value", [
    ("surface.size_um", 1e-300), ("material.n", 1e308), ("material.kappa", 1e300),
    ("illumination.waist_um", 1e-300), ("illumination.waist_um", 1e300),
    ("illumination.wavelengths_um", [1e-300]), ("illumination.wavelengths_um", [1e300]),
    ("material.exterior_index", 1e6),
])
def test_the_issues_extremes_are_refused_at_load_with_the_range(key, value):
    section, name = key.split(".")
    config = copy.deepcopy(BASE)
    config[section][name] = value
    with pytest.raises(ConfigError) as info:
        load_config(config)
    message = str(info.value)
    assert f"[{section}] {name} = " in message and any(t in message for t in _shown(value)), message
    assert any(word in message for word in ("physical range", "must be <=")), message


@pytest.mark.parametrize("key, used, typo", [
    ("illumination.wavelengths_um", [0.01, 0.4, 10.0], [4e-4]), ("illumination.directions_deg", [[89.9, 0], [0, -180]],
                                                                   [[30, 1e4]]),
    ("material.n", 1.0001, 1e5), ("material.n", 0.05, 1e-4), ("material.kappa", 1e3, 2e4), ("material.kappa", 1e-8, 1e5),
    ("surface.rms_height_um", 4e-6, 1e-7), ("surface.size_um", 162.0, 2e6), ("material.exterior_index", 1.33, 11.0),
    ("fiber.radius_um", 80.0, 1e-7), ("fiber.segments", 15_000, 10**6), ("run.memory_gb", 0.01, 1e-4),
])
def test_the_ranges_refuse_typos_and_accept_what_the_project_uses(key, used, typo):
    """The extremes suite's values (tests/extremes.py: λ 0.01 µm, κ 1e3 and 1e-8, n 1.0001, θ 89.9°,
    heights 1e-5 λ, x = 1000 fibers), the shipped configs' and real media's load; a value a few
    times beyond the physical range is refused, naming it."""
    section, name = key.split(".")
    check_key(section, name, used)  # no ConfigError
    with pytest.raises(ConfigError, match=rf"\[{section}\] {name} = .*(physical range|must be <=)"):
        check_key(section, name, typo)


# --- keys that conflict or would be ignored --------------------------------------------------------

@pytest.mark.parametrize("material, words", [
    ({"name": "gold", "kappa": 2.0}, ("kappa = 2.0 and name", "ignored", "gold")),
    ({"table": [[0.4, 1.5, 0.0], [0.7, 1.5, 0.0]], "kappa": 0.5}, ("kappa = 0.5 and table", "ignored")),
    ({"table": [[0.4, "1.5", 0.0], [0.7, 1.5, 0.0]]}, ("n must be a number", "1.5")),
    ({"table": [[0.4, 1.5, True], [0.7, 1.5, 0.0]]}, ("kappa must be a number", "True")),
])
def test_conflicting_or_ignored_material_keys_are_refused(material, words):
    config = {**copy.deepcopy(BASE), "material": material}
    with pytest.raises(ConfigError) as info:
        load_config(config)
    assert all(w in str(info.value) for w in words), str(info.value)


@pytest.mark.parametrize("extra", [{"cells": 64}, {"seed": 3}])
def test_surface_file_with_keys_it_ignores_is_refused(tmp_path, extra):
    np.save(tmp_path / "z.npy", np.zeros((13, 13)))
    config = {**copy.deepcopy(BASE), "surface": {"file": str(tmp_path / "z.npy"), "size_um": 3.0, **extra}}
    (key, value), = extra.items()
    with pytest.raises(ConfigError, match=rf"\[surface\] {key} = {value} and file = .*would be ignored"):
        load_config(config)
    del config["surface"][key]
    assert load_config(config).cases[0].surface.file is not None


def test_a_long_path_in_a_refusal_keeps_its_file_name(tmp_path):
    """Refusals show at most 80 characters of a value, cut in the middle: a file deep in a long
    folder keeps its name (cut at the end, the name was what went)."""
    deep = tmp_path / ("a_long_folder_name_" * 6) / "heights_of_sample_7.npy"
    deep.parent.mkdir()
    np.save(deep, np.zeros((13, 9)))
    config = {**copy.deepcopy(BASE), "surface": {"file": str(deep), "size_um": 3.0}}
    with pytest.raises(ConfigError) as info:
        load_config(config)
    message = str(info.value)
    assert "heights_of_sample_7.npy" in message and "..." in message and str(deep) not in message, message


# --- tracebacks turned into messages ---------------------------------------------------------------

def _plan_refusal(argv: list[str], capsys, folder: Path, *words: str) -> str:
    """Run ``argv``: exit 2, one line ``wavebrdf: error: ...`` holding ``words``, nothing written."""
    before = tree(folder)
    code = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("wavebrdf: error: "), (code, err)
    assert all(w in lines[0] for w in words), lines[0]
    assert tree(folder) == before
    return lines[0]


def _fiber_config(folder: Path, points_file: str) -> Path:
    config = {**copy.deepcopy(FIBER), "fiber": {"shape": "polygon", "points_file": points_file},
              "model": {"name": "fiber-bem"}, "study": {"name": "x", "output": str(folder / "x.h5")}}
    path = folder / "x.toml"
    path.write_text(dump_toml(config))
    return path


@pytest.mark.parametrize("kind, words", [
    ("latin-1", ("points_file", "shape.txt", "not UTF-8 text (byte 0xb5")),
    ("binary", ("points_file", "shape.txt", "not UTF-8 text")),
    ("folder", ("points_file", "shape.txt", "is a folder, not a file")),
    ("fifo", ("points_file", "shape.txt", "not a regular file (a named pipe)")),
])
def test_a_points_file_that_is_not_a_text_file_is_named_for_what_it_is(tmp_path, capsys, kind, words):
    target = tmp_path / "shape.txt"
    if kind == "latin-1":
        target.write_bytes("# contour in µm\n0 0\n1 0\n0 1\n".encode("latin-1"))
    elif kind == "binary":
        target.write_bytes(bytes(range(256)) * 4)
    elif kind == "folder":
        target.mkdir()
    else:
        os.mkfifo(target)  # never opened: reading it would block
    _plan_refusal(["plan", str(_fiber_config(tmp_path, "shape.txt"))], capsys, tmp_path, *words)


@pytest.mark.parametrize("text", ["x = " + "[" * 1200 + "]" * 1200, "x = " + "{a = " * 1200 + "1" + "}" * 1200,
                                  "[model]\nname = \"kirchhoff\"\n[model.kirchhoff" + ".a" * 1200 + "]\nb = 1"])
def test_a_config_nested_1200_deep_is_refused_in_one_line(tmp_path, capsys, text):
    path = tmp_path / "deep.toml"
    path.write_text(text + "\n")
    _plan_refusal(["plan", str(path)], capsys, tmp_path, "deep.toml", "nested")
    _plan_refusal(["plan", str(tmp_path / "deep.toml"), "--set", "surface.x=" + "[" * 1200 + "]" * 1200], capsys,
                  tmp_path, "--set surface.x", "nest")


def test_python_api_configs_and_overrides_nested_1200_deep_are_refused():
    deep: list = []
    for _ in range(1200):
        deep = [deep]
    with pytest.raises(ConfigError, match=r"^override surface.x: tables or arrays nested more than 32 levels"):
        load_config(_default_config(), overrides={"surface.x": deep})
    with pytest.raises(ConfigError, match=r"^config dict: tables or arrays nested more than 32 levels"):
        load_config({**copy.deepcopy(BASE), "surface": {"x": deep}})


def _default_config() -> Path:
    return Path(__file__).resolve().parents[1] / "configs" / "default.toml"


def test_render_decades_beyond_the_range_are_refused_and_tiny_data_keep_a_positive_scale(tmp_path, capsys):
    config = {**copy.deepcopy(FIBER), "study": {"name": "f", "output": str(tmp_path / "f.h5")}}
    path = tmp_path / "f.toml"
    path.write_text(dump_toml(config))
    assert main(["run", str(path), "-q", "--no-render"]) == 0
    capsys.readouterr()
    for decades in ("400", "0", "nan"):  # 400: once a ZeroDivisionError, or "damaged dataset"
        _plan_refusal(["render", str(tmp_path / "f.h5"), "--decades", decades], capsys, tmp_path,
                      f"--decades {float(decades):g}", "(0, 100]")
    assert main(["render", str(tmp_path / "f.h5"), "--decades", "100"]) == 0
    from wavebrdf.jobs.pictures.common import MAX_DECADES, log_limits, log_tone_map

    low, high = log_limits(np.array([1e-250, 1e-200]), MAX_DECADES)  # 1e-300 underflows to 0 in 10^-decades
    assert 0 < low < high == 1e-200 and np.all(np.isfinite(log_tone_map(np.ones((2, 3)), np.ones(2), low, high)))


def _surface_study(folder: Path) -> Path:
    path = folder / "s.toml"
    path.write_text(dump_toml({**copy.deepcopy(BASE), "study": {"name": "s", "output": str(folder / "out" / "s.h5")}}))
    return path


@pytest.mark.parametrize("flags, words", [
    (["--reference", "mie"], ("--reference mie", "fiber cross section", "kirchhoff")),
    (["--models", "kirchhoff,mie"], ("--models mie", "fiber cross section")),
    (["--models", ""], ("--models", "no model named")),
    (["--models", " , "], ("--models", "no model named")),
    (["--reference", ""], ("--reference", "no model named")),
    (["--models", "stam"], ("--models stam", "statistics")),
])
def test_compare_refuses_models_that_cannot_run_the_study_before_running_any(tmp_path, capsys, monkeypatch,
                                                                            flags, words):
    import wavebrdf.jobs.compare as compare

    ran = []
    monkeypatch.setattr(compare, "compare_scenes", lambda *a, **k: ran.append(a) or pytest.fail("models ran"))
    config = _surface_study(tmp_path)
    if "stam" in flags:  # a deterministic surface: no ensemble for stam
        text = config.read_text().replace('generator = "gaussian"', 'generator = "sinusoid"\namplitude_um = 0.05'
                                          '\nperiod_um = 1.0').replace("rms_height_um = 0.02\n", "")
        config.write_text(text.replace("correlation_um = [0.6, 0.4]\n", "").replace("angle_deg = 20.0\n", "")
                          .replace("seed = 1\n", ""))
    _plan_refusal(["compare", str(config), "-q", *flags], capsys, tmp_path, *words)
    assert not ran and not (tmp_path / "out").exists()


# --- plan: device buffers, linear time, short numbers ----------------------------------------------

@pytest.mark.parametrize("model", ["kirchhoff", "po", "ghs", "ohs", "ws-v", "stam"])  # gs, gm, wm: already
def test_every_surface_model_reports_its_largest_device_buffer_and_plan_checks_it(model):
    """The device check knows every approximate model's buffers from its own estimate: a device
    whose max allocation is below the largest buffer is refused at plan, one above passes."""
    import types

    from wavebrdf.jobs.plan import PlanError, check_memory, plan_study

    plan = plan_study(load_config({**copy.deepcopy(BASE), "model": {"name": model}}))
    estimate = plan.estimate(plan.tasks[0])
    assert estimate.largest_buffer_bytes is not None and estimate.device_bytes is not None
    assert estimate.largest_buffer_bytes <= estimate.device_bytes
    if model == "stam":  # host NumPy only: nothing on the device
        assert estimate.device_bytes == 0
        return
    gib = 2**30
    roomy = types.SimpleNamespace(name="test", max_alloc_gib=estimate.largest_buffer_bytes / gib * 1.01,
                                  global_mem_gib=estimate.device_bytes / gib * 1.01)
    check_memory(plan, 1, 4.0, device=roomy)
    small = types.SimpleNamespace(name="test", max_alloc_gib=estimate.largest_buffer_bytes / gib * 0.99,
                                  global_mem_gib=1e3)
    with pytest.raises(PlanError, match="needs one device buffer of .* more than the max allocation"):
        check_memory(plan, 1, 4.0, device=small)


def test_the_largest_buffer_grows_with_the_chebyshev_orders_of_a_rough_surface():
    """kirchhoff's fields buffer is orders × nodes² complex values: rougher heights at a shorter
    wavelength need more orders, and the reported buffer says so (the exterior_index = 1e6 case of
    the issue passed plan because nothing reported it)."""
    from wavebrdf.jobs.plan import plan_study

    sizes = []
    for rms in (0.02, 0.2):
        config = {**copy.deepcopy(BASE), "surface": {**SURFACE, "rms_height_um": rms, "cells": 64}}
        plan = plan_study(load_config(config))
        estimate = plan.estimate(plan.tasks[0])
        orders = int(estimate.detail.split(" Chebyshev")[0])
        sizes.append((orders, estimate.largest_buffer_bytes))
    (o1, b1), (o2, b2) = sizes
    assert o2 > o1 and b2 >= 16 * o2 * 65**2 and b2 / b1 == pytest.approx(o2 / o1, rel=0.01)


def test_plan_reads_the_index_once_per_case_whatever_the_number_of_wavelengths(monkeypatch):
    """Planning N wavelengths asks for the material index of N wavelengths in all (once per case),
    not N per task: plan time is linear in the number of tasks (issue 35 item 10: a 20,000-row
    wvl.txt planned in 182 s)."""
    import wavebrdf.jobs.plan as plan_module

    asked = []
    real = plan_module._material_index
    monkeypatch.setattr(plan_module, "_material_index", lambda spec, wl: asked.append(len(wl)) or real(spec, wl))
    for n in (50, 200):
        asked.clear()
        config = {**copy.deepcopy(BASE), "surface": {"generator": "flat", "size_um": 3.0, "cells": 24},
                  "illumination": {**ILLUMINATION, "wavelengths_um": {"start": 0.4, "stop": 0.8, "count": n},
                                   "directions_deg": [[0, 0], [30, 0]]}}
        plan = plan_module.plan_study(load_config(config))
        for task in plan.tasks:
            plan.estimate(task)
            plan.scene(task)
        assert len(plan.tasks) == 2 * n and sum(asked) == n, (n, len(asked), sum(asked))


@pytest.mark.parametrize("value, text", [(1e250, "1e+250"), (12.345, "12.35"), (999_999.0, "999999.00"),
                                         (4.72e12, "4.72e+12")])
def test_plan_numbers_stay_short(value, text):
    from wavebrdf.jobs.plan import format_bytes, format_number

    assert format_number(value) == text
    assert format_bytes(value * 2**30) == f"{float(text):.3g} GiB" and format_bytes(9.4 * 2**30) == "9.4 GiB"


@pytest.mark.parametrize("model", ["kirchhoff", "po", "ghs", "ohs", "ws-v", "wm", "gm"])  # gs: right already
def test_the_reported_largest_buffer_covers_every_buffer_the_run_allocates(cl_ctx, monkeypatch, model):
    """Each model's run, on a smooth and a rough scene, allocates no device buffer larger than its
    estimate says (the reference: the sizes pyopencl is asked for), and the estimate is not more
    than 1.5 times the largest one."""
    import pyopencl as cl

    from wavebrdf.jobs.plan import plan_study

    sizes = []
    real_buffer = cl.Buffer

    def recording(context, flags, size=0, hostbuf=None):
        sizes.append(size if hostbuf is None else np.asarray(hostbuf).nbytes)
        return real_buffer(context, flags, size, hostbuf=hostbuf) if hostbuf is not None else \
            real_buffer(context, flags, size)

    monkeypatch.setattr(cl, "Buffer", recording)
    options = {"rays": 1 << 17} if model in ("gs", "gm", "wm") else {}
    for rms, cells, resolution in ((0.02, 12, 16), (0.25, 32, 64)):
        config = {**copy.deepcopy(BASE), "model": {"name": model, **options}, "output": {"resolution": resolution},
                  "surface": {**SURFACE, "rms_height_um": rms, "cells": cells, "size_um": 0.25 * cells}}
        plan = plan_study(load_config(config))
        task = plan.tasks[0]
        reported = plan.estimate(task).largest_buffer_bytes
        sizes.clear()
        plan.model_spec(task).build().run(cl_ctx, plan.scene(task))
        assert max(sizes) <= reported <= 1.5 * max(sizes), (rms, max(sizes), reported)
