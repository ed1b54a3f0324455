"""``bakery bench -o DIR`` replaces only files a bench wrote and nobody changed since (``bakery.bench.output``):
a user's ``irradiance.md`` in the folder is refused before the run, byte for byte untouched, unless ``--force``.
Before: every bench replaced its file names in any folder without a check."""

from __future__ import annotations

import numpy as np
import pytest
from faultkit import assert_fails_cleanly, incli, snapshot

from bakery.environment.io import write_exr

pytestmark = pytest.mark.faults


def _bench(*args):
    return incli("bench", "irradiance", *args, "--face-size", "8")


def test_bench_results_replace_only_what_a_bench_wrote(tmp_path):
    images = tmp_path / "hdr"
    images.mkdir()
    sky = np.full((16, 32, 3), 0.5, np.float32)
    sky[3, 5] = 20.0
    write_exr(images / "sky.exr", sky)
    out = tmp_path / "out"
    out.mkdir()
    (out / "irradiance.md").write_text("my notes\n")
    before = snapshot(out)
    assert_fails_cleanly(_bench(images, "-o", out), 2, "irradiance.md", "not a result bakery bench wrote", "--force")
    assert snapshot(out) == before  # refused before the run: nothing written, nothing added
    assert _bench(images, "-o", out, "--force").returncode == 0
    assert (out / "irradiance.md").read_text() != "my notes\n"
    assert _bench(images, "-o", out).returncode == 0  # its own previous results: replaced without --force
    (out / "irradiance.json").write_text("{}")  # edited since: no longer the bench's
    assert_fails_cleanly(_bench(images, "-o", out), 2, "irradiance.json")


def _write_many(folder, prefix, count):
    from bakery.bench.output import write_bench_file

    for i in range(count):
        write_bench_file(folder, f"{prefix}-{i}.json", f'{{"i": {i}}}')


def test_benches_writing_into_one_folder_at_once_keep_each_others_records(tmp_path):
    """Four processes write 25 results each into one folder at the same time: the manifest records all 100 with
    the sha256 of what is on disk (before: its read-modify-write was unlocked, and a bench's record could be lost,
    after which its own result was refused as a user's file)."""
    import hashlib
    import json
    import multiprocessing

    from bakery.bench.output import MANIFEST

    context = multiprocessing.get_context("fork")
    writers = [context.Process(target=_write_many, args=(tmp_path, f"w{k}", 25)) for k in range(4)]
    for writer in writers:
        writer.start()
    for writer in writers:
        writer.join(60)
    assert all(writer.exitcode == 0 for writer in writers)
    recorded = json.loads((tmp_path / MANIFEST).read_text())["files"]
    on_disk = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in tmp_path.glob("w*.json")}
    assert len(on_disk) == 100 and recorded == on_disk
