"""``bakery export`` edits only the baked-results layer of the store it exports, and a refused layer writes nothing.

Every bad ``--layer`` (the scene's own layers, a user's file, a text file, a missing path, another store's layer, a
file USD cannot read) and a default ``<store stem>.bake.usda`` that is not the store's own layer: exit 2, one line
naming the layer, no traceback, the layer byte-identical and the export folder as it was (new or holding a previous
export). The store's own layer still gets its ``bakery:export:*`` attributes. One small bake per module."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import bakery
from bakery.errors import InputError

ROOT = Path(__file__).resolve().parents[2]


def cli(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bakery.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600, env={**os.environ, "PYTHONPATH": str(ROOT)})


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden temporaries too) → its bytes; {} if there is no folder."""
    if not folder.exists():
        return {}
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def baked(tmp_path_factory) -> Path:
    """A copy of the indoor scene (``ex/indoor``, ``ex/shared``, ``ex/data``) baked into ``indoor.h5`` (its layer
    ``indoor.bake.usda``) and into ``other/other.h5`` (``other/other.bake.usda``) at face size 8, one sample; a
    previous ktx2 export in ``previous/``; and the bad layers."""
    w = tmp_path_factory.mktemp("export_layer_safety")
    for name in ("indoor", "shared", "data"):
        shutil.copytree(ROOT / "examples" / name, w / "ex" / name)
    scene = w / "ex" / "indoor" / "indoor.usda"
    bakery.bake(scene, w / "indoor.h5", face_size=8, samples=1, jobs=1)
    (w / "other").mkdir()
    bakery.bake(scene, w / "other" / "other.h5", face_size=8, samples=1, jobs=1)
    assert (w / "indoor.bake.usda").is_file() and (w / "other" / "other.bake.usda").is_file()
    previous = cli("export", w / "indoor.h5", "-o", w / "previous", "--format", "ktx2", "--no-layer")
    assert previous.returncode == 0, previous.stderr
    (w / "user.usda").write_text('#usda 1.0\n(\n    doc = "a user\'s own layer"\n)\n\ndef Xform "Room"\n{\n}\n')
    (w / "notes.txt").write_text("not a layer\n")
    (w / "notes.usda").write_text("just some text, no USD here\n")
    # a user's file that mentions the marker but is no baked layer (records no store)
    (w / "mentions.usda").write_text('#usda 1.0\n(\n    "Baked light probes written by bakery: see there"\n)\n\n'
                                     'over "Room"\n{\n}\n')
    # the marker, but USD cannot parse it
    (w / "broken.usda").write_text('#usda 1.0\n(\n    "Baked light probes written by bakery"\n)\nover "Room" { x\n')
    return w


@pytest.fixture
def work(baked, tmp_path) -> Path:
    """A fresh copy of the module's workspace (tests may change it)."""
    shutil.copytree(baked, tmp_path / "w")
    return tmp_path / "w"


BAD_LAYERS = {
    "scene sublayer": "ex/indoor/probes.usda",
    "scene root layer": "ex/indoor/indoor.usda",
    "scene shared layer": "ex/shared/room.usda",
    "user usda": "user.usda",
    "text file": "notes.txt",
    "text file with usda suffix": "notes.usda",
    "marker without a store": "mentions.usda",
    "unparsable with marker": "broken.usda",
    "missing": "missing.usda",
    "another store's layer": "other/other.bake.usda",
    "the store itself": "indoor.h5",
    "a folder": "ex",
}


def assert_refused(result: subprocess.CompletedProcess, layer: str) -> None:
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    assert "Traceback" not in result.stderr and "ErrorException" not in result.stderr, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and layer in lines[0], result.stderr


@pytest.mark.parametrize("case", sorted(BAD_LAYERS))
@pytest.mark.parametrize("folder", ["previous", "new"])
def test_a_bad_layer_is_refused_and_nothing_is_written(work, case, folder):
    layer = BAD_LAYERS[case]
    before = {p: snapshot(work / p) if (work / p).is_dir() else (work / p).read_bytes()
              for p in ("ex", "other", "previous", "user.usda", "notes.txt", "notes.usda", "mentions.usda",
                        "broken.usda", "indoor.h5", "indoor.bake.usda")}
    listing = sorted(p.name for p in work.iterdir())
    result = cli("export", "indoor.h5", "-o", folder, "--format", "ktx2", "--layer", layer, cwd=work)
    assert_refused(result, layer)
    after = {p: snapshot(work / p) if (work / p).is_dir() else (work / p).read_bytes() for p in before}
    assert after == before  # the layer, the scene, the store, the previous export: byte-identical
    assert sorted(p.name for p in work.iterdir()) == listing  # no new folder, no missing.usda, no temporary


def test_a_default_layer_that_is_a_users_file_is_refused(work):
    """``<store stem>.bake.usda`` beside the store that bakery did not write (here: the scene's probes layer)."""
    (work / "copy").mkdir()
    shutil.copy(work / "indoor.h5", work / "copy" / "indoor.h5")
    shutil.copy(work / "ex" / "indoor" / "probes.usda", work / "copy" / "indoor.bake.usda")
    before = snapshot(work / "copy")
    result = cli("export", "copy/indoor.h5", "-o", "copy/exports", "--format", "three", cwd=work)
    assert_refused(result, "copy/indoor.bake.usda")
    assert snapshot(work / "copy") == before


def test_a_default_layer_of_another_store_is_refused(work):
    """The store copied beside a layer that records another store (its own stays where it was)."""
    shutil.copy(work / "indoor.h5", work / "other" / "other2.h5")
    shutil.copy(work / "other" / "other.bake.usda", work / "other" / "other2.bake.usda")
    before = snapshot(work / "other")
    result = cli("export", "other/other2.h5", "-o", "other/exports", "--format", "ktx2", cwd=work)
    assert_refused(result, "other/other2.bake.usda")
    assert "other.h5" in result.stderr and snapshot(work / "other") == before


def test_the_stores_own_layer_records_the_export(work):
    from pxr import Sdf

    layer = work / "indoor.bake.usda"
    ok = cli("export", "indoor.h5", "-o", "exports/ktx2", "--format", "ktx2", cwd=work)  # the default layer
    assert ok.returncode == 0, ok.stderr
    ok = cli("export", "indoor.h5", "-o", "exports/three", "--format", "three", "--layer", "indoor.bake.usda",
             cwd=work)
    assert ok.returncode == 0, ok.stderr
    opened = Sdf.Layer.OpenAsAnonymous(str(layer))
    assert "Baked light probes written by bakery" in opened.comment  # still a bakery layer: exports again
    assert opened.customLayerData["bakery"]["store"] == "indoor.h5"
    probe = opened.GetPrimAtPath("/Room/Probes/TableReflection")
    assert (work / probe.attributes["bakery:export:ktx2"].default.path).is_file()
    volume = opened.GetPrimAtPath("/Room/Probes/Volume")
    assert (work / volume.attributes["bakery:export:three:grid"].default.path).is_file()
    assert not [p for p in work.iterdir() if ".tmp-" in p.name]
    # the store and the layer moved together to another folder: still the store's own layer
    moved = work / "moved"
    moved.mkdir()
    shutil.copy(work / "indoor.h5", moved / "indoor.h5")
    shutil.copy(layer, moved / "indoor.bake.usda")
    ok = cli("export", moved / "indoor.h5", "-o", moved / "k", "--format", "ktx2")
    assert ok.returncode == 0, ok.stderr
    assert "@k/Room_Probes_TableReflection.ktx2@" in (moved / "indoor.bake.usda").read_text()


def test_a_layer_replaced_during_the_export_is_not_edited(work, monkeypatch):
    """Checked before the build, and again when staged: a layer that a user's file replaced meanwhile is refused,
    and the export's files are removed (nothing written)."""
    from bakery.export import EXPORT_FORMATS, export_store

    cls = EXPORT_FORMATS["ktx2"]
    build = cls.build
    user = (work / "ex" / "indoor" / "probes.usda").read_bytes()

    def replacing(self, context):
        yield from build(self, context)
        (work / "indoor.bake.usda").write_bytes(user)

    monkeypatch.setattr(cls, "build", replacing)
    with pytest.raises(InputError, match="indoor.bake.usda.*not a bakery baked-results layer"):
        export_store(work / "indoor.h5", work / "exports", "ktx2")
    assert (work / "indoor.bake.usda").read_bytes() == user
    assert not (work / "exports").exists()


def test_a_layer_usd_cannot_write_leaves_no_export_file(work, monkeypatch):
    """The layer is staged with the files: a failure there removes them all."""
    import bakery.usd.layer as layer_module
    from bakery.errors import SceneError
    from bakery.export import export_store

    def fail(*args, **kwargs):
        raise SceneError("indoor.bake.usda: USD could not write the layer")

    monkeypatch.setattr(layer_module, "_with_export_attributes", fail)
    layer = (work / "indoor.bake.usda").read_bytes()
    before = snapshot(work / "previous")
    for folder in ("exports", "previous"):
        with pytest.raises(SceneError, match="could not write"):
            export_store(work / "indoor.h5", work / folder, "three" if folder == "exports" else "ktx2")
    assert not (work / "exports").exists() and snapshot(work / "previous") == before
    assert (work / "indoor.bake.usda").read_bytes() == layer
    assert not [p for p in work.iterdir() if ".tmp-" in p.name]


def test_an_export_that_edits_the_layer_waits_for_no_bake_of_the_store(work):
    """A bake of the store writes its layer too: while one holds the store's lock, an export that would edit the
    layer is refused (exit 2) rather than write attributes into a layer the bake is about to replace; with
    ``--no-layer`` it only reads the store (replaced atomically) and goes ahead."""
    from bakery.files import FileLock

    before = snapshot(work)
    with FileLock(work / "indoor.h5"):  # what a running `bakery bake … -o indoor.h5` holds
        result = cli("export", "indoor.h5", "-o", "exports", "--format", "ktx2", cwd=work)
        free = cli("export", "indoor.h5", "-o", "plain", "--format", "ktx2", "--no-layer", cwd=work)
    assert result.returncode == 2 and "another bake is writing this store" in result.stderr, result.stderr
    assert "Traceback" not in result.stderr and not (work / "exports").exists()
    assert free.returncode == 0, free.stderr
    assert {k: v for k, v in snapshot(work).items() if not k.startswith("plain/")} == before
