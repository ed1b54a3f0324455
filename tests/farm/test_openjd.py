"""`bakery farm openjd` writes an Open Job Description template that `openjd check` validates and `openjd run`
runs locally: four probe-range bake tasks and a dependent merge, bit-identical to `bakery bake` (the issue's
done-when), with the operator cache shared by the tasks instead of rebuilt per task."""

import importlib.util
import json
import re
import subprocess
import sys

import pytest

from farm_helpers import ENV, FAST, INDOOR, cli, write_recipe

pytestmark = pytest.mark.skipif(importlib.util.find_spec("openjd.cli") is None,
                                reason="openjd-cli is not installed (pip install -e '.[test]')")


def openjd(*args, env=None):  # noqa: ANN001, ANN201
    return subprocess.run([sys.executable, "-m", "openjd", *map(str, args)], capture_output=True, text=True,
                          env=env or ENV, timeout=600, check=False)


def cache_state(folder):  # noqa: ANN001, ANN201
    """Name (content hash), inode and size per cached operator: a rebuild is a new file (atomic rename, new inode);
    the mtime moves on every use (the cache's least-recently-used record)."""
    return {p.name: (p.stat().st_ino, p.stat().st_size) for p in folder.glob("*.npy")}


@pytest.mark.slow
def test_a_four_task_openjd_job_merges_to_the_bytes_of_one_bake(tmp_path):
    recipe = write_recipe(tmp_path)
    cache = tmp_path / "shared-cache"  # the farm's shared operator cache
    env = {**ENV, "BAKERY_CACHE_DIR": str(cache)}
    (tmp_path / "one" / "out").mkdir(parents=True)
    one = tmp_path / "one" / "out" / "indoor.h5"
    cli("bake", INDOOR, "-o", one, "--recipe", recipe, *FAST, "-j", "1", env=env)
    built = cache_state(cache)
    assert built  # the one-process bake built the operators once

    job = tmp_path / "job" / "bake.yaml"
    job.parent.mkdir()
    store = tmp_path / "job" / "out" / "indoor.h5"
    written = cli("farm", "openjd", INDOOR, "-o", job, "--store", store, "--recipe", recipe, *FAST, "--tasks", "4",
                  "--command", f"{sys.executable} -m bakery.cli", env=env)
    assert "4 bake tasks (0-7, 8-15, 16-23, 24-25)" in written.stderr
    checked = openjd("check", job)
    assert checked.returncode == 0 and "passes validation" in checked.stdout, checked.stdout + checked.stderr
    params = job.with_name("bake.params.json")
    assert json.loads(params.read_text())["Store"] == str(store)
    run = openjd("run", job, "--step", "Merge", "--run-dependencies", "--job-param", f"file://{params}", env=env)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    for probes in ("0-7", "8-15", "16-23", "24-25"):  # each task logs its range, rays/s and timings
        assert f"probes {probes} of 26" in run.stdout and (store.parent / "indoor.shards" /
                                                           f"shard-{probes}.h5").is_file()
    assert run.stdout.count('"rays_per_second"') >= 4
    assert store.read_bytes() == one.read_bytes()
    assert (store.parent / "indoor.bake.usda").read_bytes() == (one.parent / "indoor.bake.usda").read_bytes()
    assert cache_state(cache) == built  # the tasks memory-mapped the shared operators; none was rebuilt


def test_the_template_pins_its_plan(tmp_path):
    job = tmp_path / "bake.yaml"
    store = tmp_path / "out" / "indoor.h5"
    cli("farm", "openjd", INDOOR, "-o", job, "--store", store, "--face-size", "4", *FAST, "--tasks", "2")
    text = job.read_text()
    assert "--plan-id" in text and "{{Task.Param.Probes}}" in text and "dependsOn" in text
    # The same shard command with other settings is another plan: refused with exit 2 before any work.
    plan_id = text.split('"--plan-id"')[1].split('"')[1]
    result = cli("bake", INDOOR, "--probes", "0-3", "--plan-id", plan_id, "-o", tmp_path / "s.h5", "--face-size", "8",
                 *FAST, check=False)
    assert result.returncode == 2 and "changed since the job was planned" in result.stderr


def test_an_up_to_date_store_gets_a_valid_one_task_job(tmp_path):
    """Planned against a store that is up to date, the plan bakes no probe: no range to shard, and an OpenJD step
    without tasks is not a valid template (it was written, exit 0, and `openjd check` refused it). The job is one
    `Merge` task that re-runs the bake: it reuses every probe and leaves the store's bytes as they were."""
    (tmp_path / "out").mkdir()
    store = tmp_path / "out" / "indoor.h5"
    settings = ("--face-size", "4", *FAST)
    cli("bake", INDOOR, "-o", store, *settings, "-j", "1")
    before = store.read_bytes()
    job = tmp_path / "bake.yaml"
    written = cli("farm", "openjd", INDOOR, "-o", job, "--store", store, *settings, "--tasks", "4",
                  "--command", f"{sys.executable} -m bakery.cli")
    assert "is up to date" in written.stderr, written.stderr
    checked = openjd("check", job)
    assert checked.returncode == 0 and "passes validation" in checked.stdout, checked.stdout + checked.stderr
    params = job.with_name("bake.params.json")
    run = openjd("run", job, "--step", "Merge", "--run-dependencies", "--job-param", f"file://{params}")
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    counts = re.search(r'"baked":\s*0\b', run.stdout) and re.search(r'"reused":\s*26\b', run.stdout)
    assert counts, run.stdout[-3000:]
    assert store.read_bytes() == before
