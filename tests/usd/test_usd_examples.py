"""The shipped examples: self-contained (no paths outside the repository), clean under ``check``, and bakeable."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import bakery
from bakery.usd.check import check_scene
from bakery.usd.scene import read_scene

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SCENES = [EXAMPLES / "indoor" / "indoor.usda", EXAMPLES / "outdoor" / "outdoor.usda", EXAMPLES / "plaza" / "plaza.usda"]


def test_examples_reference_only_files_inside_the_repository():
    for path in EXAMPLES.rglob("*.usda"):
        for asset in re.findall(r"@([^@]+)@", path.read_text()):
            resolved = (path.parent / asset).resolve()
            assert resolved.is_file(), f"{path}: @{asset}@ does not exist"
            assert EXAMPLES in resolved.parents, f"{path}: @{asset}@ points outside examples/"


@pytest.mark.parametrize("scene", SCENES, ids=lambda p: p.stem)
def test_example_checks_clean_and_bakes(tmp_path, scene):
    assert [i for i in check_scene(scene) if i.severity == "error"] == []
    reading = read_scene(scene)
    kinds = {p.kind for p in reading.scene.probes}
    assert kinds == {"irradiance", "reflection"}
    assert any(p.volume for p in reading.scene.probes)
    summary = bakery.bake(scene, tmp_path / "out.h5", face_size=8, encodings=["sh3"], samples=1)
    irradiance = [p for p in reading.scene.probes if p.kind == "irradiance"]
    assert (summary.baked + summary.reused) == len(irradiance) and not summary.failed
    assert len(summary.skipped) == len(reading.scene.probes) - len(irradiance)  # reflection: no sh3
    assert Path(summary.layer).is_file() and Path(summary.store).is_file()


def test_plaza_is_what_its_generator_writes():
    """examples/plaza/plaza.usda is generated (make_plaza.py, deterministic): the committed file is its output."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_plaza", EXAMPLES / "plaza" / "make_plaza.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert (EXAMPLES / "plaza" / "plaza.usda").read_text() == module.plaza()
