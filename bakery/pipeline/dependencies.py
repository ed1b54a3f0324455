"""What each scene probe's result depends on, for incremental bakes (conservative, no ``pxr``).

Global part (affects every probe): meshes (triangles, materials, shading normals and a front side other than the
winding's), the dome (texture content, scale, rotation), distant lights, the texels of every texture the capture
samples (``CaptureScene.textures``, in the order materials and lights index them), every referenced asset's bytes
and the capture's model version (:data:`bakery.capture.render.CAPTURE_MODEL_VERSION`). Any change there re-bakes all
probes — geometry anywhere can occlude, reflect or emit towards any probe.

The texels are hashed as the capture reads them, not only the files they come from: a material map refers to its
texture by index and carries only the texture's mean, so two materials that swap textures of equal means, a changed
``colorSpace`` of a texture whose mean it keeps, or a changed constant of a MaterialX graph authored in USD that is
flattened into a texture (:mod:`bakery.usd.mtlx_graph`) changed no file and no hashed field — every probe was
reused stale until 2026-12-07 (stores of scenes with textures re-bake once).

Per-probe part: the probe's own prim data (kind, position, rotation, resolution, encodings, influence) and the
bytes of its captured image, if any. Moving one probe re-bakes only that probe.

Local lights (sphere, rect, disk, cylinder) are tracked one by one in a light table stored with the bake
(root attribute ``scene_lights``, and per bake in ``/history/scene_lights``): name, hash, centre, bounding radius R,
emitting area A, radiance L (RGB, times the largest texel of a light texture, the largest factor of an IES
profile and the larger of 1 and the light's diffuse/specular multipliers), ``power`` = max_c L_c · A and a
``geometry`` hash of everything but the radiance (kind, position, orientation, size, visibility, shaping, IES
profile, texture, multipliers, shadows). A reused probe is compared with the table of the bake that produced it
(so repeated small edits cannot accumulate unnoticed). When lights are added, removed or changed, a previously baked probe p is re-baked unless
one of two sufficient conditions shows that its irradiance cannot have changed by τ = 1/256:

    (a) relative:  every changed light kept its geometry and  r = max over lights and channels of
                   |L_new,c − L_old,c| / L_old,c  < τ.
                   Light transport is linear in the emitted radiance and every light's contribution is ≥ 0, so
                   |ΔE(n)| ≤ r · E(n) < τ · E(n) in every direction n (a +0.17 % intensity edit re-bakes nothing).
    (b) absolute:  ΔE_bound(p) < τ · Ē_prev(p), with
                   E_bound(p, P) = P / max(d − R, R·10⁻³, 1 mm)²   (d: distance from p to the light centre;
                                                                    E ≤ L·Ω ≤ L·A/gap², ignoring occlusion)
                   ΔE_bound(p) = Σ over changed lights of  E_bound(p, max_c |L_new,c − L_old,c| · A)  (same
                                 geometry: only the emission changed)  or  E_bound(p, P_old) + E_bound(p, P_new)
                                 (moved, resized, reshaped, added, removed)

where Ē_prev(p) is p's mean irradiance in the previous bake (luminance of π·f00·Y00 of its stored SH). A reused
probe therefore differs from a fresh bake by less than τ · max(E(n), Ē_prev) in every direction (checked against
renders in ``tests/faults/test_incremental_delta.py``). Occlusion is ignored, which only over-estimates; so does
the total area A for a sphere (its projected area is A/4), a margin the captures need: a small light covers few
cube texels, and a capture's estimate of its irradiance was measured up to 2× the analytic L·πR²/d². Tables
written before ``geometry`` was recorded fall back to the old + new bound. Probes with no stored irradiance SH
(reflection-only) are re-baked whenever a light changes, unless (a) holds.

Many lights: above ``ENUMERATED_LIGHTS`` non-distant lights the capture draws its next-event lights from per-region
distributions (a light grid, the BVH outside it) whose probabilities follow the lights' power and places
(:mod:`bakery.capture.light_tree`); the sampling enters the global part (its version, the threshold and the draws per vertex), so crossing the threshold re-bakes every
probe. Between such scenes, an edit changes the draws of every probe, so a reused probe and a fresh bake of it are
two estimates that differ by their noise (``/diagnostics/capture/sh_noise``) as well as by the bounds above: the
guarantee holds for the expected capture, not bit for bit as it does with enumerated lights. Scenes with visible
light shapes hash the version of the small-light splat (those shapes that look small from a probe are sampled
from it, :mod:`bakery.capture.render` "Small lights"), so they re-bake once when it changes; scenes without keep
their hash.
"""

from __future__ import annotations

from math import pi, sqrt

import numpy as np

from bakery.conventions import LUMINANCE_WEIGHTS
from bakery.encodings import ENCODINGS
from bakery.files import sha256_file, stable_hash

#: τ: a light whose change stays below 1/256 of a probe's irradiance cannot change its 8-bit output.
LIGHT_INFLUENCE_FRACTION = 1.0 / 256.0


def file_digest(path: str) -> str:
    """sha256 of a file's bytes, or a fixed marker if it cannot be read (its absence is then part of the hash)."""
    try:
        return sha256_file(path)
    except OSError:
        return "<unreadable>"


#: Version of the capture's treatment of emissive triangles as lights (next-event sampling, the last vertex lit by
#: them; hashed only for scenes that emit: any other scene keeps its hash)
EMITTER_SAMPLING_VERSION = 1


#: Version of the capture's splat of light shapes that look small from a probe (:meth:`bakery.capture.render.
#: ProbeRenderer._add_small_lights`; hashed only for scenes with visible light shapes)
SMALL_LIGHT_SPLAT_VERSION = 1

#: Version of the capture's many-lights sampling (the light grid's draws, the BVH's outside it,
#: :mod:`bakery.capture.light_tree`; hashed only for scenes with more than ENUMERATED_LIGHTS non-distant lights: any
#: other scene keeps its hash). 2: per-cell distributions (:class:`~bakery.capture.light_tree.LightGrid`).
LIGHT_SAMPLING_VERSION = 2


def environment_hash(scene, assets: tuple[str, ...] = ()) -> str:  # noqa: ANN001 - bakery.capture.scene.CaptureScene
    """Hash of everything that can affect every probe (module docstring)."""
    from bakery.capture.light_tree import light_sampling
    from bakery.capture.render import SPLAT_LIGHT_GRID, SPLAT_LIGHT_TEXELS
    from bakery.capture.lights import light_model
    from bakery.capture.render import CAPTURE_MODEL_VERSION
    from bakery.environment.resample import RESAMPLE_MODEL_VERSION

    parts: list = [(mesh.name, _material_fields(mesh.material), np.asarray(mesh.triangles, dtype=np.float32),
                    None if getattr(mesh, "uvs", None) is None else np.asarray(mesh.uvs, dtype=np.float32))
                   # shading normals only when authored (the hash of a scene without them is unchanged)
                   + (() if getattr(mesh, "normals", None) is None else (np.asarray(mesh.normals, np.float32),))
                   + (() if getattr(mesh, "colors", None) is None else (("colors", np.asarray(mesh.colors, np.float32)),))
                   # the front side only when not the winding's (USD's fallback): it changes a probe's diagnostics
                   + (() if getattr(mesh, "front", 1) == 1 else (("front", int(mesh.front)),))
                   for mesh in scene.meshes]
    if scene.dome is not None:
        dome = scene.dome
        pixels = np.zeros(0) if dome.pixels is None else np.asarray(dome.pixels, dtype=np.float32)
        response = (getattr(dome, "diffuse", 1.0), getattr(dome, "specular", 1.0))
        links, casters = getattr(dome, "links", None), getattr(dome, "shadow_links", None)
        parts.append((dome.name, dome.scale, dome.rotation, dome.layout, pixels)  # the later fields only when authored
                     + (() if response == (1.0, 1.0) else (response,)) + (() if links is None else (("links", links),))
                     + (() if casters is None else (("shadow_links", casters),))
                     + (() if (getattr(dome, "shadow", True), tuple(getattr(dome, "shadow_color", (0.0,) * 3)))
                        == (True, (0.0, 0.0, 0.0)) else (("shadow", dome.shadow, tuple(dome.shadow_color)),))
                     + (() if getattr(dome, "shadow_distance", -1.0) <= 0 else (
                        ("shadow_distance", dome.shadow_distance, dome.shadow_falloff, dome.shadow_falloff_gamma),))
                     # a latlong dome is sampled as it is; every other layout is resampled to a cube first
                     + (() if dome.layout == "equirect" else (("resample", RESAMPLE_MODEL_VERSION),)))
    parts += [_light_fields(light) for light in scene.lights if light_model(light).is_global]
    parts += [_light_fields(portal) for portal in getattr(scene, "portals", ())]
    parts.append((getattr(scene, "time_code", None), getattr(scene, "working_space", "lin_rec709")))
    if any(mesh.material.emits for mesh in scene.meshes):  # emissive triangles as lights (bakery.capture.emitters)
        parts.append(("emitter_sampling", EMITTER_SAMPLING_VERSION))
    sampling = light_sampling([light.kind for light in scene.lights])
    if sampling["drawn"]:  # next-event lights drawn from the light grid
        parts.append(("light_sampling", LIGHT_SAMPLING_VERSION, sampling["enumerated_up_to"],
                      sampling["draws_per_vertex"]))
    if any(light.visible and light.kind != "distant" for light in scene.lights):  # small shapes are splatted
        parts.append(("small_light_splat", SMALL_LIGHT_SPLAT_VERSION, SPLAT_LIGHT_TEXELS, SPLAT_LIGHT_GRID))
    textures = getattr(scene, "textures", ())
    if textures:  # what the capture samples, in the order materials and lights index them (module docstring)
        parts.append(("textures", [np.asarray(texture.pixels, dtype=np.float32) for texture in textures]))
    parts += [file_digest(asset) for asset in sorted(set(assets))]
    parts.append((scene.meters_per_unit, scene.up_axis))
    parts.append(("capture model", CAPTURE_MODEL_VERSION))  # what the same scene captures to
    return stable_hash(*parts)


def _material_fields(material) -> dict:  # noqa: ANN001 - bakery.capture.scene.Material
    """A material's fields for hashing, the clearcoat and the tints only when the material has them (as
    :func:`_light_fields`)."""
    fields = dict(material.__dict__)
    if fields.get("clearcoat", 0.0) == 0.0:
        fields.pop("clearcoat", None)
        fields.pop("clearcoat_roughness", None)
        fields.pop("clearcoat_f0", None)
    if fields.get("clearcoat_f0", 0.04) == 0.04:
        fields.pop("clearcoat_f0", None)
    if fields.get("diffuse_roughness", 0.0) == 0.0:
        fields.pop("diffuse_roughness", None)
        fields.pop("diffuse_energy_compensation", None)
    if fields.get("sheen", 0.0) == 0.0:
        for name in ("sheen", "sheen_color", "sheen_roughness", "sheen_layer", "sheen_mode"):
            fields.pop(name, None)
    for name, fallback in (("sheen_layer", "diffuse"), ("sheen_mode", "conty_kulla")):
        if fields.get(name, fallback) == fallback:
            fields.pop(name, None)
    if fields.get("specular_edge_tint") is None:
        fields.pop("specular_edge_tint", None)
    for tint in ("transmission_tint", "specular_tint", "coat_tint"):
        if tuple(fields.get(tint, (1.0, 1.0, 1.0))) == (1.0, 1.0, 1.0):
            fields.pop(tint, None)
    for name in ("dielectric_f90", "metal_f82", "metal_edge_color"):  # MaterialX's explicit Fresnel terms
        if fields.get(name) is None:
            fields.pop(name, None)
    if fields.get("metal_weight", 1.0) == 1.0:
        fields.pop("metal_weight", None)
    if fields.get("layering", "preview") == "preview":  # UsdPreviewSurface's lobe combination (hashes as before)
        fields.pop("layering", None)
    if fields.get("specular_layer") is None:
        fields.pop("specular_layer", None)
    return fields


def _light_fields(light) -> dict:  # noqa: ANN001 - bakery.capture.scene.Light
    """A light's fields for hashing, the later ones only when not at their defaults (so the hashes of lights
    without them are those of the bakes before they were read)."""
    fields = dict(light.__dict__)
    for name, default in _LIGHT_DEFAULTS.items():
        if name in fields and fields[name] == default:
            del fields[name]
    return fields


#: Light fields hashed only when they differ from these (the fields added after the light table's first format)
_LIGHT_DEFAULTS = {"ies": None, "diffuse": 1.0, "specular": 1.0, "shadow": True, "shadow_color": (0.0, 0.0, 0.0),
                   "links": None, "shadow_links": None, "shadow_distance": -1.0, "shadow_falloff": -1.0,
                   "shadow_falloff_gamma": 1.0}


def _texture_peak(scene, light) -> float:  # noqa: ANN001
    """Largest RGB texel of a light's texture (1 without one): the radiance bound multiplies it."""
    index = getattr(light, "texture", -1)
    textures = getattr(scene, "textures", ())
    if index is None or index < 0 or index >= len(textures):
        return 1.0
    pixels = np.asarray(textures[index].pixels, dtype=np.float64)
    return float(max(np.max(pixels[..., :3]), 0.0)) if pixels.size else 1.0


def light_table(scene) -> list[dict]:  # noqa: ANN001
    """Local lights as JSON-able records (module docstring): name, hash, geometry hash, centre, bounding radius,
    area, radiance (RGB) and power = max radiance × area."""
    from bakery.capture.lights import light_model

    table = []
    for light in scene.lights:
        model = light_model(light)  # the light kind's class: global or local, bounding radius
        if model.is_global:
            continue
        radius = model.bounding_radius
        ies = getattr(light, "ies", None)
        peak = _texture_peak(scene, light) * (1.0 if ies is None else ies.peak)  # the largest radiance factor
        peak *= max(1.0, float(getattr(light, "diffuse", 1.0)), float(getattr(light, "specular", 1.0)))
        radiance = [float(c) * peak for c in light.radiance]
        fields = _light_fields(light)
        geometry = {k: v for k, v in fields.items() if k not in ("name", "radiance")}
        table.append({"name": light.name, "hash": stable_hash(fields), "geometry": stable_hash(geometry),
                      "position": list(map(float, light.position)), "radius": float(radius),
                      "area": float(light.area), "radiance": radiance,
                      "power": float(max(radiance)) * float(light.area)})
    return sorted(table, key=lambda r: r["name"])


def irradiance_bound(record: dict, positions: np.ndarray, power: float | None = None) -> np.ndarray:
    """E_bound (P,) of a light-table record at probe positions (P, 3) for ``power`` (default: the record's)."""
    d = np.linalg.norm(positions - np.asarray(record["position"]), axis=1)
    radius = record["radius"]
    gap = np.maximum(d - radius, max(radius * 1e-3, 1e-3))
    return (record["power"] if power is None else power) / gap**2


def change_bound(old: dict | None, new: dict | None, positions: np.ndarray) -> np.ndarray:
    """ΔE_bound (P,) of one light's change from ``old`` to ``new`` (either None: added/removed; module doc)."""
    if _same_geometry(old, new) and "area" in new:
        delta = max(abs(a - b) for a, b in zip(new["radiance"], old["radiance"]))
        return irradiance_bound(new, positions, delta * new["area"])
    bound = np.zeros(len(positions))
    for record in (old, new):
        if record is not None:
            bound += irradiance_bound(record, positions)
    return bound


def _same_geometry(old: dict | None, new: dict | None) -> bool:
    return (old is not None and new is not None and old.get("geometry") is not None
            and old.get("geometry") == new.get("geometry") and "radiance" in old and "radiance" in new)


def relative_emission_change(old_table: list[dict], new_table: list[dict]) -> float:
    """r of condition (a) (module docstring): the largest relative change of any channel of any changed light's
    radiance, or ``inf`` if a light was added, removed or changed its geometry (or was black in a channel)."""
    old = {r["name"]: r for r in old_table}
    new = {r["name"]: r for r in new_table}
    worst = 0.0
    for name in set(old) | set(new):
        before, after = old.get(name), new.get(name)
        if before is not None and after is not None and before.get("hash") == after.get("hash"):
            continue
        if not _same_geometry(before, after):
            return float("inf")
        for a, b in zip(after["radiance"], before["radiance"]):
            if a != b:
                worst = max(worst, abs(a - b) / b if b > 0 else float("inf"))
    return worst


def mean_irradiance_from_store(previous, names: list[str]) -> np.ndarray:  # noqa: ANN001 - StoreContents
    """Ē_prev (P,) per probe name from any stored encoding with a float radiance SH field
    (``Encoding.radiance_sh_field``); NaN where none is stored."""
    out = np.full(len(names), np.nan)
    index = {n: i for i, n in enumerate(previous.probe_names)}
    for name, encoding in ENCODINGS.items():
        entry = previous.encodings.get(name)
        if entry is None or encoding.radiance_sh_field is None:
            continue
        rows = {int(p): r for r, p in enumerate(entry["fields"]["probe_index"])}
        sh = entry["fields"][encoding.radiance_sh_field]
        for k, probe in enumerate(names):
            i = index.get(probe)
            if i is not None and i in rows and np.isnan(out[k]):
                f00 = np.asarray(sh[rows[i], 0], dtype=np.float64)
                out[k] = float(pi * f00 / (2.0 * sqrt(pi)) @ LUMINANCE_WEIGHTS)
    return out


def probes_affected_by_light_changes(
    old_table: list[dict], new_table: list[dict], names: list[str], positions: np.ndarray, previous_irradiance: np.ndarray,
    fraction: float = LIGHT_INFLUENCE_FRACTION,
) -> tuple[set[str], list[str]]:
    """Names of probes a light change can affect (conditions (a) and (b) of the module docstring), and the names
    of the changed lights."""
    old = {r["name"]: r for r in old_table}
    new = {r["name"]: r for r in new_table}
    changed = sorted(n for n in set(old) | set(new) if old.get(n, {}).get("hash") != new.get(n, {}).get("hash"))
    affected: set[str] = set()
    if not changed or relative_emission_change(old_table, new_table) < fraction:
        return affected, changed
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    bound = np.zeros(len(names))
    for light in changed:
        bound += change_bound(old.get(light), new.get(light), positions)
    unknown = ~np.isfinite(previous_irradiance)
    hit = unknown | (bound >= fraction * np.where(unknown, 0.0, previous_irradiance))
    affected = {n for n, h in zip(names, hit) if h}
    return affected, changed
