"""What each scene probe's result depends on, for incremental bakes (conservative, no ``pxr``).

Global part (affects every probe): meshes (triangles and materials), the dome (texture content, scale,
rotation), distant lights, and every referenced asset's bytes. Any change there re-bakes all probes — geometry
anywhere can occlude, reflect or emit towards any probe.

Per-probe part: the probe's own prim data (kind, position, rotation, resolution, encodings, influence) and the
bytes of its captured image, if any. Moving one probe re-bakes only that probe.

Local lights (sphere, rect, disk) are tracked one by one in a light table stored with the bake
(root attribute ``scene_lights``). When a light is added, removed or changed, a previously baked probe p is
re-baked iff the light's irradiance bound, before or after the change, reaches a fraction τ of the irradiance p
had in the previous bake:

    E_bound(p) = L_max · A / max(d − R, R·10⁻³, 1 mm)²   (L_max: largest radiance channel, A: emitting area,
                                                           d: distance to the light centre, R: bounding radius)
    re-bake p  ⇔  E_bound,old(p) + E_bound,new(p) ≥ τ · Ē_prev(p),   τ = 1/256,

where Ē_prev(p) is p's mean irradiance in the previous bake (luminance of π·f00·Y00 of its stored SH) — the
light changes p's irradiance by at most E_bound,old + E_bound,new anywhere, ignoring occlusion, which can only
over-estimate. Probes with no stored irradiance SH (reflection-only) are re-baked whenever any light changes.
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


def environment_hash(scene, assets: tuple[str, ...] = ()) -> str:  # noqa: ANN001 - bakery.capture.scene.CaptureScene
    """Hash of everything that can affect every probe (module docstring)."""
    parts: list = [(mesh.name, mesh.material.__dict__, np.asarray(mesh.triangles, dtype=np.float32))
                   for mesh in scene.meshes]
    if scene.dome is not None:
        dome = scene.dome
        pixels = np.zeros(0) if dome.pixels is None else np.asarray(dome.pixels, dtype=np.float32)
        parts.append((dome.name, dome.scale, dome.rotation, dome.layout, pixels))
    parts += [light.__dict__ for light in scene.lights if light.kind == "distant"]
    parts += [file_digest(asset) for asset in sorted(set(assets))]
    parts.append((scene.meters_per_unit, scene.up_axis))
    return stable_hash(*parts)


def light_table(scene) -> list[dict]:  # noqa: ANN001
    """Local lights as JSON-able records: name, hash, centre, bounding radius and radiance × area."""
    table = []
    for light in scene.lights:
        if light.kind == "distant":
            continue
        if light.kind == "rect":
            radius = 0.5 * sqrt(light.size[0] ** 2 + light.size[1] ** 2)
        else:
            radius = float(light.size[0])
        power = float(max(light.radiance)) * light.area
        table.append({"name": light.name, "hash": stable_hash(light.__dict__), "position": list(map(float, light.position)),
                      "radius": float(radius), "power": power})
    return sorted(table, key=lambda r: r["name"])


def irradiance_bound(record: dict, positions: np.ndarray) -> np.ndarray:
    """E_bound (P,) of a light-table record at probe positions (P, 3) (module docstring)."""
    d = np.linalg.norm(positions - np.asarray(record["position"]), axis=1)
    radius = record["radius"]
    gap = np.maximum(d - radius, max(radius * 1e-3, 1e-3))
    return record["power"] / gap**2


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
    """Names of probes a light change can affect, and the names of the changed lights."""
    old = {r["name"]: r for r in old_table}
    new = {r["name"]: r for r in new_table}
    changed = sorted(n for n in set(old) | set(new) if old.get(n, {}).get("hash") != new.get(n, {}).get("hash"))
    affected: set[str] = set()
    if not changed:
        return affected, changed
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    bound = np.zeros(len(names))
    for light in changed:
        for record in (old.get(light), new.get(light)):
            if record is not None:
                bound += irradiance_bound(record, positions)
    unknown = ~np.isfinite(previous_irradiance)
    hit = unknown | (bound >= fraction * np.where(unknown, 0.0, previous_irradiance))
    affected = {n for n, h in zip(names, hit) if h}
    return affected, changed
