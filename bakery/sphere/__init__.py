"""Spherical grids: cube maps, equirect and angular maps, Fibonacci sets, exact texel solid angles, resampling.

Pure numpy. Orientation conventions are those of :mod:`bakery.conventions`.
"""

from bakery.sphere.cubemap import (
    cube_face_uv_to_direction,
    cube_texel_directions,
    cube_texel_solid_angles,
    direction_to_cube_face_uv,
    sample_cube_bilinear,
)
from bakery.sphere.fibonacci import fibonacci_directions
from bakery.sphere.grid import SphericalSamples

__all__ = [
    "SphericalSamples",
    "cube_face_uv_to_direction",
    "cube_texel_directions",
    "cube_texel_solid_angles",
    "direction_to_cube_face_uv",
    "fibonacci_directions",
    "sample_cube_bilinear",
]
