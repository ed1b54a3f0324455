"""Environment images: layouts, sanitising, resampling to the bake grid, and file input (OpenImageIO).

Only :mod:`bakery.environment.io` touches files; the rest is pure numpy.
"""

from bakery.environment.layouts import LAYOUTS, EnvironmentImage
from bakery.environment.resample import cube_samples, environment_samples, resample_to_cube
from bakery.environment.sanitize import SanitizeReport, sanitize_radiance

__all__ = [
    "LAYOUTS",
    "EnvironmentImage",
    "SanitizeReport",
    "cube_samples",
    "environment_samples",
    "resample_to_cube",
    "sanitize_radiance",
]
