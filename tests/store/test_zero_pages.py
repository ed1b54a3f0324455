"""Arrays whose all-zero rows are not resident (``bakery/zero_pages.py``): the values, bytes included, are those of
the dense array, for the merge of a bake and the reading of a store."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bakery.pipeline.merge import _scatter
from bakery.zero_pages import MIN_BYTES, lazy_zeros, nonzero_rows, without_resident_zeros

ROW = (6, 128, 128, 3)  # a 128² float16 cube level: 589,824 bytes per row (MIN_BYTES from 8 rows)


def _rows(pattern: list[int]) -> np.ndarray:
    """float16 rows: 0 all zero, 1 random, 2 one −0.0 (zero value, not zero bytes), 3 one NaN."""
    rng = np.random.default_rng(len(pattern))
    out = np.zeros((len(pattern), *ROW), dtype=np.float16)
    for i, kind in enumerate(pattern):
        if kind == 1:
            out[i] = rng.random(ROW)
        elif kind == 2:
            out[i].reshape(-1)[7] = -0.0
        elif kind == 3:
            out[i].reshape(-1)[-1] = np.nan
    return out


def test_lazy_zeros_is_zero_writable_and_backed_by_a_private_map():
    array = lazy_zeros((3, 5), np.float32)
    assert array.dtype == np.float32 and array.shape == (3, 5) and not np.any(array)
    array[1, 2] = 4.0
    assert array.sum() == 4.0 and array.flags.writeable and array.flags.c_contiguous
    assert lazy_zeros((0, 4), np.float16).shape == (0, 4)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 3), min_size=1, max_size=20))
def test_without_resident_zeros_keeps_every_byte(pattern):
    dense = _rows(pattern)
    lazy = without_resident_zeros(dense)
    assert lazy.dtype == dense.dtype and lazy.shape == dense.shape
    np.testing.assert_array_equal(lazy.view(np.uint16), dense.view(np.uint16))  # −0.0 and NaN bits included
    np.testing.assert_array_equal(nonzero_rows(dense), np.array(pattern) != 0)
    if dense.nbytes < MIN_BYTES or all(pattern):
        assert lazy is dense


@settings(max_examples=25, deadline=None)
@given(st.lists(st.lists(st.integers(0, 3), min_size=1, max_size=8), min_size=1, max_size=4), st.randoms())
def test_the_merge_scatter_equals_the_dense_scatter(patterns, random):
    parts = [_rows(p) for p in patterns]
    total = sum(len(p) for p in parts)
    destination = np.arange(total)
    random.shuffle(destination)
    expected = np.empty((total, *ROW), dtype=np.float16)
    expected[destination] = np.concatenate(parts)
    np.testing.assert_array_equal(_scatter(parts, destination).view(np.uint16), expected.view(np.uint16))


def test_a_store_read_back_holds_the_same_bytes_and_a_changed_zero_row_is_found(tmp_path):
    """``read_store`` reads a large field by blocks into a lazy array (its zero rows unwritten): the values are the
    written ones, byte for byte, and a value written into one of its zero rows afterwards fails that probe's checksum
    (the lazy read hashes what it read)."""
    import h5py
    import pytest

    from bakery.store.format import StoreContents, StoreIntegrityError, read_store, write_store

    pattern = [0, 1, 0, 0, 2, 3, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0]
    levels = _rows(pattern)
    count = len(pattern)
    written = StoreContents(
        attributes={}, probe_names=[f"/p{i}" for i in range(count)], probe_kinds=["reflection"] * count,
        probe_positions=np.zeros((count, 3)),
        encodings={"e": {"attributes": {"kind": "reflection", "encoding_version": "1.0.0"},
                         "fields": {"probe_index": np.arange(count, dtype=np.int32), "level": levels}}},
        diagnostics={}, probe_hashes=[f"h{i}" for i in range(count)], probe_bake_ids=np.zeros(count, np.int32),
        history=[{"time_utc": "2026-01-01T00:00:00Z", "bakery_version": "0", "settings_hash": "s", "layers": ""}])
    path = tmp_path / "s.h5"
    write_store(path, written)
    read = read_store(path).encodings["e"]["fields"]["level"]
    assert levels.nbytes >= MIN_BYTES and read.dtype == levels.dtype
    np.testing.assert_array_equal(read.view(np.uint16), levels.view(np.uint16))
    with h5py.File(path, "r+") as f:
        f["encodings/e/level"][2, 0, 0, 0] = 1.0
    with pytest.raises(StoreIntegrityError, match="/p2"):
        read_store(path)


@settings(max_examples=25, deadline=None)
@given(pattern=st.lists(st.integers(0, 3), min_size=8, max_size=12))
def test_spilled_rows_keep_every_byte_and_the_map_is_copy_on_write(tmp_path_factory, pattern):
    """A spilled array (a bake's parent: :func:`spilled`) holds the same bytes, −0.0 and NaN payloads included, as a
    map of a sparse file; writing into the map changes the process's copy, not the file."""
    from bakery.zero_pages import discard, spilled

    dense = _rows(pattern)
    path = tmp_path_factory.mktemp("spill") / "f"
    out = spilled(dense, path)
    assert isinstance(out, np.memmap) and dense.nbytes >= MIN_BYTES
    np.testing.assert_array_equal(out.view(np.uint16), dense.view(np.uint16))
    on_disk = path.read_bytes()
    out[0] = 1
    assert path.read_bytes() == on_disk
    discard(out, path.parent / "elsewhere")
    assert path.exists()  # only files of the folder given are removed
    discard(out, path.parent)
    assert not path.exists()
    np.testing.assert_array_equal(out[1:].view(np.uint16), dense[1:].view(np.uint16))  # mapped until dropped


def test_a_spill_beyond_the_file_size_limit_is_an_os_error(tmp_path):
    """Rows go to the file by write calls, so a disk that cannot take them is an OSError naming why (here the file
    size limit, EFBIG), never a SIGBUS at a page fault of a shared map."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(f"""
        import resource, signal, sys
        import numpy as np
        from bakery.zero_pages import spilled
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 20, 1 << 20))
        try:
            spilled(np.ones((8, 6, 128, 128, 3), np.float16), __import__("pathlib").Path({str(tmp_path / "f")!r}))
        except OSError as error:
            print("OSError", error.errno)
            sys.exit(0)
        sys.exit(1)
    """)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.startswith("OSError"), (result.returncode, result.stderr)
