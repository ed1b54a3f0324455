"""Preview renders of spheres lit by a probe (seed 000 Fig. 4 style), through the public store API.

Camera: orthographic, looking down −Z at a unit sphere; every pixel's view vector is v = (0, 0, 1) (towards the
viewer) and its normal n = (x, y, √(1 − x² − y²)). Diffuse sphere (albedo 1): radiance E(n)/π. Chrome (F0 = 1)
and glass (F0 = 0.04) spheres: the specular radiance E(v, n, α, F0) the encoding reconstructs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bakery.report.png import exposure_for, png_data_uri, tone_map


def sphere_geometry(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (M, 3) of the pixels inside the disc and the (size, size) mask."""
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(c, -c)
    r2 = x * x + y * y
    mask = r2 < 1.0
    z = np.sqrt(np.clip(1.0 - r2, 0.0, 1.0))
    normals = np.stack([x, y, z], axis=-1)[mask]
    return normals, mask


def _image(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    img = np.zeros((*mask.shape, 3))
    img[mask] = values
    return img


def render_row(images: dict[str, np.ndarray], mask: np.ndarray, key: str | None) -> dict[str, str]:
    """PNG data URIs of a row of images sharing one exposure (that of ``key``, else the first image)."""
    base = images[key] if key in images else next(iter(images.values()))
    k = exposure_for(base, mask)
    return {label: png_data_uri(tone_map(img, k, mask)) for label, img in images.items()}


def irradiance_previews(store: Any, probe: str, encodings: list[str], reference: Any | None, size: int = 48) -> dict:
    normals, mask = sphere_geometry(size)
    images: dict[str, np.ndarray] = {}
    if reference is not None:
        from bakery.report.quality import reference_irradiance_for

        images["reference"] = _image(reference_irradiance_for(reference, normals) / np.pi, mask)
    for name in encodings:
        images[name] = _image(store.evaluate_irradiance(name, normals, probes=[probe])[0] / np.pi, mask)
    return render_row(images, mask, "reference")


def reflection_previews(store: Any, probe: str, encodings: list[str], reference: Any | None, alpha: float,
                        f0: float, size: int = 48) -> dict:
    normals, mask = sphere_geometry(size)
    view = np.broadcast_to(np.array([0.0, 0.0, 1.0]), normals.shape).copy()
    alphas = np.full(len(normals), alpha)
    f0s = np.full(len(normals), f0)
    images: dict[str, np.ndarray] = {}
    if reference is not None:  # the reference of the per-α figures (bakery.report.quality.reference_reflection)
        from bakery.reflection.reference import reflected_radiance
        from bakery.report.quality import reference_reflection

        e0, e1 = reference_reflection(reference, view, normals, alpha)
        images["reference"] = _image(reflected_radiance(e0, e1, f0s), mask)
    for name in encodings:
        images[name] = _image(store.evaluate_reflection(name, view, normals, alphas, f0s, probes=[probe])[0], mask)
    return render_row(images, mask, "reference")
