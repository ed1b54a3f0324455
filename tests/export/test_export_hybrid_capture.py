"""Exports of a store whose reflection encoding is the hybrid (the console/pc-high default): by default the hybrid
keeps the capture (its α = 0 ``level0``) for every probe (``keep_capture``), and the exported base level is the
capture, the same as the split-sum chain's level 0 of the same bake. Baked with ``keep_capture = false`` it keeps it
only for probes that need the mirror level, so a probe with ``first_level`` > 0 is refused with a one-line error
(its cube maps would be black)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bakery
from bakery.errors import InputError
from bakery.export import export_store
from bakery.export.source import captures

ROOT = Path(__file__).resolve().parents[2]
INDOOR = ROOT / "examples" / "indoor" / "indoor.usda"


@pytest.fixture(scope="module")
def hybrid_stores(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("hybrid_export")
    common = dict(face_size=32, samples=1, bounces=1, jobs=1)  # at 32² the table probe skips levels (α ≥ 0.16)
    bakery.bake(INDOOR, d / "plain.h5", encodings=("sh3", "shexp_hybrid"),
                encoding_settings={"shexp_hybrid": {"keep_capture": False}}, **common)
    bakery.bake(INDOOR, d / "kept.h5", encodings=("sh3", "shexp_hybrid", "splitsum"), **common)  # the default
    return {"plain": d / "plain.h5", "kept": d / "kept.h5"}


def _rough_probes(store) -> list[str]:  # noqa: ANN001
    fields = store.fields("shexp_hybrid")
    return [store.probe_names[int(p)] for p, k in zip(fields["probe_index"], fields["first_level"][:, 0], strict=True)
            if k > 0]


def test_a_probe_without_its_capture_is_refused_and_nothing_is_written(hybrid_stores, tmp_path):
    store = bakery.open_store(hybrid_stores["plain"])
    rough = _rough_probes(store)
    assert rough, "the indoor example has a reflection probe that sees only rough materials"
    with pytest.raises(InputError, match="keep_capture"):
        export_store(hybrid_stores["plain"], tmp_path / "k", "ktx2")
    result = subprocess.run([sys.executable, "-m", "bakery.cli", "export", str(hybrid_stores["plain"]), "-o",
                             str(tmp_path / "cli"), "--format", "ktx2"], capture_output=True, text=True, timeout=300,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 2 and "Traceback" not in result.stderr and rough[0] in result.stderr
    assert not (tmp_path / "k").exists() and not (tmp_path / "cli").exists()


def test_a_default_bake_keeps_the_capture_and_the_export_uses_it(hybrid_stores, tmp_path):
    store = bakery.open_store(hybrid_stores["kept"])
    rough = _rough_probes(store)
    assert rough
    kept = captures(store, "shexp_hybrid", rough)
    reference = captures(store, "splitsum", rough)  # split-sum's level 0 is the capture at the bake's face size
    for probe in rough:
        assert np.abs(kept[probe]).max() > 0
        np.testing.assert_array_equal(kept[probe], reference[probe])
    # engines still upload only first_level … L − 1: keeping the capture changes the store, not the upload
    fields = store.fields("shexp_hybrid")
    plain = bakery.open_store(hybrid_stores["plain"]).fields("shexp_hybrid")
    np.testing.assert_array_equal(fields["first_level"], plain["first_level"])
    result = export_store(hybrid_stores["kept"], tmp_path / "k", "ktx2")
    assert len(result.files) >= len(rough)


@pytest.mark.parametrize("format_name", ["ktx2", "gltf", "filament", "three"])
def test_an_export_reads_the_levels_lazily_and_writes_the_same_bytes(hybrid_stores, tmp_path, monkeypatch, format_name):
    """``bakery export`` opens the store with lazy fields (a block of probes' levels read at a time): with every
    field lazy (the size threshold lowered to one byte, where a production store's levels are lazy at 4 MiB), each
    format writes the same files, byte for byte, as from the loaded store."""
    import bakery.store.format as store_format
    from bakery.export import EXPORT_FORMATS
    from bakery.store.format import LazyField

    if format_name not in EXPORT_FORMATS:
        pytest.skip(f"no {format_name} export")
    store = hybrid_stores["kept"]
    eager = export_store(store, tmp_path / "eager", format_name, layer=False)
    monkeypatch.setattr(store_format, "MIN_BYTES", 1)
    with bakery.open_store(store, lazy=True) as opened:
        assert isinstance(opened.fields("shexp_hybrid")["level0"], LazyField)
    lazy = export_store(store, tmp_path / "lazy", format_name, layer=False)
    assert sorted(map(str, lazy.files)) == sorted(map(str, eager.files)) and eager.files
    for path in eager.files:
        assert (tmp_path / "lazy" / path).read_bytes() == (tmp_path / "eager" / path).read_bytes(), path
