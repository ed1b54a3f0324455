"""Issue 15 case 1 — outputs never replace what they should not: a bake writes its store only to a new path or over a
bakery store of a format this bakery writes, its layer only to a new path or over a bakery layer; ``migrate -o``
and ``report -o`` follow the same policy. Everything else is refused before any work (exit 2, the file and the
reason named, every file byte-identical) unless ``--force``, which still never overwrites an input."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import bakery.farm
from faultkit import (
    SCENE_FLAGS,
    assert_fails_cleanly,
    incli,
    scene_text,
    snapshot,
    temporaries,
    write_env,
)

pytestmark = pytest.mark.faults
OPENJD_FLAGS = ("--face-size", "4", "--samples", "1")


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    """A workspace: an image, a scene with a sublayer, a previous store and every kind of file in the way."""
    d = tmp_path_factory.mktemp("policy")
    write_env(d / "city.hdr".replace(".hdr", ".exr"), 1)
    (d / "sub.usda").write_text("#usda 1.0\n")
    (d / "scene.usda").write_text(scene_text(2, extra='    subLayers = [@./sub.usda@]\n'))
    assert incli("bake", d / "city.exr", "-o", d / "prev.h5", "-e", "sh2", "--face-size", "4").returncode == 0
    (d / "notes.h5").write_text("my notes, not a store\n")
    with h5py.File(d / "foreign.h5", "w") as f:
        f["data"] = np.arange(10)
    with h5py.File(d / "city.h5", "w") as f:  # an unrelated HDF5 file beside the image (the default -o)
        f["measurements"] = np.ones(4)
    for name, version in (("newer.h5", "9.0.0"), ("newer_minor.h5", "1.9.0")):
        shutil.copy(d / "prev.h5", d / name)
        with h5py.File(d / name, "a") as f:
            f.attrs["format_version"] = version
    data = (d / "prev.h5").read_bytes()
    (d / "truncated.h5").write_bytes(data[: len(data) // 2])
    (d / "layer.usda").write_text("#usda 1.0\n(\n    doc = \"my hand-written layer\"\n)\n")
    (d / "out.bake.usda").write_text("#usda 1.0\n(\n    doc = \"not a bakery layer\"\n)\n")
    (d / "rdir").mkdir()
    shutil.copy(d / "prev.h5", d / "rdir" / "report.json")  # a store that happens to be called report.json
    (d / "rep").mkdir()
    (d / "rep" / "report.html").write_text("<html>my page</html>")
    (d / "job.yaml").write_text("my: own yaml\n")
    (d / "mine.params.json").write_text('{"my": "own parameters"}\n')
    shutil.copy(Path(bakery.farm.__file__).with_name("calibration.json"), d / "cal.json")
    return d


def _refused(ws, args, *needles):
    before = snapshot(ws)
    result = incli(*args)
    assert_fails_cleanly(result, 2, *needles)
    assert snapshot(ws) == before  # nothing touched, nothing added
    assert not temporaries(ws)


CASES = {
    # the scene replaced by the store / the image replaced by the store
    "store onto the scene": (["bake", "{d}/scene.usda", "-o", "{d}/scene.usda"], ["scene.usda", "HDF5"]),
    "store onto the image": (["bake", "{d}/city.exr", "-o", "{d}/city.exr"], ["city.exr", "HDF5"]),
    "store onto a text file": (["bake", "{d}/city.exr", "-o", "{d}/notes.h5"], ["notes.h5", "not an HDF5 file"]),
    "store onto a foreign HDF5 file": (["bake", "{d}/city.exr", "-o", "{d}/foreign.h5"],
                                       ["foreign.h5", "not a bakery probe store"]),
    "store onto a newer-format store": (["bake", "{d}/city.exr", "-o", "{d}/newer.h5"], ["newer.h5", "9.0.0", "newer"]),
    "store onto a newer-minor store": (["bake", "{d}/city.exr", "-o", "{d}/newer_minor.h5"],
                                       ["newer_minor.h5", "1.9.0", "newer"]),
    "store onto a truncated store": (["bake", "{d}/city.exr", "-o", "{d}/truncated.h5"],
                                     ["truncated.h5", "truncated or corrupt"]),
    "default -o onto an unrelated HDF5 file": (["bake", "{d}/city.exr"], ["city.h5", "not a bakery probe store"]),
    "layer onto a hand-written layer": (["bake", "{d}/scene.usda", "-o", "{d}/new.h5", "--layer", "{d}/layer.usda"],
                                        ["layer.usda", "not a bakery baked-results layer"]),
    "default layer onto a foreign file": (["bake", "{d}/scene.usda", "-o", "{d}/out.h5"],
                                          ["out.bake.usda", "not a bakery baked-results layer"]),
    "layer onto the scene": (["bake", "{d}/scene.usda", "-o", "{d}/new.h5", "--layer", "{d}/scene.usda"],
                             ["scene.usda", "input"]),
    "layer onto a sublayer": (["bake", "{d}/scene.usda", "-o", "{d}/new.h5", "--layer", "{d}/sub.usda"],
                              ["sub.usda"]),
    "layer onto the store": (["bake", "{d}/scene.usda", "-o", "{d}/new.h5", "--layer", "{d}/prev.h5"], ["prev.h5"]),
    "migrate -o onto the scene": (["migrate", "{d}/prev.h5", "-o", "{d}/scene.usda"], ["scene.usda", "HDF5"]),
    "migrate -o onto a foreign HDF5 file": (["migrate", "{d}/prev.h5", "-o", "{d}/foreign.h5"],
                                            ["foreign.h5", "not a bakery probe store"]),
    "migrate -o onto a newer store": (["migrate", "{d}/prev.h5", "-o", "{d}/newer.h5"], ["newer.h5", "newer"]),
    "report -o over a foreign page": (["report", "{d}/prev.h5", "-o", "{d}/rep", "--no-previews"],
                                      ["report.html", "not a bakery report"]),
    "report -o onto a file": (["report", "{d}/prev.h5", "-o", "{d}/notes.h5", "--no-previews"],
                              ["notes.h5", "not a directory"]),
    # --force never overwrites an input of the bake
    "--force: store onto the image": (["bake", "{d}/city.exr", "-o", "{d}/city.exr", "--force"], ["city.exr"]),
    "--force: layer onto the scene": (["bake", "{d}/scene.usda", "-o", "{d}/new.h5", "--layer", "{d}/scene.usda",
                                       "--force"], ["scene.usda", "input"]),
    "--force: layer onto a sublayer": (["bake", "{d}/scene.usda", "-o", "{d}/new.h5", "--layer", "{d}/sub.usda",
                                        "--force"], ["sub.usda"]),
    "--force: report over its own store": (["report", "{d}/rdir/report.json", "-o", "{d}/rdir", "--no-previews",
                                            "--force"], ["report.json", "input"]),
    # farm job templates and calibrations (they used to replace any file, the scene included, with exit 0)
    "openjd -o onto the scene": (["farm", "openjd", "{d}/scene.usda", "-o", "{d}/scene.usda", *OPENJD_FLAGS],
                                 ["scene.usda", "job template"]),
    "openjd -o onto a foreign YAML file": (["farm", "openjd", "{d}/scene.usda", "-o", "{d}/job.yaml", *OPENJD_FLAGS],
                                           ["job.yaml", "not a job template"]),
    "openjd parameters onto a foreign JSON file": (["farm", "openjd", "{d}/scene.usda", "-o", "{d}/mine.yaml",
                                                    *OPENJD_FLAGS], ["mine.params.json", "not a job parameter file"]),
    "--force: openjd -o onto its calibration": (["farm", "openjd", "{d}/scene.usda", "-o", "{d}/cal.json",
                                                 "--calibration", "{d}/cal.json", "--force", *OPENJD_FLAGS],
                                                ["cal.json", "input"]),
    # what the farm job's tasks will write, checked when the template is written, not after the bake tasks ran
    "openjd --shard-dir onto a file": (["farm", "openjd", "{d}/scene.usda", "-o", "{d}/j1.yaml", "--shard-dir",
                                        "{d}/notes.h5", *OPENJD_FLAGS], ["notes.h5", "not a folder"]),
    "openjd --layer onto a sublayer": (["farm", "openjd", "{d}/scene.usda", "-o", "{d}/j2.yaml", "--layer",
                                        "{d}/sub.usda", *OPENJD_FLAGS], ["sub.usda", "input"]),
    "calibrate -o onto a text file": (["farm", "calibrate", "-o", "{d}/notes.h5"], ["notes.h5", "not a calibration"]),
    # a name the temporary files beside it cannot extend (failed after the whole bake until 2026-12-06)
    "store name too long": (["bake", "{d}/city.exr", "-o", "{d}/" + "n" * 236 + ".h5"], ["file name is too long"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_refused_before_any_work(ws, case):
    args, needles = CASES[case]
    _refused(ws, [a.format(d=ws) for a in args], *needles)


def test_force_replaces_a_foreign_file_but_nothing_else(ws, tmp_path):
    target = tmp_path / "foreign.h5"
    shutil.copy(ws / "foreign.h5", target)
    result = incli("bake", ws / "city.exr", "-o", target, "-e", "sh2", "--face-size", "4", "--force")
    assert result.returncode == 0, result.output
    import bakery

    assert bakery.open_store(target).probe_names == ["/environment"]


def test_a_previous_store_and_layer_are_replaced(ws, tmp_path):
    scene = tmp_path / "scene.usda"
    scene.write_text(scene_text(2))
    store = tmp_path / "s.h5"
    for _ in range(2):  # the second bake replaces its own store and layer: allowed
        result = incli("bake", scene, "-o", store, *SCENE_FLAGS, "-j", "1")
        assert result.returncode == 0, result.output
    assert (tmp_path / "s.bake.usda").is_file() and not temporaries(tmp_path)
    migrated = tmp_path / "copy.h5"
    assert incli("migrate", store, "-o", migrated).returncode == 0  # a new path
    assert incli("migrate", store, "-o", migrated).returncode == 0  # over a store: allowed
    rep = tmp_path / "rep"
    for _ in range(2):
        assert incli("report", store, "-o", rep, "--no-previews").returncode == 0


def test_another_stores_layer_is_refused_and_force_replaces_it(ws, tmp_path):
    """A bakery layer that records another store that still exists is that bake's result: ``x.h5`` and ``x.hdf5``
    share the default ``x.bake.usda``, and ``--layer`` may name another bake's layer (before: silently taken over,
    and ``bakery export`` of the first store then refused its own layer)."""
    scene = tmp_path / "scene.usda"
    scene.write_text(scene_text(2))
    assert incli("bake", scene, "-o", tmp_path / "scene.h5", *SCENE_FLAGS, "-j", "1").returncode == 0
    before = snapshot(tmp_path)
    result = incli("bake", scene, "-o", tmp_path / "scene.hdf5", *SCENE_FLAGS, "-j", "1")
    assert_fails_cleanly(result, 2, "scene.bake.usda", "the store scene.h5, not of scene.hdf5", "--force")
    assert snapshot(tmp_path) == before and not temporaries(tmp_path)
    (tmp_path / "scene.h5").unlink()  # an orphan layer (its store is gone) is replaced without --force
    assert incli("bake", scene, "-o", tmp_path / "scene.hdf5", *SCENE_FLAGS, "-j", "1").returncode == 0
    assert incli("bake", scene, "-o", tmp_path / "scene.h5", *SCENE_FLAGS, "-j", "1").returncode == 2
    assert incli("bake", scene, "-o", tmp_path / "scene.h5", *SCENE_FLAGS, "-j", "1", "--force").returncode == 0


@given(data=st.binary(max_size=96), marker=st.binary(min_size=1, max_size=7), position=st.integers(0, 96),
       insert=st.booleans(), limit=st.integers(0, 110), chunk=st.integers(1, 9))
def test_the_layer_marker_search_reads_in_chunks_and_finds_what_a_whole_read_finds(data, marker, position, insert,
                                                                                   limit, chunk):
    """The layer check's chunked search (a 256 MB read allocated 256 MB per bake) against ``marker in data[:limit]``,
    markers straddling chunk borders included."""
    import io

    from bakery.pipeline.run import _contains

    if insert:
        data = data[:position] + marker + data[position:]
    assert _contains(io.BytesIO(data), marker, limit, chunk) == (marker in data[:limit])


def test_a_previous_job_template_and_its_parameters_are_replaced(ws, tmp_path):
    template = tmp_path / "job.yaml"
    for _ in range(2):  # the second run replaces what the first wrote: allowed
        result = incli("farm", "openjd", ws / "scene.usda", "-o", template, "--store", tmp_path / "s.h5", *OPENJD_FLAGS)
        assert result.returncode == 0, result.output
    assert template.read_text().startswith("# Open Job Description") and (tmp_path / "job.params.json").is_file()
    assert not temporaries(tmp_path)
