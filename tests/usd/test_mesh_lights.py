"""UsdLuxMeshLightAPI: a mesh (or gprim) with the API is geometry that emits — before, the prim was read as a
light kind the capture did not know and its geometry vanished from the bake. The probe looking up at the panel
sees exactly the radiance its materialSyncMode gives (camera rays hit the emissive triangles)."""

from __future__ import annotations

import numpy as np
import pytest
from usd_scenes import header, material, probe, write

from bakery.capture import capture_probes
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 8


def _panel(mode: str | None = None, extra: str = "", binding: str = "") -> str:
    sync = f'    uniform token light:materialSyncMode = "{mode}"\n' if mode else ""
    bind = f"    rel material:binding = <{binding}>\n" if binding else ""
    schemas = '"MeshLightAPI", "MaterialBindingAPI"' if binding else '"MeshLightAPI"'
    return f"""
def Mesh "Panel" (
    prepend apiSchemas = [{schemas}]
)
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(-20, 2, -20), (-20, 2, 20), (20, 2, 20), (20, 2, -20)]
    float inputs:intensity = 4
    color3f inputs:color = (1, 0.5, 0.25)
{sync}{extra}{bind}}}
"""


def _seen_above(text: str, tmp_path, name: str) -> tuple[np.ndarray, object]:
    reading = read_scene(write(tmp_path / f"{name}.usda", header() + text + probe("P", (0.0, 0.5, 0.0))))
    cubes, _ = capture_probes(reading.scene, N, samples=1, bounces=0)
    up = cube_texel_directions(N)[..., 1] > 0.5
    return cubes[0][up], reading


@pytest.mark.parametrize("mode, glow, expected", [
    (None, None, (4.0, 2.0, 1.0)),                                  # fallback materialGlowTintsLight, no glow: L
    ("materialGlowTintsLight", (0.5, 1.0, 2.0), (2.0, 2.0, 2.0)),   # L ⊙ the material's emissive colour
    ("independent", (0.5, 1.0, 2.0), (4.0, 2.0, 1.0)),              # L
    ("noMaterialResponse", (0.5, 1.0, 2.0), (4.0, 2.0, 1.0)),       # L, no reflection
])
def test_mesh_light_emits_by_its_material_sync_mode(tmp_path, mode, glow, expected):
    mat = "" if glow is None else material("Glow", diffuse=(0.8, 0.8, 0.8), emissive=glow)
    seen, reading = _seen_above(mat + _panel(mode, binding="" if glow is None else "/Glow"), tmp_path, "panel")
    assert len(reading.scene.meshes) == 1 and reading.scene.lights == ()
    assert not [i for i in reading.issues if "not supported" in i.message or "emits light" in i.message]
    np.testing.assert_allclose(seen, np.broadcast_to(expected, seen.shape), rtol=1e-6)
    if mode == "noMaterialResponse":
        m = reading.scene.meshes[0].material
        assert max(m.albedo) == 0 and max(m.f0) == 0


def test_mesh_light_normalize_divides_by_its_area_in_stage_units(tmp_path):
    """normalize: L / area (40 m × 40 m = 1600 m², metersPerUnit 1)."""
    seen, _ = _seen_above(_panel(extra="    bool inputs:normalize = 1\n"), tmp_path, "normalized")
    np.testing.assert_allclose(seen, np.broadcast_to(np.array([4.0, 2.0, 1.0]) / 1600.0, seen.shape), rtol=1e-6)


def test_point_instanced_mesh_lights_emit(tmp_path):
    """A MeshLightAPI prototype of a PointInstancer: every instance's surface emits the light's L."""
    text = """
def PointInstancer "Lamps"
{
    int[] protoIndices = [0, 0]
    point3f[] positions = [(0, 0, 0), (0, 0, 30)]
    rel prototypes = [</Lamps/Prototypes/Panel>]
    def Scope "Prototypes"
    {
""" + _panel().replace("\n", "\n        ") + """
    }
}
"""
    seen, reading = _seen_above(text, tmp_path, "instanced")
    assert len(reading.scene.meshes) == 2
    assert all(m.material.emission == pytest.approx((4.0, 2.0, 1.0)) for m in reading.scene.meshes)
    np.testing.assert_allclose(seen, np.broadcast_to((4.0, 2.0, 1.0), seen.shape), rtol=1e-6)
