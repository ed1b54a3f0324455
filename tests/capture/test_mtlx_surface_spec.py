"""MaterialX surfaces' specular lobes against their MaterialX 1.39 reference graphs (``libraries/bxdf/
open_pbr_surface.mtlx``, ``standard_surface.mtlx`` of the ``MaterialX`` package): the float nodes of the graph are
evaluated here node by node as the .mtlx file wires them (a small interpreter over the real nodegraph, not bakery's
reader), the dielectric_bsdf's Fresnel is ``mx_fresnel_dielectric`` written out, and the directional albedo is
integrated by quadrature — never numbers bakery produced.

open_pbr_surface's dielectric reflection (NG_open_pbr_surface_surfaceshader): ``dielectric_reflection`` =
dielectric_bsdf(tint = specular_color, ior = ``modulated_eta_s``), the IOR whose F0 is clamp(specular_weight ·
F0(``eta_s``), 0, 0.99999), ``eta_s`` = mix(specular_ior, the specular/coat IOR ratio ≥ 1, coat_weight). The capture
draws it as Schlick F0 = F0(ior)·specular_tint, F90 = min(1, 50·F0(ior))·specular_edge_tint (bakery.capture.surfaces),
whose F90 stands for the exact curve by its hemispherical mean (docs/capture.md).

The metal lobes (below "The metal lobes"), with the graphs' wiring checked on the .mtlx files themselves:
open_pbr_surface's ``metal_bsdf`` = generalized_schlick_bsdf(weight = specular_weight, color0 = base_color·base_weight,
color82 = specular_color) — ``mx_fresnel_hoffman_schlick`` written out here — and standard_surface's ``metal_bsdf`` =
conductor_bsdf of ``artistic_ior``(base_color·base, specular_color·specular) — ``mx_artistic_ior`` written out, the
conductor's Fresnel in complex arithmetic (Snell's law), not MaterialX's real-valued form that bakery uses. gltf_pbr's
dielectric: generalized_schlick_bsdf(color0 = min(F0(ior)·specular_color, 1)·specular, color90 = specular)."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import pytest
from test_bsdf_spec import _gauss, _half_vector_nodes, _hemisphere, _microfacet
from usd_scenes import header, material, mtlx_material, plane_mesh, probe, write

from bakery.capture import capture_probes
from bakery.capture.bsdf import Bsdf, Fresnel
from bakery.capture.surfaces import Surfaces
from bakery.capture.tracer import SceneTracer
from bakery.sphere.cubemap import cube_texel_directions
from bakery.usd.scene import read_scene

OPEN_PBR = "ND_open_pbr_surface_surfaceshader"
STANDARD = "ND_standard_surface_surfaceshader"
DOME = 'def DomeLight "Sky"\n{\n    float inputs:intensity = 1\n}\n'
N = 16


# ---------------------------------------------------------------------------------------------------------------
# The references


@lru_cache(maxsize=1)
def _open_pbr_graph():  # noqa: ANN202
    import MaterialX as mx

    library = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), library)
    graph = library.getNodeGraph("NG_open_pbr_surface_surfaceshader")
    assert graph is not None
    return library, graph


def _graph_float(node_name: str, interface: dict[str, float]) -> float:
    """The float a node of NG_open_pbr_surface_surfaceshader computes, its interface inputs bound to ``interface``
    (else the nodedef's defaults): the stdlib nodes' definitions (mix: bg + (fg − bg)·mix, ifgreater: value1 >
    value2 ? in1 : in2, …) evaluated as the graph wires them."""
    library, graph = _open_pbr_graph()
    defaults = {i.getName(): i.getValue() for i in library.getNodeDef("ND_open_pbr_surface_surfaceshader")
                .getActiveInputs() if i.getValue() is not None}

    def value(node, name: str) -> float:  # noqa: ANN001
        inp = node.getInput(name)
        if inp is None:  # the node's own default (e.g. clamp's low/high)
            return float(node.getNodeDef().getInput(name).getValue())
        if inp.getNodeName():
            return evaluate(graph.getNode(inp.getNodeName()))
        if inp.getInterfaceName():
            return float(interface.get(inp.getInterfaceName(), defaults[inp.getInterfaceName()]))
        return float(inp.getValue())

    def evaluate(node) -> float:  # noqa: ANN001
        category = node.getCategory()
        a = (lambda n: value(node, n))
        if category == "mix":
            return a("bg") + (a("fg") - a("bg")) * a("mix")
        if category == "ifgreater":
            return a("in1") if a("value1") > a("value2") else a("in2")
        if category in ("divide", "subtract", "add", "multiply", "power", "min"):
            x, y = a("in1"), a("in2")
            return {"divide": lambda: x / y, "subtract": lambda: x - y, "add": lambda: x + y,
                    "multiply": lambda: x * y, "power": lambda: x ** y, "min": lambda: min(x, y)}[category]()
        if category == "clamp":
            return min(max(a("in"), a("low")), a("high"))
        if category == "sqrt":
            return math.sqrt(a("in"))
        if category == "sign":
            return float(np.sign(a("in")))
        raise AssertionError(f"node {node.getName()} ({category}) is not interpreted")

    return evaluate(graph.getNode(node_name))


def _fresnel_dielectric(c: np.ndarray, ior: float) -> np.ndarray:
    """``mx_fresnel_dielectric`` (MaterialX pbrlib genglsl, after Lagarde's memo): the exact unpolarised Fresnel
    reflectance at cos θ = c, total internal reflection 1."""
    g2 = ior * ior + c * c - 1.0
    g = np.sqrt(np.maximum(g2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        f = 0.5 * ((g - c) / (g + c)) ** 2 * (1.0 + (((g + c) * c - 1.0) / ((g - c) * c + 1.0)) ** 2)
    return np.where(g2 < 0, 1.0, f)


def _f0(ior: float) -> float:
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def _hemispherical_mean(fresnel) -> float:  # noqa: ANN001
    """∫₀¹ F(μ) 2μ dμ (Gauss–Legendre)."""
    mu, w = _gauss(2048)
    return float(np.sum(fresnel(mu) * 2.0 * mu * w))


def _schlick_f90_of_mean(ior: float) -> float:
    """The representation docs/capture.md states: the Schlick F90 whose curve F0 + (F90 − F0)(1 − μ)⁵ (∫ (1 − μ)⁵ 2μ dμ
    = 1/21) has the exact curve's hemispherical mean, at most 1."""
    if ior == 1.0:
        return 0.0
    mean = _hemispherical_mean(lambda mu: _fresnel_dielectric(mu, ior))
    return min(1.0, _f0(ior) + 21.0 * (mean - _f0(ior)))


def _ggx_albedo(theta: float, rough: float, fresnel) -> float:  # noqa: ANN001
    """A(θo) = ∫ F(v·h)·D·G2/(4 cos cos)·cos θi dωi of a GGX lobe (α = r²), in the lobe's own half-vector measure."""
    alpha = max(rough * rough, 1e-3)
    wo = np.array([math.sin(theta), 0.0, math.cos(theta)])
    wi, d = _half_vector_nodes(wo, alpha)
    wo_k = np.repeat(wo[:, None], wi.shape[1], 1)
    spec, vh = _microfacet(wo_k, np.where(d > 0, wi, np.array([[0.0], [0.0], [1.0]])), alpha)
    return float(np.sum(fresnel(np.clip(vh, 0.0, 1.0)) * spec * np.abs(wi[2]) * d))


def _view_averaged(rough: float, fresnel) -> float:  # noqa: ANN001
    """∫ A(θo) 2 cos θo d cos θo: the lobe's albedo under uniform light, averaged over views."""
    mu, w = _gauss(24)
    return float(sum(wk * 2 * m * _ggx_albedo(math.acos(m), rough, fresnel) for m, wk in zip(mu, w)))


# ---------------------------------------------------------------------------------------------------------------
# The reader


def _reading(tmp_path, category_id: str, inputs: str, name: str = "scene"):  # noqa: ANN001, ANN202
    text = header() + DOME + mtlx_material("Mat", category_id, inputs) + plane_mesh("Floor", 1e4, "/Mat")
    reading = read_scene(write(tmp_path / f"{name}.usda", text + probe("P", (0.0, 1.0, 0.0))))
    assert not reading.errors, reading.errors
    return reading


def _schlick_terms(material) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
    """The dielectric (metalness 0) lobe's Schlick (F0, F90) the capture draws for ``material``: F0 = F0(ior) ⊙
    specular_tint, F90 = min(1, 50·F0(ior)) ⊙ specular_edge_tint (or specular_tint), bakery.capture.surfaces."""
    f0 = _f0(material.ior)
    edge = material.specular_tint if material.specular_edge_tint is None else material.specular_edge_tint
    return f0 * np.asarray(material.specular_tint), min(1.0, 50.0 * f0) * np.asarray(edge)


CASES = {  # name: (inputs, interface values of the graph)
    "weight 0.5": ({"specular_weight": 0.5, "specular_color": (1.0, 0.5, 0.25)}, {"specular_weight": 0.5}),
    "weight 0.1": ({"specular_weight": 0.1}, {"specular_weight": 0.1}),
    "weight 2, ior 2.5": ({"specular_weight": 2.0, "specular_ior": 2.5}, {"specular_weight": 2.0,
                                                                          "specular_ior": 2.5}),
    "coat 1": ({"coat_weight": 1.0}, {"coat_weight": 1.0}),
    "coat 0.5, coat_ior 1.3": ({"coat_weight": 0.5, "coat_ior": 1.3, "specular_color": (0.2, 0.9, 1.0)},
                               {"coat_weight": 0.5, "coat_ior": 1.3}),
    "coat 1, ior 1.8, weight 0.7": ({"coat_weight": 1.0, "specular_ior": 1.8, "specular_weight": 0.7},
                                    {"coat_weight": 1.0, "specular_ior": 1.8, "specular_weight": 0.7}),
}


def _usda(inputs: dict) -> str:
    lines = []
    for name, value in inputs.items():
        if isinstance(value, tuple):
            lines.append(f"color3f inputs:{name} = {value}")
        else:
            lines.append(f"float inputs:{name} = {value}")
    return "\n        ".join(lines)


@pytest.mark.parametrize("case", list(CASES))
def test_open_pbr_dielectric_f0_and_f90_follow_the_graph(tmp_path, case):
    """F0 = specular_color·F0(modulated_eta_s) — specular_weight scales F0 alone, through the IOR, and the coat's
    IOR ratio enters by coat_weight — and F90 = specular_color·F90(modulated_eta_s): white for IORs ≥ 1.34, the
    hemispherical-mean Schlick F90 of the exact Fresnel below (the coated base: 0.35 at relative IOR 1.067)."""
    inputs, interface = CASES[case]
    material = _reading(tmp_path, OPEN_PBR, _usda(inputs)).scene.meshes[0].material
    eta = _graph_float("modulated_eta_s", interface)
    colour = np.asarray(inputs.get("specular_color", (1.0, 1.0, 1.0)))
    f0, f90 = _schlick_terms(material)
    np.testing.assert_allclose(f0, colour * _f0(eta), rtol=2e-6, atol=1e-9)
    np.testing.assert_allclose(f90, colour * _schlick_f90_of_mean(eta), rtol=1e-4, atol=1e-7)


def test_open_pbr_coated_base_reflects_as_the_graph(tmp_path):
    """specular_ior 1.5 under coat_ior 1.6 at coat_weight 1: the graph's base is a dielectric of relative IOR
    1.6/1.5 (F0 0.00104, not 0.04). Its GGX albedo averaged over views (roughness 0.3), exact Fresnel, against the
    capture's Schlick lobe: within 20 % (measured +17 %; Schlick with F90 = 1 would be 3.2×, the capture before this
    fix, F0 0.04, 7×)."""
    eta = _graph_float("modulated_eta_s", {"coat_weight": 1.0})
    assert eta == pytest.approx(1.6 / 1.5, rel=1e-6)
    material = _reading(tmp_path, OPEN_PBR, "float inputs:coat_weight = 1").scene.meshes[0].material
    f0, f90 = (float(x[0]) for x in _schlick_terms(material))
    assert f0 == pytest.approx(_f0(1.6 / 1.5), rel=1e-5)
    graph = _view_averaged(0.3, lambda c: _fresnel_dielectric(c, eta))
    capture = _view_averaged(0.3, lambda c: f0 + (f90 - f0) * (1.0 - c) ** 5)
    before = _view_averaged(0.3, lambda c: 0.04 + 0.96 * (1.0 - c) ** 5)
    assert capture == pytest.approx(graph, rel=0.20)
    assert before > 6 * graph


@pytest.mark.parametrize("rough", [0.1, 0.3, 0.6])
def test_dielectric_residual_of_the_schlick_representation(rough):
    """The residual docs/capture.md states: the view-averaged GGX albedo of the capture's Schlick lobe (F0 of the
    IOR, F90 the hemispherical-mean one) against the exact Fresnel's, for the IORs of a coated OpenPBR base (1.067:
    within 35 %, measured +1 … +32 %, tiny albedos 0.017 … 0.004), 1.2, water (1.33), glass (1.5) and 2 (within
    11 %, measured −10 … +1 %: Schlick's own deviation)."""
    for ior in (1.6 / 1.5, 1.2, 1.33, 1.5, 2.0):
        f0, f90 = _f0(ior), _schlick_f90_of_mean(ior)
        exact = _view_averaged(rough, lambda c: _fresnel_dielectric(c, ior))  # noqa: B023
        schlick = _view_averaged(rough, lambda c: f0 + (f90 - f0) * (1.0 - c) ** 5)  # noqa: B023
        assert schlick == pytest.approx(exact, rel=0.35 if ior < 1.1 else 0.11), (ior, rough, schlick / exact)


def test_standard_surface_dielectric_keeps_weight_times_colour_on_the_whole_lobe(tmp_path):
    """standard_surface's ``specular_bsdf`` = dielectric_bsdf(weight = specular, tint = specular_color, ior =
    specular_IOR): the weight and the colour scale the exact curve, F0 and F90 alike (unchanged by this audit); a
    water IOR 1.33 takes the hemispherical-mean F90 (0.983)."""
    material = _reading(tmp_path, STANDARD, "float inputs:specular = 0.5\n        "
                        "color3f inputs:specular_color = (1, 0.5, 0.25)").scene.meshes[0].material
    f0, f90 = _schlick_terms(material)
    tint = 0.5 * np.array([1.0, 0.5, 0.25])
    np.testing.assert_allclose(f0, 0.04 * tint, rtol=1e-6)
    np.testing.assert_allclose(f90, tint, rtol=1e-6)
    water = _reading(tmp_path, STANDARD, "float inputs:specular_IOR = 1.33", "water").scene.meshes[0].material
    f0, f90 = _schlick_terms(water)
    np.testing.assert_allclose(f0, _f0(1.33), rtol=1e-6)
    np.testing.assert_allclose(f90, _schlick_f90_of_mean(1.33), rtol=1e-4)


def test_open_pbr_weight_scales_f0_alone_in_the_capture(tmp_path):
    """A black open_pbr floor (the dielectric lobe alone, picked with probability 1: the same paths) under a
    uniform dome, specular_weight 0.5 × colour C: its lobe is F0 = C·F0(modulated_eta_s), F90 = C·F90 of that IOR
    (0.983 at 1.329) — a dielectric_bsdf of that IOR tinted C, what a standard_surface floor of specular_IOR =
    modulated_eta_s and specular_color C is: the two floors agree texel for texel (their MaterialX layering and
    energy compensation alike, test_mtlx_layering.py). The weight leaves the grazing reflection (almost) whole: the
    capture before capture model 5 scaled F0 and F90 by 0.5 (a standard_surface floor of specular 0.5, colour C,
    IOR 1.5), 1.3× darker."""
    below = cube_texel_directions(N)[..., 1] < -0.2
    base = "float inputs:specular_roughness = 0.4\n        "
    eta = _graph_float("modulated_eta_s", {"specular_weight": 0.5})
    colour = "color3f inputs:specular_color = (1, 0.5, 0.25)"
    floors = {}
    for name, category, extra in (
            ("open", OPEN_PBR, f"float inputs:base_weight = 0\n        float inputs:specular_weight = 0.5\n        "
                               f"{colour}"),
            ("same", STANDARD, f"float inputs:base = 0\n        float inputs:specular_IOR = {eta!r}\n        {colour}"),
            ("old", STANDARD, f"float inputs:base = 0\n        float inputs:specular = 0.5\n        {colour}")):
        reading = _reading(tmp_path, category, base + extra, name)
        floors[name] = capture_probes(reading.scene, N, samples=16, bounces=0)[0][0].astype(np.float64)[below]
    np.testing.assert_allclose(floors["open"], floors["same"], rtol=2e-4, atol=1e-7)
    assert floors["open"].mean() > 1.3 * floors["old"].mean()


# ---------------------------------------------------------------------------------------------------------------
# The metal lobes: open_pbr's generalized_schlick_bsdf (F82 tint) and standard_surface's artistic-IOR conductor

GOLD = (0.944, 0.776, 0.373)  # ND_artistic_ior's default reflectivity and edge colour (gold)
GOLD_EDGE = (0.998, 0.981, 0.751)


def _graph_node(graph_name: str, node_name: str):  # noqa: ANN202
    library, _ = _open_pbr_graph()
    graph = library.getNodeGraph(graph_name)
    assert graph is not None, graph_name
    node = graph.getNode(node_name)
    assert node is not None, (graph_name, node_name)
    return node


def _wiring(node, name: str):  # noqa: ANN001, ANN202
    """Where a node input comes from: ("node", name[, output]), ("interface", name), ("value", value) or None
    (the nodedef's default)."""
    inp = node.getInput(name)
    if inp is None:
        return None
    if inp.getNodeName():
        return ("node", inp.getNodeName()) + ((inp.getOutputString(),) if inp.getOutputString() else ())
    if inp.getInterfaceName():
        return ("interface", inp.getInterfaceName())
    return ("value", inp.getValueString())


def test_the_graphs_wire_the_metal_lobes_as_modelled():
    """The MaterialX 1.39 graphs themselves: open_pbr_surface's ``metal_bsdf`` is a generalized_schlick_bsdf of weight
    specular_weight, color0 ``metal_reflectivity`` = base_color·base_weight, color82 specular_color and color90 and
    exponent left at their defaults (1, 5); standard_surface's is a conductor_bsdf of weight 1 whose ior and
    extinction are the outputs of ``artistic_ior``(reflectivity = ``metal_reflectivity`` = base_color·base,
    edge_color = ``metal_edgecolor`` = specular_color·specular); both are mixed over the dielectric by metalness."""
    open_pbr = "NG_open_pbr_surface_surfaceshader"
    metal = _graph_node(open_pbr, "metal_bsdf")
    assert metal.getCategory() == "generalized_schlick_bsdf"
    assert _wiring(metal, "weight") == ("interface", "specular_weight")
    assert _wiring(metal, "color0") == ("node", "metal_reflectivity")
    assert _wiring(metal, "color82") == ("interface", "specular_color")
    assert _wiring(metal, "color90") is None and _wiring(metal, "exponent") is None
    defaults = metal.getNodeDef()
    assert tuple(defaults.getInput("color90").getValue().asTuple()) == (1.0, 1.0, 1.0)
    assert float(defaults.getInput("exponent").getValue()) == 5.0
    reflectivity = _graph_node(open_pbr, "metal_reflectivity")
    assert {_wiring(reflectivity, "in1"), _wiring(reflectivity, "in2")} == {("interface", "base_color"),
                                                                            ("interface", "base_weight")}
    mix = _graph_node(open_pbr, "base_substrate")
    assert _wiring(mix, "fg") == ("node", "metal_bsdf_tf_mix") and _wiring(mix, "mix") == ("interface",
                                                                                          "base_metalness")
    standard = "NG_standard_surface_surfaceshader_100"
    metal = _graph_node(standard, "metal_bsdf")
    assert metal.getCategory() == "conductor_bsdf"
    assert _wiring(metal, "weight")[0] == "value" and float(metal.getInput("weight").getValue()) == 1.0
    assert _wiring(metal, "ior") == ("node", "artistic_ior", "ior")
    assert _wiring(metal, "extinction") == ("node", "artistic_ior", "extinction")
    artistic = _graph_node(standard, "artistic_ior")
    assert _wiring(artistic, "reflectivity") == ("node", "metal_reflectivity")
    assert _wiring(artistic, "edge_color") == ("node", "metal_edgecolor")
    for name, inputs in (("metal_reflectivity", {("interface", "base_color"), ("interface", "base")}),
                         ("metal_edgecolor", {("interface", "specular_color"), ("interface", "specular")})):
        node = _graph_node(standard, name)
        assert node.getCategory() == "multiply" and {_wiring(node, "in1"), _wiring(node, "in2")} == inputs
    mix = _graph_node(standard, "metalness_mix")
    assert _wiring(mix, "fg") == ("node", "metal_bsdf") and _wiring(mix, "mix") == ("interface", "metalness")


def _f82_schlick(c: np.ndarray, f0: np.ndarray, f82: np.ndarray) -> np.ndarray:
    """``mx_fresnel_hoffman_schlick`` (F90 = 1, exponent 5): Schlick − a·μ(1 − μ)⁶, a = Schlick(1/7)·(1 − F82)/
    ((1/7)(6/7)⁶)."""
    c = np.asarray(c, dtype=np.float64)[..., None]
    a = (f0 + (1.0 - f0) * (6.0 / 7.0) ** 5) * (1.0 - f82) / ((1.0 / 7.0) * (6.0 / 7.0) ** 6)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5 - a * c * (1.0 - c) ** 6


def _artistic_ior(reflectivity, edge) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
    """``mx_artistic_ior`` (pbrlib genglsl/genosl, Gulbrandsen 2014): r = clamp(reflectivity, 0, 0.99), n = mix(n_max,
    n_min, edge), k = √max(((n + 1)²r − (n − 1)²)/(1 − r), 0)."""
    r = np.clip(np.asarray(reflectivity, dtype=np.float64), 0.0, 0.99)
    n_min = (1.0 - r) / (1.0 + r)
    n_max = (1.0 + np.sqrt(r)) / (1.0 - np.sqrt(r))
    n = n_max * (1.0 - np.asarray(edge)) + n_min * np.asarray(edge)
    return n, np.sqrt(np.maximum(((n + 1.0) ** 2 * r - (n - 1.0) ** 2) / (1.0 - r), 0.0))


def _conductor(c: np.ndarray, n: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The exact unpolarised Fresnel reflectance of a conductor of complex IOR N = n + ik under air, from Snell's law
    in complex arithmetic (cos θt = √(1 − sin²θ/N²)): ½(|r_s|² + |r_p|²) — the textbook form, not MaterialX's
    real-valued rewriting ``mx_fresnel_conductor`` that the capture uses."""
    c = np.asarray(c, dtype=np.float64)[..., None]
    big = np.asarray(n, dtype=np.float64) + 1j * np.asarray(k, dtype=np.float64)
    cos_t = np.sqrt(1.0 - (1.0 - c * c) / (big * big))
    r_s = (c - big * cos_t) / (c + big * cos_t)
    r_p = (big * c - cos_t) / (big * c + cos_t)
    return 0.5 * (np.abs(r_s) ** 2 + np.abs(r_p) ** 2)


def _schlick(c: np.ndarray, f0, f90) -> np.ndarray:  # noqa: ANN001
    c = np.asarray(c, dtype=np.float64)[..., None]
    return np.asarray(f0) + (np.asarray(f90) - np.asarray(f0)) * (1.0 - c) ** 5


def _colour(value) -> str:  # noqa: ANN001
    return f"({value[0]}, {value[1]}, {value[2]})"


#: name: (surface, authored inputs, roughness, the graph's Fresnel F(μ) (…, 3) of the whole base, its diffuse share
#: (3,) (the capture's (1 − m)·base colour, weighted by 1 − F) — the dielectric share in the capture's Schlick
#: representation (tested above), the metal's as the graph has it)
METALS = {
    "open_pbr F82 gold": (
        OPEN_PBR, {"base_metalness": 1.0, "base_color": GOLD, "specular_color": GOLD_EDGE}, 0.3,
        lambda c: _f82_schlick(c, np.array(GOLD), np.array(GOLD_EDGE)), (0.0, 0.0, 0.0)),
    "open_pbr weight 0.5": (
        OPEN_PBR, {"base_metalness": 1.0, "base_weight": 0.8, "base_color": GOLD, "specular_weight": 0.5}, 0.4,
        lambda c: 0.5 * _schlick(c, 0.8 * np.array(GOLD), 1.0), (0.0, 0.0, 0.0)),
    "open_pbr dark F82 (clamped at 0)": (
        OPEN_PBR, {"base_metalness": 1.0, "base_color": (0.05, 0.05, 0.05), "specular_color": (0.2, 0.2, 0.2)}, 0.3,
        lambda c: np.maximum(_f82_schlick(c, np.full(3, 0.05), np.full(3, 0.2)), 0.0), (0.0, 0.0, 0.0)),
    "open_pbr half metal": (
        OPEN_PBR, {"base_metalness": 0.5, "base_color": (0.8, 0.5, 0.2), "specular_weight": 0.7,
                   "specular_color": GOLD_EDGE}, 0.3,
        None, (0.4, 0.25, 0.1)),
    "standard_surface gold, white edge": (
        STANDARD, {"metalness": 1.0, "base": 1.0, "base_color": GOLD}, 0.3,
        lambda c: _conductor(c, *_artistic_ior(GOLD, 1.0)), (0.0, 0.0, 0.0)),
    "standard_surface gold edge": (
        STANDARD, {"metalness": 1.0, "base": 0.9, "base_color": GOLD, "specular": 0.8, "specular_color": GOLD_EDGE},
        0.5, lambda c: _conductor(c, *_artistic_ior(0.9 * np.array(GOLD), 0.8 * np.array(GOLD_EDGE))),
        (0.0, 0.0, 0.0)),
    "standard_surface half metal": (
        STANDARD, {"metalness": 0.5, "base": 1.0, "base_color": (0.8, 0.5, 0.2), "specular_color": GOLD_EDGE}, 0.3,
        lambda c: 0.5 * np.array(GOLD_EDGE) * _schlick(c, 0.04, 1.0)
        + 0.5 * _conductor(c, *_artistic_ior((0.8, 0.5, 0.2), GOLD_EDGE)), (0.4, 0.25, 0.1)),
}


def _metal_inputs(inputs: dict, rough: float) -> str:
    lines = [f"float inputs:specular_roughness = {rough}"]
    for name, value in inputs.items():
        lines.append(f"color3f inputs:{name} = {_colour(value)}" if isinstance(value, tuple)
                     else f"float inputs:{name} = {value}")
    return "\n        ".join(lines)


def _metal_case(tmp_path, case: str):  # noqa: ANN001, ANN202
    """The case's material through the reader and the capture's Surfaces (params_soa at a floor hit), and its
    graph Fresnel (the half-metal open_pbr's dielectric share from the material's Schlick terms)."""
    category_id, inputs, rough, fresnel, diffuse = METALS[case]
    reading = _reading(tmp_path, category_id, _metal_inputs(inputs, rough), case.replace(" ", "_"))
    material = reading.scene.meshes[0].material
    surfaces = Surfaces(reading.scene, SceneTracer(reading.scene))
    z = np.zeros(1, dtype=np.float32)
    params = surfaces.params_soa(np.zeros(1, dtype=np.int32), z, z, z + 1, 0.0)
    if fresnel is None:  # open_pbr half metal: 0.5·(the dielectric's tinted Schlick) + 0.5·w·F82-Schlick
        f0_d, f90_d = _schlick_terms(material)
        weight, base = inputs["specular_weight"], np.array(inputs["base_color"])
        colour = np.array(inputs["specular_color"])

        def fresnel(c):  # noqa: ANN001, ANN202
            return 0.5 * _schlick(c, f0_d, f90_d) + 0.5 * weight * _f82_schlick(c, base, colour)
    return reading, params, rough, fresnel, np.asarray(diffuse, dtype=np.float64)


def _bsdf_of(params, wo: np.ndarray, m: int) -> Bsdf:  # noqa: ANN001
    """A float64 Bsdf at m points (n = +z) of one hit's float32 parameters (params_soa): the lobes' Fresnel as the
    capture has it, without MaterialX's layering and energy compensation (the single-scattering lobe whose Fresnel
    these tests check; test_mtlx_layering.py checks the layered BSDF)."""
    albedo, f0, rough, _, f90 = params

    def rep(a):  # noqa: ANN001, ANN202
        return np.repeat(np.asarray(a, dtype=np.float64)[:, :1], m, 1)

    if isinstance(f90, Fresnel):
        fresnel = Fresnel(None if f90.f90 is None else rep(f90.f90), None if f90.f82 is None else rep(f90.f82),
                          None if f90.conductor is None else tuple(rep(x) for x in f90.conductor))
    else:  # no metal terms beyond Schlick: F90 as given, or the BSDF's rule
        fresnel = None if f90 is None else rep(f90)
    wo = np.broadcast_to(np.asarray(wo, dtype=np.float64).reshape(3, -1), (3, m)).copy()
    return Bsdf(np.repeat(np.array([[0.0], [0.0], [1.0]]), m, 1), wo, rep(albedo), rep(f0),
                np.full(m, float(rough[0])), f90=fresnel)


@pytest.mark.parametrize("case", list(METALS))
def test_metal_lobes_evaluate_the_graphs_fresnel(tmp_path, case):
    """f·cos θi at 3000 random direction pairs of the capture's BSDF (the reader → Surfaces → Bsdf) = ρ/π·(1 − F)·cos
    + F·D·G2/(4 cos cos)·cos with the graph's F written out in this file: open_pbr's ``mx_fresnel_hoffman_schlick``
    (× specular_weight) and standard_surface's conductor of the artistic IOR (exact Fresnel in complex arithmetic),
    mixed over the dielectric share by metalness; float32 parameters (≤ 2·10⁻⁵)."""
    _, params, rough, fresnel, diffuse = _metal_case(tmp_path, case)
    assert (params[4].f82 is not None) == (case != "open_pbr weight 0.5")  # a weight alone: Schlick's curve
    rng = np.random.default_rng(17)
    k = 3000
    wo, wi = (_unit_hemisphere(rng, k) for _ in range(2))
    value, _ = _bsdf_of(params, wo, k).evaluate(wi)
    alpha = max(rough * rough, 1e-3)
    spec, vh = _microfacet(wo, wi, alpha)
    f = fresnel(np.clip(vh, 0.0, 1.0)).T
    expected = (diffuse[:, None] / math.pi * (1.0 - f) + f * spec) * wi[2]
    np.testing.assert_allclose(value, expected, rtol=2e-5, atol=1e-9)


def _unit_hemisphere(rng: np.random.Generator, k: int) -> np.ndarray:
    mu = 0.02 + 0.98 * rng.random(k)
    phi = 2 * math.pi * rng.random(k)
    sin = np.sqrt(1 - mu * mu)
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), mu])


@pytest.mark.parametrize("case", ["open_pbr F82 gold", "open_pbr weight 0.5", "standard_surface gold, white edge",
                                  "standard_surface gold edge"])
def test_smooth_metals_reflect_the_graphs_anchor_values(tmp_path, case):
    """A smooth metal (roughness 0: α = 10⁻³, G2/G1 → 1) reflects A(θ) = F(cos θ) (the estimator over the BSDF's
    own samples): at normal incidence the reflectivity — w·base_weight·base_color for open_pbr, clamp(base·base_color,
    0, 0.99) for the conductor (Gulbrandsen's construction) —, and at cos θ = 1/7 (81.79°, OpenPBR's F82 angle)
    open_pbr's F82 tint × Schlick's value there; at 60°, 81.79° and 88° the closed forms."""
    category_id, inputs, _, fresnel, _ = METALS[case]
    reading = _reading(tmp_path, category_id, _metal_inputs(inputs, 0.0), "smooth")
    surfaces = Surfaces(reading.scene, SceneTracer(reading.scene))
    z = np.zeros(1, dtype=np.float32)
    params = surfaces.params_soa(np.zeros(1, dtype=np.int32), z, z, z + 1, 0.0)
    base = np.asarray(inputs["base_color"]) * inputs.get("base_weight", inputs.get("base", 1.0))
    if category_id == OPEN_PBR:
        w = inputs.get("specular_weight", 1.0)
        f82 = np.asarray(inputs.get("specular_color", (1.0, 1.0, 1.0)))
        anchors = {0.0: w * base, math.degrees(math.acos(1 / 7)): w * f82 * (base + (1 - base) * (6 / 7) ** 5)}
    else:
        anchors = {0.0: np.minimum(base, 0.99)}
    rng = np.random.default_rng(5)
    m = 4096
    for theta_deg in (*anchors, 60.0, 88.0):
        theta = math.radians(theta_deg)
        wo = np.array([math.sin(theta), 0.0, math.cos(theta)])
        _, weight, _ = _bsdf_of(params, wo, m).sample(rng.random(m), rng.random(m), rng.random(m))
        expected = fresnel(math.cos(theta))
        np.testing.assert_allclose(expected, anchors.get(theta_deg, expected), rtol=1e-9)
        np.testing.assert_allclose(weight.mean(axis=1), expected, rtol=2e-3 if theta_deg < 85 else 1.5e-2)


@pytest.mark.parametrize("case", ["open_pbr F82 gold", "open_pbr half metal", "standard_surface gold edge",
                                  "standard_surface half metal"])
@pytest.mark.parametrize("theta_deg", [0.0, 45.0, 80.0])
def test_metal_directional_albedo_is_the_quadrature_of_the_graphs_lobe(tmp_path, case, theta_deg):
    """A(θo) of the capture's BSDF — mean(f cos/pdf) over 200 000 of its own samples — equals ∫ f cos dωi by
    quadrature with the graph's Fresnel (the specular lobe in its GGX half-vector measure, the diffuse share
    ρ·(1 − F)/π on the hemisphere): within 4 standard errors + 0.2 %."""
    _, params, rough, fresnel, diffuse = _metal_case(tmp_path, case)
    theta = math.radians(theta_deg)
    wo = np.array([math.sin(theta), 0.0, math.cos(theta)])
    expected = np.array([_ggx_albedo(theta, rough, lambda c: fresnel(c)[..., j]) for j in range(3)])  # noqa: B023
    if np.any(diffuse > 0):
        wi, d = _hemisphere()
        _, vh = _microfacet(np.repeat(wo[:, None], wi.shape[1], 1), wi, max(rough * rough, 1e-3))
        f = fresnel(np.clip(vh, 0.0, 1.0)).T
        expected += np.sum(diffuse[:, None] / math.pi * (1.0 - f) * wi[2] * d, axis=1)
    m = 200_000
    rng = np.random.default_rng(11)
    _, weight, _ = _bsdf_of(params, wo, m).sample(rng.random(m), rng.random(m), rng.random(m))
    mean, error = weight.mean(axis=1), weight.std(axis=1) / math.sqrt(m)
    assert np.all(np.abs(mean - expected) <= 4 * error + 2e-3 * expected + 1e-6), (mean, expected, error)


@pytest.mark.parametrize("theta_deg", [0.0, 40.0, 70.0, 85.0])
def test_white_metals_do_not_create_energy(tmp_path, theta_deg):
    """White furnace: the whitest metals the graphs make — open_pbr base_color 1 with F82 tint 1 (F ≡ 1) and with a
    dark tint, standard_surface base_color 1 (reflectivity clamped to 0.99) with edge colour 1 and 0 — have F ≤ 1
    at every angle, and their single-scattering GGX albedo A(θo) ≤ 1, by quadrature and by the BSDF's estimator
    (4 standard errors + 0.2 %), at roughness 0.2 and 1."""
    mu = np.linspace(0.0, 1.0, 2001)
    cases = {
        "opw": (OPEN_PBR, {"base_metalness": 1.0, "base_color": (1.0, 1.0, 1.0)},
                lambda c: _f82_schlick(c, np.ones(3), np.ones(3))),
        "opt": (OPEN_PBR, {"base_metalness": 1.0, "base_color": (1.0, 1.0, 1.0), "specular_color": (1.0, 0.5, 0.0)},
                lambda c: _f82_schlick(c, np.ones(3), np.array([1.0, 0.5, 0.0]))),
        "ssw": (STANDARD, {"metalness": 1.0, "base": 1.0, "base_color": (1.0, 1.0, 1.0)},
                lambda c: _conductor(c, *_artistic_ior(np.ones(3), 1.0))),
        "ss0": (STANDARD, {"metalness": 1.0, "base": 1.0, "base_color": (1.0, 1.0, 1.0), "specular": 0.0},
                lambda c: _conductor(c, *_artistic_ior(np.ones(3), 0.0))),
    }
    theta = math.radians(theta_deg)
    wo = np.array([math.sin(theta), 0.0, math.cos(theta)])
    for name, (category_id, inputs, fresnel) in cases.items():
        assert np.all(fresnel(mu) <= 1.0 + 1e-12) and np.all(fresnel(mu) >= 0.0), name
        for rough in (0.2, 1.0):
            reading = _reading(tmp_path, category_id, _metal_inputs(inputs, rough), f"{name}{rough}")
            surfaces = Surfaces(reading.scene, SceneTracer(reading.scene))
            z = np.zeros(1, dtype=np.float32)
            params = surfaces.params_soa(np.zeros(1, dtype=np.int32), z, z, z + 1, 0.0)
            reference = np.array([_ggx_albedo(theta, rough, lambda c: fresnel(c)[..., j])  # noqa: B023
                                  for j in range(3)])
            assert np.all(reference <= 1.0 + 1e-6), (name, rough, reference)
            m = 50_000
            rng = np.random.default_rng(int(theta_deg) + int(10 * rough))
            _, weight, _ = _bsdf_of(params, wo, m).sample(rng.random(m), rng.random(m), rng.random(m))
            mean, error = weight.mean(axis=1), weight.std(axis=1) / math.sqrt(m)
            assert np.all(np.abs(mean - reference) <= 4 * error + 2e-3), (name, rough, mean, reference)
            assert np.all(mean <= 1.0 + 4 * error + 2e-3), (name, rough, mean)


def test_metal_terms_are_read_not_reported(tmp_path):
    """The metal lobes' terms become Material fields, nothing reported (before: "… on the metal are not modelled");
    plain metals and dielectrics keep the defaults (so they shade exactly as before), and a standard_surface metal
    always carries its edge colour (its conductor is never Schlick's curve)."""
    cases = [
        (OPEN_PBR, "float inputs:base_metalness = 1\n        float inputs:specular_weight = 0.5",
         {"metal_weight": 0.5, "metal_f82": None, "metal_edge_color": None}),
        (OPEN_PBR, "float inputs:base_metalness = 1\n        color3f inputs:specular_color = (1, 0.8, 0.5)",
         {"metal_weight": 1.0, "metal_f82": (1.0, 0.8, 0.5), "metal_edge_color": None}),
        (STANDARD, "float inputs:metalness = 1\n        float inputs:specular = 0.5\n        "
                   "color3f inputs:specular_color = (1, 0.8, 0.5)",
         {"metal_weight": 1.0, "metal_f82": None, "metal_edge_color": (0.5, 0.4, 0.25)}),
        (STANDARD, "float inputs:metalness = 1", {"metal_edge_color": (1.0, 1.0, 1.0)}),
        (OPEN_PBR, "float inputs:base_metalness = 1", {"metal_weight": 1.0, "metal_f82": None}),
        (OPEN_PBR, "float inputs:specular_weight = 0.5\n        color3f inputs:specular_color = (1, 0.8, 0.5)",
         {"metal_weight": 1.0, "metal_f82": None}),
        (STANDARD, "color3f inputs:specular_color = (1, 0.8, 0.5)", {"metal_edge_color": None}),
    ]
    for i, (category_id, inputs, fields) in enumerate(cases):
        reading = _reading(tmp_path, category_id, inputs, f"m{i}")
        material = reading.scene.meshes[0].material
        for name, value in fields.items():
            got = getattr(material, name)
            assert got == (pytest.approx(value, rel=1e-6) if value is not None else None), (inputs, name, got)
        assert not [x for x in reading.issues if "metal" in x.message], reading.issues
        assert material.explicit_fresnel == (material.metal_weight != 1.0 or material.metal_f82 is not None
                                             or material.metal_edge_color is not None)


# ---------------------------------------------------------------------------------------------------------------
# gltf_pbr: KHR_materials_ior / specular — F90 = specular at every IOR


GLTF = "ND_gltf_pbr_surfaceshader"


@pytest.mark.parametrize(("inputs", "ior", "specular", "colour", "metallic"), [
    ("float inputs:ior = 1.2", 1.2, 1.0, (1.0, 1.0, 1.0), 0.0),
    ("float inputs:ior = 1", 1.0, 1.0, (1.0, 1.0, 1.0), 0.0),
    ("float inputs:ior = 1.1\n        float inputs:specular = 0.5\n        "
     "color3f inputs:specular_color = (1, 0.5, 0.25)", 1.1, 0.5, (1.0, 0.5, 0.25), 0.0),
    ("float inputs:ior = 1.5\n        float inputs:specular = 0.5\n        "
     "color3f inputs:specular_color = (1, 0.5, 0.25)", 1.5, 0.5, (1.0, 0.5, 0.25), 0.0),
    ("float inputs:ior = 1.5\n        color3f inputs:specular_color = (40, 20, 1)", 1.5, 1.0, (40.0, 20.0, 1.0), 0.0),
    ("float inputs:ior = 1.2\n        float inputs:metallic = 0.5", 1.2, 1.0, (1.0, 1.0, 1.0), 0.5),
])
def test_gltf_dielectric_f0_and_f90_follow_the_graph(tmp_path, inputs, ior, specular, colour, metallic):
    """IMPL_gltf_pbr_surfaceshader's ``reflection_bsdf`` = generalized_schlick_bsdf(color0 = ``dielectric_f0`` =
    min(F0(ior)·specular_color, 1)·specular, color90 = ``dielectric_f90`` = specular): F90 is specular whatever the
    IOR (the capture's min(1, 50·F0) rule gave 0.41 at IOR 1.2 and 0 at IOR 1, where the graph keeps a grazing
    reflection), the colour on F0 alone, clamped; the metal (``metal_bsdf``: Schlick(base_color, 1)) mixed in by
    metallic. Black base: F0 and F90 of the capture's Surfaces."""
    if "metallic" not in inputs:  # glTF's metallicFactor defaults to 1
        inputs += "\n        float inputs:metallic = 0"
    reading = _reading(tmp_path, GLTF, "color3f inputs:base_color = (0, 0, 0)\n        " + inputs, "gltf")
    surfaces = Surfaces(reading.scene, SceneTracer(reading.scene))
    z = np.zeros(1, dtype=np.float32)
    _, f0, _, _, f90 = surfaces.params_soa(np.zeros(1, dtype=np.int32), z, z, z + 1, 0.0)
    f90 = f90.f90 if isinstance(f90, Fresnel) else f90  # a Fresnel block: MaterialX's layering
    dielectric_f0 = np.minimum(_f0(ior) * np.asarray(colour), 1.0) * specular
    np.testing.assert_allclose(f0[:, 0], (1 - metallic) * dielectric_f0, rtol=2e-6, atol=1e-9)
    np.testing.assert_allclose(np.asarray(f90)[:, 0], (1 - metallic) * specular + metallic, rtol=2e-6)


def test_gltf_low_ior_floor_keeps_its_grazing_reflection(tmp_path):
    """A black gltf_pbr floor of IOR 1.2 under a uniform dome. Its lobe, Schlick F = F0·a + F90·b per sample, with
    MaterialX's compensation F·(1 + k·F) (test_mtlx_layering.py), is a quadratic in F0 at F90 = 1: three plain
    standard_surface floors (IOR 1.5, 1.8 and 2: F90 = 1 each) give each texel's quadratic, and the gltf floor is its
    value at F0(1.2) (KHR_materials_ior: F90 = 1), texel for texel (measured 10⁻⁶) — the capture before capture
    model 6 drew F90 = min(1, 50·F0) = 0.41 without compensation (a UsdPreviewSurface floor of IOR 1.2), 1.8× darker
    on average."""
    below = cube_texel_directions(N)[..., 1] < -0.2
    floors = {}
    for ior in (1.5, 1.8, 2.0):
        reading = _reading(tmp_path, STANDARD, f"float inputs:base = 0\n        float inputs:specular_IOR = {ior}\n"
                           "        float inputs:specular_roughness = 0.4", f"ior{ior}")
        floors[ior] = capture_probes(reading.scene, N, samples=16, bounces=0)[0][0].astype(np.float64)[below]
    reading = _reading(tmp_path, GLTF, "color3f inputs:base_color = (0, 0, 0)\n        float inputs:ior = 1.2\n"
                       "        float inputs:metallic = 0\n        float inputs:roughness = 0.4", "gltf")
    gltf = capture_probes(reading.scene, N, samples=16, bounces=0)[0][0].astype(np.float64)[below]
    text = header() + DOME + material("Old", diffuse=(0.0, 0.0, 0.0), inputs="float inputs:ior = 1.2\n        "
                                      "float inputs:roughness = 0.4") + plane_mesh("Floor", 1e4, "/Old")
    old_reading = read_scene(write(tmp_path / "old.usda", text + probe("P", (0.0, 1.0, 0.0))))
    old = capture_probes(old_reading.scene, N, samples=16, bounces=0)[0][0].astype(np.float64)[below]
    x = {ior: _f0(ior) for ior in floors}
    target = _f0(1.2)
    expected = sum(floors[i] * math.prod((target - x[j]) / (x[i] - x[j]) for j in floors if j != i) for i in floors)
    np.testing.assert_allclose(gltf, expected, rtol=2e-4, atol=1e-7)
    assert gltf.mean() > 1.8 * old.mean()


def test_gltf_at_ior_133_and_above_keeps_the_rule(tmp_path):
    """glTF's default IOR 1.5 (F0 0.04: the rule's F90 is 1 already) and any IOR ≥ 1.33 keep the material as it was:
    no dielectric_f90 field, so F90 = min(1, 50·F0)·specular as before."""
    for ior in (1.5, 1.33, 2.0):
        material = _reading(tmp_path, GLTF, f"float inputs:ior = {ior}\n        float inputs:metallic = 0.5",
                            f"g{ior}").scene.meshes[0].material
        assert material.dielectric_f90 is None and not material.explicit_fresnel, ior


# ---------------------------------------------------------------------------------------------------------------
# Both shading paths, and materials without these terms


def _write_exr(path, pixels: np.ndarray) -> None:  # noqa: ANN001
    import OpenImageIO as oiio

    h, w, c = pixels.shape
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(w, h, c, oiio.FLOAT))
    out.write_image(np.ascontiguousarray(pixels, dtype=np.float32))
    out.close()


ST = 'texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (\n        interpolation = "faceVarying"\n    )'


def textured_metal_scene(tmp_path, category_id: str, metal_input: str, extra: str):  # noqa: ANN001, ANN201
    """A floor of the MaterialX surface ``category_id`` whose base colour and ``metal_input`` are 2×2 images (base
    colours (0.9, 0.6, 0.3), (0.2, 0.8, 0.95), grey 0.5, (1, 0.1, 0); metalness 0, 0.4, 1, 0.75), ``extra`` further
    input lines, under a uniform dome: its SceneReading (shared with test_mtlx_layering.py)."""
    _write_exr(tmp_path / "base.exr", np.array([[[0.9, 0.6, 0.3], [0.2, 0.8, 0.95]],
                                                [[0.5, 0.5, 0.5], [1.0, 0.1, 0.0]]]))
    _write_exr(tmp_path / "metal.exr", np.array([[[0.0], [0.4]], [[1.0], [0.75]]]))
    shaders = """
def Shader "BaseTex"
{
    uniform token info:id = "ND_image_color3"
    asset inputs:file = @./base.exr@
    token outputs:out
}
def Shader "MetalTex"
{
    uniform token info:id = "ND_image_float"
    asset inputs:file = @./metal.exr@
    token outputs:out
}
"""
    inputs = (f"color3f inputs:base_color.connect = </BaseTex.outputs:out>\n        "
              f"float inputs:{metal_input}.connect = </MetalTex.outputs:out>\n        {extra}")
    text = header() + DOME + shaders + mtlx_material("Mat", category_id, inputs) + plane_mesh("Floor", 2.0, "/Mat",
                                                                                            extra=ST)
    reading = read_scene(write(tmp_path / "textured.usda", text + probe("P", (0.0, 1.0, 0.0))))
    assert not reading.errors, reading.errors
    return reading


@pytest.mark.parametrize(("category_id", "metal_input", "extra"), [
    (OPEN_PBR, "base_metalness", "float inputs:specular_weight = 0.6\n        "
                                 "color3f inputs:specular_color = (1, 0.7, 0.4)"),
    (STANDARD, "metalness", "float inputs:base = 0.9\n        float inputs:specular = 0.8\n        "
                            "color3f inputs:specular_color = (1, 0.7, 0.4)"),
])
def test_textured_metals_agree_on_both_shading_paths(tmp_path, category_id, metal_input, extra):
    """A base colour and a metalness read from images, per hit: the renderer's float32 path (params_soa →
    _textured_soa) and the float64 one (Surfaces.at → _point) give the same albedo, F0, F90 and metal terms at 64
    random points of the floor (≤ 10⁻⁵ relative)."""
    reading = textured_metal_scene(tmp_path, category_id, metal_input, extra)
    material = reading.scene.meshes[0].material
    assert {e["input"] for e in material.maps} >= {"diffuseColor", "metallic"} and material.explicit_fresnel
    surfaces = Surfaces(reading.scene, SceneTracer(reading.scene))
    rng = np.random.default_rng(3)
    k = 64
    prim = rng.integers(0, 2, k)
    bu, bv = rng.random(k) * 0.5, rng.random(k) * 0.5
    albedo, f0, _, _, fresnel = surfaces.params_soa(prim.astype(np.int32), bu.astype(np.float32),
                                                    bv.astype(np.float32), np.ones(k, dtype=np.float32), 0.0)
    point = surfaces.at(prim, bu, bv)
    for soa, aos in ((albedo, point.albedo), (f0, point.f0), (fresnel.f90, point.f90), (fresnel.f82, point.f82),
                     *zip(fresnel.conductor, point.conductor)):
        np.testing.assert_allclose(soa, aos.T, rtol=1e-5, atol=1e-6)
    varying = point.f82 if category_id == OPEN_PBR else point.conductor[0]  # the hits do differ
    assert np.ptp(varying.max(axis=1)) > 0.05 and np.ptp(point.albedo[:, 0]) > 0.05


def test_materials_without_metal_terms_shade_as_before(tmp_path):
    """A plain material's parameters and BSDF values are bit-identical whether or not the scene also holds a
    material with metal terms (which turns params_soa's F90 into a Fresnel block): its F82 and conductor terms are
    zero and take the Schlick path's arithmetic unchanged."""
    plain = mtlx_material("Plain", OPEN_PBR, "float inputs:base_metalness = 0.4\n        "
                                              "color3f inputs:base_color = (0.7, 0.5, 0.2)\n        "
                                              "float inputs:specular_ior = 1.7")
    metal = mtlx_material("Metal", STANDARD, "float inputs:metalness = 1")
    texts = {"alone": header() + DOME + plain + plane_mesh("Floor", 10.0, "/Plain"),
             "mixed": header() + DOME + plain + metal + plane_mesh("Floor", 10.0, "/Plain")
             + plane_mesh("Other", 1.0, "/Metal", height=-5.0)}
    rng = np.random.default_rng(9)
    k = 500
    wo, wi = _unit_hemisphere(rng, k), _unit_hemisphere(rng, k)
    results = {}
    for name, text in texts.items():
        reading = read_scene(write(tmp_path / f"{name}.usda", text + probe("P", (0.0, 1.0, 0.0))))
        assert not reading.errors, reading.errors
        tracer = SceneTracer(reading.scene)
        surfaces = Surfaces(reading.scene, tracer)
        prim = np.full(k, int(np.argmax(np.asarray(tracer.mesh_of) == 0)), dtype=np.int32)
        z = np.zeros(k, dtype=np.float32)
        albedo, f0, rough, _, f90 = surfaces.params_soa(prim, z, z, z + 1, 0.0)
        n = np.repeat(np.array([[0.0], [0.0], [1.0]], dtype=np.float32), k, 1)
        bsdf = Bsdf(n, wo.astype(np.float32), albedo, f0, rough, f90=f90)
        results[name] = (albedo, f0, f90, bsdf.evaluate(wi.astype(np.float32)))
    # both are Fresnel blocks (MaterialX's layering), the metal terms only with the metal in the scene
    assert results["alone"][2].f82 is None and results["mixed"][2].f82 is not None
    alone, mixed = results["alone"], results["mixed"]
    np.testing.assert_array_equal(alone[0], mixed[0])
    np.testing.assert_array_equal(alone[1], mixed[1])
    if alone[2].f90 is not None:  # else the BSDF's min(1, 50·luminance(F0)): the values below compare it
        np.testing.assert_array_equal(alone[2].f90, mixed[2].f90)
    np.testing.assert_array_equal(mixed[2].f82, 0)
    np.testing.assert_array_equal(mixed[2].conductor[0], 0)
    np.testing.assert_array_equal(alone[3][0], mixed[3][0])
    np.testing.assert_array_equal(alone[3][1], mixed[3][1])
