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
