"""The one bake path: outputs checked before any work, workers without USD, encoding names only in the registry,
typed recipe settings, and the library and the CLI writing the same store."""

from __future__ import annotations

import ast
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bakery
from bakery.encodings import ENCODINGS
from bakery.environment.io import write_exr

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "bakery"
EXAMPLE_SCENE = ROOT / "examples" / "indoor" / "indoor.usda"
ENV = {**os.environ, "SOURCE_DATE_EPOCH": "1700000000"}


def cli(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bakery.cli", *map(str, args)], capture_output=True, text=True,
                          env=ENV, cwd=cwd, timeout=600)


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def environment(tmp_path) -> Path:
    path = tmp_path / "sky.exr"
    rows = (np.arange(16) + 0.5) / 16
    write_exr(path, np.broadcast_to((1.2 - rows)[:, None, None], (16, 32, 3)).astype(np.float32) + 0.1, half=False)
    return path


# ------------------------------------------------------------------------------------------------ registry
def test_no_encoding_name_appears_outside_the_encodings_package():
    """Capabilities, not name lists: an encoding's name is a string literal only in its own module (and tests)."""
    names = set(ENCODINGS)
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        relative = path.relative_to(PACKAGE).as_posix()
        if relative.startswith("encodings/"):
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in names:
                offenders.append(f"{relative}:{node.lineno}: {node.value!r}")
    assert not offenders, "encoding names outside bakery/encodings/:\n" + "\n".join(offenders)


def test_encodings_package_imports_every_module_without_swallowing_errors():
    source = (PACKAGE / "encodings" / "__init__.py").read_text()
    tree = ast.parse(source)
    assert not any(isinstance(node, ast.Try) for node in ast.walk(tree)), "registration failures must be loud"
    assert {e.kind for e in ENCODINGS.values()} == {"irradiance", "reflection"}


# ------------------------------------------------------------------------------------------------ outputs first
@pytest.mark.parametrize("layer", ["baked.txt", "baked", "sub/missing/baked.usda"])
def test_a_wrong_layer_path_leaves_every_file_untouched(tmp_path, layer):
    work = tmp_path / "work"
    work.mkdir()
    store = work / "indoor.h5"
    assert cli("bake", EXAMPLE_SCENE, "-o", store, "-e", "sh2", "--face-size", "4", "--samples", "1").returncode == 0
    before = snapshot(work)
    result = cli("bake", EXAMPLE_SCENE, "-o", store, "-e", "sh3", "--face-size", "4", "--samples", "1",
                 "--layer", work / layer)
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert Path(layer).name in result.stderr
    assert snapshot(work) == before  # no new store, no .partial/, no layer, no temporaries


def test_a_store_onto_an_input_or_a_foreign_file_is_refused_before_any_work(tmp_path, environment):
    before = environment.read_bytes()
    result = cli("bake", environment, "-o", environment, "-e", "sh2", "--face-size", "4")
    assert result.returncode == 2 and "sky.exr" in result.stderr and "Traceback" not in result.stderr
    text = tmp_path / "notes.h5"
    text.write_text("not a store")
    result = cli("bake", environment, "-o", text, "-e", "sh2", "--face-size", "4")
    assert result.returncode == 2 and "notes.h5" in result.stderr
    assert environment.read_bytes() == before and text.read_text() == "not a store"
    assert not list(tmp_path.glob("*.partial"))


def test_usdc_layers_are_written_and_compose(tmp_path):
    from pxr import Usd

    from bakery.usd.layer import read_baked_values

    layer = tmp_path / "baked.usdc"
    summary = bakery.bake(EXAMPLE_SCENE, tmp_path / "indoor.h5", layer=layer, encodings=("sh2",), face_size=4,
                          samples=1)
    assert summary.layer == str(layer) and layer.read_bytes()[:8] == b"PXR-USDC"
    stage = Usd.Stage.Open(str(layer))
    assert stage is not None and read_baked_values(layer)


# ------------------------------------------------------------------------------------------------ workers
def test_workers_capture_a_scene_without_usd(tmp_path):
    """A worker process gets the plan's batch and the parent's scene snapshot: it never imports pxr, never reads
    the stage, and computes exactly what the in-process bake stored."""
    from bakery.pipeline.run import plan_bake
    from bakery.pipeline.settings import request_from

    request = request_from(EXAMPLE_SCENE, tmp_path / "s.h5", encodings=("sh3",), face_size=4, samples=1)
    source, plan = plan_bake(request)
    handle = source.prepare(tmp_path / "work")
    task = plan.batches[0].__class__(**{**plan.batches[0].__dict__, "source": handle})
    (tmp_path / "task.pkl").write_bytes(pickle.dumps(task))
    code = (
        "import pickle, sys; from bakery.pipeline.worker import run_batch; "
        f"outcome = run_batch(pickle.load(open({str(tmp_path / 'task.pkl')!r}, 'rb'))); "
        f"pickle.dump(outcome, open({str(tmp_path / 'outcome.pkl')!r}, 'wb')); "
        "print('pxr' in sys.modules, 'bakery.usd' in sys.modules)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=ENV, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["False", "False"]
    outcome = pickle.loads((tmp_path / "outcome.pkl").read_bytes())
    assert not outcome.failures
    summary = bakery.bake(EXAMPLE_SCENE, tmp_path / "s.h5", encodings=("sh3",), face_size=4, samples=1)
    store = bakery.open_store(summary.store)
    rows = store.rows("sh3", [p.name for p in outcome.result.probes])
    np.testing.assert_array_equal(store.fields("sh3")["radiance_sh"][rows], outcome.result.encoded["sh3"]["radiance_sh"])


# ------------------------------------------------------------------------------------------------ settings
@pytest.mark.parametrize("encoding,text,key", [
    ("shexp", "p_band = \"four\"", "p_band"),
    ("zh3_quantized", "sqrt_companding = \"no\"", "sqrt_companding"),
    ("shexp", "alpha_minn = 0.1", "alpha_minn"),
    ("splitsum", "n_levels = -3", "n_levels"),
])
def test_recipe_encoding_settings_are_typed(tmp_path, environment, encoding, text, key):
    recipe = tmp_path / "bad.toml"
    recipe.write_text(f'name = "bad"\n[targets]\nirradiance = ["sh2"]\n[encoding_settings.{encoding}]\n{text}\n')
    out = tmp_path / "s.h5"
    result = cli("bake", environment, "-o", out, "--recipe", recipe)
    assert result.returncode == 3 and "Traceback" not in result.stderr, result.stderr
    for needle in ("bad.toml", encoding, key):
        assert needle in result.stderr, (needle, result.stderr)
    assert not out.exists()


def test_library_and_cli_write_the_same_store(tmp_path, environment):
    a, b = tmp_path / "cli.h5", tmp_path / "api.h5"
    assert cli("bake", environment, "-o", a, "-e", "zh3", "-e", "shexp", "--face-size", "8").returncode == 0
    os.environ.setdefault("SOURCE_DATE_EPOCH", ENV["SOURCE_DATE_EPOCH"])
    if os.environ["SOURCE_DATE_EPOCH"] != ENV["SOURCE_DATE_EPOCH"]:
        pytest.skip("SOURCE_DATE_EPOCH is set to another value in this environment")
    bakery.bake(environment, b, encodings=("zh3", "shexp"), face_size=8)
    assert a.read_bytes() == b.read_bytes()


@pytest.mark.parametrize("as_type", [str, Path])
def test_one_source_path_bakes_at_the_sources_default_face_size(tmp_path, environment, as_type):
    """``bakery.bake(path, output)`` with one image or scene path (str or Path) and no face size bakes at the
    source's default face size, as ``bakery bake path`` does. The path used to be iterated as a sequence of sources
    there: a Path raised TypeError, a str's characters made an environment source (a scene baked at 64, not 32)."""
    from bakery.sources import EnvironmentSource, UsdSceneSource

    summary = bakery.bake(as_type(environment), tmp_path / "image.h5", encodings=("sh2",))
    image = bakery.open_store(tmp_path / "image.h5")
    assert image.probe_names == ["/environment"] and not summary.failed
    assert image.attributes["bake_face_size"] == EnvironmentSource.default_face_size
    bakery.bake(as_type(EXAMPLE_SCENE), tmp_path / "scene.h5", encodings=("sh2",), samples=1)
    scene = bakery.open_store(tmp_path / "scene.h5")
    assert scene.encodings["sh2"].probe_count > 0
    assert scene.attributes["bake_face_size"] == UsdSceneSource.default_face_size != EnvironmentSource.default_face_size


@pytest.mark.parametrize("arguments,named", [
    ({"sources": 5}, "sources"), ({"sources": None}, "sources"), ({"sources": [5]}, "sources"),
    ({"sources": []}, "sources"), ({"output": 5}, "output"), ({"layer": 5}, "layer"), ({"recipe": 5}, "recipe"),
    ({"encodings": 5}, "encodings"), ({"encodings": "nope"}, "unknown encoding 'nope'"),
    ({"encoding_settings": {"zh3": 5}}, "encoding_settings"), ({"encoding_settings": ["zh3"]}, "encoding_settings"),
    ({"batch_size": "3"}, "batch_size"), ({"batch_size": 2.5}, "batch_size"),
    ({"band_energy_tolerance": "x"}, "band_energy_tolerance"),
])
def test_wrongly_typed_bake_arguments_are_config_errors_naming_the_argument(tmp_path, environment, arguments, named):
    """``bakery.bake`` raised raw TypeError/AttributeError/ValueError for these, and split a str of encodings into
    letters ('unknown encoding z')."""
    from bakery.errors import ConfigError

    call = {"sources": environment, "output": tmp_path / "s.h5", "face_size": 8, **arguments}
    with pytest.raises(ConfigError, match=named):
        bakery.bake(call.pop("sources"), call.pop("output"), **call)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sky.exr"]


def test_one_encoding_name_may_be_given_as_a_str(tmp_path, environment):
    bakery.bake(environment, tmp_path / "s.h5", encodings="sh2", face_size=8)
    assert list(bakery.open_store(tmp_path / "s.h5").encodings) == ["sh2"]
