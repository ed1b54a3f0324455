"""Real spherical harmonics: basis, projection, convolution, rotation. Pure numpy."""

from bakery.sh.basis import evaluate_sh, evaluate_sh_basis, sh_bands, sh_count, sh_index
from bakery.sh.convolution import (
    convolve_zonal,
    cosine_lobe_band_factors,
    irradiance_sh_from_radiance_sh,
    zonal_to_sh,
)
from bakery.sh.projection import SHProjector, project_radiance_sh
from bakery.sh.rotation import rotate_sh, sh_rotation_matrix

__all__ = [
    "SHProjector",
    "convolve_zonal",
    "cosine_lobe_band_factors",
    "evaluate_sh",
    "evaluate_sh_basis",
    "irradiance_sh_from_radiance_sh",
    "project_radiance_sh",
    "rotate_sh",
    "sh_bands",
    "sh_count",
    "sh_index",
    "sh_rotation_matrix",
    "zonal_to_sh",
]
