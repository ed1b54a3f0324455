"""Bound materials → :class:`bakery.capture.scene.Material` (UsdPreviewSurface and MaterialX), textures as arrays.

Binding
    ``UsdShadeMaterialBindingAPI.ComputeBoundMaterial("full")``: the ``full`` purpose (baking is a full render),
    falling back to the all-purpose binding, with collection bindings and ``bindMaterialAs`` strength as UsdShade
    resolves them.

Surfaces, in order of preference
    1. a MaterialX surface (``outputs:mtlx:surface``) authored as USD shaders (``ND_standard_surface_surfaceshader``,
       ``ND_open_pbr_surface_surfaceshader``, ``ND_UsdPreviewSurface_surfaceshader``);
    2. a ``.mtlx`` document the material references — which the usd-core wheel cannot compose — read with the
       ``MaterialX`` package (:mod:`bakery.usd.mtlx`);
    3. the universal ``UsdPreviewSurface``.
    All map onto the capture's one model (diffuse, emission, metallic, roughness, specular workflow, ior,
    opacity/opacityThreshold, normal maps); what does not fit (clearcoat, transmission, sheen, …) is reported per
    prim. A gprim with no usable material uses its ``displayColor`` (else UsdPreviewSurface's 0.18 grey), read
    per hit when it varies over a Mesh (uniform, vertex, varying or faceVarying interpolation), as Hydra's fallback
    surface does.

Inputs
    Authored values, else the shader's fallbacks. An input connected to a ``UsdUVTexture`` becomes a texture map
    (``Material.maps``) evaluated per ray hit in the capture: ``scale``·texel + ``bias``, ``wrapS``/``wrapT``
    (``useMetadata`` = black, the specification's fallback: bakery reads no wrap metadata from image files),
    ``fallback`` (the node's value where its file is missing or unreadable, with a warning), the output's channels,
    and texture coordinates from the ``UsdPrimvarReader_float2`` on its ``st`` input (any ``varname``; default
    ``st``). The material's constant value for such an input is the texture's mean (for reports, and for the
    inputs the capture reads as constants). UsdTransform2d nodes between the reader and the texture are composed
    into the entry's ``st_transform`` (st' = R(rotation)·(scale ⊙ st) + translation, R counter-clockwise). Where
    the gprim has no such primvar (a Mesh without it, an implicit Sphere, Cube, …) the reader returns its
    ``fallback`` — "fallback value to be returned if geometry fetch failed", default (0, 0) (UsdPreviewSurface
    specification, Primvar Reader) — so the texture is looked up at that constant st: the entry's ``st_fallback``
    (absent: (0, 0)), turned by :func:`read_at_fallback_st` into a constant ``st_transform`` (after the
    UsdTransform2d, with the wrap modes, scale and bias of any lookup) by the scene reader. MaterialX ``texcoord``
    has no fallback input; its output's default is zero (MaterialX Standard Nodes: ``texcoord`` ``out`` default
    "zero"), so images read st (0, 0) there as well. Colour
    inputs connected to a ``UsdPrimvarReader_float3`` read the primvar per hit (a map entry with a ``primvar``: the
    mesh's corner colours, ``Mesh.colors``, interpolated with the hit's barycentrics; the reader's fallback where
    the mesh lacks it); other primvar readers give their fallback (reported).

Input types
    Every input is read with the type the shader's definition declares: Sdr's node for the ``Usd*`` shaders
    (UsdPreviewSurface, UsdUVTexture, UsdTransform2d, UsdPrimvarReader_*), MaterialX's standard library node
    definition for ``ND_*`` shaders (usd-core registers no MaterialX nodes with Sdr). A value of another type —
    ``string inputs:roughness = "rough"``, ``float inputs:diffuseColor = 0.5``, ``string inputs:file`` — is an error
    naming the prim that authored it (a shader, or the material's interface input it is connected to), its authored
    and its expected type; precision and roles aside (a ``double3`` for a ``color3f`` reads the same, as does a
    ``token`` for a ``string``).

Ranges
    UsdPreviewSurface's unit inputs (roughness, metallic, opacity, opacityThreshold, clearcoat, clearcoatRoughness)
    outside [0, 1], negative colours, diffuse and specular colours above 1 and ``ior`` ≤ 0 are reported (a warning
    on the material) and read as the capture always has (:mod:`bakery.capture.surfaces`: roughness, metallic,
    opacity and coat clamped to [0, 1], albedo and F0 to [0, 1], emission to ≥ 0; F0 = 0 for ``ior`` ≤ 0).

Colour
    ``sourceColorSpace`` "sRGB" decodes sRGB; "raw" leaves data alone; "auto" decodes as sRGB what the file's own
    metadata says is sRGB (a PNG ``sRGB`` chunk or ``gAMA`` 1/2.2; ``gAMA`` 1 is linear), else 8-bit 3- and
    4-channel images, and reads everything else as stored (UsdPreviewSurface specification,
    :func:`bakery.usd.color.auto_decodes_srgb`). PNG/TGA colours are straight alpha (read as stored: OpenImageIO's
    ``oiio:UnassociatedAlpha``). A ``colorSpace`` on the file attribute (or inherited from the layer, e.g.
    ``ACEScg``) converts colour inputs into the bake's linear Rec.709 with OpenColorIO (:mod:`bakery.usd.color`);
    data inputs (roughness, metallic, opacity, …) are never colour-converted. Textures larger than
    :data:`MAX_TEXTURE_SIZE` are box-filtered down (the capture mip-maps from there).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path

import numpy as np
from pxr import Ar, Sdf, Sdr, Usd, UsdGeom, UsdShade

from bakery.capture.scene import Material, Texture
from bakery.environment.colour import srgb_to_linear
from bakery.environment.io import read_image
from bakery.errors import ImageError, SceneError
from bakery.usd.assets import local_asset_path
from bakery.usd.color import ColorSpaceError, auto_decodes_srgb, canonical_name, to_working_space
from bakery.usd.values import typed_value

_T = Usd.TimeCode.EarliestTime()
#: Largest texture side kept in the snapshot (larger textures are box-filtered to it).
MAX_TEXTURE_SIZE = 1024


def udim_tile_size(tiles: int) -> int:
    """The side each of ``tiles`` UDIM tiles is box-filtered to: a power of two, so that a whole set holds about as
    many texels as one texture of :data:`MAX_TEXTURE_SIZE` (4 tiles: 512, 16: 256, 100: 64; at least 64) — a
    probe's footprint never needs more, and a set of a hundred 8k tiles would not fit a worker's memory."""
    if tiles <= 1:
        return MAX_TEXTURE_SIZE
    return max(64, 1 << int(np.floor(np.log2(MAX_TEXTURE_SIZE / np.sqrt(tiles)))))

#: UsdPreviewSurface fallbacks of the inputs bakery reads.
PREVIEW_FALLBACKS = {
    "diffuseColor": (0.18, 0.18, 0.18),
    "emissiveColor": (0.0, 0.0, 0.0),
    "roughness": 0.5,
    "metallic": 0.0,
    "specularColor": (0.0, 0.0, 0.0),
    "useSpecularWorkflow": 0,
    "ior": 1.5,
    "opacity": 1.0,
    "opacityThreshold": 0.0,
    "clearcoat": 0.0,
    "clearcoatRoughness": 0.01,
}
COLOR_INPUTS = ("diffuseColor", "emissiveColor", "specularColor")
#: UsdPreviewSurface inputs whose specification range is [0, 1] (module docstring "Ranges")
UNIT_INPUTS = ("roughness", "metallic", "opacity", "opacityThreshold", "clearcoat", "clearcoatRoughness")
#: UsdPreviewSurface inputs the capture does not model (reported when authored away from their fallbacks).
UNMODELLED = {"displacement": 0.0, "occlusion": 1.0}


@dataclass
class Surface:
    """A surface in the capture's model before it becomes a :class:`Material`: per input a constant value, and
    optionally a texture map (a dict as in ``Material.maps``)."""

    values: dict[str, object] = field(default_factory=dict)
    maps: dict[str, dict] = field(default_factory=dict)
    primvar: str | None = None
    notes: list[str] = field(default_factory=list)
    #: the surface it was read from (``UsdPreviewSurface`` natively or as a MaterialX node, or a MaterialX surface
    #: category): UsdPreviewSurface's own rules apply to it alone (the coat's F0 from ``ior``, the metal's F90)
    kind: str = "UsdPreviewSurface"


@dataclass
class MaterialReader:
    """Resolves bound materials of gprims, caching materials and textures.

    ``issues`` collects (severity, prim path, message) tuples; ``textures`` the texture arrays (by index);
    ``files`` every file read (for dependency hashes)."""

    time: Usd.TimeCode = field(default_factory=lambda: _T)
    load_textures: bool = True
    issues: list[tuple[str, str, str]] = field(default_factory=list)
    textures: list[Texture] = field(default_factory=list)
    files: set[str] = field(default_factory=set)
    _materials: dict[str, tuple[Material, bool, str | None]] = field(default_factory=dict)
    _texture_index: dict[tuple[str, str], int | None] = field(default_factory=dict)
    _means: dict[int, np.ndarray] = field(default_factory=dict)

    def material_for(self, gprim: Usd.Prim, display_prim: Usd.Prim | None = None) -> tuple[Material, str | None]:
        """The gprim's material and the name of the primvar its textures read (None if untextured).
        ``display_prim``: the prim whose ``displayColor``/``displayOpacity`` the fallback surface reads (a GeomSubset's
        mesh: the subset binds, the primvars are the mesh's); default ``gprim``."""
        display, varying = _display_color(display_prim or gprim, self.time)
        opacity = _display_opacity(display_prim or gprim, self.time)
        binding = UsdShade.MaterialBindingAPI(gprim)
        material, _rel = binding.ComputeBoundMaterial(UsdShade.Tokens.full)
        if not material:
            targets = _binding_targets(gprim)
            for target in targets:
                mtlx = _materialx_source(gprim.GetStage(), target)
                if mtlx is not None:
                    key = str(target)
                    if key not in self._materials:
                        self._materials[key] = self._read_mtlx_document(key, *mtlx)
                    result, use_display, primvar = self._materials[key]
                    return (_default_material(display, result.name, varying, opacity), None) if use_display else \
                        (result, primvar)
            if targets:
                self._warn_once(str(targets[0]), f"bound material {targets[0]} does not exist; using defaults")
            return _default_material(display, varying=varying, opacity=opacity), None
        key = str(material.GetPath())
        if key not in self._materials:
            self._materials[key] = self._read_material(material)
        result, use_display, primvar = self._materials[key]
        return (_default_material(display, result.name, varying, opacity), None) if use_display else \
            (result, primvar)

    # ------------------------------------------------------------------------------------------------------------
    def _warn_once(self, prim: str, message: str, severity: str = "warning") -> None:
        issue = (severity, prim, message)
        if issue not in self.issues:
            self.issues.append(issue)

    def _read_material(self, material: UsdShade.Material) -> tuple[Material, bool, str | None]:
        path = str(material.GetPath())
        mtlx_shader = None
        output = material.GetSurfaceOutput("mtlx")
        if output and output.GetAttr().IsAuthored():
            for attr in output.GetValueProducingAttributes():
                if UsdShade.Output.IsOutput(attr):
                    mtlx_shader = UsdShade.Shader(attr.GetPrim())
        if mtlx_shader:
            shader_id = mtlx_shader.GetShaderId() or ""
            from bakery.usd.mtlx import surface_from_usd_shader

            surface = surface_from_usd_shader(self, mtlx_shader, shader_id)
            if surface is not None:
                return self._finish(path, surface)
        shader, _name, _type = material.ComputeSurfaceSource()
        if not shader:
            if mtlx_shader:
                self._warn_once(path, f"MaterialX-only material with an unsupported surface "
                                f"{mtlx_shader.GetShaderId()!r}; falling back to displayColor/defaults")
            else:
                self._warn_once(path, "material has no surface shader; falling back to displayColor/defaults")
            return Material(name=path), True, None
        shader_id = shader.GetShaderId() or ""
        if shader_id != "UsdPreviewSurface":
            self._warn_once(path, f"surface shader {shader.GetPath()} is {shader_id or 'untyped'!r}, not "
                            "UsdPreviewSurface; falling back to displayColor/defaults")
            return Material(name=path), True, None
        surface = Surface()
        for name, fallback in PREVIEW_FALLBACKS.items():
            self._preview_input(shader, name, fallback, surface)
        for name, neutral in UNMODELLED.items():
            shader_input = shader.GetInput(name)
            value = self._input_value(shader, name, None)
            if shader_input and (shader_input.HasConnectedSource() or (
                    value is not None and float(np.mean(value)) != neutral)):
                surface.notes.append(f"{name} is not modelled by the capture")
        self._preview_input(shader, "normal", (0.0, 0.0, 1.0), surface)  # a tangent-space normal map
        entry = surface.maps.get("normal")
        index = -1 if entry is None else int(entry["texture"])
        if 0 <= index < len(self.textures) and self.textures[index].color_space == "srgb_texture":
            surface.notes.append("normal map decoded as sRGB (sourceColorSpace sRGB, or auto on an 8-bit file, as "
                                 "UsdUVTexture specifies); normal maps are normally authored 'raw'")
        return self._finish(path, surface)

    def _finish(self, path: str, surface: Surface) -> tuple[Material, bool, str | None]:
        v = {**PREVIEW_FALLBACKS, **surface.values}
        constants = {k: value for k, value in surface.values.items() if k not in surface.maps}
        for note in [*surface.notes, *_range_notes(constants)]:
            self._warn_once(path, note)
        opacity, threshold = float(np.mean(v["opacity"])), float(np.mean(v["opacityThreshold"]))
        maps = []
        for name, entry in surface.maps.items():
            if name in ("clearcoat", "clearcoatRoughness"):  # read as constants: the texture's mean
                self._warn_once(path, f"{name} is textured; its mean {float(np.mean(v[name])):g} is used")
                continue
            maps.append(dict(entry, input=name))
        preview = surface.kind == "UsdPreviewSurface"
        clearcoat_f0 = float(surface.values.get("clearcoat_f0", 0.04))
        ior = float(np.mean(v["ior"]))
        coated = float(np.mean(v["clearcoat"])) > 0
        if preview and coated and ior > 0:  # the spec's ior: "… including the clearcoat if clearcoat > 0"
            f0 = ((1.0 - ior) / (1.0 + ior)) ** 2
            clearcoat_f0 = 0.04 if abs(f0 - 0.04) <= 1e-9 else f0  # the spec's fallback 1.5: exactly 0.04
        material = Material(
            name=path,
            diffuse=_color(v["diffuseColor"]),
            emission=_color(v["emissiveColor"]),
            roughness=float(np.mean(v["roughness"])),
            metallic=float(np.mean(v["metallic"])),
            specular=_color(v["specularColor"]),
            use_specular_workflow=bool(int(np.mean(v["useSpecularWorkflow"]))),
            ior=float(np.mean(v["ior"])),
            opacity=opacity,
            opacity_threshold=threshold,
            maps=tuple(sorted(maps, key=lambda m: m["input"])),
            clearcoat=float(np.clip(np.mean(v["clearcoat"]), 0.0, 1.0)),
            clearcoat_roughness=float(np.clip(np.mean(v["clearcoatRoughness"]), 0.0, 1.0)),
            clearcoat_f0=clearcoat_f0,
            metal_edge_albedo=preview,
            diffuse_roughness=float(surface.values.get("diffuse_roughness", 0.0)),
            diffuse_energy_compensation=bool(surface.values.get("diffuse_energy_compensation", False)),
            sheen=float(surface.values.get("sheen", 0.0)),
            sheen_color=tuple(float(x) for x in surface.values.get("sheen_color", (1.0, 1.0, 1.0))),
            sheen_roughness=float(surface.values.get("sheen_roughness", 0.3)),
            sheen_layer=str(surface.values.get("sheen_layer", "diffuse")),
            sheen_mode=str(surface.values.get("sheen_mode", "conty_kulla")),
            transmission_tint=tuple(float(x) for x in surface.values.get("transmission_tint", (1.0, 1.0, 1.0))),
            specular_tint=tuple(float(x) for x in surface.values.get("specular_tint", (1.0, 1.0, 1.0))),
            specular_edge_tint=(None if surface.values.get("specular_edge_tint") is None else
                                tuple(float(x) for x in surface.values["specular_edge_tint"])),
            coat_tint=tuple(float(x) for x in surface.values.get("coat_tint", (1.0, 1.0, 1.0))),
            dielectric_f90=_optional_color(surface.values.get("dielectric_f90")),
            metal_weight=float(surface.values.get("metal_weight", 1.0)),
            metal_f82=_optional_color(surface.values.get("metal_f82")),
            metal_edge_color=_optional_color(surface.values.get("metal_edge_color")),
            layering=str(surface.values.get("layering", "preview")),
            specular_layer=_optional_color(surface.values.get("specular_layer")),
        )
        numbers = {name: value for name, value in material.__dict__.items() if isinstance(value, float) or (
            isinstance(value, tuple) and value and all(isinstance(x, (int, float)) for x in value))}
        bad = sorted(name for name, value in numbers.items()
                     if not np.all(np.isfinite(np.asarray(value, dtype=np.float64))))
        bad += sorted(f"{entry['input']} map" for entry in maps if not all(
            np.all(np.isfinite(np.asarray(entry.get(key, 0.0), dtype=np.float64))) for key in ("scale", "bias")))
        if bad:  # NaN or ±inf would poison every ray that meets the surface
            self._warn_once(path, f"material inputs are not finite: {', '.join(bad)}; author finite values",
                            severity="error")
        return material, False, surface.primvar if maps else None

    # ------------------------------------------------------------------------------------------------------------
    def _producer(self, shader_input: UsdShade.Input):  # noqa: ANN202
        """(value, upstream shader, output name) at the end of the input's connections (interface inputs followed);
        the value of the type the shader declares for the input, else None and an error (module doc "Input
        types")."""
        attrs = shader_input.GetValueProducingAttributes()
        if attrs and UsdShade.Output.IsOutput(attrs[0]):
            output = UsdShade.Output(attrs[0])
            return None, UsdShade.Shader(output.GetPrim()), output.GetBaseName()
        return self._declared_value(shader_input, attrs[0] if attrs else shader_input.GetAttr()), None, None

    def _declared_value(self, shader_input: UsdShade.Input, attr: Usd.Attribute):  # noqa: ANN202
        """The value of ``attr`` (the end of ``shader_input``'s connections) if it has the type the input's shader
        declares for it; otherwise an error on the prim that authored it, and None (the fallback is used)."""
        shader_id = UsdShade.Shader(shader_input.GetPrim()).GetShaderId() or ""
        expected = declared_input_type(shader_id, shader_input.GetBaseName())
        try:
            return typed_value(attr, self.time, expected)
        except SceneError as error:
            self._warn_once(str(attr.GetPrim().GetPath()), f"{error} (an input of {shader_id or 'a shader'})",
                            severity="error")
            return None

    def _input_value(self, shader: UsdShade.Shader, name: str, fallback):  # noqa: ANN001, ANN202
        """An input's value through its connections to interface inputs (not computed by a shader), else
        ``fallback``."""
        shader_input = shader.GetInput(name)
        value = self._producer(shader_input)[0] if shader_input else None
        return fallback if value is None else value

    def _preview_input(self, shader: UsdShade.Shader, name: str, fallback, surface: Surface) -> None:  # noqa: ANN001
        shader_input = shader.GetInput(name)
        if not shader_input:
            return
        value, upstream, output = self._producer(shader_input)
        if upstream is None:
            if value is not None:
                surface.values[name] = value
            return
        upstream_id = upstream.GetShaderId() or ""
        if upstream_id == "UsdUVTexture":
            entry, mean, primvar = self._uv_texture(upstream, output, name in COLOR_INPUTS)
            if entry is None:  # no file authored: the input's value; a file that cannot be read: the fallback
                if mean is not None:
                    surface.values[name] = mean if np.ndim(fallback) else float(np.mean(mean))
                elif value is not None:
                    surface.values[name] = value
                return
            surface.maps[name] = entry
            surface.values[name] = mean if np.ndim(fallback) else float(np.mean(mean))
            if primvar:
                if surface.primvar and surface.primvar != primvar:
                    surface.notes.append(f"textures read different primvars ({surface.primvar}, {primvar}); "
                                         f"{surface.primvar} is used for all")
                surface.primvar = surface.primvar or primvar
            return
        if upstream_id.startswith("UsdPrimvarReader"):
            fb_value = self._input_value(upstream, "fallback", None)
            if fb_value is not None:
                surface.values[name] = fb_value
            varname = upstream.GetInput("varname")
            primvar = self._producer(varname)[0] if varname else None
            if name in COLOR_INPUTS and upstream_id in ("UsdPrimvarReader_float3", "UsdPrimvarReader_normal",
                                                         "UsdPrimvarReader_point", "UsdPrimvarReader_vector") \
                    and primvar:  # per-vertex colours: read at every hit (the fallback where the mesh lacks them)
                surface.maps[name] = vertex_color_entry(str(primvar))
            else:
                surface.notes.append(f"input {name} reads primvar {primvar!r} through {upstream_id}; the reader's "
                                     "fallback is used (only colour inputs read float3 primvars per hit)")
            return
        self._warn_once(str(shader.GetPath()), f"input {name} is connected to {upstream_id or 'an untyped shader'}, "
                        "which the capture does not evaluate; its value is used")

    def _uv_texture(self, texture: UsdShade.Shader, output: str, is_color: bool):  # noqa: ANN202
        """(map entry, mean value of the output, primvar name) of a UsdUVTexture; (None, the output's ``fallback``,
        None) where it has no file or its file cannot be found or read (UsdPreviewSurface specification: "Fallback
        value used when texture can not be read"; reported)."""
        path = str(texture.GetPath())
        file_input = texture.GetInput("file")
        asset = self._producer(file_input)[0] if file_input else None
        channels = output if output in ("r", "g", "b", "a") else "rgb"
        fallback = _value4(self._input_value(texture, "fallback", None), (0.0, 0.0, 0.0, 1.0))
        fallback_out = (float(fallback[{"r": 0, "g": 1, "b": 2, "a": 3}[channels]]) if channels != "rgb" else
                        fallback[:3].copy())
        if not isinstance(asset, Sdf.AssetPath) or not asset.path:  # "Fallback value to be returned when no
            self._warn_once(path, "UsdUVTexture has no inputs:file; its fallback "  # texture is connected" (Sdr)
                            f"{_shown(fallback_out)} is used")
            return None, fallback_out, None
        udim = "<UDIM>" in asset.path
        tiles = self._udim_tiles(file_input, asset.path) if udim else []
        resolved = tiles[0][1] if udim and tiles else (None if udim else local_asset_path(asset))
        if resolved is None:  # "Fallback value used when texture can not be read" (UsdPreviewSurface specification)
            self._warn_once(path, f"texture {asset.path!r} not found; the UsdUVTexture's fallback "
                            f"{_shown(fallback_out)} is used")
            return None, fallback_out, None
        source_cs = str(self._input_value(texture, "sourceColorSpace", "") or "auto")
        color_space = file_input.GetAttr().GetColorSpace() if file_input else ""
        if not color_space:
            color_space = _inherited_color_space(texture.GetPrim())
        size = udim_tile_size(len(tiles)) if udim else 0
        index = self.texture_index(resolved, source_cs, path, color_space, is_color, size)
        if index is None:  # unreadable (reported by texture_index): the fallback, as for a missing file
            self._warn_once(path, f"the UsdUVTexture's fallback {_shown(fallback_out)} is used for "
                            f"{Path(resolved).name}")
            return None, fallback_out, None
        udim_tiles, texel_mean = (), self._means[index]
        if udim:  # every tile, by its number; the mean over the tiles stands for the whole texture
            indices = [(tile, self.texture_index(file, source_cs, path, color_space, is_color, size))
                       for tile, file in tiles]
            udim_tiles = tuple((tile, i) for tile, i in indices if i is not None)
            texel_mean = np.mean([self._means[i] for _, i in udim_tiles], axis=0)
        scale = _value4(self._input_value(texture, "scale", None), (1.0, 1.0, 1.0, 1.0))
        bias = _value4(self._input_value(texture, "bias", None), (0.0, 0.0, 0.0, 0.0))
        wrap = tuple(_wrap_mode(str(self._input_value(texture, w, "") or "useMetadata")) for w in ("wrapS", "wrapT"))
        mean = texel_mean * scale + bias
        mean_out = float(mean[{"r": 0, "g": 1, "b": 2, "a": 3}[channels]]) if channels != "rgb" else mean[:3]
        primvar = "st"
        st_input = texture.GetInput("st")
        transform = None  # UsdTransform2d nodes between the reader and the texture, composed
        fallback_st = (0.0, 0.0)  # what the reader returns where the gprim has no such primvar
        for _ in range(8):
            if not st_input:
                break
            _value, reader, _out = self._producer(st_input)
            reader_id = (reader.GetShaderId() or "") if reader is not None else ""
            if reader_id == "UsdTransform2d":
                inner = transform2d_affine(self._input_value(reader, "scale", (1.0, 1.0)),
                                           float(self._input_value(reader, "rotation", 0.0)),
                                           self._input_value(reader, "translation", (0.0, 0.0)))
                transform = inner if transform is None else compose_affine(transform, inner)
                st_input = reader.GetInput("in")
                continue
            if reader_id.startswith("UsdPrimvarReader"):
                varname = reader.GetInput("varname")
                name = self._producer(varname)[0] if varname else None
                if name:
                    primvar = str(name)
                fallback_st = _st_value(self._input_value(reader, "fallback", None))
            elif reader is not None:
                self._warn_once(path, f"st is computed by {reader_id or 'an untyped shader'}, which the capture does "
                                "not evaluate; the primvar st is read")
            break
        entry = {"texture": index, "channels": channels, "scale": tuple(map(float, scale)),
                 "bias": tuple(map(float, bias)), "fallback": tuple(map(float, fallback)), "wrap": wrap}
        if transform is not None and transform != IDENTITY_AFFINE:
            entry["st_transform"] = transform
        if fallback_st != (0.0, 0.0):  # read by the scene reader only (module docstring "Inputs")
            entry["st_fallback"] = fallback_st
        if udim_tiles:
            entry["udim"] = udim_tiles
        return entry, mean_out, primvar

    def _udim_tiles(self, file_input: UsdShade.Input, pattern: str) -> list[tuple[int, str]]:
        """The existing tiles (number, file) 1001–1100 of a ``<UDIM>`` path, resolved against the layer that
        authored it (as Hydra's UDIM textures are: the resolver does not expand ``<UDIM>``)."""
        attrs = file_input.GetValueProducingAttributes() if file_input else []
        attr = attrs[0] if attrs else file_input.GetAttr()
        layers = [spec.layer for spec in attr.GetPropertyStack(self.time)] if attr else []
        found = []
        for tile in range(1001, 1101):
            name = pattern.replace("<UDIM>", str(tile))
            for layer in layers[:1]:
                candidate = Sdf.ComputeAssetPathRelativeToLayer(layer, name) if layer else name
                resolved = Ar.GetResolver().Resolve(candidate)
                if resolved and Path(str(resolved)).is_file():
                    found.append((tile, str(resolved)))
        return found

    def texture_index(self, filename: str, source_cs: str, prim: str, color_space: str = "",
                      is_color: bool = True, max_size: int = 0) -> int | None:
        """Index in :attr:`textures` of a file read as linear Rec.709 RGBA (None if unreadable), box-filtered to
        at most ``max_size`` (default :data:`MAX_TEXTURE_SIZE`) texels a side."""
        max_size = int(max_size) or MAX_TEXTURE_SIZE
        key = (filename, f"{source_cs}|{color_space}|{int(is_color)}|{max_size}")
        if key in self._texture_index:
            return self._texture_index[key]
        self.files.add(filename)
        try:
            # UsdPreviewSurface colour inputs are straight alpha ("no pre-multiplication"): a PNG's or TGA's colours
            # as stored (OpenImageIO premultiplies them unless asked not to)
            image = read_image(filename, channels=4, unassociated_alpha=True)
        except ImageError as error:
            self._warn_once(prim, f"texture cannot be read: {error}")
            self._texture_index[key] = None
            return None
        pixels = _rgba(image.pixels.astype(np.float64))
        label = "raw"
        auto_srgb, why = False, ""
        if source_cs == "auto" and not color_space:  # the specification's rule (bakery.usd.color.auto_decodes_srgb)
            auto_srgb, why = auto_decodes_srgb(filename, image.is_8bit, int(image.pixels.shape[2]))
        decode_srgb = source_cs == "sRGB" or (source_cs == "auto" and not color_space and auto_srgb)
        if source_cs == "raw":
            pass
        elif decode_srgb:
            pixels[..., :3] = srgb_to_linear(pixels[..., :3])
            label = "srgb_texture"
        elif is_color and color_space:
            try:
                canonical_name(color_space)
                pixels[..., :3] = to_working_space(pixels[..., :3], color_space)
                label = color_space
            except ColorSpaceError as error:
                self._warn_once(prim, f"{error}; texture read as linear Rec.709")
                label = "lin_rec709"
        elif is_color:
            label = "lin_rec709"
            self._warn_once(prim, f"{Path(filename).name}: no colour-space information ({why}; sourceColorSpace "
                            "auto decodes sRGB only for 8-bit 3- or 4-channel files or an sRGB tag); read as "
                            "linear Rec.709")
        self._means[len(self.textures)] = pixels.reshape(-1, 4).mean(axis=0)
        pixels = _downsample(pixels, max_size)
        self.textures.append(Texture(name=filename, pixels=pixels.astype(np.float32), color_space=label))
        self._texture_index[key] = len(self.textures) - 1
        return len(self.textures) - 1

    def texture_mean(self, index: int) -> np.ndarray:
        return self._means[index]

    def computed_texture(self, pixels: np.ndarray, name: str, is_color: bool) -> int:
        """Index in :attr:`textures` of a texture computed by the reader (a flattened MaterialX graph,
        :mod:`bakery.usd.mtlx_graph`): ``pixels`` (H, W, C ≤ 4) in the working space (colour) or raw (data); one
        channel fills RGB, a missing alpha is 1."""
        pixels = _rgba(np.asarray(pixels, dtype=np.float64))
        self._means[len(self.textures)] = pixels.reshape(-1, 4).mean(axis=0)
        self.textures.append(Texture(name=name, pixels=pixels.astype(np.float32),
                                     color_space="lin_rec709" if is_color else "raw"))
        return len(self.textures) - 1

    # ------------------------------------------------------------------------------------------------------------
    def _read_mtlx_document(self, target: str, document: str, material_name: str) -> tuple[Material, bool, str | None]:
        from bakery.usd.mtlx import MaterialXError, surface_from_document

        self.files.add(document)
        try:
            surface = surface_from_document(self, document, material_name, target)
        except MaterialXError as error:
            self._warn_once(target, f"MaterialX material {material_name!r} in {Path(document).name}: {error}; "
                            "falling back to displayColor/defaults")
            return Material(name=target), True, None
        return self._finish(target, surface)


def _rgba(pixels: np.ndarray) -> np.ndarray:
    c = pixels.shape[2]
    if c == 1:
        return np.concatenate([np.repeat(pixels, 3, axis=2), np.ones_like(pixels)], axis=2)
    if c == 2:
        return np.concatenate([np.repeat(pixels[..., :1], 3, axis=2), pixels[..., 1:2]], axis=2)
    if c == 3:
        return np.concatenate([pixels, np.ones_like(pixels[..., :1])], axis=2)
    return pixels[..., :4].copy()


def _downsample(pixels: np.ndarray, limit: int) -> np.ndarray:
    while max(pixels.shape[:2]) > limit:
        h, w = pixels.shape[:2]
        h2, w2 = max(1, h // 2), max(1, w // 2)
        pixels = pixels[: h2 * 2 if h > 1 else 1, : w2 * 2 if w > 1 else 1]
        pixels = pixels.reshape(h2, -1, w2, pixels.shape[1] // w2, 4).mean(axis=(1, 3))
    return pixels


@cache
def declared_input_type(shader_id: str, name: str) -> Sdf.ValueTypeName | None:
    """The type the definition of shader ``shader_id`` declares for its input ``name`` (module doc "Input types"):
    Sdr's node, else MaterialX's node definition of an ``ND_…`` id; None where neither knows the shader or input."""
    node = Sdr.Registry().GetShaderNodeByIdentifier(shader_id) if shader_id else None
    if node is not None:
        shader_input = node.GetShaderInput(name)
        return shader_input.GetTypeAsSdfType().GetSdfType() if shader_input else None
    if shader_id.startswith("ND_"):
        from bakery.usd.mtlx import nodedef_input_type

        return Sdf.ValueTypeNames.Find(_MTLX_TYPES.get(nodedef_input_type(shader_id, name), "")) or None
    return None


#: MaterialX value types → the USD value types they are authored as in USD (usdMtlx's mapping)
_MTLX_TYPES = {"boolean": "bool", "integer": "int", "float": "float", "color3": "color3f", "color4": "color4f",
               "vector2": "float2", "vector3": "float3", "vector4": "float4", "matrix33": "matrix3d",
               "matrix44": "matrix4d", "string": "string", "filename": "asset", "integerarray": "int[]",
               "floatarray": "float[]", "color3array": "color3f[]", "vector3array": "float3[]"}


def _range_notes(values: dict[str, object]) -> list[str]:
    """Warnings for untextured inputs (by their UsdPreviewSurface names) outside their range, with the clamp the
    capture applies (module doc "Ranges")."""
    notes = []
    for name in UNIT_INPUTS:
        value = values.get(name)
        if value is not None and np.ndim(value) == 0 and not 0.0 <= float(value) <= 1.0:
            notes.append(f"{name} = {float(value):g} is outside [0, 1]; read as {min(max(float(value), 0.0), 1.0):g}")
    for name in COLOR_INPUTS:
        value = values.get(name)
        if value is None or not np.size(value):
            continue
        colour = np.asarray(value, dtype=np.float64).reshape(-1)
        shown = "(" + ", ".join(f"{x:g}" for x in colour) + ")"
        if colour.min() < 0.0:
            notes.append(f"{name} = {shown} has negative components; they are read as 0")
        if name != "emissiveColor" and colour.max() > 1.0:  # a reflectance above 1 would create energy
            notes.append(f"{name} = {shown} has components above 1; they are read as 1")
    ior = values.get("ior")
    if ior is not None and np.ndim(ior) == 0 and float(ior) <= 0.0:
        notes.append(f"ior = {float(ior):g} is not positive; the dielectric reflects nothing (F0 = 0)")
    return notes


def _color(value) -> tuple[float, float, float]:  # noqa: ANN001
    return tuple(float(x) for x in np.broadcast_to(np.asarray(value, dtype=np.float64), 3))


def _optional_color(value) -> tuple[float, float, float] | None:  # noqa: ANN001
    """A colour (3,) of floats, or None (the Material field's default)."""
    return None if value is None else _color(value)


def _value4(value, fallback) -> np.ndarray:  # noqa: ANN001
    """A float4 input's value (4,) float64, ``fallback`` where it has none."""
    return np.asarray(fallback if value is None else value, dtype=np.float64).reshape(-1)[:4]


def _shown(value) -> str:  # noqa: ANN001
    """A scalar or a colour as text: ``0.5`` or ``(0.2, 0.4, 0.6)``."""
    if np.ndim(value) == 0:
        return f"{float(value):g}"
    return "(" + ", ".join(f"{float(x):g}" for x in np.asarray(value).reshape(-1)) + ")"


def _wrap_mode(token: str) -> str:
    """A UsdUVTexture ``wrapS``/``wrapT`` token as the capture's wrap mode. ``useMetadata`` (the fallback) "look[s]
    for wrapS and wrapT metadata in the texture file itself ... If the texture contains no such metadata, then fall
    back to black" (UsdPreviewSurface specification; Hydra Storm: HdWrapNoOpinion → clamp to a black border).
    bakery reads no wrap metadata from files (see docs/capture.md), so ``useMetadata`` — and an unknown token, which
    Hydra also reads as useMetadata — is black."""
    return {"repeat": "repeat", "clamp": "clamp", "mirror": "mirror"}.get(token, "black")


def _inherited_color_space(prim: Usd.Prim) -> str:
    """``colorSpace`` metadata on the prim or its ancestors (UsdShade/UsdColorSpaceAPI style), else ""."""
    while prim and not prim.IsPseudoRoot():
        for key in ("colorSpace",):
            if prim.HasMetadata(key):
                return str(prim.GetMetadata(key))
        attr = prim.GetAttribute("colorSpace:name")
        if attr and attr.HasAuthoredValue():
            return str(attr.Get())
        prim = prim.GetParent()
    layer = prim.GetStage().GetRootLayer() if prim else None
    if layer is not None:
        value = layer.customLayerData.get("colorSpace") if layer.customLayerData else None
        if value:
            return str(value)
    return ""


def _display_color(gprim: Usd.Prim, time: Usd.TimeCode = _T) -> tuple[tuple[float, float, float] | None, bool]:
    """The mean of the gprim's ``displayColor`` (None if not authored) and whether it varies over a Mesh (more
    than one distinct value, not constant interpolation)."""
    primvar = UsdGeom.PrimvarsAPI(gprim).FindPrimvarWithInheritance("displayColor")  # constant ones inherit
    if not primvar or not primvar.HasAuthoredValue():
        return None, False
    value = primvar.ComputeFlattened(time)
    if value is None or len(value) == 0:
        return None, False
    colours = np.asarray(value, dtype=np.float64).reshape(-1, 3)
    varying = (gprim.IsA(UsdGeom.Mesh) and primvar.GetInterpolation() != UsdGeom.Tokens.constant
               and bool(np.any(colours != colours[0])))
    return tuple(float(x) for x in colours.mean(axis=0)), varying


#: The identity of :func:`transform2d_affine` and :func:`compose_affine`: ((a, b, tx), (c, d, ty)).
IDENTITY_AFFINE = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))


def transform2d_affine(scale, rotation: float, translation) -> tuple[tuple[float, float, float], ...]:  # noqa: ANN001
    """UsdTransform2d as an affine map of texture coordinates: st' = R(rotation)·(scale ⊙ st) + translation, R
    counter-clockwise by ``rotation`` degrees about the origin (UsdPreviewSurface specification: "in * scale *
    rotate + translation")."""
    sx, sy = (float(x) for x in scale)
    c, s = np.cos(np.radians(rotation)), np.sin(np.radians(rotation))
    tx, ty = (float(x) for x in translation)
    return ((float(c * sx), float(-s * sy), tx), (float(s * sx), float(c * sy), ty))


def compose_affine(outer, inner) -> tuple[tuple[float, float, float], ...]:  # noqa: ANN001
    """outer ∘ inner of two affine maps ((a, b, tx), (c, d, ty)) (inner applied first)."""
    m = np.vstack([np.asarray(outer, dtype=np.float64), [0.0, 0.0, 1.0]]) @ np.vstack(
        [np.asarray(inner, dtype=np.float64), [0.0, 0.0, 1.0]])
    return tuple(tuple(float(x) for x in row) for row in m[:2])


def _st_value(value) -> tuple[float, float]:  # noqa: ANN001
    """A primvar reader's ``fallback`` as texture coordinates (s, t): its first two components; (0, 0), the
    UsdPrimvarReader_float2 fallback, where it has none or they are not finite."""
    if value is None:
        return (0.0, 0.0)
    numbers = np.asarray(value, dtype=np.float64).reshape(-1)
    if numbers.size < 2 or not np.all(np.isfinite(numbers[:2])):
        return (0.0, 0.0)
    return (float(numbers[0]), float(numbers[1]))


def _reads_st(entry: dict) -> bool:
    """Whether a map entry is a texture looked up at texture coordinates (not a colour primvar read per hit)."""
    return "primvar" not in entry


def without_st_fallbacks(material: Material) -> Material:
    """``material`` for a gprim that has the primvar its textures read: its map entries without ``st_fallback``
    (which only :func:`read_at_fallback_st` uses; the capture never sees it, so the scene's hash is unchanged)."""
    if not any("st_fallback" in entry for entry in material.maps):
        return material
    return replace(material, maps=tuple({k: v for k, v in entry.items() if k != "st_fallback"}
                                        for entry in material.maps))


def read_at_fallback_st(material: Material) -> tuple[Material, str]:
    """``material`` for a gprim without the primvar its textures read, and a description of what is read instead.

    The UsdPreviewSurface specification's ``UsdPrimvarReader_float2``: "fallback value to be returned if geometry
    fetch failed" (default (0, 0)); a ``UsdUVTexture`` fed by it samples the texture at that st (after the
    UsdTransform2d between them, with its wrap modes, scale and bias), everywhere on the gprim. Each texture entry's
    ``st_transform`` becomes the constant map st ↦ T(fallback) (T its own transform; a degenerate map, so the
    footprint — and the level of detail — is zero: the full-resolution texture, bilinearly, as Hydra Storm samples
    a constant st, whose screen-space derivatives vanish). A tangent-space normal map is dropped: it has no tangent
    frame without texture coordinates (Storm's TBN from the st derivatives is then zero and the unperturbed normal
    is shaded). Colour primvars read per hit are kept."""
    maps, readings, dropped = [], {}, False
    for entry in material.maps:
        if not _reads_st(entry):
            maps.append(entry)
            continue
        if entry.get("input") == "normal" and entry.get("space") != "world":
            dropped = True
            continue
        fallback = tuple(float(x) for x in entry.get("st_fallback", (0.0, 0.0)))
        constant = compose_affine(entry.get("st_transform", IDENTITY_AFFINE),
                                  ((0.0, 0.0, fallback[0]), (0.0, 0.0, fallback[1])))
        moved = {k: v for k, v in entry.items() if k != "st_fallback"}
        moved["st_transform"] = constant
        maps.append(moved)
        readings.setdefault(fallback, []).append(str(entry.get("input", "?")))
    texts = []
    if len(readings) == 1:
        texts.append(f"the textures are read at the primvar reader's fallback st {_shown(next(iter(readings)))}")
    elif readings:
        texts.append("the textures are read at their primvar readers' fallback st: " + ", ".join(
            f"{_shown(value)} ({', '.join(inputs)})" for value, inputs in readings.items()))
    if dropped:
        texts.append("the normal map is not applied (no tangent frame without texture coordinates)")
    text = "; ".join(texts)
    return replace(material, maps=tuple(maps)), text


def vertex_color_entry(primvar: str) -> dict:
    """A map entry (``Material.maps``) that reads the colour primvar ``primvar`` at each hit: the mesh's
    ``colors`` interpolated with the hit's barycentrics, times ``scale`` plus ``bias``."""
    return {"primvar": primvar, "scale": (1.0, 1.0, 1.0, 1.0), "bias": (0.0, 0.0, 0.0, 0.0)}


def _display_opacity(gprim: Usd.Prim, time: Usd.TimeCode = _T) -> float:
    """The mean of the gprim's authored ``displayOpacity``, clamped to [0, 1]; 1 when not authored."""
    primvar = UsdGeom.PrimvarsAPI(gprim).FindPrimvarWithInheritance("displayOpacity")
    if not primvar or not primvar.HasAuthoredValue():
        return 1.0
    value = primvar.ComputeFlattened(time)
    values = np.asarray(value if value is not None else [], dtype=np.float64).reshape(-1)
    if values.size == 0 or not np.all(np.isfinite(values)):
        return 1.0
    return float(np.clip(values, 0.0, 1.0).mean())


def _default_material(display: tuple[float, float, float] | None, name: str = "<default>",
                      varying: bool = False, opacity: float = 1.0) -> Material:
    """Hydra's fallback surface: the gprim's ``displayColor`` (its mean; read per hit when it varies over the
    gprim, ``varying``), else UsdPreviewSurface's grey; ``opacity``, the mean ``displayOpacity``, is its presence,
    as hdPrman's fallback material wires ``displayOpacity`` to ``presence``
    (third_party/renderman-*/plugin/hdPrman/rileyFallbackMaterialSceneIndexPlugin.cpp)."""
    if display is None:
        return Material(name=name, opacity=opacity)
    maps = (dict(vertex_color_entry("displayColor"), input="diffuseColor"),) if varying else ()
    return Material(name=name, diffuse=display, maps=maps, opacity=opacity)


def _binding_targets(gprim: Usd.Prim) -> list[Sdf.Path]:
    api = UsdShade.MaterialBindingAPI(gprim)
    targets: list[Sdf.Path] = []
    for purpose in (UsdShade.Tokens.full, UsdShade.Tokens.allPurpose):
        rel = api.GetDirectBindingRel(purpose)
        if rel:
            targets.extend(t for t in rel.GetTargets() if t not in targets)
    return targets


def _materialx_source(stage: Usd.Stage, target: Sdf.Path) -> tuple[str, str] | None:
    """(.mtlx file, material name) for a binding target under a prim that references a ``.mtlx`` document, as
    usdMtlx maps it (materials at ``<root>/Materials/<name>``), or None."""
    for prefix in reversed(target.GetPrefixes()):
        prim = stage.GetPrimAtPath(prefix)
        if not prim:
            continue
        for spec in prim.GetPrimStack():
            for ref in list(spec.referenceList.GetAddedOrExplicitItems()) + list(
                spec.payloadList.GetAddedOrExplicitItems()
            ):
                if not ref.assetPath.lower().endswith(".mtlx"):
                    continue
                layer_dir = Path(spec.layer.realPath or spec.layer.identifier).parent
                document = (layer_dir / ref.assetPath).resolve()
                if not document.is_file():
                    resolved = local_asset_path(Sdf.AssetPath(str(layer_dir / ref.assetPath)))
                    if resolved is None:
                        continue
                    document = Path(resolved)
                relative = target.MakeRelativePath(prefix)
                parts = [p for p in str(relative).split("/") if p and p != "."]
                ref_target = str(ref.primPath) if ref.primPath and not ref.primPath.isEmpty else "/MaterialX"
                full = [p for p in ref_target.split("/") if p] + parts
                return str(document), full[-1]
    return None
