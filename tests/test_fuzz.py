"""Generated bad input (Hypothesis, derandomized: the same cases every run): configs (TOML keys and
values), height files, datasets and command-line flags. Every case must end with exit status 2
and exactly one line ``wavebrdf: error: ...`` naming the key, file or flag (and the value where
there is one), no traceback, and nothing written. Each test runs its cases in-process through
``wavebrdf.jobs.cli.main`` and checks that it ran its quota (330 cases in all).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from wavebrdf.jobs.cli import main

SETTINGS = dict(derandomize=True, database=None, deadline=None, print_blob=True,
                suppress_health_check=list(HealthCheck))

BASE = {
    "study": {"name": "fz", "output": "fz.h5"},
    "surface": {"generator": "gaussian", "size_um": 3.0, "cells": 12, "rms_height_um": 0.02, "correlation_um": 0.6},
    "material": {"name": "gold"},
    "illumination": {"wavelengths_um": [0.5], "directions_deg": [[0, 0]], "waist_um": 0.6},
    "model": {"name": "kirchhoff"},
    "output": {"resolution": 16},
}


def toml_value(value) -> str:
    """TOML text of a generated value (strings as JSON-escaped basic strings)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    return value.isoformat()  # dates


def toml(config: dict) -> str:
    return "\n".join(f"[{section}]\n" + "".join(f"{json.dumps(k)} = {toml_value(v)}\n" for k, v in keys.items())
                     for section, keys in config.items())


def tree(folder: Path) -> set:
    return {(str(p.relative_to(folder)), p.stat().st_size if p.is_file() else -1) for p in folder.rglob("*")}


class Case:
    """One example: a fresh folder (the working directory), the call, the checks."""

    def __init__(self, root: Path, counter: list):
        counter.append(1)
        self.folder = root / f"case{len(counter)}"
        self.folder.mkdir()

    def expect_refusal(self, argv: list[str], capsys, *names: str, allow_success: bool = False) -> str | None:
        os.chdir(self.folder)
        before = tree(self.folder)
        code = main(argv)
        err = capsys.readouterr().err
        assert "Traceback" not in err, err
        if code == 0 and allow_success:
            return None
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith("wavebrdf: error: "), (argv, code, err)
        assert any(name in lines[0] for name in names), (names, lines[0])
        assert tree(self.folder) == before, (lines[0], tree(self.folder) - before)
        return lines[0]


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


def fuzz(strategy, examples: int, body, root: Path) -> None:
    """Run ``body(case, Case)`` on ``examples`` generated cases, each in a fresh folder under
    ``root``; check that the quota ran (Hypothesis stops early on a small space)."""
    counter: list = []

    @settings(max_examples=examples, **SETTINGS)
    @given(strategy)
    def check(case):
        body(case, Case(root, counter))

    check()
    assert len(counter) >= examples, len(counter)


# --- configs --------------------------------------------------------------------------------------------

text = st.text(st.characters(exclude_categories=["Cs", "Cc"]), max_size=12)
nan_inf = st.sampled_from([math.nan, math.inf, -math.inf])
huge_int = st.integers(min_value=2**63, max_value=10**30) | st.integers(max_value=-(2**63), min_value=-(10**30))
not_number = st.one_of(text, st.booleans(), st.lists(st.integers(), max_size=2),
                       st.dictionaries(text, st.integers(), max_size=1), st.dates())
non_positive = st.one_of(st.floats(max_value=0, allow_nan=False), st.integers(max_value=0))
positive_bad = st.one_of(non_positive, nan_inf, not_number)


def int_bad(low: int):
    return st.one_of(st.integers(max_value=low - 1), huge_int, st.floats(allow_nan=True), not_number)


def _is_a_name(value: str) -> bool:
    """A valid choice somewhere: a model, a material, a generator, an option value."""
    from wavebrdf.jobs import config
    from wavebrdf.solver.materials import Material, MaterialError
    from wavebrdf.solver.models import model_names

    choices = {"flat", "gaussian", "sinusoid", "s", "p", "unpolarized", "exact", "paraxial", "plane", "double",
               "single", "auto", "serial", "processes", "mpi"} | set(model_names()) | set(config.SCHEMA)
    choices |= set(getattr(config, "SURFACE_GENERATORS", ()))
    if value in choices or value.lower() in choices:
        return True
    try:
        Material.from_name(value)
    except (MaterialError, AttributeError, TypeError):
        return False
    return True


choice_bad = st.one_of(text.filter(lambda t: not _is_a_name(t)), st.integers(), st.booleans())
wavelength_bad = st.one_of(st.just([]), st.lists(positive_bad, min_size=1, max_size=3), st.just([0.5, 0.5]),
                           st.floats(min_value=0.1, max_value=1), text)
angle = st.floats(min_value=-720, max_value=720, allow_nan=False)
direction_bad = st.one_of(st.just([]), st.lists(st.lists(angle, min_size=3, max_size=3), min_size=1, max_size=2),
                          st.lists(st.tuples(st.floats(min_value=90, max_value=1e6) | nan_inf, angle).map(list),
                                   min_size=1, max_size=2), st.just([[0, 0], [0, 0]]), text)

BAD_VALUES = {
    ("study", "name"): st.one_of(st.just(""), st.builds(lambda a, b: f"{a}/{b}", text, text),
                                 st.builds(lambda a: f"..{a}", text), st.integers(), st.booleans()),
    ("study", "output"): st.one_of(text.filter(lambda t: not t.endswith((".h5", ".hdf5", ".nc"))),
                                   st.builds(lambda a: f"/nonexistent/{a.replace('/', '_') or 'd'}/x.h5", text),
                                   st.integers()),
    ("surface", "size_um"): positive_bad,
    ("surface", "cells"): st.one_of(int_bad(3), st.integers(min_value=10**6, max_value=2**62)),
    ("surface", "seed"): int_bad(0),
    ("surface", "rms_height_um"): st.one_of(st.floats(max_value=-1e-9, allow_nan=False), nan_inf, not_number),
    ("surface", "correlation_um"): st.one_of(non_positive, nan_inf, text, st.booleans(), st.just([1.0])),
    ("surface", "generator"): choice_bad,
    ("material", "name"): choice_bad,
    ("material", "exterior_index"): st.one_of(st.floats(max_value=0.99, allow_nan=False), nan_inf, not_number),
    ("illumination", "wavelengths_um"): wavelength_bad,
    ("illumination", "directions_deg"): direction_bad,
    ("illumination", "waist_um"): positive_bad,
    ("illumination", "polarization"): choice_bad,
    ("illumination", "beam"): choice_bad,
    ("model", "name"): choice_bad,
    ("model", "precision"): choice_bad,
    ("output", "resolution"): st.one_of(st.integers(max_value=15), st.integers(min_value=8193), huge_int, not_number),
    ("output", "per_polarization"): st.one_of(st.integers(), text, st.floats()),
    ("run", "executor"): choice_bad,
    ("run", "workers"): int_bad(1),
    ("run", "memory_gb"): positive_bad,
    ("run", "retries"): int_bad(0),
}
KEY_NAMES = sorted(BAD_VALUES)
REQUIRED = [("surface", "size_um"), ("illumination", "wavelengths_um"), ("model", "name"), ("material", "name")]


@st.composite
def bad_config(draw) -> tuple[dict, str]:
    """(a config with one thing wrong, the name its error must mention)."""
    config = json.loads(json.dumps(BASE))
    how = draw(st.sampled_from(["value"] * 8 + ["unknown key", "unknown section", "missing key", "not a table"]))
    if how == "value":
        section, key = draw(st.sampled_from(KEY_NAMES))
        config.setdefault(section, {})[key] = draw(BAD_VALUES[(section, key)])
        return config, key
    if how == "unknown key":
        section = draw(st.sampled_from(["study", "surface", "illumination", "output", "run"]))
        key = draw(st.from_regex(r"[a-z_]{1,12}", fullmatch=True).filter(lambda k: k not in _known(section)))
        config.setdefault(section, {})[key] = draw(st.integers())
        return config, key
    if how == "unknown section":
        section = draw(st.from_regex(r"[a-z]{1,10}", fullmatch=True).filter(lambda s: s not in _sections()))
        config[section] = {"x": 1}
        return config, section
    if how == "missing key":
        section, key = draw(st.sampled_from(REQUIRED))
        del config[section][key]
        return config, section
    section = draw(st.sampled_from(["surface", "illumination", "output", "run"]))
    config[section] = draw(st.integers())
    return config, section


def _known(section: str) -> set:
    from wavebrdf.jobs.config import SCHEMA

    return set(SCHEMA.get(section, {}))


def _sections() -> set:
    from wavebrdf.jobs.config import SCHEMA

    return set(SCHEMA) | {"sweep"}


def _write_config(folder: Path, config: dict) -> Path:
    text = "".join(f"{s} = {toml_value(v)}\n" for s, v in config.items() if not isinstance(v, dict))  # top level first
    text += toml({s: v for s, v in config.items() if isinstance(v, dict)})
    path = folder / "fz.toml"
    path.write_text(text)
    return path


def test_fuzz_configs(workdir, capsys):
    def body(case, c):
        (config, name), command = case
        path = _write_config(c.folder, config)
        c.expect_refusal([command, str(path), "-q", "--no-render"] if command == "run" else [command, str(path)],
                         capsys, name, "not valid TOML")

    fuzz(st.tuples(bad_config(), st.sampled_from(["plan", "run"])), 150, body, workdir)


# --- height files ---------------------------------------------------------------------------------------

bad_dtype = st.one_of(hnp.boolean_dtypes(), hnp.complex_number_dtypes(), hnp.unicode_string_dtypes(max_len=3),
                      hnp.byte_string_dtypes(max_len=3), hnp.datetime64_dtypes(),
                      st.just(np.dtype([("a", "f8"), ("b", "i4")])))
bad_shape = st.one_of(st.just(()), hnp.array_shapes(min_dims=1, max_dims=1, max_side=20),
                      hnp.array_shapes(min_dims=3, max_dims=3, max_side=5),
                      st.tuples(st.integers(4, 12), st.integers(4, 12)).filter(lambda s: s[0] != s[1]),
                      st.tuples(st.integers(0, 3), st.integers(0, 3)).filter(lambda s: s[0] == s[1]))


@st.composite
def bad_heights(draw) -> tuple[str, bytes | np.ndarray]:
    """(file name, array for np.save or raw bytes): a height file that cannot be used."""
    kind = draw(st.sampled_from(["dtype", "shape", "nonfinite", "raw-npy", "text", "text-ragged"]))
    if kind == "dtype":
        return "z.npy", draw(hnp.arrays(draw(bad_dtype), (6, 6)))
    if kind == "shape":
        return "z.npy", draw(hnp.arrays(np.float64, draw(bad_shape), elements=st.floats(-1, 1)))
    if kind == "nonfinite":
        z = np.zeros((6, 6))
        z[draw(st.integers(0, 5)), draw(st.integers(0, 5))] = draw(nan_inf)
        return draw(st.sampled_from(["z.npy", "z.txt"])), z
    if kind == "raw-npy":
        return "z.npy", draw(st.binary(max_size=200))
    if kind == "text":
        token = draw(st.text(st.characters(categories=["L", "P", "S"]), min_size=1, max_size=4).filter(
            lambda t: "#" not in t and "," not in t and not _is_float(t)))
        rows = [["0.0"] * 6 for _ in range(6)]
        rows[draw(st.integers(0, 5))][draw(st.integers(0, 5))] = token
        return draw(st.sampled_from(["z.txt", "z.csv"])), "\n".join(" ".join(r) for r in rows).encode()
    lengths = draw(st.lists(st.integers(1, 8), min_size=2, max_size=6).filter(lambda l: len(set(l)) > 1))
    return "z.txt", "\n".join(" ".join(["0"] * n) for n in lengths).encode()


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def test_fuzz_height_files(workdir, capsys):
    def body(case, c):
        name, content = case
        if isinstance(content, np.ndarray):
            if name.endswith(".npy"):
                np.save(c.folder / name, content)
            else:
                np.savetxt(c.folder / name, content)
        else:
            (c.folder / name).write_bytes(content)
        config = json.loads(json.dumps(BASE))
        config["surface"] = {"file": name, "size_um": 3.0}
        c.expect_refusal(["plan", str(_write_config(c.folder, config))], capsys, name)

    fuzz(bad_heights(), 60, body, workdir)


# --- datasets -------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fuzz-dataset")
    config = json.loads(json.dumps(BASE))
    config["study"]["output"] = str(folder / "fz.h5")
    config["illumination"]["wavelengths_um"] = [0.5, 0.6]
    assert main(["run", str(_write_config(folder, config)), "-q", "--no-render"]) == 0
    return folder / "fz.h5"


REQUIRED_OBJECTS = ["brdf", "albedo", "albedo_sp", "theta_i", "phi_i", "polarization", "wavelength_um", "incidence",
                    "u", "v"]


@st.composite
def damage(draw):
    """(how, what): a change that leaves no complete wavebrdf dataset."""
    how = draw(st.sampled_from(["delete", "retype", "attr", "version", "truncate", "garbage", "empty"]))
    if how in ("delete", "retype"):
        return how, draw(st.sampled_from(REQUIRED_OBJECTS))
    if how == "attr":
        return how, draw(st.sampled_from(["format", "kind"])), draw(st.one_of(text, st.integers(-2**62, 2**62)))
    if how == "version":
        return how, draw(st.one_of(st.integers(-2**62, 2**62).filter(lambda v: v != 1), text,
                                   st.floats(allow_nan=False)))
    if how == "truncate":
        return how, draw(st.floats(min_value=0.0, max_value=0.95))
    if how == "garbage":
        return how, draw(st.binary(max_size=400))
    return (how,)


def _damage(path: Path, change) -> None:
    how = change[0]
    if how in ("truncate", "garbage", "empty"):
        if how == "truncate":
            os.truncate(path, int(path.stat().st_size * change[1]))
        else:
            path.write_bytes(change[1] if how == "garbage" else b"")
        return
    with h5py.File(path, "r+") as h5:
        if how == "delete":
            del h5[change[1]]
        elif how == "retype":
            name = change[1]
            del h5[name]
            h5[name] = np.array(["x"], dtype=object).astype(h5py.string_dtype()) if name != "polarization" else 3
        elif how == "attr":
            if change[2] == "" or (isinstance(change[2], str) and change[2] in ("wavebrdf", "surface", "fiber")):
                h5.attrs[change[1]] = 7
            else:
                h5.attrs[change[1]] = change[2]
        else:
            h5.attrs["format_version"] = change[1]


def test_fuzz_datasets(workdir, capsys, dataset):
    def body(case, c):
        change, command = case
        path = c.folder / "d.h5"
        shutil.copyfile(dataset, path)
        _damage(path, change)
        c.expect_refusal([command, str(path)], capsys, "d.h5")

    fuzz(st.tuples(damage(), st.sampled_from(["inspect", "inspect", "render"])), 60, body, workdir)


# --- command-line flags ---------------------------------------------------------------------------------

number_text = st.one_of(st.integers(-10**6, 0).map(str), st.sampled_from(["nan", "inf", "-inf", "", "1e999x", "0.0"]),
                        text.filter(lambda t: not _is_float(t)))
FLAGS = {
    "run": ["--workers"],
    "plan": ["--workers", "--memory-gb", "--rows"],
    "submit": ["--nodes", "--ntasks-per-node", "--cpus-per-task", "--memory-gb"],
}
PATHS = ["missing.toml", "folder", "/dev/null", "binary.toml"]


@st.composite
def bad_command(draw):
    """(argv, names one of which the error must mention) with at least one bad flag or path."""
    command = draw(st.sampled_from(["run", "plan", "submit", "inspect", "render"]))
    path_kind = draw(st.sampled_from(["good"] * 3 + PATHS))
    if command in ("inspect", "render"):
        path = draw(st.sampled_from(PATHS))
        return [command, path], [path if path != "folder" else "is a folder"]
    argv = [command, path_kind]
    names = [path_kind] if path_kind != "good" else []
    flags = draw(st.lists(st.sampled_from(FLAGS[command]), min_size=0 if names else 1, max_size=2, unique=True))
    for flag in flags:
        value = draw(number_text)
        argv += [flag, value]  # "--flag" "value": a value starting with "-" is taken as one too (argparse)
        names.append(flag)
    if command == "submit":
        argv += ["--time", draw(st.sampled_from(["01:00", "1 hour"]))]
        names.append("--time")
        if "--nodes" not in flags:
            argv += ["--nodes", "1"]
    if "folder" in names:
        names.append("is a folder")
    return argv, names


def test_fuzz_command_line(workdir, capsys):
    def body(case, c):
        argv, names = case
        config = json.loads(json.dumps(BASE))
        _write_config(c.folder, config).rename(c.folder / "good")
        (c.folder / "folder").mkdir()
        (c.folder / "binary.toml").write_bytes(bytes(range(256)) * 4)
        argv = [str(c.folder / a) if a in ("good", "folder", "missing.toml", "binary.toml") else a for a in argv]
        c.expect_refusal(argv, capsys, *names, "unrecognized arguments", "expected one argument")

    fuzz(bad_command(), 60, body, workdir)


def test_the_fuzz_helpers_write_valid_configs(tmp_path, capsys):
    """The unmodified base config is accepted: each refusal above comes from the one change."""
    path = _write_config(tmp_path, json.loads(json.dumps(BASE)))
    os.chdir(tmp_path)
    assert main(["plan", str(path)]) == 0, capsys.readouterr().err
    assert textwrap.dedent(toml_value([1.5, "a\"b", {"k": math.inf}])) == '[1.5, "a\\"b", {"k" = inf}]'
