"""Issue 15 cases 7 and 8 — values and options.

7. Finite but huge input (texels of 3.0e38, near float32's maximum) overflows in the projection: the probe's
   encoded values would be ``inf``. Such a probe is refused (reported as failed, exit 2 if it was the only one,
   exit 6 with the others written otherwise), never stored.
8. Command-line values are validated by click types and ranges: ``--jobs -2`` and ``--jobs 0`` are usage errors
   (exit 2), a malformed ``--scheduler`` address too, and an unreachable scheduler is a one-line error (exit 2)
   within seconds, not a traceback after 30 s."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from faultkit import assert_fails_cleanly, cli, incli, write_env

import bakery
from bakery.environment.io import write_exr

pytestmark = pytest.mark.faults


@pytest.fixture
def huge(tmp_path):
    path = tmp_path / "huge.exr"
    write_exr(path, np.full((16, 32, 3), 3.0e38, dtype=np.float32), half=False)  # float32 texels
    return path


def test_overflowing_input_is_refused_not_stored(tmp_path, huge):
    store = tmp_path / "s.h5"
    assert incli("bake", write_env(tmp_path / "ok.exr"), "-o", store, "-e", "sh3", "--face-size", "4").returncode == 0
    before = store.read_bytes()
    result = incli("bake", huge, "-o", store, "-e", "sh3", "--face-size", "4")
    assert_fails_cleanly(result, 2, "/environment", "sh3", "non-finite", "not stored")
    assert store.read_bytes() == before


def test_overflowing_probe_is_left_out_and_the_others_written(tmp_path, huge):
    store = tmp_path / "s.h5"
    result = incli("bake", write_env(tmp_path / "ok.exr"), huge, "-o", store, "-e", "sh2", "-e", "sh3",
                   "--face-size", "4", "--json")
    assert result.returncode == 6, result.output
    summary = json.loads(result.output[result.output.index("{"):])
    assert list(summary["failed"]) == ["/environment/huge"] and "non-finite" in summary["failed"]["/environment/huge"]
    written = bakery.open_store(store)
    assert written.probe_names == ["/environment/ok"]
    for name in written.encodings:
        for key, values in written.fields(name).items():
            assert np.all(np.isfinite(values)), (name, key)


@pytest.mark.parametrize("value", ["-2", "0", "two"])
def test_jobs_must_be_a_positive_integer(tmp_path, value):
    result = incli("bake", write_env(tmp_path / "ok.exr"), "-o", tmp_path / "s.h5", "--jobs", value)
    assert_fails_cleanly(result, 2, "--jobs")
    assert not (tmp_path / "s.h5").exists()


def test_api_jobs_are_checked():
    from bakery.errors import ConfigError
    from bakery.pipeline.executors import make_executor

    for jobs in (0, -2, 1.5, True):
        with pytest.raises(ConfigError, match="jobs"):
            make_executor(jobs)


@pytest.mark.parametrize("address", ["banana", "tcp://nohost", "tcp://host:99999", "http://x:1"])
def test_malformed_scheduler_address(tmp_path, address):
    result = incli("bake", write_env(tmp_path / "ok.exr"), "-o", tmp_path / "s.h5", "--scheduler", address)
    assert_fails_cleanly(result, 2, "--scheduler")


def test_unreachable_scheduler_fails_fast_and_cleanly(tmp_path):
    start = time.monotonic()
    result = cli("bake", write_env(tmp_path / "ok.exr"), "-o", tmp_path / "s.h5", "--scheduler", "tcp://127.0.0.1:9")
    assert_fails_cleanly(result, 2, "tcp://127.0.0.1:9", "cannot connect to the Dask scheduler")
    assert time.monotonic() - start < 20 and not (tmp_path / "s.h5").exists()
