"""Glossy reflection from environment radiance: reference integration, DFG / Fresnel-tail tables, the split-sum
prefiltered chain and SH exponentials (seed 000). Pure numpy/scipy; one module per method.

Roughness is GGX α; views point towards the viewer; conventions of :mod:`bakery.conventions`.
"""

from bakery.reflection.reference import fdv_cosine_weights, integrate_reflection, reflected_radiance
from bakery.reflection.tables import DFGTables, compute_dfg_tables, lookup_table

__all__ = [
    "DFGTables",
    "compute_dfg_tables",
    "fdv_cosine_weights",
    "integrate_reflection",
    "lookup_table",
    "reflected_radiance",
]
