"""Glossy reflection from environment radiance: reference integration, DFG / Fresnel-tail tables, the split-sum
prefiltered chain and its bandwidth chain, SH exponentials (seed 000), lights, the hybrid blend and the shared input
rules (:mod:`bakery.reflection.validation`). Pure numpy/scipy; one module per method.

Roughness is GGX α; views point towards the viewer; conventions of :mod:`bakery.conventions`.
"""

from bakery.reflection.reference import (
    fdv_cosine_weights,
    integrate_reflection,
    reflected_radiance,
)
from bakery.reflection.shexp import SHExpSettings, evaluate_shexp, fit_shexp
from bakery.reflection.splitsum import (
    BandwidthChainSettings,
    SplitSumSettings,
    evaluate_split_sum,
    kernel_order,
    prefilter_bandwidth_chain,
    prefilter_batch,
    prefilter_chain,
    prefilter_level,
)
from bakery.reflection.tables import DFGTables, compute_dfg_tables, lookup_table
from bakery.reflection.validation import check_alpha, clamp_view_to_horizon

__all__ = [
    "BandwidthChainSettings",
    "DFGTables",
    "SHExpSettings",
    "SplitSumSettings",
    "check_alpha",
    "clamp_view_to_horizon",
    "compute_dfg_tables",
    "evaluate_shexp",
    "evaluate_split_sum",
    "fdv_cosine_weights",
    "fit_shexp",
    "integrate_reflection",
    "kernel_order",
    "lookup_table",
    "prefilter_bandwidth_chain",
    "prefilter_batch",
    "prefilter_chain",
    "prefilter_level",
    "reflected_radiance",
]
