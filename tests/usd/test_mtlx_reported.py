"""Surface inputs the capture does not model are reported per prim when authored away from their neutral value
(so a bake never silently drops them), and not reported at their node definitions' defaults."""

from __future__ import annotations

import pytest
from usd_scenes import box_mesh, header, mtlx_material, probe, write

from bakery.usd.scene import read_scene

CASES = [("ND_standard_surface_surfaceshader", name, value) for name, value in (
    ("specular_anisotropy", "float inputs:specular_anisotropy = 0.5"),
    ("coat_affect_color", "float inputs:coat_affect_color = 1"),
    ("thin_film_thickness", "float inputs:thin_film_thickness = 300"),
    ("transmission_scatter", "color3f inputs:transmission_scatter = (0.2, 0.2, 0.2)"),
)] + [("ND_gltf_pbr_surfaceshader", "iridescence", "float inputs:iridescence = 1")] + [
    ("ND_open_pbr_surface_surfaceshader", name, value) for name, value in (
    ("thin_film_weight", "float inputs:thin_film_weight = 1"),
    ("specular_roughness_anisotropy", "float inputs:specular_roughness_anisotropy = 0.5"),
)]


def _issues(tmp_path, shader_id: str, inputs: str) -> list[str]:
    text = header() + mtlx_material("M", shader_id, inputs) + box_mesh("Box", 1.0, "/M")
    reading = read_scene(write(tmp_path / "scene.usda", text + 'def DomeLight "Sky"\n{\n}\n' + probe("P", (0, 3, 0))))
    return [i.message for i in reading.issues]


@pytest.mark.parametrize(("shader_id", "name", "inputs"), CASES)
def test_an_unmodelled_input_is_reported(tmp_path, shader_id, name, inputs):
    assert any(f"{name} is not modelled" in m for m in _issues(tmp_path, shader_id, inputs))


@pytest.mark.parametrize("shader_id", ["ND_standard_surface_surfaceshader", "ND_open_pbr_surface_surfaceshader"])
def test_defaults_are_not_reported(tmp_path, shader_id):
    assert not [m for m in _issues(tmp_path, shader_id, "") if "not modelled" in m]


@pytest.mark.parametrize(("shader_id", "inputs", "names"), [
    ("ND_standard_surface_surfaceshader", "float inputs:specular_roughness = nan\n        "
     "float inputs:sheen = 1\n        float inputs:sheen_roughness = nan", "roughness, sheen_roughness"),
    ("ND_open_pbr_surface_surfaceshader", "color3f inputs:base_color = (1, nan, 0)", "diffuse"),
])
def test_non_finite_material_inputs_are_errors_naming_the_material(tmp_path, shader_id, inputs, names):
    """NaN or ±inf in a material would poison every ray meeting its surface: an error on the material prim (the
    bake refuses the scene), naming the inputs."""
    text = header() + mtlx_material("M", shader_id, inputs) + box_mesh("Box", 1.0, "/M")
    reading = read_scene(write(tmp_path / "scene.usda", text + 'def DomeLight "Sky"\n{\n}\n' + probe("P", (0, 3, 0))))
    errors = [i for i in reading.errors if i.prim == "/M"]
    assert errors and f"not finite: {names}" in errors[0].message, reading.issues
