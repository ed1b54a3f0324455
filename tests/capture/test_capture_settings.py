"""Capture settings end to end: recipe ``[capture]`` keys and CLI flags reach the renderer, the achieved SH noise is
stored per probe (``/diagnostics/capture/sh_noise``) and shown by ``bakery inspect``; adaptive sampling stops at the
target."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from usd_scenes import box_mesh, header, material, probe, write

import bakery
from bakery.errors import ConfigError
from bakery.pipeline.settings import CaptureSettings, request_from


def _scene(tmp_path):
    text = header() + material("M", diffuse=(0.7, 0.7, 0.7), emissive=(1.0, 1.0, 1.0)) + box_mesh("Box", 2.0, "/M")
    return write(tmp_path / "box.usda", text + probe("A", (0.2, 0.1, 0.0)) + probe("B", (-0.5, 0.3, 0.4)))


def _recipe(tmp_path, capture: str):
    path = tmp_path / "r.toml"
    path.write_text(f'name = "r"\n[targets]\nirradiance = ["sh3"]\n[bake]\nface_size = 8\n[capture]\n{capture}\n')
    return path


def test_recipe_capture_section_and_flags(tmp_path):
    recipe = _recipe(tmp_path, "samples = 3\nbounces = 5\ntarget_noise = 0.05\nsubdivision = 1\ntime = 12.0")
    request = request_from(_scene(tmp_path), tmp_path / "o.h5", recipe=str(recipe))
    assert request.capture == CaptureSettings(samples=3, bounces=5, target_noise=0.05, subdivision=1, time=12.0)
    request = request_from(_scene(tmp_path), tmp_path / "o.h5", recipe=str(recipe), samples=2, target_noise=0.0)
    assert request.capture.samples == 2 and request.capture.target_noise == 0.0 and request.capture.bounces == 5
    assert CaptureSettings().bounces == 64  # default: enough for closed rooms (Russian roulette)
    with pytest.raises(ConfigError):
        request_from(_scene(tmp_path), tmp_path / "o.h5", recipe=str(_recipe(tmp_path, "rays = 3")))
    with pytest.raises(ConfigError):
        CaptureSettings(target_noise=1.5)


@pytest.mark.parametrize("seed", [1 << 63, -(1 << 63) - 1, 10**23])
def test_a_seed_the_store_cannot_record_is_refused_before_the_capture(tmp_path, seed):
    """The store records the seed as an HDF5 int64: a larger one used to fail after the whole capture (a raw
    TypeError, a checkpoint folder left behind); now a ConfigError / exit 2 before any work."""
    scene = _scene(tmp_path)
    with pytest.raises(ConfigError, match="seed must be a 64-bit signed integer"):
        bakery.bake(scene, tmp_path / "o.h5", seed=seed)
    result = subprocess.run([sys.executable, "-m", "bakery.cli", "bake", str(scene), "-o", str(tmp_path / "o.h5"),
                             "--seed", str(seed)], capture_output=True, text=True)
    assert result.returncode == 2 and "--seed" in result.stderr and "Traceback" not in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box.usda"]
    assert CaptureSettings(seed=(1 << 63) - 1).seed == (1 << 63) - 1 and CaptureSettings(seed=-(1 << 63)).seed < 0


def test_adaptive_noise_is_stored_and_inspected(tmp_path):
    scene = _scene(tmp_path)
    recipe = _recipe(tmp_path, "samples = 2\ntarget_noise = 0.02")
    summary = bakery.bake(scene, tmp_path / "box.h5", recipe=str(recipe))
    store = bakery.open_store(tmp_path / "box.h5")
    noise = np.asarray(store.diagnostics["capture/sh_noise"], dtype=np.float64)
    samples = np.asarray(store.diagnostics["capture/samples"], dtype=np.float64)
    assert noise.shape == (2,) and (noise <= 0.02).all() and (samples > 2).all()
    assert store.attributes["capture_target_noise"] == pytest.approx(0.02)
    assert store.attributes["capture_working_space"] == "lin_rec709"
    assert summary is not None
    shown = subprocess.run([sys.executable, "-m", "bakery.cli", "inspect", str(tmp_path / "box.h5")],
                           capture_output=True, text=True)
    assert shown.returncode == 0 and "SH noise" in shown.stdout, shown.stdout + shown.stderr
    listed = subprocess.run([sys.executable, "-m", "bakery.cli", "inspect", str(tmp_path / "box.h5"), "--probes", "/*",
                             "--json"], capture_output=True, text=True)
    rows = json.loads(listed.stdout)
    assert all(0 < row["sh_noise"] <= 0.02 for row in rows)
