"""The example studies (``wavebrdf example``): the configs of ``configs/`` and the data files
they read, shipped in the wheel as ``wavebrdf/examples`` and written to a folder of the user's.

Relative input files in a config are read from the config's folder (jobs/input_files.py), so an
example is written with the files it names (``configs/data/...``) beside it; its ``[study]
output`` stays relative to the folder ``wavebrdf run`` is started in.
"""

from __future__ import annotations

import difflib
import shutil
import tomllib
from pathlib import Path

from wavebrdf.jobs.errors import ConfigError

__all__ = ["examples_folder", "list_examples", "write_example"]


def examples_folder() -> Path:
    """The folder of the example configs: ``wavebrdf/examples`` in an installed wheel, the
    checkout's ``configs/`` in an editable install."""
    package = Path(__file__).resolve().parent.parent  # wavebrdf/ installed; the checkout when editable
    installed = package / "examples"
    return installed if installed.is_dir() else package / "configs"


def _summary(path: Path, width: int = 100) -> str:
    """The first sentence of a config's leading comment (what the study is), at most ``width``
    characters."""
    lines = []
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    text = " ".join(lines)
    end = text.find(". ")
    text = text if end < 0 else text[: end + 1]
    return text if len(text) <= width else text[: text.rfind(" ", 0, width - 1)] + " …"


def list_examples() -> dict[str, str]:
    """{name: the first sentence of its leading comment} of every example config, by name."""
    return {p.stem: _summary(p) for p in sorted(examples_folder().glob("*.toml"))}


def _input_files(config: Path) -> list[Path]:
    """The files next to ``config`` that its string values name (relative paths that exist)."""
    found = []

    def walk(value):
        if isinstance(value, dict):
            for item in value.values():
                walk(item)
        elif isinstance(value, list):
            for item in value:
                walk(item)
        elif isinstance(value, str) and value and not Path(value).is_absolute():
            candidate = config.parent / value
            if candidate.is_file() and config.parent in candidate.resolve().parents:
                found.append(Path(value))

    walk(tomllib.loads(config.read_text(encoding="utf-8")))
    return found


def write_example(name: str, folder: str | Path = ".", force: bool = False) -> list[Path]:
    """Write the example config ``name`` (with or without ``.toml``) and the data files it reads
    into ``folder`` (created if missing); return the written paths, the config first. An existing
    file is refused (ConfigError naming it) unless ``force``."""
    names = list_examples()
    stem = name[:-5] if name.endswith(".toml") else name
    if stem not in names:
        near = difflib.get_close_matches(stem, names, n=1)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        raise ConfigError(f"example {name!r}: no such example{hint} (available: {', '.join(names)})")
    source = examples_folder() / f"{stem}.toml"
    folder = Path(folder)
    pairs = [(source, folder / source.name)] + [(source.parent / rel, folder / rel) for rel in _input_files(source)]
    existing = [str(target) for _, target in pairs if target.exists()]
    if existing and not force:
        raise ConfigError(f"example {stem}: would overwrite {', '.join(existing)}; add --force, or write it into "
                          "another folder (--out DIR)")
    for src, target in pairs:
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, target)
    return [target for _, target in pairs]
