"""Spherical grids: cube maps, Fibonacci sets, exact texel solid angles, cube resampling, local frames.

Pure numpy. Orientation conventions are those of :mod:`bakery.conventions`.
"""

from bakery.sphere.cubemap import (
    cube_face_uv_to_direction,
    cube_texel_directions,
    cube_texel_solid_angles,
    direction_to_cube_face_uv,
    resample_cube,
    sample_cube_bilinear,
)
from bakery.sphere.fibonacci import fibonacci_directions
from bakery.sphere.grid import SphericalSamples
from bakery.sphere.sampling import orthonormal_frame

__all__ = [
    "SphericalSamples",
    "cube_face_uv_to_direction",
    "cube_texel_directions",
    "cube_texel_solid_angles",
    "direction_to_cube_face_uv",
    "fibonacci_directions",
    "orthonormal_frame",
    "resample_cube",
    "sample_cube_bilinear",
]
