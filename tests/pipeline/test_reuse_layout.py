"""Verify before reuse: a probe whose content hash matches is re-baked when the previous store's fields of one of its
encodings are not the fields this bake writes (a layout change the hash did not see would otherwise merge rows of
two layouts)."""

import numpy as np

import bakery
from bakery.pipeline.plan import changed_layouts
from bakery.pipeline.settings import BakeSettings
from bakery.store.format import read_store


def test_a_layout_the_bake_does_not_write_is_not_reused(tmp_path):
    store = tmp_path / "s.h5"
    image = np.full((16, 32, 3), 0.5, np.float32)
    image[4, 8] = 200.0  # a sun
    path = tmp_path / "sky.exr"
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(32, 16, 3, oiio.FLOAT))
    out.write_image(image)
    out.close()
    gap = {"shexp_hybrid": {"gap_level": True}}
    bakery.bake(path, store, encodings=("shexp_hybrid",), face_size=8, encoding_settings=gap)
    previous = read_store(store, load_fields=False)
    settings = BakeSettings(encodings=("shexp_hybrid",), face_size=8, encoding_settings=gap)
    assert changed_layouts(previous, {"shexp_hybrid"}, settings) == set()
    del previous.encodings["shexp_hybrid"]["fields"]["gap_skipped"]  # as a store baked before the field existed
    assert changed_layouts(previous, {"shexp_hybrid"}, settings) == {"shexp_hybrid"}
    assert changed_layouts(previous, {"sh3"}, settings) == set()  # not in the store: nothing to reuse

    first = bakery.open_store(store).fields("shexp_hybrid")["gap_skipped"]
    summary = bakery.bake(path, store, encodings=("shexp_hybrid",), face_size=8, encoding_settings=gap)
    assert summary.reused == summary.planned and summary.baked == 0  # the same layout: reused
    np.testing.assert_array_equal(bakery.open_store(store).fields("shexp_hybrid")["gap_skipped"], first)
