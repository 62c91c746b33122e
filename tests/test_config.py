"""Bad input gives a one-line error naming the problem, and writes nothing."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

from wavebrdf.jobs.cli import main
from wavebrdf.jobs.config import ConfigError, parse_config

BASE = """
[study]
output = "{out}"

[surface]
{surface}

[material]
{material}

[illumination]
wavelengths_um = {wavelengths}
directions_deg = [[0, 0], [30, 10]]
waist_um = 1.0

[model]
name = "kirchhoff"

[output]
resolution = 32
"""
GOOD_SURFACE = 'generator = "gaussian"\nsize_um = 6.0\ncells = 48\nrms_height_um = 0.05\ncorrelation_um = 1.0'


def write_config(tmp_path: Path, *, surface=GOOD_SURFACE, material='name = "gold"', wavelengths="[0.5, 0.6]",
                 out=None, extra="") -> Path:
    out = out or str(tmp_path / "result.h5")
    text = BASE.format(out=out, surface=surface, material=material, wavelengths=wavelengths) + extra
    path = tmp_path / "study.toml"
    path.write_text(textwrap.dedent(text))
    return path


def heights_file(tmp_path: Path, z: np.ndarray, name="z.txt") -> str:
    path = tmp_path / name
    np.savetxt(path, z, delimiter=",")
    return path.name


def run_cli(config: Path, capsys) -> tuple[int, str]:
    code = main(["run", str(config), "--no-render", "--quiet"])
    err = capsys.readouterr().err.strip()
    return code, err


BAD_CASES = {
    "missing key": (dict(surface='generator = "flat"\ncells = 8'), r"\[surface\] size_um: missing required key"),
    "wrong type": (dict(wavelengths='"0.5"'), r"\[illumination\] wavelengths_um = \"0.5\": must be a non-empty list"),
    "negative size": (dict(surface='generator = "flat"\nsize_um = -3.0\ncells = 8'), r"size_um = -3.0: must be > 0"),
    "negative wavelength": (dict(wavelengths="[0.5, -0.4]"), r"wavelengths_um .*values must be finite numbers > 0"),
    "negative kappa": (dict(material="n = 1.5\nkappa = -0.1"), r"\[material\] kappa = -0.1: must be >= 0"),
    "negative kappa in table": (
        dict(material="table = [[0.4, 1.5, 0.0], [0.7, 1.5, -0.2]]"), r"kappa must be >= 0"),
    "unknown material": (dict(material='name = "unobtainium"'), r"material.name 'unobtainium' is unknown"),
    "wavelength outside table": (
        dict(material="table = [[0.4, 1.5, 0.0], [0.55, 1.5, 0.0]]"), r"defined for 0.4–0.55 µm"),
    "unknown section": (dict(extra="\n[surfaces]\nx = 1\n"), r"\[surfaces\]: unknown section; did you mean 'surface'"),
    "invalid TOML": (dict(extra='\n[model]\nname = "kirchhoff"\n'), r"not valid TOML"),
    "typo key": (dict(surface=GOOD_SURFACE + "\nrms_hieght_um = 0.1"), r"did you mean 'rms_height_um'"),
}


@pytest.mark.parametrize("case", list(BAD_CASES))
def test_bad_config_one_line_error_and_no_output(tmp_path, capsys, case):
    kwargs, pattern = BAD_CASES[case]
    config = write_config(tmp_path, **kwargs)
    code, err = run_cli(config, capsys)
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith("wavebrdf: error:")
    assert pytest.importorskip("re").search(pattern, err), err
    assert not any(p.name.startswith("result") for p in tmp_path.iterdir())


@pytest.mark.parametrize(
    "heights, pattern",
    [
        (np.where(np.eye(9) > 0, np.nan, 0.0), "NaN/inf"),
        (np.full((9, 9), np.inf), "NaN/inf"),
        (np.zeros((9, 12)), "must be square"),
        (np.zeros((3, 3)), "too small"),
    ],
    ids=["nan", "inf", "non-square", "too-small"],
)
def test_bad_height_file(tmp_path, capsys, heights, pattern):
    name = heights_file(tmp_path, heights)
    config = write_config(tmp_path, surface=f'file = "{name}"\nsize_um = 2.0')
    code, err = run_cli(config, capsys)
    assert code == 2 and len(err.splitlines()) == 1 and pattern in err, err
    assert not any(p.name.startswith("result") for p in tmp_path.iterdir())


def test_unwritable_output(tmp_path, capsys):
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("a file where a folder is expected")
    config = write_config(tmp_path, out=str(blocker / "sub" / "result.h5"))
    code, err = run_cli(config, capsys)
    assert code == 2 and "not writable" in err and len(err.splitlines()) == 1


def test_missing_config_file(tmp_path, capsys):
    code, err = run_cli(tmp_path / "nope.toml", capsys)
    assert code == 2 and "does not exist" in err


def test_sweep_expands_cases_and_labels(tmp_path):
    config = write_config(tmp_path, extra='\n[sweep]\n"surface.rms_height_um" = [0.02, 0.04]\n"surface.seed" = [1, 2, 3]\n')
    cfg = parse_config(config.read_text(), config)
    assert cfg.case_shape == (2, 3)
    assert [c.sweep_values for c in cfg.cases][4] == {"surface.rms_height_um": 0.04, "surface.seed": 2}
    assert cfg.cases[4].surface.parameters["rms_height_um"] == 0.04


@pytest.mark.parametrize(
    "sweep, pattern",
    [
        ('"illumination.wavelengths_um" = [[0.5], [0.6]]', "cannot be swept"),
        ('"illumination.polarization" = ["s", "p"]', r"cannot be swept \(the dataset labels its BRDF with one"),
        ('"output.per_polarization" = [true, false]', "cannot be swept"),
        ('"run.workers" = [1, 2]', r"cannot be swept \(it does not change the results\)"),
        ('"surface.rms_hight_um" = [0.1]', "not a config key"),
        ('"surface.seed" = []', "non-empty list"),
        ('"surface.rms_height_um" = [0.1, -0.1]', r"rms_height_um = -0.1: must be >= 0 \(in the sweep case"),
    ],
)
def test_bad_sweeps(tmp_path, sweep, pattern):
    config = write_config(tmp_path, extra=f"\n[sweep]\n{sweep}\n")
    with pytest.raises(ConfigError, match=pattern):
        parse_config(config.read_text(), config)


def test_surface_file_and_generator_are_exclusive(tmp_path):
    name = heights_file(tmp_path, np.zeros((9, 9)))
    config = write_config(tmp_path, surface=f'file = "{name}"\nsize_um = 2.0\ngenerator = "flat"')
    with pytest.raises(ConfigError, match="exactly one of file, generator"):
        parse_config(config.read_text(), config)


def test_whitespace_and_npy_height_files(tmp_path):
    z = np.random.default_rng(0).normal(scale=0.01, size=(9, 9))
    np.savetxt(tmp_path / "z_ws.txt", z)
    np.save(tmp_path / "z.npy", z)
    for name in ("z_ws.txt", "z.npy"):
        config = write_config(tmp_path, surface=f'file = "{name}"\nsize_um = 2.0')
        study = parse_config(config.read_text(), config).cases[0]
        assert np.allclose(study.surface.build().z, z, atol=1e-12)


FLAT_PATCH = 'generator = "flat"\nsize_um = 2.0\ncells = 16'
AIM_FLAT_EDGE = """
[study]
output = "{out}"

[surface]
{surface}

[material]
name = "glass"

[illumination]
wavelengths_um = [0.5]
directions_deg = [[0, 0]]
waist_um = 0.5
beam = "{beam}"

[model]
name = "bem"
method = "aim"

[model.aim]
edge = "flat"
"""


@pytest.mark.parametrize(
    "surface, beam, pattern",
    [
        (FLAT_PATCH, "paraxial",
         r'\[model.aim\] edge = "flat": needs illumination.beam = "exact"'),
        (GOOD_SURFACE, "exact", r"\[model.aim\] aim.edge = 'flat' .* border heights leave that plane by up to"),
    ],
    ids=["paraxial-beam", "rough-border"],
)
def test_flat_edge_needs_an_exact_beam_and_a_flat_border(tmp_path, capsys, surface, beam, pattern):
    config = tmp_path / "study.toml"
    config.write_text(AIM_FLAT_EDGE.format(out=tmp_path / "result.h5", surface=surface, beam=beam))
    code, err = run_cli(config, capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert pytest.importorskip("re").search(pattern, err), err




def aim_config(tmp_path: Path, key: str, value: str) -> str:
    """The flat-edge AIM study with one [model.aim] key set instead."""
    text = AIM_FLAT_EDGE.format(out=tmp_path / "result.h5", surface=FLAT_PATCH, beam="exact")
    return text.replace('edge = "flat"', f"{key} = {value}")


@pytest.mark.parametrize(
    "key, value, pattern",
    [
        ("tolerance", "-1", r"\[model.aim\] tolerance = -1: must be > 0"),
        ("max_iterations", "0", r"\[model.aim\] max_iterations = 0: must be >= 1"),
        ("restart", "-1", r"\[model.aim\] restart = -1: must be >= 1"),
        ("near_storage", '"half"', r'\[model.aim\] near_storage = "half": must be one of "single", "double"'),
        ("near_cells", "nan", r"\[model.aim\] near_cells = nan: must be finite"),
        ("stencil", "[4, 4]", r"\[model.aim\] stencil = \[4, 4\]: must be a list of 3 integers"),
        ("tolerence", "1e-5", r"\[model.aim\] tolerence: unknown key; did you mean 'tolerance'"),
    ],
)
def test_model_options_are_checked_at_load(tmp_path, capsys, key, value, pattern):
    """Every model option is checked when the config is read, by `plan` as by `run`."""
    import re

    config = tmp_path / "study.toml"
    config.write_text(aim_config(tmp_path, key, value))
    assert main(["plan", str(config)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and re.search(pattern, err), err
    assert not any(p.name.startswith("result") for p in tmp_path.iterdir())


def test_model_options_in_their_own_table(tmp_path):
    """[model.<name>] holds the same keys as [model]; giving one twice is refused."""
    text = aim_config(tmp_path, "tolerance", "1e-5")
    moved = text.replace('[model]\nname = "bem"\nmethod = "aim"\n', '[model]\nname = "bem"\n\n[model.bem]\nmethod = "aim"\n')
    study = parse_config(moved).cases[0]
    assert study.model.options.method == "aim" and study.model.options.aim.tolerance == 1e-5
    twice = moved.replace('[model]\nname = "bem"\n', '[model]\nname = "bem"\nmethod = "dense"\n')
    with pytest.raises(ConfigError, match=r"\[model.bem\] method: also given in \[model\]"):
        parse_config(twice)
    with pytest.raises(ConfigError, match=r'\[model\] method = "fast": must be one of "dense", "aim"'):
        parse_config(text.replace('method = "aim"', 'method = "fast"'))


def test_every_study_kind_is_complete():
    """A study kind names its config section, its dataset layout, its pictures and its plugin; the
    [illumination] keys that only one kind reads belong to no other; a config's kind is the one
    whose section it gives, and its study, plan and dataset carry it."""
    from wavebrdf.jobs.overrides import dict_config_text
    from wavebrdf.jobs.plan import plan_study
    from wavebrdf.jobs.sections import SECTIONS
    from wavebrdf.jobs.store import LAYOUTS
    from wavebrdf.jobs.study_kinds import STUDY_KINDS, study_kind
    from wavebrdf.solver.models import Capabilities

    owners = {}
    for name, kind in STUDY_KINDS.items():
        assert kind.name == name and study_kind(name) is kind
        assert kind.section in SECTIONS and name in LAYOUTS and kind.plugin.startswith("wavebrdf")
        assert set(kind.model_inputs) <= set(Capabilities.INPUTS) and kind.scenes
        assert set(kind.pictures.KINDS) >= {k for k, _, _ in (*kind.pictures.PER_CASE, *kind.pictures.PER_DIRECTION)}
        assert set(kind.required_illumination) <= set(kind.illumination_keys) | {"wavelengths_um"}
        for key in kind.illumination_keys:
            assert owners.setdefault(key, name) == name, f"{key} read by {owners[key]} and {name}"
    with pytest.raises(KeyError, match="unknown study kind 'sphere'"):
        study_kind("sphere")
    fiber = {"fiber": {"shape": "circle", "radius_um": 1.0}, "material": {"n": 1.5},
             "illumination": {"wavelengths_um": [0.5], "theta_i_deg": [0]}, "model": {"name": "mie"}}
    config = parse_config(dict_config_text(fiber))
    plan = plan_study(config)
    assert config.cases[0].kind is STUDY_KINDS["fiber"] and [t.kind for t in plan.tasks] == ["fiber"]
    assert config.cases[0].surface is None and config.cases[0].fiber.shape == "circle"
