"""The on-disk operator cache stays under its size limit: least recently used files go first, never the one just
written and never a file the cache did not write; a file pruned by another process is a miss, not damage."""

import os
import warnings

import numpy as np
import pytest

from bakery import operator_cache


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("BAKERY_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("BAKERY_CACHE_MAX_MB", "1")  # 1 MB: three 400 kB operators do not fit
    return tmp_path


def operator(seed):
    return np.random.default_rng(seed).random(100_000, dtype=np.float32)  # 400 kB


def age(directory, seconds):
    """Make every cache file ``seconds`` older (mtime is the cache's record of use)."""
    for path in directory.glob("*.npy"):
        stat = path.stat()
        os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns - int(seconds * 1e9)))


def test_the_least_recently_used_operator_is_pruned_first(cache):
    operator_cache.save("a", operator(1))
    age(cache, 30)
    operator_cache.save("b", operator(2))
    age(cache, 30)
    assert operator_cache.load("a") is not None  # a is used again: b is now the least recently used
    foreign = cache / "notes.npy"
    np.save(foreign, np.zeros(200_000, np.float32))  # 800 kB that the cache did not write
    operator_cache.save("c", operator(3))
    assert operator_cache.load("b") is None
    np.testing.assert_array_equal(operator_cache.load("a"), operator(1))
    np.testing.assert_array_equal(operator_cache.load("c"), operator(3))
    assert foreign.exists()
    cached = sum(p.stat().st_size for p in cache.glob("*.npy") if p != foreign)
    assert cached <= 2**20


def test_the_file_just_written_is_kept_even_above_the_limit(cache):
    big = np.zeros(400_000, np.float32)  # 1.6 MB > the 1 MB limit
    operator_cache.save("small", operator(1))
    age(cache, 30)
    operator_cache.save("big", big)
    assert operator_cache.load("small") is None
    np.testing.assert_array_equal(operator_cache.load("big"), big)


def test_files_of_earlier_versions_are_pruned_and_no_limit_keeps_everything(cache, monkeypatch):
    legacy = cache / ("0123456789abcdef" * 2 + ".npy")  # the name format before content hashes
    np.save(legacy, np.zeros(200_000, np.float32))
    age(cache, 60)
    monkeypatch.setenv("BAKERY_CACHE_MAX_MB", "0")
    operator_cache.save("a", operator(1))
    operator_cache.save("b", operator(2))
    assert legacy.exists() and len(list(cache.glob("*.npy"))) == 3
    monkeypatch.setenv("BAKERY_CACHE_MAX_MB", "1")
    operator_cache.save("c", operator(3))
    assert not legacy.exists()


def test_a_file_pruned_by_another_process_is_a_quiet_miss(cache):
    operator_cache.save("a", operator(1))
    (path,) = operator_cache._candidates("a")
    path.unlink()  # between another process's listing and its load
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert operator_cache._verified(path) is None
