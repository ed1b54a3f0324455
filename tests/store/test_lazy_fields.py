"""Stores read with lazy fields (``read_store(lazy_fields=True)``, ``open_store(lazy=True)``): a large field reads
the rows it is indexed with from the verified file. Its values are the eager reader's, byte for byte, for every
kind of index; it is verified as the eager reader verifies (the per-probe and per-dataset checksums, in one pass);
and it keeps reading the file it verified."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bakery.errors import StoreFormatError
from bakery.store.format import LazyField, StoreContents, StoreIntegrityError, read_store, write_store
from bakery.zero_pages import MIN_BYTES

ROW = (6, 64, 64, 3)  # a 64² float16 cube level: 147,456 bytes a row
COUNT = 40  # 5.9 MB: a lazy field (≥ MIN_BYTES)


def _contents(seed: int = 0, count: int = COUNT) -> StoreContents:
    rng = np.random.default_rng(seed)
    levels = rng.normal(size=(count, *ROW)).astype(np.float16)
    levels[::3] = 0  # zero rows, as a chain's unused levels
    levels[1].reshape(-1)[5] = -0.0
    levels[2].reshape(-1)[9] = np.nan
    first = (np.arange(count) % 3).astype(np.int32)
    return StoreContents(
        attributes={}, probe_names=[f"/p{i}" for i in range(count)], probe_kinds=["reflection"] * count,
        probe_positions=rng.normal(size=(count, 3)),
        encodings={"e": {"attributes": {"kind": "reflection", "encoding_version": "1.0.0"},
                         "fields": {"probe_index": np.arange(count, dtype=np.int32)[::-1].copy(), "level": levels,
                                    "first_level": first}}},
        diagnostics={}, probe_hashes=[f"h{i}" for i in range(count)], probe_bake_ids=np.zeros(count, np.int32),
        history=[{"time_utc": "2026-01-01T00:00:00Z", "bakery_version": "0", "settings_hash": "s", "layers": ""}])


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("lazy") / "s.h5"
    write_store(path, _contents())
    return path


def test_lazy_fields_are_the_eager_values(store):
    eager = read_store(store).encodings["e"]["fields"]
    lazy = read_store(store, lazy_fields=True)
    try:
        fields = lazy.encodings["e"]["fields"]
        assert isinstance(fields["level"], LazyField) and eager["level"].nbytes >= MIN_BYTES
        assert isinstance(fields["first_level"], np.ndarray)  # small fields are read
        assert fields["level"].shape == eager["level"].shape and fields["level"].dtype == eager["level"].dtype
        np.testing.assert_array_equal(np.asarray(fields["level"]).view(np.uint16), eager["level"].view(np.uint16))
        assert lazy.integrity.verified and not lazy.integrity.problems
    finally:
        lazy.close()


_index = st.one_of(
    st.integers(-COUNT, COUNT - 1),
    st.builds(slice, st.one_of(st.none(), st.integers(-COUNT, COUNT)), st.one_of(st.none(), st.integers(-COUNT, COUNT)),
              st.one_of(st.none(), st.integers(1, 4))),
    st.lists(st.integers(-COUNT, COUNT - 1), max_size=12).map(lambda v: np.asarray(v, dtype=np.int64)),
    st.lists(st.booleans(), min_size=COUNT, max_size=COUNT).map(np.asarray),
)


@settings(max_examples=25, deadline=None)
@given(key=_index, inner=st.one_of(st.none(), st.integers(0, 5)))
def test_lazy_indexing_is_numpy_indexing(store, key, inner):
    """Rows by a row, a slice, an array of rows (unsorted, repeated, negative) or a mask, with or without an index
    into the row: the same values (bytes) as the same index of the eager array."""
    eager = read_store(store).encodings["e"]["fields"]["level"]
    opened = read_store(store, lazy_fields=True)
    try:
        lazy = opened.encodings["e"]["fields"]["level"]
        full = key if inner is None else (key, inner)
        expected = eager[full]
        got = lazy[full]
        assert got.shape == expected.shape and got.dtype == expected.dtype
        np.testing.assert_array_equal(np.asarray(got).view(np.uint16), np.asarray(expected).view(np.uint16))
    finally:
        opened.close()


def test_a_changed_row_fails_the_lazy_open_as_the_eager_one(tmp_path):
    """A value changed in a large field's row fails that probe's checksum and the field's dataset checksum, lazy or
    eager (the lazy open hashes the field as the per-probe pass reads it); the file is closed again."""
    path = tmp_path / "s.h5"
    write_store(path, _contents())
    with h5py.File(path, "r+") as f:
        f["encodings/e/level"][4, 1, 2, 3, 0] = 7.0  # row 4 holds probe_index[4] = /p35
    for lazy in (False, True):
        with pytest.raises(StoreIntegrityError, match="/p35") as raised:
            read_store(path, lazy_fields=lazy)
        assert "/encodings/e/level does not match its checksum" in str(raised.value)
    with h5py.File(path, "r+"):  # nothing holds it open
        pass


def test_a_lazy_store_reads_the_file_it_verified(tmp_path):
    """A bake that replaces the store while a lazy reader has it open (a rename over the path) does not change what
    the reader reads: its handle is the verified file's."""
    path = tmp_path / "s.h5"
    write_store(path, _contents(seed=1))
    expected = np.asarray(read_store(path).encodings["e"]["fields"]["level"][5])
    opened = read_store(path, lazy_fields=True)
    level = opened.encodings["e"]["fields"]["level"]
    other = tmp_path / "other.h5"
    write_store(other, _contents(seed=2))
    other.replace(path)  # as a bake commits a store (a rename)
    np.testing.assert_array_equal(level[5].view(np.uint16), expected.view(np.uint16))
    opened.close()
    with pytest.raises(StoreFormatError, match="closed"):  # its fields cannot be read any more
        level[5]


def test_a_damaged_chunk_of_a_lazy_field_names_the_dataset(tmp_path):
    """A byte flipped inside a stored chunk of a large field fails HDF5's fletcher32 check when the chunk is read:
    the eager and the lazy open both raise a :class:`StoreIntegrityError` naming the dataset."""
    path = tmp_path / "s.h5"
    write_store(path, _contents())
    with h5py.File(path, "r") as f:
        chunk = f["encodings/e/level"].id.get_chunk_info(3)
    with open(path, "r+b") as raw:
        raw.seek(chunk.byte_offset + chunk.size // 2)
        byte = raw.read(1)
        raw.seek(-1, 1)
        raw.write(bytes([byte[0] ^ 0xFF]))
    for lazy in (False, True):
        with pytest.raises(StoreIntegrityError, match="/encodings/e/level cannot be read"):
            read_store(path, lazy_fields=lazy)
    with h5py.File(path, "r+"):  # nothing holds it open
        pass
