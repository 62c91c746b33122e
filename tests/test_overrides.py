"""Ranges in configs, ``--set`` / ``**overrides`` and the TOML written back into datasets."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from wavebrdf.jobs.cli import main
from wavebrdf.jobs.config import ConfigError, load_config
from wavebrdf.jobs.overrides import apply_overrides, dump_toml, parse_assignment

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ROOT / "configs" / "default.toml"


def test_ranges_expand_to_the_documented_values():
    config = load_config(DEFAULT, overrides={
        "illumination.wavelengths_um": {"start": 0.4, "stop": 0.7, "count": 31},
        "illumination.directions_deg": {"theta": {"start": 0, "stop": 60, "count": 3}, "phi": [0, 45, 90]},
        "sweep": {"surface.rms_height_um": {"start": 0.02, "stop": 0.1, "count": 5},
                  "surface.seed": {"start": 3, "stop": 9, "count": 3}}})
    ill = config.cases[0].illumination
    assert np.allclose(ill.wavelengths_um, np.linspace(0.4, 0.7, 31), rtol=0, atol=1e-12)
    assert 0.55 in ill.wavelengths_um and 0.7 in ill.wavelengths_um  # exact decimal values, selectable
    # θ × φ, θ-major; normal incidence once (its azimuth means nothing)
    assert ill.directions_deg == ((0, 0), (30, 0), (30, 45), (30, 90), (60, 0), (60, 45), (60, 90))
    assert config.sweep_axes["surface.seed"] == (3, 6, 9)  # integers stay integers
    assert np.allclose(config.sweep_axes["surface.rms_height_um"], [0.02, 0.04, 0.06, 0.08, 0.1])
    assert len(config.cases) == 15


@pytest.mark.parametrize("value, problem", [
    ({"start": 0.4, "stop": 0.7}, "exactly these keys"),
    ({"start": 0.4, "stop": 0.7, "count": 0}, "count must be an integer from 1"),
    ({"start": 0.5, "stop": 0.5, "count": 3}, "start != stop"),
    ({"start": 0.4, "stop": math.inf, "count": 3}, "stop must be a finite number"),
    ({"start": -0.4, "stop": 0.7, "count": 3}, "values must be finite numbers > 0"),
])
def test_bad_ranges_name_the_key_and_value(value, problem):
    with pytest.raises(ConfigError, match=r"^\[illumination\] wavelengths_um = .*" + problem):
        load_config(DEFAULT, overrides={"illumination.wavelengths_um": value})


def test_overrides_set_merge_and_refuse():
    data = {"surface": {"generator": "gaussian", "seed": 1}, "model": {"name": "bem", "aim": {"tolerance": 1e-4}}}
    out = apply_overrides(data, [("surface.seed", 5), ("model.aim.solver", "csym"),
                                 ("surface", {"rms_height_um": 0.1}), ('sweep."surface.seed"', [1, 2])])
    assert out == {"surface": {"generator": "gaussian", "seed": 5, "rms_height_um": 0.1},
                   "model": {"name": "bem", "aim": {"tolerance": 1e-4, "solver": "csym"}},
                   "sweep": {"surface.seed": [1, 2]}}
    assert data["surface"]["seed"] == 1  # the input is not changed
    with pytest.raises(ConfigError, match=r"override surface.seed.x = 2: surface.seed is 1, not a table"):
        apply_overrides(data, {"surface.seed.x": 2})
    with pytest.raises(ConfigError, match=r"override surface..seed: not a dotted config key"):
        apply_overrides(data, {"surface..seed": 2})
    with pytest.raises(ConfigError, match=r"override surface.seed = .*object is not a config value"):
        apply_overrides(data, {"surface.seed": object()})


def test_command_line_values_are_toml_or_bare_words():
    assert parse_assignment("material.name=gold") == ("material.name", "gold")
    assert parse_assignment("output.resolution = 64") == ("output.resolution", 64)
    assert parse_assignment('study.name="a b"') == ("study.name", "a b")
    assert parse_assignment("illumination.wavelengths_um={start=0.4,stop=0.7,count=4}") == (
        "illumination.wavelengths_um", {"start": 0.4, "stop": 0.7, "count": 4})
    with pytest.raises(ConfigError, match=r"--set a=0.4,0.5: 0.4,0.5 is not a TOML value"):
        parse_assignment("a=0.4,0.5")


def test_written_toml_reads_back_the_same():
    data = {"study": {"name": "x", "output": "out/é x.h5"},
            "illumination": {"wavelengths_um": [0.45, 1e-05, 3.0], "directions_deg": [[0, 0], [30.5, 90]],
                             "range": {"start": 0.4, "stop": 0.7, "count": 4}},
            "model": {"name": "bem", "aim": {"stencil": [4, 4, 0], "precision": "single", "flat": True}},
            "sweep": {"surface.rms_height_um": [0.02, 0.05], "material.name": ["gold", 'say "hi"']}}
    assert tomllib.loads(dump_toml(data)) == data


def test_cli_set_plans_the_overridden_study(capsys):
    assert main(["plan", str(DEFAULT), "--set", "illumination.directions_deg={theta=[0,30],phi=[0,90]}",
                 "--set", "illumination.wavelengths_um=[0.5]", "--set", "output.resolution=64"]) == 0
    assert "total: 3 tasks" in capsys.readouterr().out
    # a full turn of φ lists φ = 0 once (φ + 360° is the same direction), θ = 0 once whatever φ
    assert main(["plan", str(DEFAULT), "--set", "illumination.directions_deg={theta=[0,30],phi={start=0,stop=360,"
                 "count=13}}", "--set", "illumination.wavelengths_um=[0.5]", "--set", "output.resolution=64"]) == 0
    assert "total: 13 tasks" in capsys.readouterr().out
    assert main(["plan", str(DEFAULT), "--set", "illumination.directions_deg=[[30,0],[30,360]]"]) == 2
    assert "[30.0, 0.0] and [30.0, 360.0] are one direction" in capsys.readouterr().err
    for flags, text in ((["--set", "output.resolution=8"], "[output] resolution = 8: must be >= 16"),
                        (["--set", "illumination.wavelengths_um=0.4,0.5"],
                         "--set illumination.wavelengths_um=0.4,0.5: 0.4,0.5 is not a TOML value"),
                        (["--set", "surface.rms_heigth_um=0.1"], "[surface] rms_heigth_um: unknown key"),
                        (["--set", "output"], "--set output: expected key=value")):
        assert main(["plan", str(DEFAULT), *flags]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and text in err, err
