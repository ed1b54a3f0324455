"""Probes that reference a captured environment image: load it and orient it by the probe's transform.

The image is in the probe's local frame (its latlong/cube/angular layout as in :mod:`bakery.conventions`); a bake
direction ω reads the image at Rᵀω, R the probe-local → bake rotation. The image is first resampled to a cube of
twice the bake face size (area-weighted, :func:`bakery.environment.resample_to_cube`), then looked up bilinearly
at the rotated texel centres, which skips the rotation entirely when R is the identity.
"""

from __future__ import annotations

import numpy as np

from bakery.environment import resample_to_cube
from bakery.environment.io import read_environment
from bakery.sphere.cubemap import cube_texel_directions, sample_cube_bilinear


def orient_cube(local_cube: np.ndarray, rotation: np.ndarray, face_size: int) -> np.ndarray:
    """Cube (6, N, N, 3) in the bake frame from a cube in the probe's local frame and the local → bake rotation."""
    directions = cube_texel_directions(face_size).reshape(-1, 3)
    local = directions @ np.asarray(rotation, dtype=np.float64)  # Rᵀω for row vectors
    return sample_cube_bilinear(local_cube, local).reshape(6, face_size, face_size, -1).astype(np.float32)


def load_captured_cube(path: str, rotation: np.ndarray, face_size: int) -> np.ndarray:
    """Radiance cube (6, N, N, 3) float32 of a captured image at ``path`` oriented by ``rotation``.

    Raises:
        ImageError: the image is missing or unreadable (from :func:`bakery.environment.io.read_environment`).
    """
    image, _report = read_environment(path)
    rotation = np.asarray(rotation, dtype=np.float64)
    if np.allclose(rotation, np.eye(3), atol=1e-9):
        return resample_to_cube(image, face_size)
    return orient_cube(resample_to_cube(image, 2 * face_size), rotation, face_size)
