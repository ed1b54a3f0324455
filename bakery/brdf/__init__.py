"""Microfacet BRDF pieces for glossy reflection: GGX D, height-correlated Smith V, Schlick F, and samplers.

Pure numpy. Roughness is GGX α everywhere (:mod:`bakery.conventions`); directions are unit 3-vectors.
"""

from bakery.brdf.ggx import (
    fresnel_schlick,
    ggx_distribution,
    ggx_lambda,
    reflect,
    smith_g1,
    smith_visibility_correlated,
)
from bakery.brdf.sampling import (
    ggx_ndf_pdf,
    reflection_pdf_from_half_pdf,
    sample_ggx_ndf,
    sample_ggx_vndf,
    to_local,
    to_world,
    vndf_pdf,
)
from bakery.sphere.sampling import orthonormal_frame  # re-exported: the frame lives in bakery.sphere

__all__ = [
    "fresnel_schlick",
    "ggx_distribution",
    "ggx_lambda",
    "ggx_ndf_pdf",
    "orthonormal_frame",
    "reflect",
    "reflection_pdf_from_half_pdf",
    "sample_ggx_ndf",
    "sample_ggx_vndf",
    "smith_g1",
    "smith_visibility_correlated",
    "to_local",
    "to_world",
    "vndf_pdf",
]
