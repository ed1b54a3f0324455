"""The HDF5 probe store on its own: write → read round trips every kind of array exactly and deterministically,
``diff`` measures changes against a closed form, newer majors are refused."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bakery.errors import StoreFormatError
from bakery.store.diff import diff_stores
from bakery.store.format import (
    FORMAT_VERSION,
    StoreContents,
    StoreIntegrityError,
    overwrite_refusal,
    read_store,
    write_store,
    write_store_file,
)

DTYPES = ["float32", "float16", "uint8", "int32", "float64"]


def contents(rng: np.random.Generator, count: int, dtype: str) -> StoreContents:
    names = [f"/probes/p{i}" for i in range(count)]
    field = (rng.uniform(-4, 4, size=(count, 5, 3)) if dtype.startswith("float")
             else rng.integers(0, 100, size=(count, 5, 3))).astype(dtype)
    return StoreContents(
        attributes={"settings": '{"face_size": 8}', "nested": {"a": [1, 2]}, "flag": True},
        probe_names=names, probe_kinds=["irradiance"] * count,
        probe_positions=rng.normal(size=(count, 3)),
        encodings={"e": {"attributes": {"kind": "irradiance", "encoding_version": "1.0.0"},
                         "fields": {"probe_index": np.arange(count, dtype=np.int32), "values": field},
                         "shared": {"table": rng.uniform(size=(4, 4)).astype(np.float32)}}},
        diagnostics={"group/leaf": rng.uniform(size=count).astype(np.float32)},
        probe_hashes=[f"h{i}" for i in range(count)], probe_bake_ids=np.zeros(count, dtype=np.int32),
        history=[{"time_utc": "2026-01-01T00:00:00Z", "bakery_version": "0", "settings_hash": "s", "layers": ""}],
    )


@given(count=st.integers(1, 40), dtype=st.sampled_from(DTYPES), seed=st.integers(0, 2**16))
def test_round_trip_is_exact(tmp_path_factory, count, dtype, seed):
    path = tmp_path_factory.mktemp("rt") / "s.h5"
    written = contents(np.random.default_rng(seed), count, dtype)
    write_store(path, written)
    read = read_store(path)
    assert read.probe_names == written.probe_names and read.probe_hashes == written.probe_hashes
    np.testing.assert_array_equal(read.probe_positions, written.probe_positions)
    for key, array in written.encodings["e"]["fields"].items():
        assert read.encodings["e"]["fields"][key].dtype == array.dtype
        np.testing.assert_array_equal(read.encodings["e"]["fields"][key], array)
    np.testing.assert_array_equal(read.encodings["e"]["shared"]["table"], written.encodings["e"]["shared"]["table"])
    np.testing.assert_array_equal(read.diagnostics["group/leaf"], written.diagnostics["group/leaf"])
    assert read.attributes["format_version"] == FORMAT_VERSION and read.attributes["flag"]


def test_same_contents_give_the_same_bytes(tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write_store(a, contents(np.random.default_rng(1), 8, "float32"))
    write_store(b, contents(np.random.default_rng(1), 8, "float32"))
    assert a.read_bytes() == b.read_bytes()


def test_diff_reports_the_relative_change_of_one_probe(tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    first = contents(np.random.default_rng(2), 4, "float64")
    write_store(a, first)
    changed = contents(np.random.default_rng(2), 4, "float64")
    values = changed.encodings["e"]["fields"]["values"]
    values[2] *= 1.5  # ‖1.5v − v‖ / ‖v‖ = 0.5 exactly
    write_store(b, changed)
    report = diff_stores(a, b)
    assert report["unchanged"] == 3 and list(report["changed"]) == ["/probes/p2"]
    assert report["changed"]["/probes/p2"]["e"] == pytest.approx(0.5, rel=1e-12)


def test_diff_names_encodings_in_one_store_only_and_probes_missing_from_an_encoding(tmp_path):
    """Before: a 13-encoding store and an sh2-only store diffed "unchanged", and a probe present in an encoding of one
    store only was skipped."""
    import copy

    a, b, c = tmp_path / "a.h5", tmp_path / "b.h5", tmp_path / "c.h5"
    first = contents(np.random.default_rng(3), 4, "float64")
    write_store(a, first)
    extra = copy.deepcopy(first)
    extra.encodings["f"] = copy.deepcopy(first.encodings["e"])
    write_store(b, extra)
    report = diff_stores(a, b)
    assert report["encodings_added"] == ["f"] and report["encodings_removed"] == []
    assert report["changed"] == {} and report["unchanged"] == 4  # "e" is equal; "f" is named, not compared
    assert diff_stores(b, a)["encodings_removed"] == ["f"]
    fewer = copy.deepcopy(first)  # probe p1 no longer has encoding "e"
    keep = np.array([0, 2, 3])
    fewer.encodings["e"]["fields"] = {k: v[keep] for k, v in fewer.encodings["e"]["fields"].items()}
    write_store(c, fewer)
    report = diff_stores(a, c)
    assert report["changed"] == {"/probes/p1": {"e": 1.0}} and report["unchanged"] == 3


def test_newer_major_is_refused_with_a_message(tmp_path):
    path = tmp_path / "s.h5"
    write_store(path, contents(np.random.default_rng(3), 2, "float32"))
    with h5py.File(path, "r+") as f:
        f.attrs["format_version"] = "9.0.0"
    with pytest.raises(StoreFormatError, match="s.h5"):
        read_store(path)


# ------------------------------------------------------------------------------------------------ integrity (1.2.0)
def test_every_fixed_size_dataset_has_fletcher32_and_checksums_verify(tmp_path):
    path = tmp_path / "s.h5"
    write_store(path, contents(np.random.default_rng(4), 6, "float32"))
    with h5py.File(path, "r") as f:
        datasets = []
        f.visititems(lambda name, item: datasets.append(item) if isinstance(item, h5py.Dataset) else None)
        for item in datasets:
            if h5py.check_string_dtype(item.dtype) is None and item.shape != ():
                assert item.fletcher32, item.name
        assert f["checksums/probe"].shape == (6, 32)
    read = read_store(path)
    assert read.integrity.verified and read.integrity.ok


@given(count=st.integers(1, 12), seed=st.integers(0, 2**16))
def test_per_probe_checksums_are_the_specs_sha256(tmp_path_factory, count, seed):
    """``/checksums/probe`` against schemas/store-v1.md "Integrity", built here byte by byte from the spec: two
    encodings, one covering a permuted subset of the probes, fields of several dtypes and row shapes."""
    from bakery.files import sha256_digest

    rng = np.random.default_rng(seed)
    written = contents(rng, count, "float32")
    rows = rng.permutation(count)[: max(1, count // 2)].astype(np.int32)
    written.encodings["d"] = {"attributes": {"kind": "reflection", "encoding_version": "1.0.0"},
                              "fields": {"probe_index": rows, "scalar": rng.normal(size=len(rows)),
                                         "codes": rng.integers(0, 256, size=(len(rows), 2, 2)).astype(np.uint8)}}
    path = tmp_path_factory.mktemp("cs") / "s.h5"
    write_store(path, written)
    with h5py.File(path, "r") as f:
        stored = f["checksums/probe"][()]
    for i in range(count):
        parts = [b"probe\0", written.probe_names[i].encode(), b"\0", written.probe_kinds[i].encode(), b"\0",
                 np.asarray(written.probe_positions[i], dtype="<f8").tobytes(), written.probe_hashes[i].encode(),
                 b"\0", np.asarray(written.probe_bake_ids[i], dtype="<i4").tobytes()]
        for name in sorted(written.encodings):
            fields = written.encodings[name]["fields"]
            for r in np.flatnonzero(np.asarray(fields["probe_index"]) == i):
                parts += [b"encoding\0", name.encode(), b"\0"]
                for key in sorted(k for k in fields if k != "probe_index"):
                    row = np.asarray(fields[key])[r]
                    parts += [key.encode(), b"\0", row.dtype.str.encode(), repr(row.shape).encode(), row.tobytes()]
        assert sha256_digest(*parts) == stored[i].tobytes(), i


@pytest.mark.parametrize("row", [0, 3])
def test_a_changed_value_names_the_dataset_and_the_probe(tmp_path, row):
    path = tmp_path / "s.h5"
    write_store(path, contents(np.random.default_rng(5), 6, "float32"))
    with h5py.File(path, "r+") as f:
        f["encodings/e/values"][row, 0, 0] += 1.0
    with pytest.raises(StoreIntegrityError, match="/encodings/e/values") as error:
        read_store(path)
    assert f"/probes/p{row}" in str(error.value)
    lenient = read_store(path, strict=False)
    assert lenient.integrity.bad_probes == {f"/probes/p{row}"} and not lenient.integrity.whole_store


def test_damaged_shared_tables_and_attributes_distrust_the_whole_store(tmp_path):
    path = tmp_path / "s.h5"
    write_store(path, contents(np.random.default_rng(6), 3, "float32"))
    with h5py.File(path, "r+") as f:
        f["encodings/e/shared/table"][0, 0] = 7.0
        f.attrs["settings"] = '{"face_size": 9}'
    lenient = read_store(path, strict=False)
    assert lenient.integrity.whole_store
    assert any("/encodings/e/shared/table" in p for p in lenient.integrity.problems)
    assert any("attributes of /" in p for p in lenient.integrity.problems)


def test_write_store_file_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "missing-folder" / "s.h5"
    with pytest.raises(OSError):
        write_store_file(target, contents(np.random.default_rng(7), 2, "float32"))
    assert not target.exists()


def test_overwrite_refusal_recognises_only_readable_bakery_stores(tmp_path):
    store = tmp_path / "s.h5"
    write_store(store, contents(np.random.default_rng(8), 2, "float32"))
    assert overwrite_refusal(store) is None
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.arange(3)
    assert "not a bakery probe store" in overwrite_refusal(other)
    (tmp_path / "text.h5").write_text("hello")
    assert "not an HDF5 file" in overwrite_refusal(tmp_path / "text.h5")
    with h5py.File(store, "r+") as f:
        f.attrs["format_version"] = "1.9.0"
    assert "newer" in overwrite_refusal(store)
