"""MaterialX surfaces → the capture's material model (:class:`bakery.usd.materials.Surface`).

Sources: ``.mtlx`` documents read with the ``MaterialX`` package (the usd-core wheel has no usdMtlx file format, so
a reference to a ``.mtlx`` file does not compose), and MaterialX shaders authored as USD prims (``info:id`` =
``ND_<node>_surfaceshader``). Defaults and input types come from MaterialX's own standard library node
definitions: a surface input of another type than its definition declares is an error on the material.

Mapping (metallic workflow of the capture; see ``docs/capture.md``)
    ===================  ==============================================  ==========================================
    capture              standard_surface                                open_pbr_surface
    ===================  ==============================================  ==========================================
    diffuse              base · base_color                               base_weight · base_color
    metallic             metalness                                       base_metalness
    roughness            specular_roughness                              specular_roughness
    ior                  specular_IOR                                    specular_ior
    emission             emission · emission_color                       emission_luminance · emission_color
    opacity              mean(opacity)                                   geometry_opacity
    coat (clearcoat)     coat, coat_roughness, F0 from coat_IOR          coat_weight, coat_roughness, coat_ior
    specular_tint        specular · specular_color (F0 and F90)          specular_color, F0 of modulated_eta_s
                                                                     (specular_weight, coat IOR ratio)
    metal (Material.     conductor_bsdf of artistic_ior(base·base_color,  generalized_schlick_bsdf: weight
    metal_*)             edge specular·specular_color)                   specular_weight, F82 specular_color
    coat_tint            mix(1, coat_color, coat)                        mix(1, coat_color, coat_weight)
    diffuse roughness    diffuse_roughness (qualitative Oren–Nayar)      base_diffuse_roughness (EON)
    subsurface           diffuse limit: mix(diffuse, subsurface_color)   the same, subsurface_weight
    sheen (Material.sheen*) sheen, sheen_color, sheen_roughness: over the   fuzz_weight, fuzz_color, fuzz_roughness:
                         diffuse lobe (Imageworks)                       over the coat (Zeltner's LTC)
    ===================  ==============================================  ==========================================

    standard_surface, open_pbr_surface and gltf_pbr shade with MaterialX's layering and energy compensation
    (Material.layering "materialx"; the dielectric_bsdf's own Fresnel and weight apart from its tint:
    Material.specular_layer, :func:`_specular_and_coat_tints`); ``UsdPreviewSurface`` nodes keep Hydra Storm's
    model, as a native UsdPreviewSurface.

    ``UsdPreviewSurface`` nodes map input for input; ``gltf_pbr`` maps base_color, metallic, roughness, ior,
    emissive, clearcoat, KHR specular (:func:`_gltf_specular`), KHR sheen (over diffuse and specular, under the
    coat; :func:`_sheen`) and alpha as its ``alpha_mode`` says. Inputs connected to ``image``/``tiledimage`` nodes
    (directly or through a nodegraph output) become texture maps with the node's file, ``colorspace`` (colour inputs
    are converted with OpenColorIO), address modes and default; a scalar weight multiplying a textured colour
    (base · base_color) folds into the map's scale. Chains of ``multiply``/``add``/``subtract``/``mix`` with
    constant operands over one image (or ``geompropvalue``) fold into the map's scale and bias (:func:`fold_affine`);
    any other graph over images (several images, a textured mix amount, separate/extract, clamp, …) is flattened into
    a texture of its own (:mod:`bakery.usd.mtlx_graph`);
    a colour input fed by ``geompropvalue`` reads that primvar per hit (vertex colours); image coordinates follow
    ``tiledimage`` tiling and a ``place2d``; a tangent-space ``normalmap`` of an image is a normal map (2·in − 1, x
    and y times its ``scale``), and a ``normalize`` of an image through constant arithmetic a world-space one.
    Transmission is read as thin, straight pass-through: the presence (opacity) is multiplied by
    1 − transmission·(1 − metalness), and the light that passes is tinted by the transmission colour (reported: no
    refraction, no reflection of the transmitted light). What the capture cannot represent (:data:`_UNMODELLED`:
    thin film, anisotropy, dispersion, …; other node types in a graph) is reported per prim.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from bakery.usd.materials import (
    COLOR_INPUTS,
    IDENTITY_AFFINE,
    Surface,
    compose_affine,
    udim_tile_size,
    vertex_color_entry,
)
from bakery.usd.mtlx_graph import GraphAccess, GraphError, flatten_graph

_SUPPORTED = ("standard_surface", "open_pbr_surface", "UsdPreviewSurface", "gltf_pbr")
#: Surfaces shaded with MaterialX's layering and energy compensation (Material.layering "materialx": pbrlib's
#: ``layer``, ``dielectric_bsdf``/``generalized_schlick_bsdf`` throughput, ``mx_ggx_energy_compensation``); a
#: UsdPreviewSurface, native or as a MaterialX node, keeps Hydra Storm's model
_LAYERED = ("standard_surface", "open_pbr_surface", "gltf_pbr")
#: Lobe weights the capture does not model: (input, neutral value).
_UNMODELLED = {
    "standard_surface": (("thin_film_thickness", 0.0), ("specular_anisotropy", 0.0),
                         ("coat_anisotropy", 0.0), ("coat_affect_color", 0.0), ("coat_affect_roughness", 0.0),
                         ("transmission_extra_roughness", 0.0), ("transmission_dispersion", 0.0),
                         ("transmission_scatter", 0.0)),
    "open_pbr_surface": (("thin_film_weight", 0.0), ("specular_roughness_anisotropy", 0.0),
                         ("coat_roughness_anisotropy", 0.0),
                         ("transmission_dispersion_scale", 0.0), ("transmission_scatter", 0.0)),
    "UsdPreviewSurface": (("displacement", 0.0),),
    "gltf_pbr": (("iridescence", 0.0), ("anisotropy_strength", 0.0)),
}
#: (specular weight, specular colour, coat weight, coat colour): the dielectric specular lobe is weighted by
#: weight × colour, and the coat lets mix(1, coat colour, coat weight) through to the base, both surfaces' stdlib
#: graphs (:func:`_specular_and_coat_tints`)
_TINTS = {"standard_surface": ("specular", "specular_color", "coat", "coat_color"),
          "open_pbr_surface": ("specular_weight", "specular_color", "coat_weight", "coat_color")}
#: (diffuse roughness input, energy compensation) of the surfaces' oren_nayar_diffuse_bsdf (stdlib graphs)
_DIFFUSE_ROUGHNESS = {"standard_surface": ("diffuse_roughness", False),
                      "open_pbr_surface": ("base_diffuse_roughness", True)}
#: (subsurface weight, subsurface colour): the dielectric base is mix(diffuse, subsurface, weight) in both
#: surfaces' MaterialX graphs; the capture reads the subsurface lobe as its diffuse limit
#: (:func:`_subsurface_as_diffuse`)
_SUBSURFACE = {"standard_surface": ("subsurface", "subsurface_color"),
               "open_pbr_surface": ("subsurface_weight", "subsurface_color")}
#: (weight or None, colour, roughness inputs, what the layer lies over, sheen_bsdf mode) of each surface's sheen
#: (:func:`_sheen`; Material.sheen_layer / sheen_mode)
_SHEEN = {"standard_surface": ("sheen", "sheen_color", "sheen_roughness", "diffuse", "conty_kulla"),
          "gltf_pbr": (None, "sheen_color", "sheen_roughness", "base", "conty_kulla"),
          "open_pbr_surface": ("fuzz_weight", "fuzz_color", "fuzz_roughness", "coat", "zeltner")}
#: (transmission weight, metalness) inputs: transmission is modelled as thin, straight pass-through — the surface's
#: presence (opacity) is multiplied by 1 − t·(1 − metalness), the share of the base that is not transmitted
_TRANSMISSION = {"standard_surface": ("transmission", "metalness"),
                 "open_pbr_surface": ("transmission_weight", "base_metalness"),
                 "gltf_pbr": ("transmission", "metallic")}
#: (colour that tints the transmitted light, Beer's-law depth input or None): MaterialX's ``dielectric_bsdf`` tint of
#: each surface's transmission lobe (``gltf_pbr``: ``base_color``, as KHR_materials_transmission)
_TRANSMISSION_TINT = {"standard_surface": ("transmission_color", "transmission_depth"),
                      "open_pbr_surface": ("transmission_color", "transmission_depth"),
                      "gltf_pbr": ("base_color", None)}


def _is_colour(name: str) -> bool:
    """Whether a surface input is a colour (its textures are colour-managed): ``*_color``, ``emissive`` (gltf_pbr)
    and UsdPreviewSurface's colour inputs."""
    return name in COLOR_INPUTS or "color" in name or name == "emissive"


class MaterialXError(ValueError):
    """A MaterialX document or material that cannot be read."""


@lru_cache(maxsize=1)
def _library():  # noqa: ANN202
    import MaterialX as mx

    library = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), library)
    return library


def nodedef_input_type(node_def_name: str, name: str) -> str:
    """The MaterialX type (``float``, ``color3``, …) the standard library's node definition ``node_def_name``
    declares for input ``name``; "" if it has no such definition or input."""
    node_def = _library().getNodeDef(node_def_name)
    node_input = node_def.getActiveInput(name) if node_def is not None else None
    return node_input.getType() if node_input is not None else ""


def _category(node_def_name: str) -> str:
    """``ND_standard_surface_surfaceshader`` → ``standard_surface``."""
    name = node_def_name[3:] if node_def_name.startswith("ND_") else node_def_name
    return name.rsplit("_surfaceshader", 1)[0]


def _surface_inputs(category: str) -> list:
    """The active inputs of the standard library's ``surfaceshader`` definition of ``category`` ([] if none)."""
    for node_def in _library().getNodeDefs():
        if node_def.getNodeString() == category and node_def.getType() == "surfaceshader":
            return node_def.getActiveInputs()
    return []


def _defaults(category: str) -> dict[str, object]:
    return {i.getName(): _py(i.getValue()) for i in _surface_inputs(category) if i.getValue() is not None}


@lru_cache(maxsize=16)
def _surface_input_types(category: str) -> dict[str, str]:
    """{input: MaterialX type} of the standard library's ``surfaceshader`` definition of ``category``."""
    return {i.getName(): i.getType() for i in _surface_inputs(category)}


def graph_type_problems(node, seen: set[str] | None = None) -> list[str]:  # noqa: ANN001
    """Why ``node`` and the nodes upstream of it in a MaterialX document match no node definition of their category
    (an input of another type than every definition declares, an input no definition has, an output type none
    has), one sentence per node; [] when all match. A category without any definition is not judged here (the graph
    evaluator reports the nodes it cannot evaluate)."""
    seen = set() if seen is None else seen
    if node.getNamePath() in seen:
        return []
    seen.add(node.getNamePath())
    problems = []
    definitions = node.getDocument().getMatchingNodeDefs(node.getCategory())
    if definitions and node.getNodeDef() is None:  # MaterialX matches a definition by output and input types
        problems.append(_mismatch(node, definitions))
    for inp in node.getInputs():
        upstream = inp.getConnectedNode()
        if upstream is not None:
            problems += graph_type_problems(upstream, seen)
    return problems


def _mismatch(node, definitions: list) -> str:  # noqa: ANN001
    """The sentence of :func:`graph_type_problems` for ``node``, whose category has ``definitions`` but none
    matching."""
    what = f"node {node.getNamePath()} ({node.getCategory()}, {node.getType()})"
    outputs = [d for d in definitions if d.getType() == node.getType()]
    if not outputs:
        declared = ", ".join(dict.fromkeys(d.getType() for d in definitions))
        return f"{what}: no definition of {node.getCategory()} outputs {node.getType()} (they output {declared})"
    for inp in node.getInputs():
        declared = list(dict.fromkeys(d.getActiveInput(inp.getName()).getType() for d in outputs
                                      if d.getActiveInput(inp.getName()) is not None))
        if not declared:
            return f"{what}: {inp.getName()} is not an input of {node.getCategory()}"
        if inp.getType() not in declared:
            shown = f" {inp.getValueString()!r}" if inp.getValueString() else ""
            return (f"{what}: input {inp.getName()} is authored as {inp.getType()}{shown}, expected "
                    f"{' or '.join(declared)}")
    authored = ", ".join(f"{inp.getName()} {inp.getType()}" for inp in node.getInputs())
    return f"{what}: no definition of {node.getCategory()} takes these input types together ({authored})"


def _py(value):  # noqa: ANN001, ANN202
    """MaterialX values (Color3, Vector2, float, …) as Python floats / tuples."""
    if isinstance(value, (int, float, bool, str)):
        return value
    try:
        return tuple(float(x) for x in value.asTuple())
    except AttributeError:
        try:
            return tuple(float(x) for x in value)
        except TypeError:
            return value


def _mean(value) -> float:  # noqa: ANN001
    return float(np.mean(np.asarray(value, dtype=np.float64)))


#: (capture input, the surface's input, its weight input or None, scalar?) per MaterialX surface category; any other
#: category is read as UsdPreviewSurface (same input names as the capture's model).
_INPUT_MAP: dict[str, tuple[tuple[str, str, str | None, bool], ...]] = {
    "standard_surface": (
        ("diffuseColor", "base_color", "base", False), ("metallic", "metalness", None, True),
        ("roughness", "specular_roughness", None, True), ("ior", "specular_IOR", None, True),
        ("emissiveColor", "emission_color", "emission", False), ("opacity", "opacity", None, True),
        ("clearcoat", "coat", None, True), ("clearcoatRoughness", "coat_roughness", None, True)),
    "open_pbr_surface": (
        ("diffuseColor", "base_color", "base_weight", False), ("metallic", "base_metalness", None, True),
        ("roughness", "specular_roughness", None, True), ("ior", "specular_ior", None, True),
        ("emissiveColor", "emission_color", "emission_luminance", False), ("opacity", "geometry_opacity", None, True),
        ("clearcoat", "coat_weight", None, True), ("clearcoatRoughness", "coat_roughness", None, True)),
    "gltf_pbr": (
        ("diffuseColor", "base_color", None, False), ("metallic", "metallic", None, True),
        ("roughness", "roughness", None, True), ("ior", "ior", None, True),
        ("emissiveColor", "emissive", "emissive_strength", False), ("opacity", "alpha", None, True),
        ("clearcoat", "clearcoat", None, True), ("clearcoatRoughness", "clearcoat_roughness", None, True)),
}
_PREVIEW_SURFACE_MAP = tuple((name, name, None, False) for name in ("diffuseColor", "emissiveColor", "specularColor")) \
    + tuple((name, name, None, True) for name in ("metallic", "roughness", "ior", "opacity", "opacityThreshold",
                                                  "useSpecularWorkflow", "clearcoat", "clearcoatRoughness"))


def _to_surface(category: str, values: dict[str, object], maps: dict[str, dict], notes: list[str]) -> Surface:
    """Map a MaterialX surface's inputs (values and texture maps by input name) onto the capture's model."""
    d = {**_defaults(category), **values}
    surface = Surface(notes=list(notes), kind=category)
    if category in _LAYERED:  # MaterialX's layer() and energy compensation (Material.layering)
        surface.values["layering"] = "materialx"
    for name, neutral in _UNMODELLED.get(category, ()):
        if name in maps or (name in d and abs(_mean(d[name]) - neutral) > 1e-6):
            surface.notes.append(f"{category} {name} is not modelled by the capture")
    coat_ior = {"standard_surface": ("coat", "coat_IOR"), "open_pbr_surface": ("coat_weight", "coat_ior")}.get(category)
    if coat_ior and _mean(d.get(coat_ior[0], 0.0)) > 0:  # the coat's F0 from its IOR (0.04 at 1.5 exactly)
        ior = _mean(d.get(coat_ior[1], 1.5))
        f0 = ((ior - 1.0) / (ior + 1.0)) ** 2 if ior > 0 else 0.0
        if abs(f0 - 0.04) > 1e-9:
            surface.values["clearcoat_f0"] = float(f0)
    if "normal" in maps:  # a tangent-space normal map, already decoded to [−1, 1]³ (:func:`_normal_entry`)
        surface.maps["normal"] = {k: v for k, v in maps["normal"].items() if k != "_mean"}

    def put(target: str, colour_input: str | None, weight_input: str | None, scalar: bool = False) -> None:
        weight = _mean(d.get(weight_input, 1.0)) if weight_input else 1.0
        if weight_input and weight_input in maps:
            surface.notes.append(f"{category} {weight_input} is textured; its mean {weight:g} is used")
        if colour_input is None:
            return
        value = d.get(colour_input)
        if colour_input in maps:
            entry = dict(maps[colour_input])
            scale = np.asarray(entry.get("scale", (1.0, 1.0, 1.0, 1.0)), dtype=np.float64)
            entry["scale"] = tuple(float(x) for x in scale * np.array([weight, weight, weight, 1.0]))
            if scalar:
                entry["channels"] = entry.get("channels", "r") if entry.get("channels") != "rgb" else "r"
            surface.maps[target] = entry
            value = entry.pop("_mean", value)
        if value is None:
            return
        array = np.asarray(value, dtype=np.float64) * weight
        surface.values[target] = float(array.mean()) if scalar else tuple(np.broadcast_to(array, 3).tolist())

    for target, colour_input, weight_input, scalar in _INPUT_MAP.get(category, _PREVIEW_SURFACE_MAP):
        put(target, colour_input, weight_input, scalar)
    if category == "gltf_pbr":
        _gltf_alpha_mode(d, surface)
        _gltf_specular(d, maps, surface)
    if category in _SUBSURFACE:
        _subsurface_as_diffuse(category, d, maps, surface)
    if category in _TINTS:
        _specular_and_coat_tints(category, d, maps, surface)
    if category in _SHEEN:
        _sheen(category, d, maps, surface)
    if category in _DIFFUSE_ROUGHNESS:
        name, compensated = _DIFFUSE_ROUGHNESS[category]
        roughness = _mean(maps[name].get("_mean", d.get(name, 0.0)) if name in maps else d.get(name, 0.0))
        if name in maps:
            surface.notes.append(f"{category} {name} is textured; its mean is used")
        if roughness > 0:
            surface.values["diffuse_roughness"] = min(roughness, 1.0)
            surface.values["diffuse_energy_compensation"] = compensated
    if category in _TRANSMISSION:
        _transmission_as_presence(category, d, maps, surface)
    surface.primvar = "st" if any("primvar" not in entry for entry in surface.maps.values()) else None
    return surface


def _gltf_alpha_mode(values: dict[str, object], surface: Surface) -> None:
    """glTF 2.0 ``alphaMode`` (gltf_pbr ``alpha_mode``): 0 OPAQUE ignores alpha (the surface is opaque), 1 MASK cuts
    out where alpha < ``alpha_cutoff`` (the capture's opacityThreshold), 2 BLEND keeps alpha as presence."""
    mode = int(round(_mean(values.get("alpha_mode", 0))))
    if mode == 0:
        surface.values["opacity"] = 1.0
        surface.maps.pop("opacity", None)
    elif mode == 1:
        surface.values["opacityThreshold"] = _mean(values.get("alpha_cutoff", 0.5))


def _gltf_specular(values: dict[str, object], maps: dict[str, dict], surface: Surface) -> None:
    """KHR_materials_specular (gltf_pbr ``specular``, ``specular_color``; the stdlib graph's dielectric_f0 and
    dielectric_f90): F0 = min(F0(ior)·specular_color, 1)·specular and F90 = specular, so the dielectric lobe's F0 is
    tinted by specular·specular_color and its F90 by specular alone — at every IOR (KHR_materials_ior: F90 = 1
    whatever the IOR; below 1.33, where the capture's min(1, 50·F0) rule would dim it, and under a textured IOR,
    Material.dielectric_f90 = specular carries it as is). Textured: their means, reported."""
    def constant(name: str) -> np.ndarray:
        value = values.get(name, 1.0)
        if name in maps:
            value = maps[name].get("_mean", value)
            surface.notes.append(f"gltf_pbr {name} is textured; its mean is used")
        return np.broadcast_to(np.asarray(value, dtype=np.float64), 3)

    weight, colour = constant("specular"), constant("specular_color")
    ior = _mean(values.get("ior", 1.5))
    f0 = ((ior - 1.0) / (ior + 1.0)) ** 2 if ior > 0 else 0.0
    colour = np.minimum(colour, 1.0 / f0) if f0 > 0 else colour  # min(F0·C, 1)
    if np.any(weight * colour != 1.0) or np.any(weight != 1.0):
        surface.values["specular_tint"] = tuple(float(x) for x in np.clip(weight * colour, 0.0, None))
        surface.values["specular_edge_tint"] = tuple(float(x) for x in np.clip(weight, 0.0, None))
    if "ior" in maps or min(1.0, 50.0 * f0) < 1.0:  # the capture's rule would dim F90 below IOR 1.33: F90 = specular
        surface.values["dielectric_f90"] = tuple(float(x) for x in np.clip(weight, 0.0, None))


def _subsurface_as_diffuse(category: str, values: dict[str, object], maps: dict[str, dict],
                           surface: Surface) -> None:
    """Subsurface weight s (textured: its mean) and colour C: the diffuse albedo becomes (1 − s)·diffuse + s·C,
    the subsurface lobe's diffusion limit — light entering the surface leaves where it entered, as it does when its
    mean free path (millimetres for skin, wax, marble) is far below the distances the probes resolve. A textured
    diffuse or C folds into the map's scale and bias (the other taken as its mean when both are textured)."""
    weight_input, colour_input = _SUBSURFACE[category]
    weight = _mean(values.get(weight_input, 0.0))
    if weight_input in maps:
        weight = _mean(maps[weight_input].get("_mean", weight))
        surface.notes.append(f"{category} {weight_input} is textured; its mean {weight:g} is used")
    weight = min(max(weight, 0.0), 1.0)
    if weight <= 0:
        return
    colour = np.broadcast_to(np.asarray(values.get(colour_input, (1.0, 1.0, 1.0)), dtype=np.float64), 3)
    diffuse = np.broadcast_to(np.asarray(surface.values.get("diffuseColor", (0.18,) * 3), dtype=np.float64), 3)
    base_map, colour_map = surface.maps.get("diffuseColor"), maps.get(colour_input)
    if colour_map is not None:
        colour = np.broadcast_to(np.asarray(colour_map.get("_mean", colour), dtype=np.float64), 3)
    surface.values["diffuseColor"] = tuple(float(x) for x in (1.0 - weight) * diffuse + weight * colour)
    if base_map is not None:  # (1 − s)·(a·tex + b) + s·C
        if colour_map is not None:
            surface.notes.append(f"{category} {colour_input} and the base colour are both textured; the mean of "
                                 f"{colour_input} is mixed with the base colour's texture")
        surface.maps["diffuseColor"] = _folded_entry(base_map, *_rgb_affine(1.0 - weight, weight * colour))
    elif colour_map is not None:  # s·(a·tex + b) + (1 − s)·diffuse
        entry = {k: v for k, v in colour_map.items() if k != "_mean"}
        surface.maps["diffuseColor"] = _folded_entry(entry, *_rgb_affine(weight, (1.0 - weight) * diffuse))
    surface.notes.append(f"{category} {weight_input} {weight:g} is read as its diffuse limit (albedo "
                         f"{colour_input} where light enters): no light travels under the surface")


def _specular_and_coat_tints(category: str, values: dict[str, object], maps: dict[str, dict],
                             surface: Surface) -> None:
    """Material.specular_tint / specular_edge_tint: the dielectric lobe's Schlick F0 and F90 relative to the
    capture's F0(ior), min(1, 50·F0(ior)) — standard_surface: specular × specular_color on both, F90 that of
    :func:`_dielectric_f90`; open_pbr_surface: specular_color on both, F0 and F90 those of the graph's
    modulated IOR (:func:`_open_pbr_dielectric`); the metal lobes' own terms by :func:`_metal_terms` — and
    Material.coat_tint = mix(1, coat colour, coat weight) (what the coat passes to the base; the coat's own lobe is
    the capture's clearcoat). With a tint, Material.specular_layer (u0, u90, w): the dielectric_bsdf's own Schlick
    F0 = F0(ior)·u0, F90 = min(1, 50·F0(ior))·u90 and its weight w, which MaterialX's layering takes without the
    tint (standard_surface: u0 = 1, w = specular; open_pbr_surface: u0 = F0(modulated_eta_s)/F0(ior), w = 1).
    Textured: their means, reported."""
    weight_input, colour_input, coat_input, coat_colour_input = _TINTS[category]

    def constant(name: str, fallback):  # noqa: ANN001, ANN202
        value = values.get(name, fallback)
        if name in maps:
            value = maps[name].get("_mean", value)
            surface.notes.append(f"{category} {name} is textured; its mean is used")
        return np.broadcast_to(np.asarray(value, dtype=np.float64), 3)

    coat = min(max(float(np.mean(constant(coat_input, 0.0))), 0.0), 1.0)
    weight, colour = constant(weight_input, 1.0), np.clip(constant(colour_input, 1.0), 0.0, None)
    metal_input = "base_metalness" if category == "open_pbr_surface" else "metalness"
    if metal_input in maps or _mean(values.get(metal_input, 0.0)) > 0:  # the metal lobe's own terms
        _metal_terms(category, weight, colour, surface)
    ior_input = "specular_ior" if category == "open_pbr_surface" else "specular_IOR"
    ior = _mean(maps[ior_input].get("_mean", values.get(ior_input, 1.5)) if ior_input in maps
                else values.get(ior_input, 1.5))
    f0_ior = _ior_f0(ior)  # the capture's dielectric F0 (Material.ior = the surface's specular IOR)
    if category == "open_pbr_surface":  # the weight modulates the IOR (F0 alone); the colour tints the lobe
        f0, f90 = _open_pbr_dielectric(ior, float(np.mean(weight)), coat, _mean(values.get("coat_ior", 1.6)))
        if f0 > 0 and f0_ior <= 0:
            surface.notes.append(f"{category} specular_ior {ior:g} under a coat: the base's reflection (F0 {f0:.3g}) "
                                 "is not modelled")
        u0 = f0 / f0_ior if f0_ior > 0 else 0.0
        f0_tint = colour * u0
        layer_weight = 1.0  # dielectric_reflection's weight: its default
        if ior_input in maps and coat > 0:
            surface.notes.append(f"{category} {ior_input} is textured under a coat: the coat's IOR ratio is applied "
                                 "at its mean")
    else:  # standard_surface: dielectric_bsdf weight × tint scale the whole lobe
        f0, f90 = f0_ior, _dielectric_f90(ior)
        f0_tint = np.clip(weight * colour, 0.0, None)
        colour = f0_tint
        u0, layer_weight = 1.0, max(float(np.mean(weight)), 0.0)  # specular_bsdf's weight: specular
    # Schlick F90 of the capture's dielectric is min(1, 50·F0(ior)) (bakery.capture.bsdf): the edge tint rescales
    # it to the graph's F90 (_dielectric_f90)
    rule = min(1.0, 50.0 * f0_ior)
    u90 = f90 / rule if rule > 0 and f0 > 0 else 0.0
    edge = colour * u90
    if np.any(f0_tint != 1.0) or np.any(edge != f0_tint):
        surface.values["specular_tint"] = tuple(float(x) for x in f0_tint)
        if np.any(np.abs(edge - f0_tint) > 1e-12):
            surface.values["specular_edge_tint"] = tuple(float(x) for x in edge)
        # the dielectric_bsdf's own Fresnel and weight, apart from the tint (Material.specular_layer)
        surface.values["specular_layer"] = (float(u0), float(u90), float(layer_weight))
    passed = np.clip((1.0 - coat) + coat * constant(coat_colour_input, 1.0), 0.0, 1.0)
    if category == "open_pbr_surface" and coat > 0:
        passed = passed * _open_pbr_coat_darkening(values, maps, coat)
    if np.any(passed != 1.0):
        surface.values["coat_tint"] = tuple(float(x) for x in passed)


def _metal_terms(category: str, weight: np.ndarray, colour: np.ndarray, surface: Surface) -> None:
    """The metal lobe of a surface with some metalness, as its stdlib graph wires it (Material.metal_*):

    * open_pbr_surface (NG_open_pbr_surface_surfaceshader): ``metal_bsdf`` = generalized_schlick_bsdf(weight =
      ``specular_weight``, color0 = ``metal_reflectivity`` = base_color·base_weight, color82 = ``specular_color``,
      color90 = 1, exponent 5) — ``mx_fresnel_hoffman_schlick``, the F82-tint Fresnel (Hoffman 2023; OpenPBR's
      metal): Material.metal_weight = specular_weight, Material.metal_f82 = specular_color, each only away from 1
      (at 1 the lobe is Schlick(F0, 1), the capture's metal as before);
    * standard_surface (NG_standard_surface_surfaceshader_100): ``metal_bsdf`` = conductor_bsdf(weight 1, ior and
      extinction of ``artistic_ior``(reflectivity = ``metal_reflectivity`` = base_color·base, edge_color =
      ``metal_edgecolor`` = specular_color·specular)), the exact conductor Fresnel of Gulbrandsen's complex IOR:
      Material.metal_edge_color = specular·specular_color, always (the default edge colour 1 is not Schlick's
      curve: a hemispherical mean of 0.595 against 0.524 at F0 0.5).

    ``weight`` and ``colour`` (3,) are the surface's specular weight and colour (textured: their means, reported by
    the caller). Colours are clipped to [0, 1] (the inputs' range; an F82 tint above 1 would lift the curve above 1,
    an edge colour above 1 extrapolate the artistic IOR below n_min), reported."""
    if category == "open_pbr_surface":
        w = max(float(np.mean(weight)), 0.0)
        if w != 1.0:
            surface.values["metal_weight"] = w
        if np.any(colour != 1.0):
            if np.any(colour > 1.0):
                surface.notes.append(f"{category} specular_color above 1 on the metal is clipped to 1 (its F82 tint)")
            surface.values["metal_f82"] = tuple(float(x) for x in np.clip(colour, 0.0, 1.0))
        return
    edge = np.clip(weight * colour, 0.0, None)
    if np.any(edge > 1.0):
        surface.notes.append(f"{category} specular·specular_color above 1 on the metal is clipped to 1 (the "
                             "artistic IOR's edge colour)")
    surface.values["metal_edge_color"] = tuple(float(x) for x in np.clip(edge, 0.0, 1.0))


def _ior_f0(ior: float) -> float:
    """((n − 1)/(n + 1))², the normal-incidence reflectance of a dielectric of IOR n (MaterialX ``mx_ior_to_f0``)."""
    return ((ior - 1.0) / (ior + 1.0)) ** 2 if ior > 0 else 0.0


@lru_cache(maxsize=256)
def _dielectric_f90(ior: float) -> float:
    """The Schlick F90 that stands for MaterialX ``dielectric_bsdf``'s exact Fresnel F(μ, n) (``mx_fresnel_dielectric``)
    in the capture's F0 + (F90 − F0)(1 − μ)⁵ with F0 = F0(n): the one of the same hemispherical mean ∫ F 2μ dμ (the
    albedo of a smooth surface under uniform light), F90 = F0 + 21·(∫ F 2μ dμ − F0), at most 1 — 1 from n ≈ 1.34 up
    (where Schlick's mean is within 7 % of the exact one), falling to 0 as n → 1 (F → 0 but at grazing: Schlick's
    F90 = 1 there would keep a mean of 1/21 of a surface that reflects nothing; at n = 1.067, a coated OpenPBR base,
    0.35). ``docs/capture.md`` gives the residuals."""
    if ior <= 0 or ior == 1.0:
        return 0.0
    mu, w = _GAUSS
    c2 = mu * mu
    g2 = ior * ior + c2 - 1.0
    g = np.sqrt(np.maximum(g2, 0.0))
    exact = np.where(g2 < 0, 1.0, 0.5 * ((g - mu) / (g + mu)) ** 2
                     * (1.0 + (((g + mu) * mu - 1.0) / ((g - mu) * mu + 1.0)) ** 2))
    f0 = _ior_f0(ior)
    return float(min(1.0, max(0.0, f0 + 21.0 * (float(np.sum(exact * 2.0 * mu * w)) - f0))))


def _gauss_unit(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


#: the quadrature of :func:`_dielectric_f90`'s hemispherical means
_GAUSS = _gauss_unit(512)


def _open_pbr_dielectric(ior: float, weight: float, coat: float, coat_ior: float) -> tuple[float, float]:
    """(F0, F90) of open_pbr_surface's dielectric reflection (NG_open_pbr_surface_surfaceshader): under a coat the
    base's IOR is the relative one, ``eta_s`` = mix(specular_ior, max(r, 1/r), coat_weight) with r =
    specular_ior/coat_ior (``specular_to_coat_ior_ratio_tir_fix``); ``specular_weight`` scales its F0 alone,
    ``scaled_specular_F0_clamped`` = clamp(weight·F0(eta_s), 0, 0.99999), through the IOR of that F0,
    ``modulated_eta_s`` = (1 + s√F0)/(1 − s√F0), s = sign(eta_s − 1), which is the ``dielectric_reflection``'s IOR.
    F90: :func:`_dielectric_f90` of that IOR."""
    ratio = ior / coat_ior if coat_ior != 0 else 1.0
    fixed = ratio if ratio > 1.0 else (coat_ior / ior if ior != 0 else 1.0)
    eta = (1.0 - coat) * ior + coat * fixed
    f0 = min(max(weight * _ior_f0(eta), 0.0), 0.99999)
    root = float(np.sign(eta - 1.0)) * f0 ** 0.5
    modulated = (1.0 + root) / (1.0 - root)
    return (f0, _dielectric_f90(modulated)) if root != 0 else (0.0, 0.0)


def _open_pbr_coat_darkening(values: dict[str, object], maps: dict[str, dict], coat: float) -> np.ndarray:
    """OpenPBR's coat darkening (stdlib graph NG_open_pbr_surface_surfaceshader ``modulated_base_darkening``): light
    the coat reflects back inside darkens a saturated base, (1 − K)/(1 − E_base·K) with K = 1 − (1 − F0_c)/n_c² the
    coat's internal reflectance and E_base = mix(mix(base_color, subsurface_color, subsurface_weight),
    specular_weight·base_color, base_metalness); mixed in by coat_weight·coat_darkening. Textured colours: means."""
    def mean(name: str, fallback):  # noqa: ANN001, ANN202
        value = maps[name].get("_mean", values.get(name, fallback)) if name in maps else values.get(name, fallback)
        return np.broadcast_to(np.asarray(value, dtype=np.float64), 3)

    n = max(_mean(values.get("coat_ior", 1.6)), 1e-6)
    f0 = ((n - 1.0) / (n + 1.0)) ** 2
    k = 1.0 - (1.0 - f0) / (n * n)
    base = mean("base_color", (0.8, 0.8, 0.8))
    dielectric = base + _mean(values.get("subsurface_weight", 0.0)) * (mean("subsurface_color", (0.8,) * 3) - base)
    metal = _mean(values.get("specular_weight", 1.0)) * base
    e_base = dielectric + _mean(values.get("base_metalness", 0.0)) * (metal - dielectric)
    darkening = (1.0 - k) / (1.0 - e_base * k)
    amount = coat * _mean(values.get("coat_darkening", 1.0))
    return 1.0 + amount * (darkening - 1.0)


def _sheen(category: str, values: dict[str, object], maps: dict[str, dict], surface: Surface) -> None:
    """A surface's sheen layer (:data:`_SHEEN`, the stdlib graphs' ``sheen_bsdf`` and where their ``layer`` puts
    it) → Material.sheen*; textured inputs: their means. gltf_pbr's graph weighs the lobe by max(sheen_color),
    colours it sheen_color / max(sheen_color) and squares its roughness."""
    weight_input, colour_input, roughness_input, layer, mode = _SHEEN[category]
    read = {}
    for name in (weight_input, colour_input, roughness_input):
        if name is None:
            continue
        value = values.get(name)
        if name in maps:
            value = maps[name].get("_mean", value)
            surface.notes.append(f"{category} {name} is textured; its mean is used")
        read[name] = value
    colour = np.clip(np.broadcast_to(np.asarray(read[colour_input], dtype=np.float64), 3), 0.0, None)
    roughness = min(max(_mean(read[roughness_input]), 0.0), 1.0)
    if weight_input is None:  # gltf_pbr: sheen_intensity = max(sheen_color), colour / intensity, roughness²
        weight = float(colour.max())
        colour = colour / weight if weight > 0 else colour
        roughness = roughness * roughness
    else:
        weight = _mean(read[weight_input])
    weight = min(max(weight, 0.0), 1.0)
    if weight <= 0:
        return
    surface.values["sheen"] = weight
    surface.values["sheen_color"] = tuple(float(x) for x in colour)
    surface.values["sheen_roughness"] = roughness
    surface.values["sheen_layer"] = layer
    surface.values["sheen_mode"] = mode


def _rgb_affine(factor: float, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(scale, bias) (4,) of v → factor·v + offset on RGB, alpha unchanged (:func:`_folded_entry`'s operands)."""
    return np.array([factor, factor, factor, 1.0]), np.append(np.asarray(offset, dtype=np.float64), 0.0)


def _transmission_as_presence(category: str, values: dict[str, object], maps: dict[str, dict],
                              surface: Surface) -> None:
    """Transmission weight t (textured: its mean) → presence ×(1 − t·(1 − metalness)) (:data:`_TRANSMISSION`),
    the transmitted light tinted by the surface's transmission colour C (:data:`_TRANSMISSION_TINT`; textured:
    its mean): a window of t = 1 lets all light through unrefracted, times C. With a geometry opacity o < 1 as well,
    a passed-through hit is the absent part (1 − o, untinted) or the transmitted one (o·t·(1 − m), tinted), so a
    pass is tinted by their mixture ((1 − o) + o·t·(1 − m)·C) / ((1 − o) + o·t·(1 − m)). Reported when t > 0."""
    weight_input, metal_input = _TRANSMISSION[category]
    weight = min(max(_mean(values.get(weight_input, 0.0)), 0.0), 1.0)
    if weight_input in maps:
        weight = min(max(_mean(maps[weight_input].get("_mean", weight)), 0.0), 1.0)
    if weight <= 0:
        return
    transmitted = weight * (1.0 - min(max(_mean(values.get(metal_input, 0.0)), 0.0), 1.0))
    keep = 1.0 - transmitted
    opacity = min(max(float(surface.values.get("opacity", 1.0)), 0.0), 1.0)
    surface.values["opacity"] = opacity * keep
    if "opacity" in surface.maps:
        entry = surface.maps["opacity"]
        entry["scale"] = tuple(float(x) * keep for x in entry.get("scale", (1.0, 1.0, 1.0, 1.0)))
        entry["bias"] = tuple(float(x) * keep for x in entry.get("bias", (0.0, 0.0, 0.0, 0.0)))
    tint_input, depth_input = _TRANSMISSION_TINT[category]
    colour = values.get(tint_input, (1.0, 1.0, 1.0))
    if tint_input in maps:
        colour = maps[tint_input].get("_mean", colour)
        surface.notes.append(f"{category} {tint_input} is textured; its mean tints the transmitted light")
    colour = np.clip(np.broadcast_to(np.asarray(colour, dtype=np.float64), 3), 0.0, 1.0)
    passed = (1.0 - opacity) + opacity * transmitted
    if passed > 0 and np.any(colour != 1.0):
        tint = ((1.0 - opacity) + opacity * transmitted * colour) / passed
        surface.values["transmission_tint"] = tuple(float(x) for x in tint)
    if depth_input and _mean(values.get(depth_input, 0.0)) > 0:
        surface.notes.append(f"{category} {depth_input} {_mean(values[depth_input]):g}: the absorption over that "
                             f"depth is read as the tint {tint_input} at the surface (thin transmission)")
    surface.notes.append(f"{category} {weight_input} {weight:g} is modelled as straight pass-through (presence "
                         f"×{keep:g}, tinted by {tint_input}): no refraction or reflection of the transmitted light")


# ----------------------------------------------------------------------------------------------------------------
def surface_from_document(reader, document: str, material_name: str, prim: str) -> Surface:  # noqa: ANN001
    """The surface of ``material_name`` (a ``surfacematerial``) in the ``.mtlx`` file ``document``."""
    import MaterialX as mx

    doc = mx.createDocument()
    try:
        mx.readFromXmlFile(doc, document)
    except Exception as error:  # MaterialX raises ExceptionParseError / ExceptionFileMissing
        raise MaterialXError(f"cannot read the document ({error})") from None
    doc.importLibrary(_library())
    material = doc.getNode(material_name)
    if material is None:
        raise MaterialXError("no such material in the document")
    shader_input = material.getInput("surfaceshader")
    shader = shader_input.getConnectedNode() if shader_input is not None else None
    if shader is None:
        raise MaterialXError("the material has no surfaceshader")
    category = shader.getCategory()
    if category not in _SUPPORTED:
        raise MaterialXError(f"surface {category!r} is not supported (supported: {', '.join(_SUPPORTED)})")
    values: dict[str, object] = {}
    maps: dict[str, dict] = {}
    notes: list[str] = []
    base_dir = Path(document).parent
    declared = _surface_input_types(category)
    for inp in shader.getActiveInputs():
        name = inp.getName()
        if name in declared and inp.getType() != declared[name]:  # as a USD shader's inputs (materials.py)
            shown = f" {inp.getValueString()!r}" if inp.getValueString() else ""
            reader._warn_once(prim, f"MaterialX {Path(document).name}: {shader.getName()} input {name} is authored "
                              f"as {inp.getType()}{shown}, expected {declared[name]}", severity="error")
            continue
        upstream = inp.getConnectedNode()
        upstream_output = inp.getOutputString() or "out"  # the output of a multi-output node (separate3: outg)
        if upstream is None and inp.getNodeGraphString():
            graph = doc.getNodeGraph(inp.getNodeGraphString())
            output = graph.getOutput(inp.getOutputString() or "out") if graph is not None else None
            upstream = output.getConnectedNode() if output is not None else None
            upstream_output = (output.getOutputString() if output is not None else "") or "out"
        if upstream is None:
            if inp.getValue() is not None:
                values[name] = _py(inp.getValue())
            continue
        problems = graph_type_problems(upstream)
        for problem in problems:  # the document's own graph nodes: what MaterialX's validate() calls interface errors
            reader._warn_once(prim, f"MaterialX {Path(document).name}: {problem}", severity="error")
        if problems:
            continue
        if name == "normal":
            entry = _document_normal_map(reader, upstream, base_dir, prim, notes)
            if entry is not None:
                maps[name] = entry
            continue
        folded = fold_affine(upstream, lambda node: node.getCategory(), _document_operand)
        if folded is None:  # a graph over several images, or other nodes: flattened into a texture of its own
            _put_flattened(reader, name, prim, upstream, upstream_output, _document_access(reader, base_dir, prim),
                           values, maps, notes)
            continue
        leaf, scale, bias = folded  # an image or a colour primvar, through constant multiply/add/subtract/mix
        if leaf.getCategory() == "geompropvalue":  # a colour primvar read per hit
            entry = vertex_color_entry(str(leaf.getInputValue("geomprop"))) if leaf.getType() in (
                "color3", "vector3") and leaf.getInputValue("geomprop") else None
        else:
            entry = _image_map(reader, leaf, base_dir, _is_colour(name), prim)
        if entry is not None:
            maps[name] = _folded_entry(entry, scale, bias)
        elif leaf.getCategory() == "geompropvalue":
            notes.append(f"input {name}: its geompropvalue names no colour primvar; its default is used")
    return _to_surface(category, values, maps, notes)


def _normal_entry(entry: dict, scale) -> dict:  # noqa: ANN001
    """ND_normalmap on an image map entry: n = (2·in − 1) with x, y times ``scale`` (float or vector2), the
    tangent-space normal the capture's normal maps read (:meth:`bakery.capture.surfaces.Surfaces.mapped_normals`)."""
    sx, sy = (np.broadcast_to(np.asarray(1.0 if scale is None else _py(scale), dtype=np.float64), 2)[:2]).tolist()
    return dict(entry, channels="rgb", scale=(2.0 * sx, 2.0 * sy, 2.0, 1.0), bias=(-sx, -sy, -1.0, 0.0))


def _unmapped_normal(notes: list[str], what: str) -> None:
    notes.append(f"normal is {what}, which the capture does not evaluate (the mesh's normals are used)")


def _world_normal_entry(entry: dict, scale: np.ndarray, bias: np.ndarray) -> dict:
    """``normalize`` of a constant-affine image (:func:`fold_affine`): a world-space normal map (the surfaces'
    ``normal`` input is in world space, MaterialX's ``Nworld``), the image decoded by the chain's scale and bias."""
    return dict(_folded_entry(dict(entry, channels="rgb"), scale, bias), space="world")


def _document_normal_map(reader, node, base_dir: Path, prim: str, notes: list[str]) -> dict | None:  # noqa: ANN001
    """The map entry of a ``normalmap`` node (tangent space) fed by an ``image``/``tiledimage`` node, or of a
    ``normalize`` of an image through constant arithmetic (world space; MaterialX upgrades a 1.38 object-space
    ``normalmap`` to exactly this graph), or None."""
    if node.getCategory() == "normalize":
        source = node.getInput("in")
        upstream = source.getConnectedNode() if source is not None else None
        folded = None if upstream is None else fold_affine(upstream, lambda n: n.getCategory(), _document_operand)
        if folded is None or folded[0].getCategory() not in ("image", "tiledimage"):
            _unmapped_normal(notes, "a normalize of a computed vector")
            return None
        entry = _image_map(reader, folded[0], base_dir, False, prim)
        return None if entry is None else _world_normal_entry(entry, folded[1], folded[2])
    if node.getCategory() != "normalmap":
        _unmapped_normal(notes, f"computed by a {node.getCategory()} node")
        return None
    if (node.getInputValue("space") or "tangent") != "tangent":
        _unmapped_normal(notes, "an object-space normal map")
        return None
    source = node.getInput("in")
    image = source.getConnectedNode() if source is not None else None
    if image is None or image.getCategory() not in ("image", "tiledimage"):
        _unmapped_normal(notes, "a normalmap of a computed vector")
        return None
    entry = _image_map(reader, image, base_dir, False, prim)
    return None if entry is None else _normal_entry(entry, node.getInputValue("scale"))


def _image_map(reader, node, base_dir: Path, is_color: bool, prim: str) -> dict | None:  # noqa: ANN001
    file_input = node.getInput("file")
    if file_input is None:
        return None
    filename = file_input.getResolvedValueString()
    path = Path(filename)
    if not path.is_absolute():
        path = (base_dir / path).resolve()
    color_space = file_input.getActiveColorSpace() or ""
    source = "raw" if not is_color else "auto"
    tiles = ()
    size = 0
    if "<UDIM>" in filename:  # every tile 1001–1100 next to the document
        files = [(tile, Path(str(path).replace("<UDIM>", str(tile)))) for tile in range(1001, 1101)]
        files = [(tile, f) for tile, f in files if f.is_file()]
        size = udim_tile_size(len(files))
        tiles = tuple((tile, reader.texture_index(str(f), source, prim, color_space, is_color, size))
                      for tile, f in files)
        tiles = tuple((tile, i) for tile, i in tiles if i is not None)
        path = Path(str(path).replace("<UDIM>", str(tiles[0][0]))) if tiles else path
    if not path.is_file():
        reader._warn_once(prim, f"MaterialX image {filename!r} not found; the input's default is used")
        return None
    index = reader.texture_index(str(path), source, prim, color_space, is_color, size)
    if index is None:
        return None
    modes = {"periodic": "repeat", "clamp": "clamp", "mirror": "mirror", "constant": "black"}
    wrap = tuple(modes.get((node.getInputValue(a) or "periodic"), "repeat") for a in ("uaddressmode", "vaddressmode"))
    default = node.getInputValue("default")
    mean = reader.texture_mean(index)
    entry = {"texture": index, "channels": "rgb" if node.getType() in ("color3", "color4", "vector3") else "r",
            "scale": (1.0, 1.0, 1.0, 1.0), "bias": (0.0, 0.0, 0.0, 0.0),
            "fallback": tuple(np.broadcast_to(np.asarray(_py(default) if default is not None else 0.0, dtype=float),
                                              4).tolist()) if default is not None and np.ndim(_py(default)) <= 1
            and np.size(_py(default)) in (1, 4) else (0.0, 0.0, 0.0, 1.0),
            "wrap": wrap, "_mean": tuple(mean[:3].tolist()), **_udim_fields(reader, tiles)}
    return _with_transform(entry, _document_st_transform(node, lambda message: reader._warn_once(prim, message)))


def place2d_affine(pivot, scale, rotate: float, offset, order: int = 0) -> tuple[tuple[float, float, float], ...]:  # noqa: ANN001
    """MaterialX ``place2d`` (stdlib NG_place2d_vector2) as an affine map of texture coordinates, R the
    ``rotate2d`` matrix [[c, s], [−s, c]] of ``rotate`` degrees: order 0 (SRT) out = R·((tc − pivot)/scale) −
    offset + pivot; order 1 (TRS) out = R·((tc − pivot) − offset)/scale + pivot."""
    p, o = np.asarray(pivot, dtype=np.float64), np.asarray(offset, dtype=np.float64)
    inverse_scale = np.diag(1.0 / np.asarray(scale, dtype=np.float64))
    c, s = np.cos(np.radians(rotate)), np.sin(np.radians(rotate))
    rotation = np.array([[c, s], [-s, c]])
    if int(order) == 1:
        linear = inverse_scale @ rotation
        shift = -linear @ (p + o) + p
    else:
        linear = rotation @ inverse_scale
        shift = -linear @ p - o + p
    return tuple(tuple(float(x) for x in (*linear[k], shift[k])) for k in range(2))


def tiled_affine(uvtiling, uvoffset, image_size=(1.0, 1.0), tile_size=(1.0, 1.0)  # noqa: ANN001
                 ) -> tuple[tuple[float, float, float], ...]:
    """MaterialX ``tiledimage`` (stdlib NG_tiledimage): tc' = (tc·uvtiling − uvoffset) / realworldimagesize ·
    realworldtilesize, as an affine map."""
    k = np.asarray(tile_size, dtype=np.float64) / np.asarray(image_size, dtype=np.float64)
    a, d = np.asarray(uvtiling, dtype=np.float64) * k
    tx, ty = -np.asarray(uvoffset, dtype=np.float64) * k
    return ((float(a), 0.0, float(tx)), (0.0, float(d), float(ty)))


def _with_transform(entry: dict, transform) -> dict:  # noqa: ANN001
    """``entry`` with its texture-coordinate transform (None or the identity: none)."""
    if transform is not None and transform != IDENTITY_AFFINE:
        entry["st_transform"] = transform
    return entry


def _document_st_transform(node, warn):  # noqa: ANN001, ANN202
    """The affine texture-coordinate transform of a document's ``image``/``tiledimage`` node: its tiling, after a
    ``place2d`` on its ``texcoord`` (whose own texcoord is the geometry's), or None."""
    def value(n, name: str, fallback):  # noqa: ANN001, ANN202
        v = n.getInputValue(name)
        return fallback if v is None else _py(v)

    transform = None
    if node.getCategory() == "tiledimage":
        transform = tiled_affine(value(node, "uvtiling", (1.0, 1.0)), value(node, "uvoffset", (0.0, 0.0)),
                                 value(node, "realworldimagesize", (1.0, 1.0)),
                                 value(node, "realworldtilesize", (1.0, 1.0)))
    texcoord = node.getInput("texcoord")
    upstream = texcoord.getConnectedNode() if texcoord is not None else None
    if upstream is not None and upstream.getCategory() == "place2d":
        place = place2d_affine(value(upstream, "pivot", (0.0, 0.0)), value(upstream, "scale", (1.0, 1.0)),
                               float(value(upstream, "rotate", 0.0)), value(upstream, "offset", (0.0, 0.0)),
                               int(value(upstream, "operationorder", 0)))
        transform = place if transform is None else compose_affine(transform, place)
        inner = upstream.getInput("texcoord")
        upstream = inner.getConnectedNode() if inner is not None else None
    if upstream is not None and upstream.getCategory() != "texcoord":
        warn(f"texture coordinates computed by a {upstream.getCategory()} node are read as the mesh's")
    return transform


# ----------------------------------------------------------------------------------------------------------------
#: Nodes folded into a map entry's scale and bias when one operand is a constant (out = scale ⊙ leaf + bias).
_AFFINE_NODES = ("multiply", "add", "subtract", "mix")
#: Leaves of a folded chain: images (texture maps) and colour primvars (vertex colours).
_LEAVES = ("image", "tiledimage", "geompropvalue")


def _rgb(value) -> np.ndarray:  # noqa: ANN001
    """A MaterialX float or colour constant as RGB (3,) (a float broadcasts)."""
    array = np.asarray(_py(value), dtype=np.float64).reshape(-1)
    return np.broadcast_to(array[:3] if array.size >= 3 else array[:1], 3).copy()


def fold_affine(node, category_of, operand, depth: int = 0):  # noqa: ANN001, ANN201
    """(leaf node, scale (4,), bias (4,)) with out = scale ⊙ leaf + bias for a chain of ``multiply`` / ``add`` /
    ``subtract`` / ``mix`` nodes over one image or ``geompropvalue`` leaf whose other operands are constants (a
    ``constant`` node, an authored or a nodedef default value), or None (anything else: two computed operands, a
    textured mix amount, other nodes). ``category_of(node)`` names a node's category; ``operand(node, name)`` gives
    ("node", upstream), ("value", v) or None. Alpha passes unchanged."""
    one, zero = np.ones(4), np.zeros(4)
    category = category_of(node)
    if category in _LEAVES:
        return node, one, zero
    if category not in _AFFINE_NODES or depth > 16:
        return None
    names = ("fg", "bg") if category == "mix" else ("in1", "in2")
    a, b = operand(node, names[0]), operand(node, names[1])
    if a is None or b is None or (a[0] == "node") == (b[0] == "node"):
        return None
    computed_first = a[0] == "node"
    inner = fold_affine(a[1] if computed_first else b[1], category_of, operand, depth + 1)
    if inner is None:
        return None
    leaf, scale, bias = inner
    rgb = _rgb(b[1] if computed_first else a[1])
    c_scale, c_bias = np.r_[rgb, 1.0], np.r_[rgb, 0.0]  # alpha passes
    if category == "multiply":
        return leaf, scale * c_scale, bias * c_scale
    if category == "add":
        return leaf, scale, bias + c_bias
    if category == "subtract":  # X − c, or c − X
        negate = np.r_[-1.0, -1.0, -1.0, 1.0]
        return (leaf, scale, bias - c_bias) if computed_first else (leaf, scale * negate, c_bias + bias * negate)
    amount = operand(node, "mix")
    if amount is None or amount[0] != "value":
        return None
    m = float(np.asarray(_py(amount[1]), dtype=np.float64).reshape(-1)[0])
    w = m if computed_first else 1.0 - m  # the computed operand's weight: fg weighs mix, bg 1 − mix
    weight = np.r_[w, w, w, 1.0]
    return leaf, scale * weight, bias * weight + (1.0 - w) * c_bias


def _folded_entry(entry: dict, scale: np.ndarray, bias: np.ndarray) -> dict:
    """A map entry with a folded chain's scale and bias applied after its own: value' = scale ⊙ value + bias."""
    own_scale = np.asarray(entry.get("scale", (1.0,) * 4), dtype=np.float64)
    own_bias = np.asarray(entry.get("bias", (0.0,) * 4), dtype=np.float64)
    folded = dict(entry, scale=tuple(float(x) for x in own_scale * scale),
                  bias=tuple(float(x) for x in own_bias * scale + bias))
    if "_mean" in entry:
        folded["_mean"] = tuple(float(x) for x in np.asarray(entry["_mean"], dtype=np.float64) * scale[:3] + bias[:3])
    return folded


def _document_operand(node, name: str):  # noqa: ANN001, ANN202
    """:func:`fold_affine`'s operand of a document node: its connected node (a ``constant`` node: its value), its
    value, the value of the node graph's interface input it is bound to, or its nodedef's default."""
    inp = node.getInput(name)
    if inp is not None:
        upstream = inp.getConnectedNode()
        if upstream is not None:
            if upstream.getCategory() == "constant":
                value = upstream.getInputValue("value")
                return None if value is None else ("value", value)
            return "node", upstream, inp.getOutputString() or "out"
        interface = inp.getInterfaceInput() if inp.hasInterfaceName() else None
        if interface is not None:
            return None if interface.getValue() is None else ("value", interface.getValue())
        if inp.getValue() is not None:
            return "value", inp.getValue()
    node_def = node.getNodeDef()
    default = node_def.getInput(name) if node_def is not None else None
    return None if default is None or default.getValue() is None else ("value", default.getValue())


def _document_access(reader, base_dir: Path, prim: str) -> GraphAccess:  # noqa: ANN001
    """:class:`GraphAccess` to a MaterialX document's nodes (images read next to the document)."""
    return GraphAccess(
        category=lambda node: node.getCategory(), node_type=lambda node: node.getType(), operand=_document_operand,
        image=lambda node: _image_map(reader, node, base_dir, node.getType() in ("color3", "color4"), prim),
        pixels=lambda index: reader.textures[index].pixels, key=lambda node: node.getNamePath())


def _usd_access(reader) -> GraphAccess:  # noqa: ANN001
    """:class:`GraphAccess` to MaterialX shaders authored as USD prims (``ND_…`` ids)."""
    def node_type(shader) -> str:  # noqa: ANN001
        node_def = _library().getNodeDef(shader.GetShaderId() or "")
        return node_def.getType() if node_def is not None else ""

    return GraphAccess(
        category=_usd_node_category, node_type=node_type, operand=lambda node, n: _usd_operand(reader, node, n),
        image=lambda node: _usd_image_map(reader, node, node_type(node) in ("color3", "color4")),
        pixels=lambda index: reader.textures[index].pixels, key=lambda shader: str(shader.GetPath()))


def _put_flattened(reader, name: str, prim: str, node, output: str, access: GraphAccess,  # noqa: ANN001
                   values: dict[str, object], maps: dict[str, dict], notes: list[str]) -> None:
    """Surface input ``name`` computed by ``node``'s ``output``: flattened (:func:`bakery.usd.mtlx_graph.
    flatten_graph`) into a texture map, a constant value when the graph reads no image, or a note and the input's
    default when the graph cannot be flattened."""
    try:
        flat = flatten_graph(node, output, access)
    except GraphError as error:
        notes.append(f"input {name} is computed by {error}; its default is used (bake the input to an image "
                     "to capture it)")
        return
    values_of = np.asarray(flat.fallback, dtype=np.float64).reshape(-1)
    fallback = values_of[:3] if values_of.size >= 3 else np.repeat(values_of[:1], 3)  # a float (or vector2's x): RGB
    if flat.pixels is None and flat.tint_primvar:  # a constant times the primvar: the colour read per hit, scaled
        maps[name] = dict(vertex_color_entry(flat.tint_primvar), scale=(*map(float, fallback[:3]), 1.0))
        return
    if flat.pixels is None:
        values[name] = float(flat.fallback[0]) if flat.fallback.size == 1 else tuple(float(x) for x in fallback[:3])
        return
    index = reader.computed_texture(flat.pixels, f"{prim}: {name} (MaterialX graph)", _is_colour(name))
    rgba = np.r_[fallback, values_of[3] if values_of.size > 3 else 1.0]
    entry = {"texture": index, "channels": "rgb" if flat.pixels.shape[-1] >= 3 else "r",
             "scale": (1.0, 1.0, 1.0, 1.0), "bias": (0.0, 0.0, 0.0, 0.0), "fallback": tuple(float(x) for x in rgba),
             "wrap": flat.wrap, "_mean": tuple(float(x) for x in reader.texture_mean(index)[:3])}
    if flat.tint_primvar:
        entry["tint_primvar"] = flat.tint_primvar
    maps[name] = _with_transform(entry, flat.st_transform)


def _usd_node_category(shader) -> str:  # noqa: ANN001
    """The MaterialX category of a shader authored in USD (its ``ND_…`` node definition's node), or ""."""
    node_def = _library().getNodeDef(shader.GetShaderId() or "")
    return node_def.getNodeString() if node_def is not None else ""


def _usd_operand(reader, shader, name: str):  # noqa: ANN001, ANN202
    """:func:`_document_operand` for a shader authored in USD (interface inputs followed by the reader)."""
    shader_input = shader.GetInput(name)
    if shader_input:
        value, upstream, _output = reader._producer(shader_input)
        if upstream is not None:
            if _usd_node_category(upstream) == "constant":
                constant = reader._input_value(upstream, "value", None)
                return None if constant is None else ("value", constant)
            return "node", upstream, _output or "out"
        if value is not None:
            return "value", value
    node_def = _library().getNodeDef(shader.GetShaderId() or "")
    default = node_def.getInput(name) if node_def is not None else None
    return None if default is None or default.getValue() is None else ("value", default.getValue())


def _udim_fields(reader, tiles: tuple[tuple[int, int], ...]) -> dict:  # noqa: ANN001
    """A map entry's UDIM tiles ((number, texture index), …) and their mean, or nothing for a single image."""
    if not tiles:
        return {}
    return {"udim": tiles, "_mean": tuple(np.mean([reader.texture_mean(i)[:3] for _, i in tiles], axis=0).tolist())}


def surface_from_usd_shader(reader, shader, shader_id: str) -> Surface | None:  # noqa: ANN001
    """The surface of a MaterialX shader authored as a USD prim (``ND_…_surfaceshader``), or None if its node is not
    supported. Inputs connected to UsdUVTexture or ND_image nodes become maps."""
    category = _category(shader_id)
    if category not in _SUPPORTED:
        return None
    values: dict[str, object] = {}
    maps: dict[str, dict] = {}
    notes: list[str] = []
    for shader_input in shader.GetInputs():
        name = shader_input.GetBaseName()
        value, upstream, output = reader._producer(shader_input)
        if upstream is None:
            if value is not None:
                values[name] = _py(value)
            continue
        upstream_id = upstream.GetShaderId() or ""
        if name == "normal":
            entry = _usd_normal_map(reader, upstream, upstream_id, notes)
            if entry is not None:
                maps[name] = entry
            continue
        if upstream_id == "UsdUVTexture":
            entry, mean, _primvar = reader._uv_texture(upstream, output, _is_colour(name))
            if entry is not None:
                maps[name] = dict(entry, _mean=mean)
            continue
        folded = fold_affine(upstream, _usd_node_category, lambda node, n: _usd_operand(reader, node, n))
        if folded is None and _usd_node_category(upstream):  # a MaterialX graph: flattened into a texture
            _put_flattened(reader, name, str(upstream.GetPath()), upstream, output or "out", _usd_access(reader),
                           values, maps, notes)
            continue
        if folded is not None:  # an image or a colour primvar, through constant multiply/add/subtract/mix
            leaf, scale, bias = folded
            leaf_id = leaf.GetShaderId() or ""
            entry = None
            if leaf_id.startswith("ND_image_") or leaf_id.startswith("ND_tiledimage_"):
                entry = _usd_image_map(reader, leaf, _is_colour(name))
            elif leaf_id in ("ND_geompropvalue_color3", "ND_geompropvalue_vector3"):  # a colour primvar per hit
                primvar = reader._input_value(leaf, "geomprop", "")
                entry = vertex_color_entry(str(primvar)) if primvar else None
            if entry is not None:
                maps[name] = _folded_entry(entry, scale, bias)
                continue
        notes.append(f"input {name} is computed by {upstream_id or 'an untyped shader'}, which the capture does not "
                     "evaluate; its default is used")
    return _to_surface(category, values, maps, notes)


def _usd_normal_map(reader, node, node_id: str, notes: list[str]) -> dict | None:  # noqa: ANN001
    """:func:`_document_normal_map` for a MaterialX ``ND_normalmap…`` shader authored in USD."""
    if node_id == "UsdUVTexture":  # a tangent-space normal in [−1, 1]³ after the texture's scale/bias
        entry, _mean, _primvar = reader._uv_texture(node, "rgb", False)
        return None if entry is None else dict(entry, channels="rgb")
    if node_id.startswith("ND_normalize_vector3"):
        source = node.GetInput("in")
        _value, upstream, _output = reader._producer(source) if source else (None, None, None)
        folded = None if upstream is None else fold_affine(upstream, _usd_node_category,
                                                            lambda shader, n: _usd_operand(reader, shader, n))
        leaf_id = (folded[0].GetShaderId() or "") if folded is not None else ""
        if not (leaf_id.startswith("ND_image_") or leaf_id.startswith("ND_tiledimage_")):
            _unmapped_normal(notes, "a normalize of a computed vector")
            return None
        entry = _usd_image_map(reader, folded[0], False)
        return None if entry is None else _world_normal_entry(entry, folded[1], folded[2])
    if not node_id.startswith("ND_normalmap"):
        _unmapped_normal(notes, f"computed by {node_id or 'an untyped shader'}")
        return None
    space = reader._input_value(node, "space", "")
    if space and str(space) != "tangent":
        _unmapped_normal(notes, "an object-space normal map")
        return None
    source = node.GetInput("in")
    _value, image, _output = reader._producer(source) if source else (None, None, None)
    image_id = (image.GetShaderId() or "") if image is not None else ""
    if not (image_id.startswith("ND_image_") or image_id.startswith("ND_tiledimage_")):
        _unmapped_normal(notes, "a normalmap of a computed vector")
        return None
    entry = _usd_image_map(reader, image, False)
    return None if entry is None else _normal_entry(entry, reader._input_value(node, "scale", None))


def _usd_image_map(reader, node, is_color: bool) -> dict | None:  # noqa: ANN001
    from pxr import Sdf

    from bakery.usd.assets import local_asset_path

    file_input = node.GetInput("file")
    asset = reader._input_value(node, "file", None)
    if not isinstance(asset, Sdf.AssetPath) or not asset.path:
        return None
    color_space = file_input.GetAttr().GetColorSpace() or ""
    source = "raw" if not is_color else "auto"
    tiles = ()
    size = 0
    if "<UDIM>" in asset.path:
        found = reader._udim_tiles(file_input, asset.path)
        size = udim_tile_size(len(found))
        tiles = tuple((tile, i) for tile, i in ((t, reader.texture_index(f, source, str(node.GetPath()), color_space,
                                                                         is_color, size)) for t, f in found)
                      if i is not None)
        resolved = found[0][1] if found else None
    else:
        resolved = local_asset_path(asset)
    if resolved is None:
        reader._warn_once(str(node.GetPath()), f"image {asset.path!r} not found; the input's default is used")
        return None
    index = reader.texture_index(resolved, source, str(node.GetPath()), color_space, is_color, size)
    if index is None:
        return None
    modes = {"periodic": "repeat", "clamp": "clamp", "mirror": "mirror", "constant": "black"}
    wrap = []
    for a in ("uaddressmode", "vaddressmode"):
        mode = reader._input_value(node, a, "")
        wrap.append(modes.get(str(mode) if mode else "periodic", "repeat"))
    entry = {"texture": index, "channels": "rgb" if is_color else "r", "scale": (1.0, 1.0, 1.0, 1.0),
            "bias": (0.0, 0.0, 0.0, 0.0), "fallback": (0.0, 0.0, 0.0, 1.0), "wrap": tuple(wrap),
            "_mean": tuple(reader.texture_mean(index)[:3].tolist()), **_udim_fields(reader, tiles)}
    return _with_transform(entry, _usd_st_transform(reader, node))


def _usd_st_transform(reader, node):  # noqa: ANN001, ANN202
    """:func:`_document_st_transform` for ``ND_image``/``ND_tiledimage`` shaders authored in USD (a
    ``ND_place2d_vector2`` shader on their ``texcoord``)."""
    transform = None
    if (node.GetShaderId() or "").startswith("ND_tiledimage_"):
        transform = tiled_affine(reader._input_value(node, "uvtiling", (1.0, 1.0)),
                                 reader._input_value(node, "uvoffset", (0.0, 0.0)),
                                 reader._input_value(node, "realworldimagesize", (1.0, 1.0)),
                                 reader._input_value(node, "realworldtilesize", (1.0, 1.0)))
    texcoord = node.GetInput("texcoord")
    upstream = reader._producer(texcoord)[1] if texcoord else None
    if upstream is not None and (upstream.GetShaderId() or "").startswith("ND_place2d_"):
        place = place2d_affine(reader._input_value(upstream, "pivot", (0.0, 0.0)),
                               reader._input_value(upstream, "scale", (1.0, 1.0)),
                               float(reader._input_value(upstream, "rotate", 0.0)),
                               reader._input_value(upstream, "offset", (0.0, 0.0)),
                               int(reader._input_value(upstream, "operationorder", 0)))
        transform = place if transform is None else compose_affine(transform, place)
    return transform
