"""Shards of a plan baked by independent processes and merged: the same bytes as a one-process bake; the merge
checks coverage and plan identity; shards are resumable, locked and readable stores; `bakery plan` describes the
work (issue 16)."""

import json
import shutil

import numpy as np
import OpenImageIO as oiio
import pytest

import bakery
from bakery.pipeline.settings import request_from
from bakery.pipeline.shards import (
    ShardError,
    ShardSpec,
    bake_shard,
    merge_shards,
    parse_probe_range,
    parse_shard,
    suggest_chunking,
)
from bakery.store.format import read_store
from farm_helpers import FAST, INDOOR, cli, cli_json, write_recipe


@pytest.mark.slow
def test_four_shards_merged_are_bit_identical_to_one_bake(tmp_path):
    recipe = write_recipe(tmp_path)
    (tmp_path / "one").mkdir()
    (tmp_path / "farm").mkdir()
    one = tmp_path / "one" / "indoor.h5"
    summary = cli_json("bake", INDOOR, "-o", one, "--recipe", recipe, *FAST, "-j", "1")
    assert summary["baked"] == 26 and summary["batches"] == 5
    plan = cli_json("plan", INDOOR, "-o", tmp_path / "farm" / "indoor.h5", "--recipe", recipe, *FAST, "--tasks", "4")
    assert plan["chunking"]["ranges"] == ["0-7", "8-15", "16-23", "24-25"]
    shards = []
    for i in range(1, 5):
        shard = tmp_path / "farm" / "shards" / f"s{i}.h5"
        log = cli("bake", INDOOR, "--shard", f"{i}/4", "-o", shard, "--recipe", recipe, *FAST, "-j", "1", "--json")
        task = json.loads(log.stdout)
        assert task["range"] == plan["chunking"]["ranges"][i - 1] and task["plan_id"] == plan["plan_id"]
        assert task["recomputed_outside_range"] == 0 and task["timings"]["rays_per_second"] > 0
        assert f"probes {task['range']} of 26 (plan {plan['plan_id']})" in log.stderr  # the task's log line
        shards.append(shard)
    merged = tmp_path / "farm" / "indoor.h5"
    result = cli_json("merge", *shards, "-o", merged)
    assert (result["shards"], result["baked"], result["failed"]) == (4, 26, {})
    assert merged.read_bytes() == one.read_bytes()
    assert (tmp_path / "farm" / "indoor.bake.usda").read_bytes() == (tmp_path / "one" / "indoor.bake.usda").read_bytes()
    # A shard is a store like any other: readable, marked with its plan and range, and holding un-finalized results.
    store = bakery.open_store(shards[0])
    assert store.attributes["shard_of"] == plan["plan_id"] and store.attributes["shard_range"] == "0-7"
    assert len(store.probe_names) == 8 and "finalize/zh3_hallucinated/radiance_sh3" in store.diagnostics
    assert "band_energy" in store.diagnostics and "required_band" not in store.diagnostics
    assert json.loads(cli("inspect", shards[0], "--json").stdout)["probes"] == 8


def _request(tmp_path, output, **options):
    return request_from(INDOOR, output, face_size=4, samples=1, **options)


def test_ranges_that_cut_batches_still_merge_bit_identically(tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    (tmp_path / "one").mkdir()
    one = tmp_path / "one" / "indoor.h5"
    bakery.bake(INDOOR, one, face_size=4, samples=1, jobs=1)  # default batches: 24 + 1 + 1 probes
    (tmp_path / "farm").mkdir()
    shards = []
    for first, last in [(0, 9), (10, 20), (21, 25)]:  # the first two cut the 24-probe batch
        shard = tmp_path / "farm" / f"p{first}.h5"
        summary = bake_shard(_request(tmp_path, shard), ShardSpec(probes=(first, last)))
        assert summary.probes == last - first + 1 and summary.baked == summary.probes
        shards.append(shard)
    again = bake_shard(_request(tmp_path, shards[0]), ShardSpec(probes=(0, 9)))
    assert again.already_complete and again.recomputed_outside_range == 0  # resumable; nothing recomputed
    assert "recomputed" not in again.log_line()
    merged = tmp_path / "farm" / "indoor.h5"
    merge_shards(shards, merged)
    assert merged.read_bytes() == one.read_bytes()


def test_merge_names_missing_and_duplicated_ranges_and_refuses_mixed_plans(tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    paths = {}
    for first, last in [(0, 7), (5, 12), (20, 25)]:
        paths[first] = tmp_path / f"s{first}.h5"
        bake_shard(_request(tmp_path, paths[first]), ShardSpec(probes=(first, last)))
    with pytest.raises(ShardError, match=r"missing probes 13-19 \(in no shard\); probes 5-7 are in more than one"):
        merge_shards(list(paths.values()), tmp_path / "m.h5")
    other = tmp_path / "other.h5"  # a shard of another plan (another seed)
    bake_shard(request_from(INDOOR, other, face_size=4, samples=1, seed=3), ShardSpec(probes=(8, 19)))
    with pytest.raises(ShardError, match="different plans"):
        merge_shards([paths[0], other, paths[20]], tmp_path / "m.h5")
    result = cli("merge", paths[0], paths[20], "-o", tmp_path / "m.h5", check=False)
    assert result.returncode == 2 and "missing probes 8-19" in result.stderr
    assert not (tmp_path / "m.h5").exists()
    store = tmp_path / "final.h5"  # a finished store is not a shard, and no shard task replaces it
    bakery.bake(INDOOR, store, face_size=4, samples=1, jobs=1, encodings=("sh2",))
    with pytest.raises(ShardError, match="not a shard store"):
        merge_shards([store], tmp_path / "m.h5")
    with pytest.raises(ShardError, match="is a finished store, not a shard"):
        bake_shard(_request(tmp_path, store), ShardSpec(probes=(0, 3)))


def test_a_shard_refuses_another_plan_id_and_a_range_outside_the_plan(tmp_path):
    shard = tmp_path / "s.h5"
    result = cli("bake", INDOOR, "--probes", "0-3", "--plan-id", "0123456789abcdef", "-o", shard, "--face-size", "4",
                 *FAST, check=False)
    assert result.returncode == 2 and "not 0123456789abcdef" in result.stderr and not shard.exists()
    result = cli("bake", INDOOR, "--probes", "20-30", "-o", shard, "--face-size", "4", *FAST, check=False)
    assert result.returncode == 2 and "indices 0-25" in result.stderr
    result = cli("bake", INDOOR, "--shard", "5/4", "-o", shard, check=False)
    assert result.returncode == 3 and "1..n" in result.stderr
    assert cli("bake", INDOOR, "--shard", "1/4", check=False).returncode == 2  # a shard needs its own -o


def test_parsing_and_chunking():
    assert parse_probe_range("3-9") == (3, 9) and parse_probe_range("7") == (7, 7)
    assert parse_shard("2/5") == (2, 5)
    assert suggest_chunking([1.0] * 8, 4) == [(0, 1), (2, 3), (4, 5), (6, 7)]
    assert suggest_chunking([8.0, 1.0, 1.0, 1.0, 1.0], 2) == [(0, 0), (1, 4)]
    assert suggest_chunking([1.0, 1.0], 4) == [(0, 0), (1, 1)]  # never more tasks than batches
    chunks = suggest_chunking(list(np.random.default_rng(0).uniform(0.5, 2.0, 157)), 10)
    assert len(chunks) == 10 and chunks[0][0] == 0 and chunks[-1][1] == 156
    assert all(b[0] == a[1] + 1 for a, b in zip(chunks, chunks[1:]))


def test_plan_json_counts_kinds_reuse_batches_and_costs(tmp_path):
    recipe = write_recipe(tmp_path)
    plan = cli_json("plan", INDOOR, "-o", tmp_path / "indoor.h5", "--recipe", recipe, *FAST, "--tasks", "8")
    assert plan["probes"] == {"total": 26, "by_kind": {"irradiance": 25, "reflection": 1}}
    assert (plan["reused"], plan["to_bake"], len(plan["batches"])) == (0, 26, 5)
    assert [b["range"] for b in plan["batches"]] == ["0-7", "8-15", "16-23", "24-24", "25-25"]
    estimate = plan["estimate"]
    assert estimate["seconds_per_probe"]["reflection"] > 0 and estimate["seconds_per_probe"]["irradiance"] > 0
    assert set(estimate["encode_seconds"]) == {"zh3_hallucinated", "zh3_quantized", "sh3", "zh3_deringed", "shexp",
                                               "splitsum"}
    assert plan["chunking"]["useful_tasks"] == 5 and "at most 5 tasks" in plan["chunking"]["note"]
    assert not (tmp_path / "indoor.h5").exists()
    text = cli("plan", INDOOR, "-o", tmp_path / "indoor.h5", "--recipe", recipe, *FAST, "--tasks", "8").stdout
    assert "26 probes (25 irradiance, 1 reflection)" in text and "in 5 batches" in text
    assert "a smaller [pipeline] batch_size" in text  # the recipe section is text, not console markup


def _write_hdr(path, seed):
    pixels = np.random.default_rng(seed).lognormal(0, 1, (16, 32, 3)).astype(np.float32)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(32, 16, 3, oiio.FLOAT))
    out.write_image(pixels)
    out.close()


def test_an_incremental_farm_bake_reuses_the_base_store(tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    images = []
    for i in range(6):
        images.append(tmp_path / f"env{i}.hdr")
        _write_hdr(images[-1], i)
    options = {"face_size": 8, "encodings": ("sh2", "zh3")}
    store = tmp_path / "farm" / "envs.h5"
    store.parent.mkdir()
    bakery.bake(images, store, **options, jobs=1)
    (tmp_path / "one").mkdir()
    one = tmp_path / "one" / "envs.h5"
    shutil.copy(store, one)
    _write_hdr(images[2], 99)  # one image changed: one probe to bake, five reused
    bakery.bake(images, one, **options, jobs=1)
    shard = tmp_path / "farm" / "s1.h5"
    summary = bake_shard(request_from(images, shard, **options), ShardSpec(shard=(1, 2), base=store))
    assert (summary.work_probes, summary.baked) == (1, 1)
    empty = tmp_path / "farm" / "s2.h5"  # the plan has one batch: the second of two shards is empty
    assert bake_shard(request_from(images, empty, **options), ShardSpec(shard=(2, 2), base=store)).probes == 0
    result = merge_shards([shard, empty], store)
    assert (result.baked, result.reused) == (1, 5)
    assert store.read_bytes() == one.read_bytes()
    assert len(read_store(store).history) == 2


def test_a_shard_bake_uses_its_time_and_noise_options(tmp_path):
    """`bake --shard` read neither --time nor --target-noise (the shard baked the authored defaults without a word);
    they are the bake's options, so they change the shard's plan like any setting."""
    def plan_id(*extra):
        return cli_json("bake", INDOOR, "--shard", "1/1", "-o", tmp_path / "s.h5", "--face-size", "8", "--dry-run",
                        *extra)["plan_id"]

    plain = plan_id()
    assert plan_id("--time", "5") != plain
    assert plan_id("--target-noise", "0.05") != plain


def test_a_base_that_is_not_a_store_is_refused_and_a_merged_store_beside_the_shards_is_no_shard(tmp_path):
    """``--base garbage.h5`` planned against nothing without a word (a missing base is a farm's first bake and
    stays allowed); ``merge FOLDER -o FOLDER/m.h5`` counted its own earlier output as a shard the second time."""
    from bakery.errors import InputError

    garbage = tmp_path / "garbage.h5"
    garbage.write_text("not a store\n")
    images = [tmp_path / f"env{i}.hdr" for i in range(2)]
    for i, image in enumerate(images):
        _write_hdr(image, i)
    options = {"face_size": 8, "encodings": ("sh2",)}
    folder = tmp_path / "shards"
    folder.mkdir()
    with pytest.raises(InputError, match="garbage.h5: the base store is not an HDF5 file"):
        bake_shard(request_from(images, folder / "s1.h5", **options), ShardSpec(shard=(1, 1), base=garbage))
    assert sorted(p.name for p in folder.iterdir()) == []
    bake_shard(request_from(images, folder / "s1.h5", **options), ShardSpec(shard=(1, 1), base=tmp_path / "m.h5"))
    for _ in range(2):  # the second merge finds m.h5 in the folder: not a shard
        assert merge_shards([folder], folder / "m.h5").baked == 2
