"""MaterialX gltf_pbr's alpha_mode, as the stdlib graph IMPL_gltf_pbr_surfaceshader computes opacity:
ifequal(alpha_mode, 0) → 1; ifequal(alpha_mode, 1) → ifgreatereq(alpha, alpha_cutoff) ? 1 : 0; else alpha
(glTF 2.0 alphaMode OPAQUE / MASK / BLEND)."""

from __future__ import annotations

import pytest
from usd_scenes import box_mesh, header, mtlx_material, probe, write

from bakery.usd.scene import read_scene


def _material(tmp_path, inputs: str):
    text = header() + mtlx_material("Leaf", "ND_gltf_pbr_surfaceshader", inputs) + box_mesh("Box", 1.0, "/Leaf")
    reading = read_scene(write(tmp_path / "leaf.usda", text + 'def DomeLight "Sky"\n{\n}\n' + probe("P", (0, 3, 0))))
    assert not reading.errors, reading.errors
    return reading.scene.meshes[0].material, reading


@pytest.mark.parametrize(("mode", "opacity", "threshold"), [(None, 1.0, 0.0), (0, 1.0, 0.0), (1, 0.3, 0.6),
                                                             (2, 0.3, 0.0)])
def test_alpha_mode_decides_what_alpha_means(tmp_path, mode, opacity, threshold):
    inputs = "float inputs:alpha = 0.3\n        float inputs:alpha_cutoff = 0.6"
    if mode is not None:
        inputs += f"\n        int inputs:alpha_mode = {mode}"
    material, _ = _material(tmp_path, inputs)
    assert material.opacity == pytest.approx(opacity) and material.opacity_threshold == pytest.approx(threshold)


def test_mask_uses_the_nodedef_cutoff_and_unmodelled_lobes_are_reported(tmp_path):
    material, reading = _material(tmp_path, "float inputs:alpha = 0.3\n        int inputs:alpha_mode = 1\n        "
                                            "float inputs:iridescence = 1")
    assert material.opacity_threshold == pytest.approx(0.5)  # alpha_cutoff's default
    messages = " ".join(i.message for i in reading.issues)
    assert "gltf_pbr iridescence is not modelled" in messages
