"""MaterialX specular weight/colour and coat colour as tints: standard_surface's graph weights the dielectric
specular lobe by ``specular`` × ``specular_color`` (F0 and F90 alike; open_pbr_surface's ``specular_weight`` scales
F0 alone, through ``modulated_eta_s``: tests/capture/test_mtlx_surface_spec.py) and both pass mix(1, coat_color,
coat) through the coat to the base. References: the reader's closed forms, the BSDF's Schlick terms written out, and linearity of the capture in
the tint (a tinted lobe is the untinted one times the tint, path for path)."""

from __future__ import annotations

import numpy as np
import pytest
from harness import single_scattering
from usd_scenes import header, mtlx_material, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.capture.bsdf import Bsdf
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

N = 16
DOME = 'def DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'


def _reading(tmp_path, category_id: str, inputs: str, name: str = "scene"):
    text = header() + DOME + mtlx_material("Mat", category_id, inputs) + plane_mesh("Floor", 1e4, "/Mat")
    reading = read_scene(write(tmp_path / f"{name}.usda", text + probe("P", (0.0, 1.0, 0.0))))
    assert not reading.errors, reading.errors
    return reading


@pytest.mark.parametrize(("category_id", "names"), [
    ("ND_standard_surface_surfaceshader", ("specular", "specular_color", "coat", "coat_color")),
    ("ND_open_pbr_surface_surfaceshader", ("specular_weight", "specular_color", "coat_weight", "coat_color")),
])
def test_specular_and_coat_tints_are_read(tmp_path, category_id, names):
    weight, colour, coat, coat_colour = names
    reading = _reading(tmp_path, category_id, f"float inputs:{weight} = 0.5\n        "
                       f"color3f inputs:{colour} = (1, 0.5, 0.25)\n        float inputs:{coat} = 0.6\n        "
                       f"color3f inputs:{coat_colour} = (0.2, 0.4, 1)")
    material = reading.scene.meshes[0].material
    if coat == "coat_weight":
        # open_pbr_surface.mtlx (NG_open_pbr_surface_surfaceshader): ``eta_s`` = mix(specular_ior 1.5, coat_ior/
        # specular_ior 1.6/1.5, coat_weight 0.6), its F0 scaled by specular_weight 0.5 (``scaled_specular_F0``), the
        # colour tinting the lobe; the capture's F0 is F0(specular_ior) = 0.04 × specular_tint. (Before this audit
        # the tint was weight × colour, F0 and F90 alike, without the coat's IOR.)
        eta = 0.4 * 1.5 + 0.6 * 1.6 / 1.5
        f0 = 0.5 * ((eta - 1) / (eta + 1)) ** 2
        np.testing.assert_allclose(material.specular_tint, np.array([1.0, 0.5, 0.25]) * f0 / 0.04, rtol=1e-6)
        assert material.specular_edge_tint is not None  # F90: test_mtlx_surface_spec.py
    else:
        np.testing.assert_allclose(material.specular_tint, (0.5, 0.25, 0.125), rtol=1e-6)
        assert material.specular_edge_tint is None
    expected = 0.4 + 0.6 * np.array([0.2, 0.4, 1.0])
    if coat == "coat_weight":  # OpenPBR also darkens the base under its coat (default base 0.8, coat_ior 1.6)
        k = 1 - (1 - (0.6 / 2.6) ** 2) / 1.6 ** 2
        expected = expected * (1 + 0.6 * ((1 - k) / (1 - 0.8 * k) - 1))
    np.testing.assert_allclose(material.coat_tint, expected, rtol=1e-6)
    assert not [i for i in reading.issues if "not modelled" in i.message], reading.issues
    plain = _reading(tmp_path, category_id, "", name="plain").scene.meshes[0].material
    assert plain.specular_tint == (1.0, 1.0, 1.0) and plain.coat_tint == (1.0, 1.0, 1.0)


def test_a_tinted_lobe_scales_the_whole_schlick_curve():
    """f = (1 − F)·ρ/π·cos + F·D·V·cos with F = t ⊙ Schlick(F0, F90): the specular part is t × the untinted one at
    every angle (grazing included), the diffuse part ρ/π·(1 − t ⊙ F_1)·cos."""
    rng = np.random.default_rng(3)
    m = 64
    n = np.tile(np.array([[0.0], [0.0], [1.0]], np.float32), (1, m))
    wo = rng.normal(size=(3, m)).astype(np.float32)
    wo[2] = np.abs(wo[2]) + 0.05
    wo /= np.linalg.norm(wo, axis=0)
    wi = rng.normal(size=(3, m)).astype(np.float32)
    wi[2] = np.abs(wi[2]) + 0.05
    wi /= np.linalg.norm(wi, axis=0)
    albedo = np.full((3, m), 0.5, np.float32)
    f0 = np.full((3, m), 0.04, np.float32)
    rough = np.full(m, 0.4, np.float32)
    tint = np.array([[0.5], [0.25], [0.0]], np.float32)
    plain = Bsdf(n, wo, albedo, f0, rough)
    tinted = Bsdf(n, wo, albedo, tint * f0, rough, f90=np.broadcast_to(tint * 1.0, (3, m)).astype(np.float32))
    d1, s1, _ = plain.evaluate_lobes(wi)
    dt, st, _ = tinted.evaluate_lobes(wi)
    np.testing.assert_allclose(st, tint * s1, rtol=2e-5, atol=1e-9)
    h = (wo + wi) / np.linalg.norm(wo + wi, axis=0)
    vh = np.clip((wo * h).sum(axis=0), 0, 1)
    fresnel = 0.04 + (1 - 0.04) * (1 - vh) ** 5
    cos = np.maximum(wi[2], 0)
    np.testing.assert_allclose(dt, 0.5 / np.pi * (1 - tint * fresnel) * cos, rtol=2e-5, atol=1e-9)
    np.testing.assert_allclose(d1, np.broadcast_to(0.5 / np.pi * (1 - fresnel) * cos, d1.shape), rtol=2e-5,
                               atol=1e-9)


def test_the_capture_is_linear_in_the_specular_tint(tmp_path):
    """A black dielectric floor (base 0: only the specular lobe, picked with probability 1, so the same paths)
    under a uniform dome: the floor seen by the probe with specular 0.5 × colour (1, 0.5, 0.25) is that tint times
    the untinted floor, texel for texel; with specular 0 the floor is black."""
    surface = "ND_standard_surface_surfaceshader"
    base = "float inputs:base = 0\n        float inputs:specular_roughness = 0.3\n        "
    plain = _reading(tmp_path, surface, base, "plain")
    tinted = _reading(tmp_path, surface, base + "float inputs:specular = 0.5\n        "
                      "color3f inputs:specular_color = (1, 0.5, 0.25)", "tinted")
    none = _reading(tmp_path, surface, base + "float inputs:specular = 0", "none")
    below = cube_texel_directions(N)[..., 1] < -0.2
    cubes = [capture_probes(r.scene, N, samples=16, bounces=0)[0][0].astype(np.float64)[below]
             for r in (plain, tinted, none)]
    assert cubes[0].min() > 0.01
    np.testing.assert_allclose(cubes[1], cubes[0] * np.array([0.5, 0.25, 0.125]), rtol=1e-5)
    assert float(np.abs(cubes[2]).max()) == 0.0


def test_the_coat_colour_filters_the_base(tmp_path):
    """A white diffuse base (specular 0) under a coat of weight 1 and colour C: the floor is the coat's own
    reflection plus C ⊙ the base's share, so per channel it interpolates linearly between the captures with C = 0
    and C = 1 (64 rays per texel: 1.5 %); a coat weight 0 passes everything whatever C."""
    surface = "ND_standard_surface_surfaceshader"
    base = "float inputs:base = 0.8\n        float inputs:specular = 0\n        float inputs:coat = 1\n        "
    colours = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0), "tinted": (0.2, 0.5, 0.9)}
    below = cube_texel_directions(N)[..., 1] < -0.2
    mean = {}
    for name, colour in colours.items():
        reading = _reading(tmp_path, surface, base + f"color3f inputs:coat_color = {colour}", name)
        cube = capture_probes(reading.scene, N, samples=64, bounces=0)[0][0].astype(np.float64)
        mean[name] = cube[below].mean(axis=0)
    expected = mean["black"] + np.array(colours["tinted"]) * (mean["white"] - mean["black"])
    np.testing.assert_allclose(mean["tinted"], expected, rtol=0.015)
    assert mean["white"][0] > 5 * mean["black"][0]  # the base dominates a white coat
    uncoated = _reading(tmp_path, surface, "float inputs:coat = 0\n        color3f inputs:coat_color = (0, 0, 0)",
                        "uncoated").scene.meshes[0].material
    assert uncoated.coat_tint == (1.0, 1.0, 1.0)


def test_the_coat_f0_comes_from_its_ior(tmp_path):
    """F0 = ((n − 1)/(n + 1))² at normal incidence: 0.04 at standard_surface's coat_IOR 1.5 (the hash and the
    coat table then as before), 0.0533 at open_pbr's default coat_ior 1.6; nothing reported."""
    standard = _reading(tmp_path, "ND_standard_surface_surfaceshader", "float inputs:coat = 1", "standard")
    assert standard.scene.meshes[0].material.clearcoat_f0 == 0.04
    reading = _reading(tmp_path, "ND_open_pbr_surface_surfaceshader", "float inputs:coat_weight = 1", "open")
    assert reading.scene.meshes[0].material.clearcoat_f0 == pytest.approx((0.6 / 2.6) ** 2)
    assert not [i for i in reading.issues if "coat" in i.message], reading.issues


def test_the_capture_is_linear_in_the_coat_f0(tmp_path):
    """A coat of weight 1 over a black base (the coat lobe alone, picked with probability 1): Schlick's
    F = F0·(1 − g) + g is linear in F0, so the coated floor at IOR 1.6 interpolates, texel for texel, between the
    floors at IOR 1.5 (F0 0.04) and 2 (F0 1/9)."""
    surface = "ND_standard_surface_surfaceshader"
    base = ("float inputs:base = 0\n        float inputs:specular = 0\n        float inputs:coat = 1\n        "
            "float inputs:coat_roughness = 0.3\n        float inputs:coat_IOR = ")
    below = cube_texel_directions(N)[..., 1] < -0.2
    floors = {}
    for ior in (1.5, 2.0, 1.6):
        reading = _reading(tmp_path, surface, base + str(ior), f"coat{ior}")
        cube = capture_probes(single_scattering(reading.scene), N, samples=16, bounces=0)[0][0]
        floors[ior] = cube.astype(np.float64)[below]
    f0 = {ior: ((ior - 1) / (ior + 1)) ** 2 for ior in floors}
    share = (f0[1.6] - f0[1.5]) / (f0[2.0] - f0[1.5])
    np.testing.assert_allclose(floors[1.6], floors[1.5] + share * (floors[2.0] - floors[1.5]), rtol=1e-4)
    assert floors[2.0].mean() > 1.5 * floors[1.5].mean()


def test_open_pbr_coat_darkening_is_folded_into_the_coat_tint(tmp_path):
    """OpenPBR: the coat passes mix(1, coat_color, w) × mix(1, (1 − K)/(1 − E_base K), w·coat_darkening), K = 1 −
    (1 − F0)/n² (the stdlib graph's ``coat_attenuation`` and ``modulated_base_darkening``); coat_darkening 0 leaves
    the colour alone."""
    inputs = ("float inputs:coat_weight = 0.8\n        color3f inputs:coat_color = (1, 0.5, 0.5)\n        "
              "color3f inputs:base_color = (0.9, 0.3, 0.1)\n        float inputs:coat_ior = 1.5")
    material = _reading(tmp_path, "ND_open_pbr_surface_surfaceshader", inputs, "dark").scene.meshes[0].material
    k = 1 - (1 - 0.04) / 1.5 ** 2
    base = np.array([0.9, 0.3, 0.1])
    darkening = 1 + 0.8 * ((1 - k) / (1 - base * k) - 1)
    attenuation = 0.2 + 0.8 * np.array([1.0, 0.5, 0.5])
    np.testing.assert_allclose(material.coat_tint, attenuation * darkening, rtol=1e-6)  # float32 inputs
    off = _reading(tmp_path, "ND_open_pbr_surface_surfaceshader", inputs + "\n        float inputs:coat_darkening = 0",
                   "off").scene.meshes[0].material
    np.testing.assert_allclose(off.coat_tint, attenuation, rtol=1e-6)


def test_gltf_khr_specular_tints_f0_by_colour_and_f90_by_weight(tmp_path):
    """KHR_materials_specular (the stdlib graph's dielectric_f0/f90): F0 = 0.04·specular·specular_color, F90 =
    specular. On a black gltf_pbr floor (the specular lobe alone, the same paths) Schlick's F = F0·(1 − g) + F90·g
    is linear in (F0, F90), so two plain floors (IOR 1.5 and 2) give each texel's two parts, and the KHR floor is
    their combination at (0.04·s·C, s), texel for texel."""
    gltf = "ND_gltf_pbr_surfaceshader"
    base = "color3f inputs:base_color = (0, 0, 0)\n        float inputs:metallic = 0\n        float inputs:roughness = 0.4"
    below = cube_texel_directions(N)[..., 1] < -0.2
    floors = {}
    for name, extra in (("ior15", "\n        float inputs:ior = 1.5"), ("ior2", "\n        float inputs:ior = 2"),
                        ("khr", "\n        float inputs:specular = 0.5\n        color3f inputs:specular_color = "
                                "(1, 0.5, 0.25)")):
        reading = _reading(tmp_path, gltf, base + extra, name)
        cube = capture_probes(single_scattering(reading.scene), N, samples=16, bounces=0)[0][0]
        floors[name] = cube.astype(np.float64)[below]
        if name == "khr":
            material = reading.scene.meshes[0].material
            np.testing.assert_allclose(material.specular_tint, (0.5, 0.25, 0.125), rtol=1e-6)
            np.testing.assert_allclose(material.specular_edge_tint, 0.5, rtol=1e-6)
    f0a, f0b = 0.04, 1 / 9  # ((n − 1)/(n + 1))² at 1.5 and 2, F90 = 1 for both
    grazing = (floors["ior2"] * f0a - floors["ior15"] * f0b) / (f0a - f0b)  # the F90 part b, per texel and channel
    normal = (floors["ior15"] - grazing) / f0a  # the F0 part a
    expected = normal * (0.04 * 0.5 * np.array([1.0, 0.5, 0.25])) + grazing * 0.5
    np.testing.assert_allclose(floors["khr"], expected, rtol=2e-4, atol=1e-7)
