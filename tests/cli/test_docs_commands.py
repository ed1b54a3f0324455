"""The commands and snippets of README.md and the docs, run as a user copies them onto a fresh machine.

Fast: every option a documented command synopsis names is an option of that command. Slow (a bake of the indoor
example each): the README's set-up command (without its `pip install`), then the engine-integration guide's reader
commands and the USD examples' commands on its output, and the README's Python API block as a script — in a folder
holding only a copy of `examples/`.
"""

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
OPTION = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*|-[a-zA-Z])(?![\w-])")


def blocks(doc: str, lang: str) -> list[str]:
    return re.findall(r"```" + lang + r"\n(.*?)```", (REPO / doc).read_text(), re.S)


def commands_block(doc: str, heading: str) -> str:
    text = (REPO / doc).read_text()
    section = text[text.index(heading):]
    return re.search(r"```sh\n(.*?)```", section, re.S).group(1)


SYNOPSES = {
    "README.md Commands": commands_block("README.md", "## Commands"),
    "README.md farm": commands_block("README.md", "## Running on a farm"),
    "docs/exports.md": blocks("docs/exports.md", "sh")[0],
    "docs/report.md": blocks("docs/report.md", "sh")[0],
    "docs/farm.md": blocks("docs/farm.md", "sh")[0],
    "examples/USD_EXAMPLES.md": "\n".join(blocks("examples/USD_EXAMPLES.md", "sh")),
}


@pytest.mark.parametrize("doc", list(SYNOPSES))
def test_every_documented_option_exists(doc):
    import click

    from bakery.cli import main

    checked, unknown = 0, []
    commands = []
    for raw in SYNOPSES[doc].splitlines():
        line = raw.split("#", 1)[0]
        words = line.split()
        if not words:
            continue
        if words[0] == "bakery":
            commands, rest = [main], words[1:]
            while rest and all(isinstance(c, click.Group) for c in commands):
                names = rest[0].split("|")  # `bench irradiance|reflection|pareto`: each of them
                if not all(name in commands[0].commands for name in names):
                    break
                commands, rest = [commands[0].commands[name] for name in names], rest[1:]
        elif not raw.startswith(" "):  # another program (python, openjd, mkdir): not bakery's options
            commands = []
        for command in commands:
            known = {"--help"} | {o for p in command.params for o in (*p.opts, *p.secondary_opts)}
            for option in OPTION.findall(line):
                checked += 1
                if option not in known:
                    unknown.append(f"{command.name} {option}: {raw.strip()}")
    assert checked, f"{doc}: no bakery options found (did the synopsis move?)"
    assert not unknown, f"{doc}: options the CLI does not have:\n" + "\n".join(unknown)


# ------------------------------------------------------------------------------------------------ slow: run them
PRELUDE = 'bakery() { "$PY" -m bakery.cli "$@"; }\npython() { "$PY" "$@"; }\nset -e\n'


def fresh_folder(tmp_path: Path) -> Path:
    """A folder with only a copy of the repository's examples (README commands run from the repository root)."""
    shutil.copytree(REPO / "examples", tmp_path / "examples", ignore=shutil.ignore_patterns("__pycache__"))
    return tmp_path


def sh(script: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PY": sys.executable, "SOURCE_DATE_EPOCH": "1700000000"}
    return subprocess.run(["bash", "-c", PRELUDE + script], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600)


@pytest.mark.slow
def test_readme_setup_then_engine_reader_and_usd_examples(tmp_path):
    folder = fresh_folder(tmp_path)
    setup = blocks("README.md", "sh")[0].strip()
    assert setup.startswith("pip install -e . && "), setup
    result = sh(setup.removeprefix("pip install -e . && "), folder)
    assert result.returncode == 0, result.stderr
    assert (folder / "indoor.h5").is_file() and (folder / "indoor.bake.usda").is_file()
    assert "26 probes" in result.stdout and "checksums verified" in result.stdout, result.stdout

    reader = commands_block("docs/engine-integration.md", "## 5. A reader without bakery")
    result = sh(reader, folder)
    assert result.returncode == 0, result.stderr
    assert "/Room/Probes/Volume|zh3: 24 probe(s), irradiance at +Y" in result.stdout, result.stdout
    out = dict(np.load(folder / "irradiance.npz"))
    normals = np.load(folder / "normals.npy")
    assert out["/Room/Probes/Volume|zh3_quantized"].shape == (24, len(normals), 3)
    assert out["/Room/Probes/UnderTable|sh3"].shape == (1, len(normals), 3)

    for block in blocks("examples/USD_EXAMPLES.md", "sh"):  # check + bake (unchanged: reused), irradiance only
        result = sh(block, folder)
        assert result.returncode == 0, (block, result.stderr)


@pytest.mark.slow
def test_readme_python_api_block_runs_as_a_script(tmp_path):
    folder = fresh_folder(tmp_path)
    text = (REPO / "README.md").read_text()
    code = re.search(r"## Python API\n\n```python\n(.*?)```", text, re.S).group(1)
    (folder / "snippet.py").write_text(code)
    result = subprocess.run([sys.executable, "snippet.py"], cwd=folder, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    import bakery

    store = bakery.open_store(folder / "indoor.h5")
    assert {"zh3_deringed", "shexp_hybrid"} <= set(store.encodings)
    assert sorted(bakery.open_store(folder / "mine.h5").encodings) == ["shexp", "zh3"]
