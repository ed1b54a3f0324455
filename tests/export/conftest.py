"""Stores the export tests share (baked once per session through the one bake path) and the Node consumers."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import bakery
from bakery.environment.io import write_exr

ROOT = Path(__file__).resolve().parents[2]
JS = Path(__file__).resolve().parent / "js"
NODE_MODULES = ROOT / "tests" / "node_modules"
SUN_DIRECTION = None  # set by the sun fixture: unit direction towards the sun texel


def sun_sky(path: Path, sun: float = 5000.0) -> np.ndarray:
    """A dim sky, a ground and one very bright texel (the sun); returns the direction towards the sun."""
    h, w = 32, 64
    rows = (np.arange(h) + 0.5) / h
    sky = np.zeros((h, w, 3), np.float32)
    sky[...] = np.array([0.3, 0.5, 1.0]) * (1.2 - rows)[:, None, None]
    sky[h // 2:] = np.array([0.2, 0.15, 0.1])
    i, j = h // 4, w // 3
    sky[i, j] = sun
    write_exr(path, sky, half=False)
    lon = np.pi - 2 * np.pi * (j + 0.5) / w  # bakery.conventions equirect: column 0 = +π, longitude = atan2(x, z)
    lat = np.pi / 2 - np.pi * (i + 0.5) / h
    return np.array([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)])


@pytest.fixture(scope="session")
def stores(tmp_path_factory) -> dict[str, Path]:
    """``sun``: an environment image (one distant probe, sh3 + splitsum, 32² faces); ``indoor`` / ``outdoor``: the
    example scenes at small settings (each with its baked layer beside the store)."""
    d = tmp_path_factory.mktemp("export_stores")
    direction = sun_sky(d / "sun.exr")
    bakery.bake(d / "sun.exr", d / "sun.h5", encodings=("sh3", "splitsum"), face_size=32)
    (d / "sun_direction.json").write_text(json.dumps(direction.tolist()))
    for scene, encodings in (("indoor", ("sh3", "zh3", "splitsum")), ("outdoor", ("sh3", "splitsum"))):
        bakery.bake(ROOT / "examples" / scene / f"{scene}.usda", d / f"{scene}.h5", encodings=encodings,
                    face_size=16, samples=1, jobs=1)
    return {"sun": d / "sun.h5", "indoor": d / "indoor.h5", "outdoor": d / "outdoor.h5",
            "sun_direction": d / "sun_direction.json"}


def node_or_skip(*packages: str) -> str:
    node = shutil.which("node")
    if node is None:
        pytest.skip("Node.js is not installed (the export consumer tests run three.js, Babylon.js, Filament, "
                    "ktx-parse and libktx in Node)")
    for package in packages:
        if not (NODE_MODULES / package).is_dir():
            pytest.skip(f"npm package {package} is not installed: run `npm ci --prefix tests` (.ci/run does)")
    return node


def run_node(script: str, *args: str, packages: tuple[str, ...] = (), timeout: int = 600) -> dict:
    node = node_or_skip(*packages)
    result = subprocess.run([node, str(JS / script), *map(str, args)], capture_output=True, text=True,
                            timeout=timeout, cwd=ROOT / "tests")
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout)


def chromium_or_skip() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("headless Chromium is not installed (apt-get install -y chromium); Babylon.js runs in it")
