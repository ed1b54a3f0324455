"""MaterialX subsurface read as its diffuse limit: the dielectric base of both surfaces is
mix(fg = subsurface, bg = diffuse, mix = weight) (stdlib graphs NG_standard_surface_surfaceshader_100
``subsurface_mix`` and NG_open_pbr_surface_surfaceshader ``opaque_base``), so the albedo where light enters is
(1 − s)·base·base_color + s·subsurface_color; a textured colour keeps its texture through the mix."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
from usd_scenes import box_mesh, header, mtlx_material, plane_mesh, probe, write

from bakery.usd.scene import read_scene

DOME = 'def DomeLight "Sky"\n{\n}\n'
ST = 'texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (\n        interpolation = "faceVarying"\n    )'


def _read(tmp_path, category_id: str, inputs: str, extra: str = ""):
    text = header() + mtlx_material("Skin", category_id, inputs) + extra + box_mesh("Box", 1.0, "/Skin")
    text += plane_mesh("Floor", 2.0, "/Skin", height=-1.0, extra=ST)
    reading = read_scene(write(tmp_path / "skin.usda", text + DOME + probe("P", (0, 3, 0))))
    assert not reading.errors, reading.errors
    return reading


@pytest.mark.parametrize("weight", [0.0, 0.4, 1.0])
def test_standard_surface_subsurface_mixes_the_albedo(tmp_path, weight):
    reading = _read(tmp_path, "ND_standard_surface_surfaceshader",
                    f"float inputs:base = 0.8\n        color3f inputs:base_color = (0.5, 0.4, 0.3)\n        "
                    f"float inputs:subsurface = {weight}\n        color3f inputs:subsurface_color = (0.9, 0.3, 0.2)")
    material = reading.scene.meshes[0].material
    expected = (1 - weight) * 0.8 * np.array([0.5, 0.4, 0.3]) + weight * np.array([0.9, 0.3, 0.2])
    np.testing.assert_allclose(material.diffuse, expected, rtol=1e-6)
    messages = " ".join(i.message for i in reading.issues)
    assert ("diffuse limit" in messages) == (weight > 0) and "subsurface is not modelled" not in messages


def test_open_pbr_subsurface_takes_its_default_colour(tmp_path):
    """open_pbr_surface's subsurface_color defaults to 0.8 (its node definition); base_weight 1, base_color 0.8."""
    reading = _read(tmp_path, "ND_open_pbr_surface_surfaceshader", "float inputs:subsurface_weight = 0.5")
    np.testing.assert_allclose(reading.scene.meshes[0].material.diffuse, 0.5 * 0.8 + 0.5 * 0.8, rtol=1e-6)
    reading = _read(tmp_path, "ND_open_pbr_surface_surfaceshader",
                    "float inputs:subsurface_weight = 0.25\n        color3f inputs:base_color = (1, 0, 0)")
    np.testing.assert_allclose(reading.scene.meshes[0].material.diffuse, (0.75 + 0.2, 0.2, 0.2), rtol=1e-6)


def _texture(tmp_path) -> str:
    path = tmp_path / "skin.exr"
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(2, 1, 3, oiio.FLOAT))
    out.write_image(np.array([[[0.2, 0.4, 0.6], [0.6, 0.4, 0.2]]], dtype=np.float32))
    out.close()
    return """
def Shader "Tex"
{
    uniform token info:id = "ND_image_color3"
    asset inputs:file = @./skin.exr@
    token outputs:out
}
"""


@pytest.mark.parametrize("textured", ["base_color", "subsurface_color"])
def test_a_textured_colour_keeps_its_texture_through_the_mix(tmp_path, textured):
    """The textured input's map becomes v → factor·v + offset: (1 − s)·base·tex + s·C, or s·tex + (1 − s)·base·B."""
    other = "subsurface_color" if textured == "base_color" else "base_color"
    inputs = (f"float inputs:base = 0.5\n        float inputs:subsurface = 0.3\n        "
              f"color3f inputs:{other} = (0.1, 0.2, 0.3)\n        "
              f"color3f inputs:{textured}.connect = </Tex.outputs:out>")
    reading = _read(tmp_path, "ND_standard_surface_surfaceshader", inputs, extra=_texture(tmp_path))
    material = reading.scene.meshes[1].material  # the floor, which has texture coordinates
    (entry,) = [m for m in material.maps if m["input"] == "diffuseColor"]
    constant = np.array([0.1, 0.2, 0.3])
    if textured == "base_color":
        factor, offset = 0.7 * 0.5, 0.3 * constant
    else:
        factor, offset = 0.3, 0.7 * 0.5 * constant
    np.testing.assert_allclose(entry["scale"][:3], factor, rtol=1e-6)
    np.testing.assert_allclose(entry["bias"][:3], offset, rtol=1e-6)
    mean = np.array([0.4, 0.4, 0.4])  # the texture's mean colour
    np.testing.assert_allclose(material.diffuse, factor * mean + offset, rtol=1e-5)
