"""UsdPreviewSurface → :class:`bakery.capture.scene.Material` (diffuse, emission, roughness, metallic).

Inputs are read as authored, else UsdPreviewSurface's fallbacks (diffuseColor 0.18, emissiveColor 0, roughness 0.5,
metallic 0). An input connected to a ``UsdUVTexture`` takes the texture's mean (scale · mean + bias, the connected
output's channels), decoding sRGB-encoded 8-bit images to linear first; an input connected to a
``UsdPrimvarReader`` takes the mean of the gprim's primvar (e.g. ``displayColor``). A missing texture falls back to
the input's authored value or fallback, with a warning. Materials with no universal (UsdPreviewSurface) surface but
a MaterialX one, or bindings to MaterialX materials that could not be composed (the usd-core wheel reads no
``.mtlx``), warn and fall back to the gprim's ``displayColor`` or the defaults.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade

from bakery.capture.scene import Material
from bakery.environment.io import read_image
from bakery.errors import ImageError
from bakery.usd.assets import local_asset_path

_T = Usd.TimeCode.EarliestTime()

#: UsdPreviewSurface fallbacks of the inputs bakery reads.
PREVIEW_FALLBACKS = {
    "diffuseColor": (0.18, 0.18, 0.18),
    "emissiveColor": (0.0, 0.0, 0.0),
    "roughness": 0.5,
    "metallic": 0.0,
}


@dataclass
class MaterialReader:
    """Resolves bound materials of gprims, caching materials and texture means.

    ``issues`` collects (severity, prim path, message) tuples for the caller.
    """

    issues: list[tuple[str, str, str]] = field(default_factory=list)
    _materials: dict[str, tuple[Material, bool]] = field(default_factory=dict)
    _textures: dict[str, np.ndarray | None] = field(default_factory=dict)

    def material_for(self, gprim: Usd.Prim) -> Material:
        display = _display_color(gprim)
        binding = UsdShade.MaterialBindingAPI(gprim)
        material, _rel = binding.ComputeBoundMaterial()
        if not material:
            targets = _binding_targets(gprim)
            if targets:
                target = targets[0]
                if _is_materialx_target(gprim.GetStage(), target):
                    self._warn_once(str(target), f"material {target} is MaterialX-only (its .mtlx could not be "
                                    "read); falling back to displayColor/defaults")
                else:
                    self._warn_once(str(target), f"bound material {target} does not exist; using defaults")
            return _default_material(display)
        key = str(material.GetPath())
        if key not in self._materials:
            self._materials[key] = self._read_material(material)
        result, use_display = self._materials[key]
        return _default_material(display, name=result.name) if use_display else result

    # ------------------------------------------------------------------------------------------------------------
    def _warn_once(self, prim: str, message: str) -> None:
        issue = ("warning", prim, message)
        if issue not in self.issues:
            self.issues.append(issue)

    def _read_material(self, material: UsdShade.Material) -> tuple[Material, bool]:
        path = str(material.GetPath())
        shader, _name, _type = material.ComputeSurfaceSource()
        if not shader:
            mtlx, _, _ = material.ComputeSurfaceSource("mtlx")
            if mtlx:
                self._warn_once(path, "MaterialX-only material (no UsdPreviewSurface); falling back to "
                                "displayColor/defaults")
            else:
                self._warn_once(path, "material has no surface shader; falling back to displayColor/defaults")
            return Material(name=path), True
        shader_id = shader.GetShaderId() or ""
        if shader_id != "UsdPreviewSurface":
            self._warn_once(path, f"surface shader {shader.GetPath()} is {shader_id or 'untyped'!r}, not "
                            "UsdPreviewSurface; falling back to displayColor/defaults")
            return Material(name=path), True
        values = {name: self._input_value(shader, name, fallback) for name, fallback in PREVIEW_FALLBACKS.items()}
        return (
            Material(
                name=path,
                diffuse=tuple(float(x) for x in np.broadcast_to(values["diffuseColor"], 3)),
                emission=tuple(float(x) for x in np.broadcast_to(values["emissiveColor"], 3)),
                roughness=float(np.mean(values["roughness"])),
                metallic=float(np.mean(values["metallic"])),
            ),
            False,
        )

    def _input_value(self, shader: UsdShade.Shader, name: str, fallback):
        shader_input = shader.GetInput(name)
        fallback_arr = np.asarray(fallback, dtype=np.float64)
        if not shader_input:
            return fallback_arr
        authored = shader_input.Get(_T)
        base = fallback_arr if authored is None else np.asarray(authored, dtype=np.float64)
        if not shader_input.HasConnectedSource():
            return base
        sources = shader_input.GetConnectedSources()[0]
        if not sources:
            return base
        source = sources[0]
        upstream = UsdShade.Shader(source.source.GetPrim())
        upstream_id = upstream.GetShaderId() or "" if upstream else ""
        output = str(source.sourceName)
        if upstream_id == "UsdUVTexture":
            mean = self._texture_mean(upstream, output)
            if mean is None:
                return base
            return mean if fallback_arr.ndim else np.asarray(mean).mean()
        # Constant inputs passed through (e.g. a material interface input) or primvar readers: use the authored
        # upstream value if any, else the base value.
        value = upstream.GetInput("fallback").Get(_T) if upstream and upstream.GetInput("fallback") else None
        return base if value is None else np.asarray(value, dtype=np.float64)

    def _texture_mean(self, texture: UsdShade.Shader, output: str) -> np.ndarray | float | None:
        file_input = texture.GetInput("file")
        asset = file_input.Get(_T) if file_input else None
        path = str(texture.GetPath())
        if not isinstance(asset, Sdf.AssetPath) or not asset.path:
            self._warn_once(path, "UsdUVTexture has no inputs:file; using the input's value")
            return None
        resolved = local_asset_path(asset)
        if resolved is None:
            self._warn_once(path, f"texture {asset.path!r} not found; using the input's value")
            return None
        color_space = str(texture.GetInput("sourceColorSpace").Get(_T) or "auto") if texture.GetInput(
            "sourceColorSpace") else "auto"
        rgba = self._read_mean(resolved, color_space, path)
        if rgba is None:
            return None
        scale = _input4(texture, "scale", (1.0, 1.0, 1.0, 1.0))
        bias = _input4(texture, "bias", (0.0, 0.0, 0.0, 0.0))
        rgba = rgba * scale + bias
        channels = {"r": 0, "g": 1, "b": 2, "a": 3}
        if output in channels:
            return float(rgba[channels[output]])
        return rgba[:3]

    def _read_mean(self, filename: str, color_space: str, prim: str) -> np.ndarray | None:
        key = f"{filename}|{color_space}"
        if key in self._textures:
            return self._textures[key]
        try:
            image = read_image(filename, channels=4)
        except ImageError as error:
            self._warn_once(prim, f"texture cannot be read: {error}")
            self._textures[key] = None
            return None
        pixels, is_8bit = image.pixels.astype(np.float64), image.is_8bit
        c = pixels.shape[2]
        if c == 1:
            pixels = np.concatenate([np.repeat(pixels, 3, axis=2), np.ones_like(pixels)], axis=2)
        elif c == 2:
            pixels = np.concatenate([np.repeat(pixels[..., :1], 3, axis=2), pixels[..., 1:2]], axis=2)
        elif c == 3:
            pixels = np.concatenate([pixels, np.ones_like(pixels[..., :1])], axis=2)
        if color_space == "sRGB" or (color_space == "auto" and is_8bit):
            pixels[..., :3] = srgb_to_linear(pixels[..., :3])
        mean = pixels.reshape(-1, 4).mean(axis=0)
        self._textures[key] = mean
        return mean


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding of values in [0, 1]."""
    values = np.asarray(values)
    return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4)


def _input4(shader: UsdShade.Shader, name: str, fallback) -> np.ndarray:
    shader_input = shader.GetInput(name)
    value = shader_input.Get(_T) if shader_input else None
    return np.asarray(fallback if value is None else value, dtype=np.float64)


def _display_color(gprim: Usd.Prim) -> tuple[float, float, float] | None:
    primvar = UsdGeom.PrimvarsAPI(gprim).GetPrimvar("displayColor")
    if not primvar or not primvar.HasAuthoredValue():
        return None
    value = primvar.ComputeFlattened(_T)
    if value is None or len(value) == 0:
        return None
    return tuple(float(x) for x in np.asarray(value, dtype=np.float64).reshape(-1, 3).mean(axis=0))


def _default_material(display: tuple[float, float, float] | None, name: str = "<default>") -> Material:
    if display is None:
        return Material(name=name)
    return Material(name=name, diffuse=display)


def _binding_targets(gprim: Usd.Prim) -> list[Sdf.Path]:
    rel = UsdShade.MaterialBindingAPI(gprim).GetDirectBindingRel()
    return list(rel.GetTargets()) if rel else []


def _is_materialx_target(stage: Usd.Stage, target: Sdf.Path) -> bool:
    """Whether a missing binding target sits under a prim whose composition failed on a ``.mtlx`` asset."""
    prefixes = {str(p) for p in target.GetPrefixes()}
    for error in stage.GetCompositionErrors():
        text = str(error)
        if ".mtlx" not in text:
            continue
        if any(f"<{p}>" in text or f"{p}>" in text for p in prefixes):
            return True
    # The binding points into a prim that references a .mtlx file.
    for prefix in target.GetPrefixes():
        prim = stage.GetPrimAtPath(prefix)
        if not prim:
            continue
        for spec in prim.GetPrimStack():
            for ref in list(spec.referenceList.GetAddedOrExplicitItems()) + list(
                spec.payloadList.GetAddedOrExplicitItems()
            ):
                if ref.assetPath.lower().endswith(".mtlx"):
                    return True
    return False
