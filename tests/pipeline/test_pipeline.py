"""The bake pipeline: determinism across executors, incremental bakes, resume after SIGKILL, crash-safe writes,
migration, recipes, per-probe failures. Real files, real processes, a real Dask LocalCluster."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import OpenImageIO as oiio
import pytest

import bakery
from bakery.errors import ConfigError
from bakery.pipeline.recipe import RECIPE_DIR, load_recipe
from bakery.store.format import FORMAT_VERSION, migrate_store, read_store

ENV = {**os.environ, "SOURCE_DATE_EPOCH": "1700000000"}
ENCODINGS = ["-e", "sh2", "-e", "zh3", "-e", "zh3_quantized"]


def bakery_cli(*args, check=True):
    result = subprocess.run([sys.executable, "-m", "bakery.cli", *map(str, args)], capture_output=True, text=True,
                            env=ENV)
    if check and result.returncode != 0:
        raise AssertionError(result.stderr)
    return result


def write_hdr(path, seed, size=(32, 64)):
    pixels = np.random.default_rng(seed).lognormal(0, 1, (*size, 3)).astype(np.float32)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(size[1], size[0], 3, oiio.FLOAT))
    out.write_image(pixels)
    out.close()


@pytest.fixture
def environments(tmp_path):
    folder = tmp_path / "envs"
    folder.mkdir()
    paths = []
    for i in range(6):
        path = folder / f"env{i}.hdr"
        write_hdr(path, i)
        paths.append(path)
    return paths


def recipe(tmp_path, batch_size):
    path = tmp_path / "small.toml"
    path.write_text(f'name = "small"\n[targets]\nirradiance = ["sh2", "zh3", "zh3_quantized"]\n'
                    f'[bake]\nface_size = 8\n[pipeline]\nbatch_size = {batch_size}\n')
    return path


def test_stores_are_bit_identical_across_executors(tmp_path, environments):
    r = recipe(tmp_path, 2)
    stores = {}
    for label, flags in {"serial": ["--jobs", "1"], "processes": ["--jobs", "2"],
                         "dask": ["--dask-local", "--jobs", "2"]}.items():
        stores[label] = tmp_path / f"{label}.h5"
        summary = json.loads(bakery_cli("bake", *environments, "-o", stores[label], "--recipe", r, "--json",
                                        *flags).stdout)
        assert summary["baked"] == 6 and summary["executor"] == label
    reference = stores["serial"].read_bytes()
    assert stores["processes"].read_bytes() == reference
    assert stores["dask"].read_bytes() == reference


def test_incremental_rebake_counts(tmp_path, environments):
    r = recipe(tmp_path, 2)
    store = tmp_path / "s.h5"
    first = json.loads(bakery_cli("bake", *environments, "-o", store, "--recipe", r, "--json", "-j", "1").stdout)
    assert (first["baked"], first["reused"]) == (6, 0)
    again = json.loads(bakery_cli("bake", *environments, "-o", store, "--recipe", r, "--json", "-j", "1").stdout)
    assert (again["baked"], again["reused"]) == (0, 6)
    write_hdr(environments[3], 99)  # change one probe's input
    one = json.loads(bakery_cli("bake", *environments, "-o", store, "--recipe", r, "--json", "-j", "1").stdout)
    assert (one["baked"], one["reused"]) == (1, 5)
    contents = read_store(store)
    assert len(contents.history) == 2  # the first bake (5 reused probes) and this one
    changed = contents.probe_names.index("/environment/env3")
    assert contents.probe_bake_ids[changed] == 1 and sorted(set(contents.probe_bake_ids)) == [0, 1]
    # The incremental store equals a clean bake of the same inputs, field for field.
    clean = tmp_path / "clean.h5"
    bakery_cli("bake", *environments, "-o", clean, "--recipe", r, "-j", "1")
    a, b = bakery.open_store(store), bakery.open_store(clean)
    for name in a.encodings:
        for key, value in a.fields(name).items():
            np.testing.assert_array_equal(value, b.fields(name)[key])
    diff = json.loads(bakery_cli("diff", clean, store, "--json").stdout)
    assert diff["changed"] == {} and diff["unchanged"] == 6


def test_a_new_encoding_version_changes_the_probe_hash(monkeypatch):
    """A stored result is reused only by the code that would compute it: the probe's content hash covers the
    versions of its encodings, so a numerical change of one encoding (a version bump) re-bakes its probes."""
    from bakery.encodings import get_encoding
    from bakery.pipeline.plan import probe_content_hash
    from bakery.probe import Probe
    from bakery.sources.base import PlannedProbe

    planned = PlannedProbe(Probe("/environment/a", ("irradiance",)), capture=("image", 16), inputs=("abc",))
    before = probe_content_hash("image", planned, ("sh2", "zh3"), "settings")
    assert probe_content_hash("image", planned, ("zh3", "sh2"), "settings") == before  # order-free
    monkeypatch.setattr(get_encoding("zh3"), "version", get_encoding("zh3").version + "-changed")
    assert probe_content_hash("image", planned, ("sh2", "zh3"), "settings") != before


def test_diff_reports_changed_probes(tmp_path, environments):
    r = recipe(tmp_path, 6)
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    bakery_cli("bake", *environments, "-o", a, "--recipe", r, "-j", "1")
    write_hdr(environments[0], 1234)
    bakery_cli("bake", *environments[:5], "-o", b, "--recipe", r, "-j", "1")
    report = json.loads(bakery_cli("diff", a, b, "--json").stdout)
    assert report["removed"] == ["/environment/env5"] and list(report["changed"]) == ["/environment/env0"]


def _kill_when(process, partial, finished_batches, timeout=120):
    """SIGKILL ``process`` as soon as the journal holds ``finished_batches`` checkpoints (or it exits)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and process.poll() is None:
        if partial.is_dir() and len(list(partial.glob("*.pkl"))) >= finished_batches:
            process.send_signal(signal.SIGKILL)
            break
        time.sleep(0.01)
    process.wait()
    return process.returncode == -signal.SIGKILL


def test_resume_after_sigkill(tmp_path):
    folder = tmp_path / "envs"
    folder.mkdir()
    sources = []
    for i in range(8):
        path = folder / f"big{i}.hdr"
        write_hdr(path, i, size=(128, 256))
        sources.append(path)
    r = tmp_path / "slow.toml"
    r.write_text('name = "slow"\n[targets]\nirradiance = ["sh2", "zh3_solved"]\n[bake]\nface_size = 16\n'
                 'reference_errors = true\nquality_directions = 1024\n[pipeline]\nbatch_size = 1\n')
    store = tmp_path / "r.h5"
    bakery_cli("bake", sources[0], "-o", store, "-e", "sh2", "--face-size", "8")  # a previous store
    previous = store.read_bytes()
    partial = tmp_path / "r.h5.partial"
    kills = 0
    for kill_after in (1, 3):  # kill after the first checkpoint, then again two checkpoints later
        process = subprocess.Popen([sys.executable, "-m", "bakery.cli", "bake", *map(str, sources), "-o", str(store),
                                    "--recipe", str(r), "-j", "1"], env=ENV, stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL)
        kills += _kill_when(process, partial, kill_after)
        assert store.read_bytes() == previous  # the killed bake never touched the previous store
    assert kills == 2
    finished_before = len(list(partial.glob("*.pkl")))
    assert 3 <= finished_before < 8
    summary = json.loads(bakery_cli("bake", *sources, "-o", store, "--recipe", r, "-j", "1", "--json").stdout)
    assert summary["resumed_batches"] == finished_before
    assert summary["baked"] == 8 and not partial.exists()
    clean = tmp_path / "clean.h5"
    bakery_cli("bake", *sources, "-o", clean, "--recipe", r, "-j", "1", "--no-resume")
    assert clean.read_bytes() == store.read_bytes()


WRITER = """
import sys, numpy as np
from bakery.store.format import StoreContents, write_store
n = 20000
contents = StoreContents({"note": "new"}, [f"/p{i}" for i in range(n)], ["irradiance"] * n, np.zeros((n, 3)),
    {"big": {"attributes": {"encoding_type": "big", "encoding_version": "1.0.0", "kind": "irradiance",
             "bytes_per_probe": 4096},
             "fields": {"probe_index": np.arange(n, dtype=np.int32),
                        "data": np.random.default_rng(0).normal(size=(n, 1024)).astype(np.float32)}}})
write_store(sys.argv[1], contents)
"""


def test_store_survives_a_crash_at_every_write_stage(tmp_path, environments):
    store = tmp_path / "keep.h5"
    bakery_cli("bake", environments[0], "-o", store, "-e", "sh2", "--face-size", "8")
    previous = store.read_bytes()
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    for delay in (0.05, 0.3, 0.6, 0.9, 1.2, 1.6):
        process = subprocess.Popen([sys.executable, str(script), str(store)])
        time.sleep(delay)
        process.send_signal(signal.SIGKILL)
        process.wait()
        if store.read_bytes() != previous:  # the writer finished before the kill: the new store must be whole
            assert read_store(store).attributes["note"] == "new"
            previous = store.read_bytes()
        else:
            assert bakery.open_store(store).probe_names == ["/environment"]


def test_newer_major_is_refused_and_migrate_round_trips(tmp_path, environments):
    store = tmp_path / "old.h5"
    bakery_cli("bake", environments[0], "-o", store, "-e", "zh3", "--face-size", "8")
    before = bakery.open_store(store).fields("zh3")
    with h5py.File(store, "r+") as f:  # make it a 1.0.0 store: no hashes, bake ids or history
        f.attrs["format_version"] = "1.0.0"
        del f["probes/content_hash"], f["probes/bake_id"], f["history"]
    assert bakery.open_store(store).format_version == "1.0.0"
    assert f"1.0.0 -> {FORMAT_VERSION}" in bakery_cli("migrate", store, "--dry-run").stdout
    assert migrate_store(store) and read_store(store).attributes["format_version"] == FORMAT_VERSION
    after = bakery.open_store(store).fields("zh3")
    for key in before:
        np.testing.assert_array_equal(before[key], after[key])
    assert len(read_store(store).history) == 1
    with h5py.File(store, "r+") as f:
        f.attrs["format_version"] = "2.0.0"
    result = bakery_cli("inspect", store, check=False)
    assert result.returncode == 2 and "newer" in result.stderr


def test_migrate_from_1_1_adds_checksums(tmp_path, environments):
    store = tmp_path / "old.h5"
    bakery_cli("bake", environments[0], "-o", store, "-e", "zh3", "--face-size", "8")
    before = bakery.open_store(store).fields("zh3")
    with h5py.File(store, "r+") as f:  # a 1.1.0 store: no /checksums
        f.attrs["format_version"] = "1.1.0"
        del f["checksums"]
    assert read_store(store).integrity.verified is False  # 1.1 stores carry nothing to verify
    out = bakery_cli("migrate", store).stdout
    assert f"1.1.0 -> {FORMAT_VERSION}" in out and "checksums" in out
    migrated = read_store(store)
    assert migrated.integrity.verified and migrated.integrity.ok
    for key, value in before.items():
        np.testing.assert_array_equal(value, bakery.open_store(store).fields("zh3")[key])
    assert "already format" in bakery_cli("migrate", store).stdout


@pytest.mark.parametrize("text,message", [
    ('name = "x"\n[targets]\nirradiance = ["nope"]', "unknown encoding 'nope'"),
    ('name = "x"\n[targets]\nirradiance = ["zh3"]\n[bake]\nface_size = 2', "bake.face_size"),
    ('name = "x"\n[targets]\nirradiance = ["zh3"]\n[bake]\nfase_size = 32', "fase_size"),
    ('[targets]\nirradiance = ["zh3"]', "'name' is a required property"),
    ('name = "x"\n[targets]\nreflection = ["zh3"]', "is a irradiance encoding"),
    ('name = "x"\n[targets\n', "not valid TOML"),
    (b'name = "x\xff"\n', "not UTF-8 text: byte 9"),  # a UnicodeDecodeError traceback before
    ("\ufeffname = 'x'".encode("utf-16"), "not UTF-8 text: byte 0"),
])
def test_recipe_schema_rejects_bad_recipes(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_bytes(text) if isinstance(text, bytes) else path.write_text(text)
    with pytest.raises(ConfigError, match=message.replace("[", "\\[").replace("(", "\\(")) as error:
        load_recipe(str(path))
    assert "bad.toml" in str(error.value)


def test_shipped_recipes_are_valid():
    presets = sorted(p.stem for p in RECIPE_DIR.glob("*.toml"))
    assert "mobile" in presets
    for name in presets:
        assert load_recipe(name).name == name


def test_a_failing_probe_is_reported_and_the_others_are_written(tmp_path, environments):
    bad = environments[0].parent / "broken.hdr"
    bad.write_bytes(environments[1].read_bytes()[:300])
    store = tmp_path / "partial.h5"
    result = bakery_cli("bake", *environments, bad, "-o", store, "--recipe", recipe(tmp_path, 2), "-j", "2",
                        "--json", check=False)
    assert result.returncode == 6
    summary = json.loads(result.stdout)
    assert list(summary["failed"]) == ["/environment/broken"] and "broken.hdr" in summary["failed"]["/environment/broken"]
    assert len(bakery.open_store(store).probe_names) == 6


def test_dry_run_prints_the_plan_and_writes_nothing(tmp_path, environments):
    store = tmp_path / "never.h5"
    result = bakery_cli("bake", *environments, "-o", store, "--recipe", recipe(tmp_path, 4), "--dry-run", "--json")
    plan = json.loads(result.stdout)
    assert plan["probes"] == 6 and plan["batches"] == 2 and not store.exists()


def test_inspect_selects_probes_by_path_and_region(tmp_path, environments):
    store = tmp_path / "s.h5"
    bakery_cli("bake", *environments, "-o", store, "--recipe", recipe(tmp_path, 6), "-j", "1")
    rows = json.loads(bakery_cli("inspect", store, "--probes", "/environment/env[12]", "--json").stdout)
    assert [r["name"] for r in rows] == ["/environment/env1", "/environment/env2"]
    assert all(len(r["content_hash"]) == 64 for r in rows)
    inside = json.loads(bakery_cli("inspect", store, "--region=-1,-1,-1,1,1,1", "--json").stdout)
    assert len(inside) == 6  # distant probes sit at the origin
    outside = json.loads(bakery_cli("inspect", store, "--region=1,1,1,2,2,2", "--json").stdout)
    assert outside == []


def test_a_changed_encoding_default_re_bakes_only_that_encodings_probes(tmp_path, monkeypatch):
    """A stored result is reused only under the parameters it was baked with, defaults included: changing the
    hybrid's default ``keep_capture`` (same bakery version, same settings file) re-bakes the reflection probe and
    no irradiance probe — before, the store kept its zero-filled ``level0`` while recording the new setting, and an
    export of it would have been black."""
    import dataclasses

    import numpy as np

    import bakery
    from pathlib import Path

    from bakery.encodings import get_encoding

    scene = Path(__file__).resolve().parents[2] / "examples" / "indoor" / "indoor.usda"
    store = tmp_path / "s.h5"
    common = dict(encodings=("sh2", "shexp_hybrid"), face_size=16, samples=1, bounces=1, jobs=1)
    hybrid = get_encoding("shexp_hybrid")
    monkeypatch.setattr(hybrid, "Params", dataclasses.make_dataclass(
        "Params", [("keep_capture", bool, dataclasses.field(default=False))], bases=(hybrid.Params,), frozen=True))
    first = bakery.bake(scene, store, **common)
    level0 = bakery.open_store(store).fields("shexp_hybrid")["level0"]
    assert first.baked > 1 and not np.any(level0)  # the table probe sees only rough materials: no capture kept
    monkeypatch.undo()  # the shipped default: keep_capture = True
    second = bakery.bake(scene, store, **common)
    assert second.baked == 1 and second.reused == first.baked - 1
    assert np.abs(bakery.open_store(store).fields("shexp_hybrid")["level0"]).max() > 0


def test_a_probe_that_fails_outside_bakery_errors_is_recorded_in_one_line():
    """A failed probe's record (store ``failed``, the CLI's ``failed NAME: …``) is one line: the error's type, its
    message and where it was raised; it used to be a three-frame traceback."""
    from bakery.errors import SceneError
    from bakery.pipeline.worker import failure_message

    def allocate():
        return np.zeros((1 << 26, 1 << 26))  # 32 PiB

    try:
        allocate()
    except MemoryError as error:
        message = failure_message(error)
    assert "\n" not in message and "Traceback" not in message
    assert message.startswith("MemoryError: Unable to allocate") and message.endswith("in allocate)")
    assert failure_message(SceneError("/World/Probe: no geometry")) == "/World/Probe: no geometry"
