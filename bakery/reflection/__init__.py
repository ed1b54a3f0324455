"""Glossy reflection from environment radiance: reference integration, DFG / Fresnel-tail tables, the split-sum
prefiltered chain and SH exponentials (seed 000). Pure numpy/scipy; one module per method.

Roughness is GGX α; views point towards the viewer; conventions of :mod:`bakery.conventions`.
"""

from bakery.reflection.reference import fdv_cosine_weights, integrate_reflection, reflected_radiance
from bakery.reflection.shexp import SHExpSettings, evaluate_shexp, fit_shexp
from bakery.reflection.splitsum import SplitSumSettings, evaluate_split_sum, prefilter_batch, prefilter_chain
from bakery.reflection.tables import DFGTables, compute_dfg_tables, lookup_table

__all__ = [
    "DFGTables",
    "SHExpSettings",
    "SplitSumSettings",
    "compute_dfg_tables",
    "evaluate_shexp",
    "evaluate_split_sum",
    "fdv_cosine_weights",
    "fit_shexp",
    "integrate_reflection",
    "lookup_table",
    "prefilter_batch",
    "prefilter_chain",
    "reflected_radiance",
]
