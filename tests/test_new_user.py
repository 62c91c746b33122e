"""What a new user tripped on (issue 32), each as the behaviour it must have: Mitsuba XML scenes
find their datasets beside them, the README's quick start and Python example run one after the
other, the commands say what they do and how to get what is missing, the quick-start config is
within its model's validity, datasets use CF names, and the wheel carries the examples, the data
and the licence without packaging warnings."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
import tomllib
import warnings
import zipfile
from pathlib import Path

import h5py
import mitsuba as mi  # the `render` extra; missing = a failure, as every reference package
import numpy as np
import pytest

import wavebrdf
from test_mitsuba import write_beckmann_dataset
from test_mitsuba_fiber import make_dataset
from wavebrdf.jobs import cli
from wavebrdf.jobs.cli import build_parser, main
from wavebrdf.jobs.config import load_config
from wavebrdf.jobs.parts import ResumeError
from wavebrdf.jobs.plan import plan_study
from wavebrdf.solver.models import model_class, model_names
from wavebrdf.solver.validity import ValidityWarning, check_waist

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
README = (ROOT / "README.md").read_text()


def readme_block(language: str, after: str) -> str:
    """The first ```language block of the README after the heading ``after``."""
    start = README.index(after)
    found = re.search(rf"```{language}\n(.*?)```", README[start:], re.S)
    return found.group(1)


def quick_start_runs() -> list[list[str]]:
    """The ``wavebrdf run`` commands of the README's quick start, as argument lists."""
    lines = readme_block("bash", "## Quick start").splitlines()
    return [shlex.split(line, comments=True)[1:] for line in lines if line.startswith("wavebrdf run ")]


@pytest.fixture(scope="module")
def lobe(tmp_path_factory):
    """A small tabulated surface dataset (the Beckmann lobe of tests/test_mitsuba.py)."""
    return write_beckmann_dataset(tmp_path_factory.mktemp("lobe") / "lobe.h5", 0.3, resolution=16,
                                  wavelengths_um=[0.45, 0.55, 0.65], directions=[[0.0, 0.0], [40.0, 0.0]])


def tiny_study(output: Path, n: float = 1.5) -> dict:
    """A flat dielectric under two directions: a study that runs in a second."""
    return {"study": {"output": str(output)}, "surface": {"generator": "flat", "size_um": 4.0, "cells": 32},
            "material": {"n": n}, "model": {"name": "kirchhoff"}, "output": {"resolution": 16},
            "illumination": {"wavelengths_um": [0.5], "directions_deg": [[0, 0], [20, 0]], "waist_um": 0.7}}


# -- Mitsuba -----------------------------------------------------------------------------------------
def test_xml_scene_reads_datasets_beside_it(lobe, tmp_path, monkeypatch):
    """``filename`` is resolved as Mitsuba resolves its plugins' files: from the XML file's folder,
    whatever the working directory (both plugins)."""
    scene_dir = tmp_path / "scene"
    scene_dir.mkdir()
    shutil.copyfile(lobe, scene_dir / "lobe.h5")
    make_dataset(scene_dir, "fiber", 'shape = "circle"\nradius_um = 0.5', "mie", [0.5, 0.6], [0, 40])
    (scene_dir / "scene.xml").write_text(
        '<scene version="3.0.0">\n'
        '  <shape type="sphere"><bsdf type="wavebrdf"><string name="filename" value="lobe.h5"/></bsdf></shape>\n'
        '  <shape type="cylinder"><bsdf type="wavebrdf_fiber"><string name="filename" value="fiber.h5"/></bsdf>'
        '</shape>\n</scene>\n')
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    import wavebrdf.mitsuba as wm

    mi.set_variant("scalar_rgb")
    wm.register()
    scene = mi.load_file(str(scene_dir / "scene.xml"))
    surface = next(s.bsdf() for s in scene.shapes() if "sphere" in str(s).lower())
    reference = mi.load_dict({"type": "wavebrdf", "filename": str(scene_dir / "lobe.h5")})
    ctx, si = mi.BSDFContext(), mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(0.3, 0.0, float(np.sqrt(0.91)))
    wo = mi.Vector3f(-0.25, 0.05, float(np.sqrt(1 - 0.25**2 - 0.05**2)))
    value = np.array(surface.eval(ctx, si, wo))
    assert value.max() > 0 and np.array_equal(value, np.array(reference.eval(ctx, si, wo)))
    assert len(scene.shapes()) == 2


def render_args(dataset, *flags) -> list[str]:
    return ["render", str(dataset), *flags]


def test_render_scene_hint_names_the_scenes_of_the_datasets_kind(lobe, capsys):
    assert main(render_args(lobe, "--scene", "fibers")) == 2
    err = capsys.readouterr().err
    assert "needs a fiber dataset" in err and "surface datasets render with --scene sphere or plate" in err
    assert "fiber datasets render with --scene fibers" not in err


def test_render_scene_takes_spp_resolution_and_variant(lobe, tmp_path, capsys):
    out = tmp_path / "png"
    assert main(render_args(lobe, "--scene", "plate", "--spp", "1", "--resolution", "8", "--variant", "scalar_rgb",
                            "--out", str(out))) == 0
    assert "Mitsuba scalar_rgb" in capsys.readouterr().out
    image = np.array(mi.Bitmap(str(out / "lobe_plate.png")))
    assert image.shape[:2] == (8, 8)
    assert main(render_args(lobe, "--spp", "4")) == 2
    assert "--spp 4: only with --scene" in capsys.readouterr().err
    assert main(render_args(lobe, "--scene", "plate", "--spp", "0")) == 2
    assert "--spp 0: must be an integer >= 1" in capsys.readouterr().err


def test_render_scene_of_a_swept_dataset_names_its_case(tmp_path, capsys):
    """A dataset of two sweep cases renders the case named (--case or --sweep), in a file that
    names it; without one it is refused listing the cases, not rendered from case 0 unsaid."""
    config = {"study": {"name": "swept", "output": str(tmp_path / "swept.h5")},
              "surface": {"generator": "gaussian", "size_um": 4.0, "cells": 40, "rms_height_um": 0.02,
                          "correlation_um": 0.8, "seed": 1},
              "material": {"name": "aluminium"},
              "illumination": {"wavelengths_um": [0.55], "waist_um": 0.8, "directions_deg": [[0, 0], [30, 0]]},
              "model": {"name": "kirchhoff"}, "output": {"resolution": 16},
              "sweep": {"surface.rms_height_um": [0.02, 0.05]}}
    wavebrdf.run(config).close()
    dataset, out = tmp_path / "swept.h5", tmp_path / "png"
    flags = ("--scene", "plate", "--spp", "1", "--resolution", "8", "--variant", "scalar_rgb", "--out", str(out))
    capsys.readouterr()
    assert main(render_args(dataset, *flags)) == 2
    assert "2 sweep cases (surface.rms_height_um = 0.02, 0.05): choose one with --case" in capsys.readouterr().err
    assert main(render_args(dataset, *flags, "--case", "1")) == 0
    assert main(render_args(dataset, *flags, "--sweep", "surface.rms_height_um=0.02")) == 0
    assert sorted(p.name for p in out.iterdir()) == ["swept_case0_plate.png", "swept_case1_plate.png"]


def test_missing_mitsuba_says_how_to_install_it(lobe, monkeypatch, capsys):
    """The message names the `render` extra and the requirement pyproject.toml gives it."""
    (requirement,) = PYPROJECT["project"]["optional-dependencies"]["render"]
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # `import mitsuba` raises ImportError
    assert main(render_args(lobe, "--scene", "sphere")) == 2
    err = capsys.readouterr().err
    assert "pip install 'wavebrdf[render]'" in err and f"pip install '{requirement}'" in err, err
    assert len(err.strip().splitlines()) == 1


# -- the README's quick start and Python example ------------------------------------------------------
def test_readme_quick_start_then_python_example(tmp_path, monkeypatch, capsys):
    """Every ``wavebrdf run`` of the quick start, then the README's Python block, in a fresh folder
    holding configs/default.toml: nothing is refused as another configuration's output."""
    (tmp_path / "configs").mkdir()
    shutil.copyfile(ROOT / "configs" / "default.toml", tmp_path / "configs" / "default.toml")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    runs = quick_start_runs()
    assert len(runs) == 2
    for args in runs:
        assert main(args + ["-q", "--no-render"]) == 0, capsys.readouterr().err
    code = readme_block("python", "## Quick start")
    assert "wavebrdf.run(" in code
    exec(compile(code, "README.md", "exec"), {})
    assert "albedo" in capsys.readouterr().out


def test_python_api_refusal_names_force_true(tmp_path):
    out = tmp_path / "flat.h5"
    wavebrdf.run(tiny_study(out)).close()
    with pytest.raises(ResumeError, match=r"add force=True to overwrite it") as refused:
        wavebrdf.run(tiny_study(out, n=2.0))
    assert "--force" not in str(refused.value)
    with wavebrdf.run(tiny_study(out, n=2.0), force=True) as ds:
        assert ds["ior_n"][0] == 2.0


def test_quick_start_config_is_within_its_models_validity():
    """Each run of the README's quick start plans tasks whose model (kirchhoff) would warn about
    nothing: neither the footprint's angular spread (check_waist) nor the sampling."""
    for args in quick_start_runs():
        parsed = build_parser().parse_args(args)
        config = load_config(ROOT / parsed.config, output=parsed.output, overrides=parsed.set)
        plan = plan_study(config)
        model = plan.model_spec(plan.tasks[0]).build()
        for task in plan.tasks:
            scene = plan.model_scene(task)
            with warnings.catch_warnings():
                warnings.simplefilter("error", ValidityWarning)
                check_waist(scene, {}, model.name)
            assert model.validity(scene) == [], (args, task)


def test_readme_states_the_quick_start_regime():
    """The time of the quick start is given with its regime, measured: the machine's cores and
    load, the kernels built on the first run or cached (not a bare '~10 s')."""
    line = next(line for line in readme_block("bash", "## Quick start").splitlines()
                if line.startswith("wavebrdf run configs/default.toml "))
    note = " ".join(README[README.index("## Quick start"):README.index("Pictures and their options")].split())
    assert "~10 s" not in line
    for words in ("cores", "first run", "cached", "load"):
        assert words in note, words


# -- commands ----------------------------------------------------------------------------------------
def test_models_prints_user_summaries_not_docstrings(capsys):
    assert main(["models"]) == 0
    lines = capsys.readouterr().out.splitlines()
    headers = {line.split(":", 1)[0]: line.split(":", 1)[1].strip() for line in lines if not line.startswith(" ")}
    assert set(headers) == set(model_names())
    for name, text in headers.items():
        assert text == model_class(name).summary, name
        for internal in ("Registry adapter", "``", "[model] name", ".py", "§", "docstring"):
            assert internal not in text, (name, text)
    # every model says what it computes
    assert not [name for name, text in headers.items() if not text]


def test_bench_outside_a_checkout_says_where_the_benchmarks_are(tmp_path, monkeypatch, capsys):
    installed = tmp_path / "site-packages" / "wavebrdf" / "jobs" / "cli.py"  # as in a wheel
    monkeypatch.setattr(cli, "__file__", str(installed))
    monkeypatch.chdir(tmp_path)
    assert main(["bench", "kirchhoff"]) == 2
    err = capsys.readouterr().err
    assert "source checkout" in err and "python benchmarks/bench_kirchhoff.py" in err, err
    monkeypatch.chdir(ROOT)  # a checkout beside the installed copy: its benchmarks are found
    assert cli.benchmarks_folder(installed.parent.parent, ROOT) == ROOT / "benchmarks"
    assert main(["bench", "nosuch"]) == 2
    err = capsys.readouterr().err
    assert "no such benchmark" in err and "kirchhoff" in err


def test_example_writes_a_config_with_the_files_it_reads(tmp_path, monkeypatch, capsys):
    assert main(["example"]) == 0
    listed = capsys.readouterr().out
    assert re.search(r"^default +Quick-start study", listed, re.M)
    folder = tmp_path / "mine"
    assert main(["example", "default", "--out", str(folder)]) == 0
    assert (folder / "default.toml").read_bytes() == (ROOT / "configs" / "default.toml").read_bytes()
    assert main(["example", "heightfield_file.toml", "--out", str(folder)]) == 0
    assert (folder / "data" / "bumps_101x101.txt").is_file()
    monkeypatch.chdir(tmp_path)  # the config reads its file from its own folder
    assert load_config(folder / "heightfield_file.toml").cases
    capsys.readouterr()
    assert main(["example", "default", "--out", str(folder)]) == 2
    assert f"would overwrite {folder / 'default.toml'}" in capsys.readouterr().err
    assert main(["example", "default", "--out", str(folder), "--force"]) == 0
    assert main(["example", "defualt"]) == 2
    assert "did you mean 'default'?" in capsys.readouterr().err


# -- datasets ----------------------------------------------------------------------------------------
def _names(group: h5py.Group, where: str = ""):
    for name, item in group.items():
        yield f"{where}/{name}", name
        if isinstance(item, h5py.Group):
            yield from _names(item, f"{where}/{name}")


def test_dataset_names_begin_with_a_letter_and_old_names_are_read(tmp_path):
    """CF 2.3: every variable and group name begins with a letter (a surface and a fiber study);
    a version-2 file, whose case variables were the bare case numbers, is still read."""
    surface = tmp_path / "flat.h5"
    wavebrdf.run(tiny_study(surface)).close()
    fiber = make_dataset(tmp_path, "fiber", 'shape = "circle"\nradius_um = 0.5', "mie", [0.5], [0, 40])
    for path in (surface, fiber):
        with h5py.File(path, "r") as h5:
            bad = [full for full, name in _names(h5) if not name[0].isalpha()]
        assert not bad, (path.name, bad)
    with wavebrdf.open(surface) as ds:
        heights = ds.surface(0)
    old = tmp_path / "v2.h5"
    shutil.copyfile(surface, old)
    with h5py.File(old, "r+") as h5:
        h5.move("surface/height_0", "surface/0")
        h5.attrs["format_version"] = 2
    with wavebrdf.open(old) as ds:
        assert np.array_equal(ds.surface(0), heights) and ds.case_variable(0).name == "/surface/0"
    with wavebrdf.open(fiber) as ds:
        assert ds.case_variable(0).shape[1] == 2
    old_fiber = tmp_path / "fiber_v2.h5"
    shutil.copyfile(fiber, old_fiber)
    with h5py.File(old_fiber, "r+") as h5:
        h5.move("fiber/polygon_0", "fiber/0")
        h5.attrs["format_version"] = 2
    for path, picture in ((old, "heights"), (old_fiber, "cross_sections")):  # the pictures of v2 files
        out = tmp_path / f"{path.stem}_png"
        assert main(["render", str(path), "--out", str(out)]) == 0
        assert list(out.glob(f"*{picture}*.png")), sorted(p.name for p in out.iterdir())


# -- packaging ---------------------------------------------------------------------------------------
def test_wheel_ships_examples_data_and_licence_without_warnings(tmp_path):
    """``pip wheel`` (build isolation: the setuptools pyproject.toml asks for) of the files
    pyproject.toml names: no packaging warnings; the example configs and their data, the submit
    templates, the fitted data and the MIT licence are in the wheel."""
    source = tmp_path / "src"
    tool = PYPROJECT["tool"]["setuptools"]
    folders = set(tool["package-dir"].values())
    files = [PYPROJECT["project"]["readme"], "pyproject.toml", *PYPROJECT["project"]["license-files"]]
    for folder in folders:
        shutil.copytree(ROOT / folder, source / folder, ignore=shutil.ignore_patterns("__pycache__"))
    for name in files:
        shutil.copyfile(ROOT / name, source / name)
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", str(tmp_path / "dist"),
                            str(source)], capture_output=True, text=True, timeout=600)
    log = built.stdout + built.stderr
    assert built.returncode == 0, log[-3000:]
    for warning in ("BuildBackendWarning", "DeprecationWarning", "deprecated", "absent from the `packages`"):
        assert warning not in log, log[-3000:]
    (wheel,) = (tmp_path / "dist").glob("wavebrdf-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        metadata = next(archive.read(n).decode() for n in names if n.endswith(".dist-info/METADATA"))
        licence = next(archive.read(n).decode() for n in names if n.endswith(".dist-info/licenses/LICENSE"))
    assert PYPROJECT["project"]["license"] == "MIT" and "License-Expression: MIT" in metadata
    assert licence.startswith("MIT License") and licence == (ROOT / "LICENSE").read_text()
    expected = {f"wavebrdf/examples/{p.name}" for p in (ROOT / "configs").glob("*.toml")}
    expected |= {f"wavebrdf/examples/data/{p.name}" for p in (ROOT / "configs" / "data").iterdir()}
    expected |= {f"wavebrdf/jobs/templates/{p.name}" for p in (ROOT / "jobs" / "templates").glob("*.sh")}
    expected |= {f"wavebrdf/solver/data/{p.name}" for p in (ROOT / "solver" / "data").iterdir()}
    assert expected <= names, sorted(expected - names)
    assert not [n for n in names if n.startswith("wavebrdf/examples/compare")]


def test_inspect_into_a_closed_pipe_is_not_a_damaged_file(lobe):
    """``wavebrdf inspect x.h5 | true``: the reader closed the pipe before the first line; the
    command says nothing more (not "damaged or incomplete") and exits as a shell's writer does
    when its reader leaves (141 = 128 + SIGPIPE)."""
    shell = f"{shlex.quote(sys.executable)} -m wavebrdf inspect {shlex.quote(str(lobe))} | true; exit ${{PIPESTATUS[0]}}"
    done = subprocess.run(["bash", "-c", shell], capture_output=True, text=True, timeout=120, cwd=lobe.parent)
    assert done.returncode == 141 and done.stderr == "", (done.returncode, done.stderr)
