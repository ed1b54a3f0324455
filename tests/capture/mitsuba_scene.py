"""A converter from bakery's CaptureScene to an independent renderer, Mitsuba 3 (``pip install -e ".[reference]"``),
for reference tests: meshes become PLY shapes with two-sided diffuse BSDFs (and area emitters where emissive),
RectLights become rectangle area emitters, and irradiance at a probe is measured by an ``irradiancemeter`` on a
tiny rectangle facing each normal. Only what the test scenes use is converted (diffuse materials, rect lights)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _write_ply(path: Path, triangles: np.ndarray) -> None:
    tris = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    lines = ["ply", "format ascii 1.0", f"element vertex {3 * len(tris)}", "property float x", "property float y",
             "property float z", f"element face {len(tris)}", "property list uchar int vertex_indices", "end_header"]
    lines += [f"{x:.9g} {y:.9g} {z:.9g}" for x, y, z in tris.reshape(-1, 3)]
    lines += [f"3 {3 * i} {3 * i + 1} {3 * i + 2}" for i in range(len(tris))]
    path.write_text("\n".join(lines) + "\n")


def _frame(origin, x, y, z):  # noqa: ANN001, ANN202
    import mitsuba as mi

    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, origin
    return mi.ScalarTransform4f(m.tolist())


def scene_dict(scene, folder: Path) -> dict:  # noqa: ANN001 - bakery.capture.scene.CaptureScene
    """A Mitsuba ``load_dict`` description of ``scene`` (PLY files written into ``folder``)."""
    folder.mkdir(parents=True, exist_ok=True)
    result: dict = {"type": "scene", "integrator": {"type": "path", "max_depth": -1, "rr_depth": 8}}
    for i, mesh in enumerate(scene.meshes):
        material = mesh.material
        if material.maps or material.metallic > 0 or (not material.use_specular_workflow) or max(material.specular) > 0:
            raise ValueError(f"{mesh.name}: only untextured, purely diffuse materials are converted")
        ply = folder / f"mesh{i}.ply"
        _write_ply(ply, mesh.triangles)
        shape = {"type": "ply", "filename": str(ply), "face_normals": True,
                 "bsdf": {"type": "twosided", "material": {
                     "type": "diffuse", "reflectance": {"type": "rgb", "value": list(map(float, material.albedo))}}}}
        if max(material.emission) > 0:
            shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": list(material.emission)}}
        result[f"mesh{i}"] = shape
    for i, light in enumerate(scene.lights):
        if light.kind != "rect" or light.shaping or light.texture >= 0:
            raise ValueError(f"{light.name}: only plain RectLights are converted")
        axes = np.asarray(light.axes, dtype=np.float64)
        w, h = light.size
        # Mitsuba's rectangle spans [-1, 1]² in its xy plane and emits towards +z; bakery's emits towards −Z
        to_world = _frame(light.position, axes[0] * w / 2, -axes[1] * h / 2, -axes[2])
        # a light's shape does not reflect (bakery.capture.render: paths end on it); Mitsuba's default BSDF is a
        # diffuse 0.5, so the shape gets a black one
        result[f"light{i}"] = {"type": "rectangle", "to_world": to_world, "emitter": {
            "type": "area", "radiance": {"type": "rgb", "value": list(map(float, light.radiance))}},
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}}
    if scene.dome is not None or scene.portals:
        raise ValueError("domes are not converted")
    return result


def irradiance(scene, folder: Path, position, normals, spp: int = 1 << 16) -> np.ndarray:  # noqa: ANN001
    """E (N, 3) at ``position`` for unit ``normals`` (N, 3), rendered by Mitsuba's path tracer."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    base = scene_dict(scene, folder)
    out = []
    for k, n in enumerate(np.asarray(normals, dtype=np.float64)):
        helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = np.cross(helper, n)
        x /= np.linalg.norm(x)
        y = np.cross(n, x)
        description = dict(base)
        description["meter"] = {
            "type": "rectangle", "to_world": _frame(position, x * 1e-4, y * 1e-4, n),
            "sensor": {"type": "irradiancemeter", "film": {
                "type": "hdrfilm", "width": 1, "height": 1, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                "sampler": {"type": "independent", "sample_count": spp, "seed": 17 + k}}}
        image = mi.render(mi.load_dict(description), spp=spp)
        out.append(np.asarray(image, dtype=np.float64).reshape(-1)[:3])
    return np.array(out)
