"""bakery installed from a wheel, as a farm deploys it (not ``pip install -e .``): the wheel carries every data
file the package reads (recipe presets and their JSON Schema, the USD schema plugin, shaders, the farm
calibration), and the installed ``bakery`` bakes a shipped example with a preset recipe from a folder outside the
repository. Before the presets moved into the package, such an install answered ``--recipe mobile`` with
"recipe 'mobile' not found; presets: none in …/pipelines".
"""

import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(wheel path, install folder): ``pip wheel`` of a copy of this repository's package files (pip builds in the
    source tree, which a test must not write to), installed with ``--target`` (no deps)."""
    root = tmp_path_factory.mktemp("wheel")
    source = root / "source"
    shutil.copytree(REPO / "bakery", source / "bakery", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, source / name)
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(root / "dist"),
                            str(source)], capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr[-3000:]
    (wheel,) = (root / "dist").glob("bakery-*.whl")
    target = root / "site"
    install = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--quiet", "--target",
                              str(target), str(wheel)], capture_output=True, text=True, timeout=600)
    assert install.returncode == 0, install.stderr[-3000:]
    return wheel, target


@pytest.mark.slow
def test_the_wheel_carries_every_file_of_the_package(installed):
    wheel, _ = installed
    names = set(zipfile.ZipFile(wheel).namelist())
    package = REPO / "bakery"
    expected = {p.relative_to(REPO).as_posix() for p in package.rglob("*")
                if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"}
    assert expected, "no package files found"
    missing = sorted(expected - names)
    assert not missing, f"files of bakery/ not in the wheel: {missing}"


@pytest.mark.slow
def test_the_installed_wheel_bakes_an_example_with_a_preset_recipe(installed, tmp_path):
    _, target = installed
    env = {**os.environ, "PYTHONPATH": str(target)}

    def run(*args):
        return subprocess.run([sys.executable, *args], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=600)

    where = run("-c", "import bakery; print(bakery.__file__)")
    assert Path(where.stdout.strip()).resolve().is_relative_to(target.resolve()), where.stdout + where.stderr
    bake = run("-m", "bakery.cli", "bake", str(REPO / "examples" / "indoor" / "indoor.usda"), "-o", "indoor.h5",
               "--recipe", "mobile")
    assert bake.returncode == 0, bake.stderr[-3000:]
    summary = re.search(r"(\d+) probes baked, 0 unchanged, 0 failed", bake.stdout + bake.stderr)
    assert summary and int(summary.group(1)) > 0, bake.stdout + bake.stderr  # mobile: the irradiance probes
    inspect = run("-m", "bakery.cli", "inspect", "indoor.h5")
    assert inspect.returncode == 0, inspect.stderr[-3000:]
    assert "zh3_quantized" in inspect.stdout
